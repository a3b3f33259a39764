"""Simulated fleets: a unit's parameters follow from its device id, a log's noise from the
device id and the session, so a device is the same physical unit in every session."""

from __future__ import annotations

import zlib

import numpy as np

from .unit import GyroUnit


def _seed(*parts: str) -> int:
    return zlib.crc32("\x1f".join(parts).encode())


def unit_for(device: str, session: str, *, seed000: bool = False, protocol: str = "turntable"
             ) -> tuple[GyroUnit, int]:
    """(the unit called ``device``, the noise seed of its log at ``session``). A sweep log
    needs the drift parameters of a :class:`SweepUnit` instead."""
    rng = np.random.default_rng(_seed(device))
    if protocol == "servo":  # the same physical unit as its turntable sessions
        from .servo import ServoProtocol, ServoUnit
        base = GyroUnit.random(rng)
        return ServoUnit.from_turntable_unit(base, ServoProtocol().temperature), _seed(device, session)
    if protocol == "sweep":
        from .sweep import SweepUnit
        return (SweepUnit.seed003() if seed000 else SweepUnit.random(rng)), _seed(device, session)
    unit = GyroUnit.seed000() if seed000 else GyroUnit.random(rng)
    return unit, _seed(device, session)
