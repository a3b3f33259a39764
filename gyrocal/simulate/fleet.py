"""Simulated fleets: a unit's parameters follow from its device id, a log's noise from the
device id and the session, so a device is the same physical unit in every session."""

from __future__ import annotations

import zlib

import numpy as np

from .unit import GyroUnit


def _seed(*parts: str) -> int:
    return zlib.crc32("\x1f".join(parts).encode())


def _servo_unit(rng, seed000: bool):
    """The same physical unit as the device's turntable sessions, on the servo."""
    from .servo import ServoProtocol, ServoUnit

    return ServoUnit.from_turntable_unit(GyroUnit.random(rng), ServoProtocol().temperature)


def _sweep_unit(rng, seed000: bool):
    from .sweep import SweepUnit

    return SweepUnit.seed003() if seed000 else SweepUnit.random(rng)


def _turntable_unit(rng, seed000: bool):
    return GyroUnit.seed000() if seed000 else GyroUnit.random(rng)


# a hand-rotation session is of the same physical unit as its turntable sessions
UNITS = {
    "turntable": _turntable_unit,
    "servo": _servo_unit,
    "sweep": _sweep_unit,
    "ferraris": _turntable_unit,
}


def unit_for(
    device: str, session: str, *, seed000: bool = False, protocol: str = "turntable"
) -> tuple[GyroUnit, int]:
    """(the unit called ``device``, the noise seed of its log at ``session``). A sweep log
    needs the drift parameters of a :class:`SweepUnit` instead."""
    return UNITS[protocol](np.random.default_rng(_seed(device)), seed000), _seed(device, session)
