"""The ``servo`` protocol of seed 001 (Sections II-B, III and IV), rendered as a rig log.

A servo (or a robot wrist) turns the unit at a constant commanded speed through a whole
number of revolutions about each sensor axis, both ways (the six-observation G-optimal
design, Fig. 1), with pauses in between. The unit is mounted by hand, so every mount tilts
the rotation axis a few degrees off the sensor axis (a new tilt per mount; the two directions
about one axis share a mount, as when the servo simply reverses, unless
``remount_every_rotation``); re-mounting is real motion while the servo stands still
(``ref_rate`` 0). The servo's actual speed ripples around the command
(Figs 7-8) but each revolution takes exactly its nominal time, so the ripple is periodic in
the revolution and averages out over a whole one (Section II-B).

Error model, as Eq 3 and Algorithm 1 use it (not Eq 1 as printed; see
:mod:`gyrocal.protocols.servo.fit`): the true rate on axis j is ``g_j = k_j (m_j + b_j)``, so the raw
output is ``m_j = g_j / k_j - b_j`` plus white noise. In the calibration file's convention,
``w = K w_true + B`` with ``K = diag(1/k)`` and ``B = -b`` (converted to deg/s).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter

from ..io.errors import ConfigError
from ..io.log import MOUNTS
from .turntable import HandlingTruth

DEG = 180.0 / math.pi
DIRECTIONS = MOUNTS  # the G-optimal design, seed 001 Section II-B


@dataclass(frozen=True)
class ServoUnit:
    """Scale factors ``k`` (1) and biases ``b`` (rad/s) in seed 001's convention, g = k (m + b)."""

    k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        k = np.asarray(self.k, dtype=float)
        b = np.asarray(self.b, dtype=float)
        if k.shape != (3,) or b.shape != (3,) or not (np.isfinite(k).all() and np.isfinite(b).all()):
            raise ConfigError(
                f"servo unit needs three finite k and three finite b; got k={self.k!r}, b={self.b!r}"
            )
        if (k <= 0).any():
            raise ConfigError(f"servo unit scale factors must be positive; got k={self.k!r}")
        object.__setattr__(self, "k", tuple(float(x) for x in k))
        object.__setattr__(self, "b", tuple(float(x) for x in b))

    @property
    def K(self) -> np.ndarray:
        """3x3 scale matrix of the file convention ``w = K w_true + B``: diag(1/k)."""
        return np.diag(1.0 / np.asarray(self.k))

    @property
    def B(self) -> np.ndarray:
        """Bias of the file convention in deg/s: -b."""
        return -np.asarray(self.b) * DEG

    def measure(self, g: np.ndarray) -> np.ndarray:
        """Noise-free raw output (rad/s) for true rates ``g`` (..., 3) in rad/s."""
        return np.asarray(g) / np.asarray(self.k) - np.asarray(self.b)

    @classmethod
    def from_turntable_unit(cls, unit, temperature: float) -> ServoUnit:
        """The servo model of a turntable-simulated unit (:class:`GyroUnit`) at
        ``temperature``: ``k = 1 / diag K(T)``, ``b = −B(T)`` (rad/s). Its cross-axis terms
        are left out (the six-parameter model has none), so a device calibrated on both rigs
        is one physical unit up to them."""
        K, B = unit.K(temperature), unit.B(temperature)
        return cls(tuple(1.0 / np.diag(K)), tuple(-np.radians(B)))

    @classmethod
    def random(cls, rng: np.random.Generator, extreme: bool = False) -> ServoUnit:
        """A unit drawn as in Section III: k ~ U(0.8, 1.2), b ~ U(-0.1, 0.1) rad/s (III-A);
        ``extreme``: k ~ U(1.2, 2.0), |b| ~ U(0.1, 0.2) rad/s with a random sign (III-C)."""
        k, b = draw_parameters(rng, 1, extreme=extreme)
        return cls(tuple(k[0]), tuple(b[0]))

    def with_effects(self, effects: dict | None) -> ServoUnit:
        """The six-parameter servo model has no further effects; any requested is refused."""
        if effects:
            raise ConfigError(
                f"the servo unit model has no effects beyond k and b; got {', '.join(map(str, effects))}"
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return {"k": list(self.k), "b": list(self.b), "b_unit": "rad/s", "convention": "g = k (m + b)"}

    @classmethod
    def from_dict(cls, d: dict) -> ServoUnit:
        return cls(tuple(d["k"]), tuple(d["b"]))


def draw_parameters(
    rng: np.random.Generator, n: int, *, extreme: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` parameter sets (k (n, 3), b (n, 3) rad/s) from seed 001's Section III ranges."""
    if extreme:
        k = rng.uniform(1.2, 2.0, (n, 3))
        b = rng.uniform(0.1, 0.2, (n, 3)) * rng.choice((-1.0, 1.0), (n, 3))
    else:
        k = rng.uniform(0.8, 1.2, (n, 3))
        b = rng.uniform(-0.1, 0.1, (n, 3))
    return k, b


def direction_axis(direction: str) -> tuple[int, float]:
    if direction not in DIRECTIONS:
        raise ConfigError(f"rotation direction {direction!r} is not one of {' '.join(DIRECTIONS)}")
    return "xyz".index(direction[1]), (1.0 if direction[0] == "+" else -1.0)


def tilted_axes(axis: np.ndarray, tilt: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit rotation axes (..., 3) in the sensor frame: sensor axis ``axis`` (0-2) tilted by
    ``tilt`` (rad) toward the azimuth ``azimuth`` (rad) in the plane of the other two axes."""
    axis = np.asarray(axis)
    tilt, azimuth = np.asarray(tilt, dtype=float), np.asarray(azimuth, dtype=float)
    eye = np.eye(3)
    return (
        np.cos(tilt)[..., None] * eye[axis]
        + (np.sin(tilt) * np.cos(azimuth))[..., None] * eye[(axis + 1) % 3]
        + (np.sin(tilt) * np.sin(azimuth))[..., None] * eye[(axis + 2) % 3]
    )


@dataclass(frozen=True)
class ServoProtocol:
    """Schedule of the servo rig. Speeds in rad/s (seed 001's unit), times in s.

    Defaults follow the paper's experiment (Section IV-A): 60 deg/s, one revolution per
    rotation, 3 s pauses, 200 Hz (Section III-A), the lower noise level 0.035 rad/s per
    sample and a 5 % speed ripple (Section III-A, assumption 4), 22 °C room.
    """

    speed: float = math.pi / 3.0  # rad/s (60 deg/s)
    revolutions: int = 1  # whole revolutions per rotation
    pause_s: float = 3.0
    sample_rate: float = 200.0
    noise: float = 0.035  # rad/s, white, std per sample (paper: 0.035 or 0.2)
    ripple: float = 0.05  # RMS speed ripple as a share of the speed
    ripple_harmonics: int = 3  # ripple at the revolution frequency and its harmonics
    mount_error_deg: float = 5.0  # hand mounting: tilt drawn from U(0, this) per mount
    temperature: float = 22.0  # °C, constant (the paper's room)
    temp_noise: float = 0.02  # °C, sensor
    order: tuple[str, ...] = DIRECTIONS
    accel_s: float = 0.3  # servo ramp to and from speed (not part of a revolution)
    handling_s: float = 4.0  # re-mounting by hand when the rotation axis changes
    remount_every_rotation: bool = False  # else the ± pair of an axis shares one mount
    mount_column: bool = False

    def __post_init__(self):
        problems = []
        if not (math.isfinite(self.speed) and self.speed > 0):
            problems.append(f"speed must be a positive rad/s value, got {self.speed!r}")
        if int(self.revolutions) != self.revolutions or self.revolutions < 1:
            problems.append(f"revolutions must be a whole number >= 1, got {self.revolutions!r}")
        if not self.sample_rate > 0:
            problems.append(f"sample_rate must be positive, got {self.sample_rate!r}")
        for name in ("pause_s", "noise", "ripple", "mount_error_deg", "accel_s", "handling_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                problems.append(f"{name} must be a finite value >= 0, got {value!r}")
        if not self.order:
            problems.append("order must name at least one rotation")
        if problems:
            raise ConfigError("servo protocol: " + "; ".join(problems))
        object.__setattr__(self, "order", tuple(self.order))
        for d in self.order:
            direction_axis(d)

    @property
    def revolution_s(self) -> float:
        return 2.0 * math.pi / self.speed

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


class RotationTruth(TypedDict):
    """One rotation of the servo: its direction, mount, times and the truth of its motion."""

    index: int
    direction: str
    mount: str
    t_start: float
    t_end: float
    samples: int
    revolutions: int
    speed_rad_s: float
    axis: list[float]  # the tilted rotation axis in the sensor frame
    tilt_deg: float
    ripple: dict[str, list[float]]  # the speed ripple's harmonics, amplitudes and phases


class ServoTruth(TypedDict):
    """The ground truth of a servo log's schedule (:func:`render_servo`)."""

    rotations: list[RotationTruth]
    handling: list[HandlingTruth]
    rows: int
    units: dict[str, str]  # by quantity


def _handling_motion(rng: np.random.Generator, n: int, fs: float) -> np.ndarray:
    """A person turning the unit in hand (rad/s): smooth swings per axis plus tremor."""
    tau = np.arange(n) / fs
    duration = n / fs
    amp = np.radians(rng.uniform(20.0, 120.0, (3, 3))) * rng.choice((-1.0, 1.0), (3, 3))
    centre = rng.uniform(0.2, 0.8, (3, 3)) * duration
    width = rng.uniform(0.03, 0.08, (3, 3)) * duration
    swings = amp * np.exp(-0.5 * ((tau[:, None, None] - centre) / width) ** 2)  # (n, axis, swing)
    w = swings.sum(axis=2)
    a = math.exp(-2 * math.pi * 8.0 / fs)  # tremor: white noise low-passed at 8 Hz
    w += lfilter([1 - a], [1, -a], rng.normal(0.0, math.radians(3.0), (n, 3)), axis=0)
    edge = min(0.15 * duration, 5.0)
    ramp = np.clip(np.minimum(tau, duration - tau) / max(edge, 1e-9), 0.0, 1.0)
    return w * (np.sin(0.5 * np.pi * ramp) ** 2)[:, None]


def _ripple(
    rng: np.random.Generator, tau: np.ndarray, period: float, rms: float, harmonics: int
) -> tuple[np.ndarray, dict[str, list[float]]]:
    """Relative speed error, periodic in the revolution: its integral over any window one
    revolution long is zero, so each revolution keeps its exact time (Section II-B)."""
    h = np.arange(1, max(harmonics, 1) + 1)
    weights = rng.uniform(0.2, 1.0, h.size) / h
    phases = rng.uniform(0.0, 2 * math.pi, h.size)
    amps = weights / np.sqrt(np.sum(weights**2) / 2.0) * rms  # RMS of the sum = rms
    s = (amps * np.sin(2 * math.pi * h * tau[:, None] / period + phases)).sum(axis=1)
    return s, {"harmonics": h.tolist(), "amplitudes": amps.tolist(), "phases": phases.tolist()}


def render_servo(
    protocol: ServoProtocol, unit: ServoUnit, rng: np.random.Generator, path, *, t0: float = 0.0
) -> ServoTruth:
    """Write the log to ``path`` (Parquet, contract section 1) and return the truth of the
    schedule: per rotation its direction, the tilted axis (sensor frame), times and speed."""
    log = _ServoSchedule(protocol, t0)
    current_axis = None
    axis_vec = None
    tilt = 0.0
    for i, direction in enumerate(protocol.order):
        axis, _ = direction_axis(direction)
        mount = "+" + "xyz"[axis]
        if axis != current_axis or (protocol.remount_every_rotation and i > 0):
            if current_axis is not None:
                log.still(protocol.pause_s, "+" + "xyz"[current_axis])
                log.remount(rng, "+" + "xyz"[current_axis], mount)
            log.still(protocol.pause_s, mount)
            tilt, axis_vec = _hand_mounted_axis(protocol, rng, axis)
            current_axis = axis
        elif i > 0:
            log.still(protocol.pause_s, mount)
        log.rotate(rng, i, direction, mount, axis_vec, tilt)
    log.still(protocol.pause_s, "+" + "xyz"[current_axis])
    rows = _write_servo_log(protocol, unit, rng, log, path)
    return ServoTruth(
        rotations=log.rotations,
        handling=log.handling,
        rows=rows,
        units={"gyro": "deg/s", "ref_rate": "deg/s", "speed_rad_s": "rad/s", "b": "rad/s"},
    )


def _hand_mounted_axis(
    protocol: ServoProtocol, rng: np.random.Generator, axis: int
) -> tuple[float, np.ndarray]:
    """A new hand mount about sensor axis ``axis``: its tilt (rad, drawn up to the protocol's
    mount error) and the rotation axis it tilts to, in the sensor frame."""
    tilt = math.radians(rng.uniform(0.0, protocol.mount_error_deg))
    azimuth = rng.uniform(0.0, 2 * math.pi)
    return tilt, tilted_axes(np.array(axis), np.array(tilt), np.array(azimuth))


@dataclass
class _ServoSchedule:
    """The log's phases as they are scheduled, each the commanded rate (rad/s, (n,)), the
    true rate in the sensor frame (rad/s, (n, 3)) and the mount's code in MOUNTS (n,); with
    the truth of every rotation and re-mount."""

    protocol: ServoProtocol
    t0: float
    ref: list[np.ndarray] = field(default_factory=list)
    true: list[np.ndarray] = field(default_factory=list)
    mount: list[np.ndarray] = field(default_factory=list)
    rotations: list[RotationTruth] = field(default_factory=list)
    handling: list[HandlingTruth] = field(default_factory=list)
    pos: int = 0  # samples scheduled so far

    def add(self, ref: np.ndarray, true: np.ndarray, mount: str) -> None:
        self.ref.append(ref)
        self.true.append(true)
        self.mount.append(np.full(len(ref), MOUNTS.index(mount), dtype=np.int8))
        self.pos += len(ref)

    def samples(self, seconds: float) -> int:
        return max(int(round(seconds * self.protocol.sample_rate)), 1)

    def time(self, pos: int) -> float:
        return self.t0 + pos / self.protocol.sample_rate

    def still(self, seconds: float, mount: str) -> None:
        n = self.samples(seconds)
        self.add(np.zeros(n), np.zeros((n, 3)), mount)

    def remount(self, rng: np.random.Generator, mount_from: str, mount_to: str) -> None:
        """The unit turned by hand from one mount to the next while the servo stands still;
        the second half of the phase carries the new mount's code."""
        n = self.samples(self.protocol.handling_s)
        t_first = self.time(self.pos)
        self.add(np.zeros(n), _handling_motion(rng, n, self.protocol.sample_rate), mount_from)
        self.mount[-1][n // 2 :] = MOUNTS.index(mount_to)
        self.handling.append(
            HandlingTruth(
                t_start=t_first, t_end=self.time(self.pos - 1), mount_from=mount_from, mount_to=mount_to
            )
        )

    def rotate(
        self,
        rng: np.random.Generator,
        index: int,
        direction: str,
        mount: str,
        axis_vec: np.ndarray,
        tilt: float,
    ) -> None:
        """One rotation ``direction`` about the mount's tilted axis ``axis_vec``: the ramp up,
        whole revolutions at the commanded speed with its ripple (drawn from ``rng``), the
        ramp down."""
        protocol, fs = self.protocol, self.protocol.sample_rate
        _, sign = direction_axis(direction)
        direction_vec = sign * axis_vec
        w_speed = protocol.speed
        period = protocol.revolution_s
        n_rot = int(round(protocol.revolutions * period * fs))
        n_acc = int(round(protocol.accel_s * fs))
        if n_acc:
            ramp = np.linspace(0.0, w_speed, n_acc + 2)[1:-1]  # never reaches the command
            self.add(sign * ramp, ramp[:, None] * direction_vec, mount)
        tau = np.arange(n_rot) / fs
        ripple, ripple_truth = _ripple(rng, tau, period, protocol.ripple, protocol.ripple_harmonics)
        actual = w_speed * (1.0 + ripple)
        t_first = self.time(self.pos)
        self.add(np.full(n_rot, sign * w_speed), actual[:, None] * direction_vec, mount)
        self.rotations.append(
            RotationTruth(
                index=index,
                direction=direction,
                mount=mount,
                t_start=t_first,
                t_end=self.time(self.pos - 1),
                samples=n_rot,
                revolutions=int(protocol.revolutions),
                speed_rad_s=w_speed,
                axis=[float(x) for x in direction_vec],
                tilt_deg=math.degrees(tilt),
                ripple=ripple_truth,
            )
        )
        if n_acc:
            ramp = np.linspace(w_speed, 0.0, n_acc + 2)[1:-1]
            self.add(sign * ramp, ramp[:, None] * direction_vec, mount)


def _write_servo_log(
    protocol: ServoProtocol, unit: ServoUnit, rng: np.random.Generator, log: _ServoSchedule, path
) -> int:
    """The unit's output over the schedule with its white noise, and the temperature
    sensor's reading, drawn from ``rng``: written to ``path``; returns the row count."""
    fs = protocol.sample_rate
    ref = np.concatenate(log.ref)
    g = np.concatenate(log.true)
    n = len(ref)
    t = log.t0 + np.arange(n) / fs
    raw = unit.measure(g) + rng.normal(0.0, protocol.noise, (n, 3))
    gyro = (raw * DEG).astype(np.float32)
    temp = protocol.temperature + rng.normal(0.0, protocol.temp_noise, n)
    temp = (np.round(temp * 256.0) / 256.0).astype(np.float32)
    cols = {
        "t": pa.array(t),
        "gyro_x": pa.array(gyro[:, 0]),
        "gyro_y": pa.array(gyro[:, 1]),
        "gyro_z": pa.array(gyro[:, 2]),
        "temp": pa.array(temp),
        "ref_rate": pa.array(ref * DEG),
    }
    if protocol.mount_column:
        cols["mount"] = pa.DictionaryArray.from_arrays(
            pa.array(np.concatenate(log.mount)), pa.array(MOUNTS, type=pa.string())
        )
    pq.write_table(pa.table(cols), path)
    return n
