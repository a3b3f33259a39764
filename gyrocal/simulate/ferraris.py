"""The hand-rotation (Ferraris) protocol rendered as a log: the unit lies still on each of
its six faces, is carried from face to face by hand, and is turned one full turn about each
sensor axis with that axis up, against a guide.

The attitude is integrated exactly: every move is a rotation about one body-fixed axis (a
face-to-face carry about the axis that takes one face to the next, a turn about the up axis
tilted by how unevenly the unit sits), so the specific force the accelerometer and the
g-sensitivity see is gravity rotated into the body, and a turn's true angle is what its
rate integrates to. The hand's guide error makes the true angle differ from 360°; the
truth records it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..io.log import FACES
from .unit import Electronics, GyroUnit


def _rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) about a unit ``axis`` by ``angle`` (rad, (n,))."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _up(label: str) -> np.ndarray:
    v = np.zeros(3)
    v["xyz".index(label[0])] = 1.0 if label[2] == "p" else -1.0
    return v


def _bell(n: int) -> np.ndarray:
    """A hand's smooth speed profile: fraction of the move done at each of n samples."""
    s = (np.arange(n) + 1) / n
    return s - np.sin(2 * np.pi * s) / (2 * np.pi)


@dataclass(frozen=True)
class FerrarisProtocol:
    """One hand-rotation session's timing and the hand's imperfections."""

    sample_rate: float = 102.4
    face_s: float = 6.0
    carry_s: float = 2.5
    turn_s: float = 3.0
    rest_s: float = 2.0
    steps: int = 1  # a turn in this many equal steps, resting between
    tilt_deg: float = 0.5  # the unit's tilt on the table (rms per axis)
    guide_error_deg: float = 0.5  # the hand's angle error against the guide (rms)
    temperature: float | None = 25.0  # None: no temp column
    sections: bool = False  # write the annotation column
    accel_columns: bool = True

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class FaceTruth(TypedDict):
    """A face the unit lay still on, up (a name of FACES), and when."""

    face: str
    t_start: float
    t_end: float


class TurnTruth(TypedDict):
    """A turn about a sensor axis: its true angle and rotation axis (sensor frame), and when."""

    axis: str
    true_angle_deg: float
    rotation_axis: list[float]
    t_start: float
    t_end: float


class FerrarisTruth(TypedDict):
    """The ground truth of a hand-rotation session (:func:`render_ferraris`)."""

    faces: list[FaceTruth]
    turns: list[TurnTruth]
    rows: int


def render_ferraris(rig: FerrarisProtocol, unit: GyroUnit, rng: np.random.Generator, path) -> FerrarisTruth:
    """Write the session to ``path`` and return its truth (faces, turns, true angles)."""
    session = _HandSession(rig)
    session.still(1.0)
    faces = [session.lie_on(face) for face in FACES]
    turns = [session.turn(rng, axis_name) for axis_name in "xyz"]
    n = _write_ferraris_log(rig, unit, rng, session, path)
    return {"faces": faces, "turns": turns, "rows": int(n)}


