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

    def to_dict(self) -> dict:
        return asdict(self)


def render_ferraris(rig: FerrarisProtocol, unit: GyroUnit, rng: np.random.Generator, path) -> dict:
    """Write the session to ``path`` and return its truth (faces, turns, true angles)."""
    fs = rig.sample_rate
    n_of = lambda s: max(2, int(round(s * fs)))  # noqa: E731
    # body-to-world attitude; world z up; gravity's specific force is +z in the world
    R = np.eye(3)
    att, w_body, label = [], [], []

    def still(seconds, name=""):
        k = n_of(seconds)
        att.append(np.repeat(R[None], k, axis=0))
        w_body.append(np.zeros((k, 3)))
        label.extend([name] * k)

    def move(axis_body, angle_rad, seconds, name=""):
        """A rotation about a body-fixed axis, bell-shaped in speed."""
        nonlocal R
        k = n_of(seconds)
        frac = _bell(k)
        turns = _rodrigues(axis_body, angle_rad * frac)
        att.append(R[None] @ turns)
        rate = np.diff(np.r_[0.0, frac]) * fs * angle_rad
        w_body.append(np.outer(rate, axis_body) * 180.0 / math.pi)
        label.extend([name] * k)
        R = att[-1][-1]

    def carry_to(target_up: np.ndarray):
        """Turn the unit so that ``target_up`` (body) points up, about the one axis that does."""
        current_up = R.T @ np.array([0.0, 0.0, 1.0])
        axis = np.cross(target_up, current_up)
        s = np.linalg.norm(axis)
        if s > 1e-9:
            move(axis / s, math.atan2(s, float(current_up @ target_up)), rig.carry_s)
        elif current_up @ target_up < 0:  # upside down: half a turn about a level axis
            level = np.cross(target_up, [1.0, 0.0, 0.0] if abs(target_up[0]) < 0.9 else [0.0, 1.0, 0.0])
            move(level / np.linalg.norm(level), math.pi, rig.carry_s)

    faces, turns = [], []
    still(1.0)
    for face in FACES:
        carry_to(_up(face))
        k0 = sum(len(a) for a in att)
        still(rig.face_s, face)
        faces.append({"face": face, "t_start": k0 / fs, "t_end": (k0 + n_of(rig.face_s) - 1) / fs})
    for axis_name in "xyz":
        carry_to(_up(f"{axis_name}_p"))
        still(rig.rest_s)
        tilt = np.deg2rad(rig.tilt_deg) * rng.normal(size=3)
        axis = _up(f"{axis_name}_p") + tilt
        axis["xyz".index(axis_name)] = 1.0  # tilted off the sensor axis by the others
        axis /= np.linalg.norm(axis)
        sign = rng.choice((-1.0, 1.0))
        true_angle = sign * (360.0 + rig.guide_error_deg * rng.normal())
        k0 = sum(len(a) for a in att)
        for _ in range(rig.steps):
            move(axis, np.deg2rad(true_angle) / rig.steps, rig.turn_s / rig.steps, f"{axis_name}_rot")
            if _ + 1 < rig.steps:
                still(rig.rest_s / 2, f"{axis_name}_rot")
        k1 = sum(len(a) for a in att)
        turns.append(
            {
                "axis": axis_name,
                "true_angle_deg": float(true_angle),
                "rotation_axis": axis.tolist(),
                "t_start": k0 / fs,
                "t_end": (k1 - 1) / fs,
            }
        )
        still(rig.rest_s)

    attitude = np.concatenate(att)
    w_true = np.concatenate(w_body)
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
        cols["section"] = pa.array([s or None for s in label], type=pa.string()).dictionary_encode()
    pq.write_table(pa.table(cols), path)
    return {"faces": faces, "turns": turns, "rows": int(n)}
