"""Simulated fleets: a unit's parameters follow from its device id, a log's noise from the
device id and the session, so a device is the same physical unit in every session."""

from __future__ import annotations

import zlib

import numpy as np

from .unit import GyroUnit


def _seed(*parts: str) -> int:
    return zlib.crc32("\x1f".join(parts).encode())


def unit_for(device: str, session: str, *, seed000: bool = False) -> tuple[GyroUnit, int]:
    """(the unit called ``device``, the noise seed of its log at ``session``)."""
    unit = GyroUnit.seed000() if seed000 else GyroUnit.random(np.random.default_rng(_seed(device)))
    return unit, _seed(device, session)