class _HandSession:
    """The session's motion as the hand makes it, sample by sample: the body-to-world
    attitude (world z up; gravity's specific force is +z in the world), the body rate
    (deg/s) and each sample's section label ("" outside one)."""

    def __init__(self, rig: FerrarisProtocol):
        self.rig = rig
        self.R = np.eye(3)  # the attitude now
        self.att: list[np.ndarray] = []
        self.w_body: list[np.ndarray] = []
        self.label: list[str] = []

    def samples(self, seconds: float) -> int:
        return max(2, int(round(seconds * self.rig.sample_rate)))

    def scheduled(self) -> int:
        """Samples so far."""
        return sum(len(a) for a in self.att)

    def still(self, seconds: float, name: str = "") -> None:
        k = self.samples(seconds)
        self.att.append(np.repeat(self.R[None], k, axis=0))
        self.w_body.append(np.zeros((k, 3)))
        self.label.extend([name] * k)

    def move(self, axis_body: np.ndarray, angle_rad: float, seconds: float, name: str = "") -> None:
        """A rotation about a body-fixed axis, bell-shaped in speed."""
        k = self.samples(seconds)
        frac = _bell(k)
        turns = _rodrigues(axis_body, angle_rad * frac)
        self.att.append(self.R[None] @ turns)
        rate = np.diff(np.r_[0.0, frac]) * self.rig.sample_rate * angle_rad
        self.w_body.append(np.outer(rate, axis_body) * 180.0 / math.pi)
        self.label.extend([name] * k)
        self.R = self.att[-1][-1]

    def carry_to(self, target_up: np.ndarray) -> None:
        """Turn the unit so that ``target_up`` (body) points up, about the one axis that does."""
        current_up = self.R.T @ np.array([0.0, 0.0, 1.0])
        axis = np.cross(target_up, current_up)
        s = np.linalg.norm(axis)
        if s > 1e-9:
            self.move(axis / s, math.atan2(s, float(current_up @ target_up)), self.rig.carry_s)
        elif current_up @ target_up < 0:  # upside down: half a turn about a level axis
            level = np.cross(target_up, [1.0, 0.0, 0.0] if abs(target_up[0]) < 0.9 else [0.0, 1.0, 0.0])
            self.move(level / np.linalg.norm(level), math.pi, self.rig.carry_s)

    def lie_on(self, face: str) -> FaceTruth:
        """Carry the unit to ``face`` up and let it lie still; the face's truth."""
        fs = self.rig.sample_rate
        self.carry_to(_up(face))
        k0 = self.scheduled()
        self.still(self.rig.face_s, face)
        return {"face": face, "t_start": k0 / fs, "t_end": (k0 + self.samples(self.rig.face_s) - 1) / fs}

    def turn(self, rng: np.random.Generator, axis_name: str) -> TurnTruth:
        """One full turn about the sensor axis ``axis_name`` with that axis up, against the
        guide: the axis tilted as the unit sits, the angle off by the hand's error (both
        drawn from ``rng``); the turn's truth."""
        rig, fs = self.rig, self.rig.sample_rate
        self.carry_to(_up(f"{axis_name}_p"))
        self.still(rig.rest_s)
        tilt = np.deg2rad(rig.tilt_deg) * rng.normal(size=3)
        axis = _up(f"{axis_name}_p") + tilt
        axis["xyz".index(axis_name)] = 1.0  # tilted off the sensor axis by the others
        axis /= np.linalg.norm(axis)
        sign = rng.choice((-1.0, 1.0))
        true_angle = sign * (360.0 + rig.guide_error_deg * rng.normal())
        k0 = self.scheduled()
        for step in range(rig.steps):
            self.move(axis, np.deg2rad(true_angle) / rig.steps, rig.turn_s / rig.steps, f"{axis_name}_rot")
            if step + 1 < rig.steps:
                self.still(rig.rest_s / 2, f"{axis_name}_rot")
        k1 = self.scheduled()
        self.still(rig.rest_s)
        return {
            "axis": axis_name,
            "true_angle_deg": float(true_angle),
            "rotation_axis": axis.tolist(),
            "t_start": k0 / fs,
            "t_end": (k1 - 1) / fs,
        }


def _write_ferraris_log(
    rig: FerrarisProtocol, unit: GyroUnit, rng: np.random.Generator, session: _HandSession, path
) -> int:
    """The unit's output over the session, with the temperature sensor's and the
    accelerometer's noise drawn from ``rng``: written to ``path``; returns the row count."""
    fs = rig.sample_rate
    attitude = np.concatenate(session.att)
    w_true = np.concatenate(session.w_body)
    n = len(w_true)
    t = np.arange(n) / fs
    force = np.einsum("nji,j->ni", attitude, np.array([0.0, 0.0, 1.0]))  # R^T z, in g
    temp = np.full(n, rig.temperature if rig.temperature is not None else unit.t_ref)
    gyro = Electronics(unit, fs, rng).measure(w_true, temp, force)
    cols = {"t": pa.array(t), **{f"gyro_{a}": pa.array(gyro[:, i]) for i, a in enumerate("xyz")}}
    if rig.temperature is not None:
        sensor = temp + rng.normal(0.0, 0.02, n)
        cols["temp"] = pa.array(sensor.astype(np.float32))
    if rig.accel_columns:
        accel = force + rng.normal(0.0, unit.accel_noise, (n, 3))
        for i, a in enumerate("xyz"):
            cols[f"accel_{a}"] = pa.array(accel[:, i].astype(np.float32))
    if rig.sections:
        cols["section"] = pa.array([s or None for s in session.label], type=pa.string()).dictionary_encode()
    pq.write_table(pa.table(cols), path)
    return n
