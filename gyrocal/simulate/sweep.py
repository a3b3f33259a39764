"""The ``sweep`` protocol of seed 003 (Section 3.1, steps 1-4), rendered as a rig log.

The chamber starts stable at ``start_temp``, then runs through ``segments``: each a ramp to a
target at a rate, followed by a hold. Like the paper's chamber, the ramp may be a staircase of
small jumps (``step_c`` every ``step_c / rate``: 0.1 °C every 20 s is 18 °C/h, Eq 20 and 25).
The die follows the chamber through a first-order lag; the unit's own sensor reads the die.
The rig turns at one constant rate about one axis for the whole log (0 in Section 3.2; 10, 5
and 20 deg/s about x, y and z in Section 4).

Output model (seed 003, Eq 16 with Eq 17's split into bias, trend and random error):

    w = K w_true + B0 + c1 ΔT + c2 ΔT² + c_r dT/dt + v,        ΔT = T − T0

T is the die temperature and T0 the unit's reference temperature ``t_ref``. The paper counts
ΔT from the stable temperature a sweep starts from (Eq 6, Section 3.2 step 2: "initial value
... set as the reference temperature"), −40 °C in its sweeps, so ``t_ref`` defaults to that.
A sweep that starts elsewhere sees the same drift as a quadratic in its own ΔT with other
coefficients. ``c_r`` (deg/s per °C/min) is a thermal-gradient term outside both of the
paper's models, zero unless set; v is white noise of ``noise`` deg/s per sample.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter

from ..io.errors import ConfigError
from ..io.log import MOUNTS, RigLog

Vec3 = tuple[float, float, float]


def _vec(value, name: str) -> Vec3:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ConfigError(f"SweepUnit.{name} must be 3 finite numbers, got {value!r}")
    return tuple(float(x) for x in arr)


@dataclass(frozen=True)
class SweepUnit:
    """Drift parameters of one unit. Rates in deg/s, temperatures in °C."""

    bias: Vec3 = (0.0, 0.0, 0.0)  # B0 at T = t_ref
    drift_dT: Vec3 = (0.0, 0.0, 0.0)  # c1, deg/s/°C
    drift_dT2: Vec3 = (0.0, 0.0, 0.0)  # c2, deg/s/°C²
    drift_rate: Vec3 = (0.0, 0.0, 0.0)  # c_r, deg/s per °C/min of the die
    t_ref: float = -40.0  # T0 that ΔT counts from
    noise: Vec3 = (0.04, 0.04, 0.04)  # white, deg/s per sample at the log's rate
    K: tuple[Vec3, Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    temp_noise: float = 0.03  # °C per sample, the temperature sensor

    def __post_init__(self):
        for f in ("bias", "drift_dT", "drift_dT2", "drift_rate", "noise"):
            object.__setattr__(self, f, _vec(getattr(self, f), f))
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise ConfigError(f"SweepUnit.K must be a finite 3x3 matrix, got {self.K!r}")
        object.__setattr__(self, "K", tuple(tuple(float(x) for x in row) for row in K))
        if min(self.noise) < 0 or not (np.isfinite(self.temp_noise) and self.temp_noise >= 0):
            raise ConfigError("SweepUnit noise and temp_noise must be >= 0")

    def drift(self, temp, temp_rate=0.0) -> np.ndarray:
        """B0 + c1 ΔT + c2 ΔT² + c_r dT/dt (deg/s), shape (..., 3), for die temperatures
        ``temp`` (°C) and rates ``temp_rate`` (°C/min)."""
        dT = np.asarray(temp, dtype=float)[..., None] - self.t_ref
        rate = np.asarray(temp_rate, dtype=float)[..., None]
        return (
            np.asarray(self.bias)
            + dT * (np.asarray(self.drift_dT) + dT * np.asarray(self.drift_dT2))
            + rate * np.asarray(self.drift_rate)
        )

    def with_effects(self, effects: dict | None) -> SweepUnit:
        """The sweep unit has no optional effects beyond its fields; only none is accepted."""
        if effects:
            raise ConfigError(
                f"the sweep simulator has no effect {next(iter(effects))!r}; set SweepUnit fields instead"
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return {k: (np.asarray(v).tolist() if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> SweepUnit:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f"unknown SweepUnit field {unknown[0]!r}; known: {', '.join(sorted(known))}")

        def tup(v):
            return tuple(tup(x) for x in v) if isinstance(v, list) else v

        return cls(**{k: tup(v) for k, v in d.items()})

    @classmethod
    def random(cls, rng: np.random.Generator, **overrides) -> SweepUnit:
        """A production unit of L3GD20 class: zero-rate level within a few deg/s, a drift of
        the datasheet's ±0.03 deg/s/°C size, curvature of 1e-4 deg/s/°C² size."""
        K = np.eye(3) + rng.normal(0.0, 2e-3, (3, 3))
        base = dict(
            bias=tuple(rng.normal(0.0, 3.0, 3)),
            drift_dT=tuple(rng.normal(0.0, 0.02, 3)),
            drift_dT2=tuple(rng.normal(0.0, 1e-4, 3)),
            noise=tuple(rng.uniform(0.03, 0.08, 3)),
            K=tuple(map(tuple, K)),
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def seed003(cls, device: str = "L3GD20", **overrides) -> SweepUnit:
        """Sizes for seed 003's two gyros, over its −40 → 85 °C sweep (:func:`SweepProtocol.seed003`).

        The paper gives no drift coefficients, only bias stabilities (Eq 31). The sizes here
        are solved from them, over the die temperatures of ``SweepProtocol.seed003()``:
        per-sample noise² = the modified model's BS (BS3 in Tables 4-7, BS2 in Table 2); c2
        such that a line in ΔT misses c2·ΔT² by the conventional model's BS2 − BS3 (Tables
        4-7; Table 2 has no conventional column, so the L3GD20 gets the same 1e-4 size);
        c1 a datasheet-sized slope (α = ±0.03 deg/s/°C); B0 the smaller root that makes the
        raw BS1 match. Targets are the means of experiments 2-5 (the first stands apart in
        both tables). "I3G4250D" is the unit of Section 4, "L3GD20" the one of
        Section 3.2 (all three axes alike; Table 2 pools them).
        """
        sizes = {
            "L3GD20": dict(
                bias=(-4.014, -4.014, -4.014),
                drift_dT=(-0.030, -0.030, -0.030),
                drift_dT2=(1.0e-4, 1.0e-4, 1.0e-4),
                noise=(0.0752, 0.0752, 0.0752),
            ),
            "I3G4250D": dict(
                bias=(1.119, -3.228, -0.300),
                drift_dT=(0.030, -0.040, 0.010),
                drift_dT2=(8.66e-5, 8.98e-5, 8.86e-5),
                noise=(0.0418, 0.0424, 0.0433),
            ),
        }
        if device not in sizes:
            raise ConfigError(f"unknown seed-003 device {device!r}; known: {', '.join(sizes)}")
        base = dict(sizes[device], t_ref=-40.0, temp_noise=0.03)
        base.update(overrides)
        return cls(**base)


class Ramp(TypedDict):
    """A ramp of the chamber with the hold at its end (:meth:`SweepProtocol.breakpoints`)."""

    t_start: float
    t_end: float
    temp_from: float  # °C
    temp_to: float
    rate: float  # °C/h, signed


class Sweep(Ramp):
    t_ref: float  # °C, the sweep's start temperature


class Span(TypedDict):
    t_start: float
    t_end: float


class Soak(Span):
    temp: float  # °C


class SweepTruth(TypedDict):
    """The ground truth of a sweep log (:func:`sweep_samples`); times in the log's t."""

    sweeps: list[Sweep]
    soak: Soak
    disturbances: list[Span]  # handled by a person
    gaps: list[Span]  # rows left out of the log
    rows: int
    sample_rate: float
    mount: str
    rig_rate: float
    die_temp_range: list[float]  # lowest and highest, °C


@dataclass(frozen=True)
class SweepProtocol:
    """Chamber programme and rig of one sweep log. Times in s, temperatures in °C,
    ramp rates in °C/h, the rig rate in deg/s.

    ``segments`` are (target °C, ramp rate °C/h, hold s after reaching the target).
    ``disturbances`` are (start s, duration s) of a person handling the unit (real motion,
    ``ref_rate`` unchanged); ``gaps`` are (start s, duration s) where the logger paused.
    """

    start_temp: float = -40.0
    segments: tuple[tuple[float, float, float], ...] = ((85.0, 18.0, 3600.0),)
    soak_s: float = 1800.0  # stable at start_temp before the first ramp
    step_c: float = 0.1  # chamber jump size; 0 = a continuous ramp
    rig_rate: float = 0.0
    mount: str = "+z"  # the sensor axis along the rig axis
    sample_rate: float = 10.0
    lag_s: float = 600.0  # chamber -> die time constant
    mount_column: bool = True
    disturbances: tuple[tuple[float, float], ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()
    t0: float = 0.0

    def __post_init__(self):
        if self.mount not in MOUNTS:
            raise ConfigError(f"SweepProtocol.mount must be one of {' '.join(MOUNTS)}, got {self.mount!r}")
        if not self.segments:
            raise ConfigError("SweepProtocol.segments is empty; expected at least one ramp")
        for target, rate, hold in self.segments:
            if not (np.isfinite(target) and rate > 0 and hold >= 0):
                raise ConfigError(
                    f"sweep segment ({target}, {rate}, {hold}) needs a finite target, "
                    "a rate > 0 °C/h and a hold >= 0 s"
                )
        for start, duration in (*self.disturbances, *self.gaps):
            if not (np.isfinite(start) and duration > 0):
                raise ConfigError(
                    f"sweep disturbance or gap ({start}, {duration}) needs a finite start "
                    "and a duration > 0 s"
                )
        if not (self.sample_rate > 0 and self.lag_s >= 0 and self.soak_s >= 0 and self.step_c >= 0):
            raise ConfigError("SweepProtocol needs sample_rate > 0 and lag_s, soak_s, step_c >= 0")
        object.__setattr__(self, "segments", tuple(tuple(float(x) for x in s) for s in self.segments))
        object.__setattr__(self, "disturbances", tuple(tuple(float(x) for x in s) for s in self.disturbances))
        object.__setattr__(self, "gaps", tuple(tuple(float(x) for x in s) for s in self.gaps))

    @classmethod
    def seed003(cls, **overrides) -> SweepProtocol:
        """Section 3.1 steps 3-4: stable at −40 °C, up to 85 °C at 18 °C/h in 0.1 °C jumps
        (every 20 s), then stable for an hour."""
        return cls(**overrides)

    @classmethod
    def quick(cls, **overrides) -> SweepProtocol:
        """A sweep of minutes for tests: −40 → 85 °C at 250 °C/h, 2 samples/s, short lag."""
        base = dict(segments=((85.0, 250.0, 300.0),), soak_s=120.0, step_c=0.0, sample_rate=2.0, lag_s=30.0)
        base.update(overrides)
        return cls(**base)

    @classmethod
    def demo(cls, **overrides) -> SweepProtocol:
        """The demo fleet's sweep: up −40 → 85 °C and back down at 60 °C/h, 1 sample/s, so
        one log holds a training sweep and a verification sweep (about 4.6 h, 17 k rows)."""
        base = dict(
            segments=((85.0, 60.0, 600.0), (-40.0, 60.0, 600.0)),
            soak_s=600.0,
            step_c=0.0,
            sample_rate=1.0,
            lag_s=120.0,
        )
        base.update(overrides)
        return cls(**base)

    def to_dict(self) -> dict[str, Any]:
        return {k: (np.asarray(v).tolist() if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> SweepProtocol:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(
                f"unknown SweepProtocol field {unknown[0]!r}; known: {', '.join(sorted(known))}"
            )

        def tup(v):
            return tuple(tup(x) for x in v) if isinstance(v, list) else v

        return cls(**{k: tup(v) for k, v in d.items()})

    def breakpoints(self) -> tuple[np.ndarray, np.ndarray, list[Ramp]]:
        """Chamber set point as a piecewise-linear function of time (before the staircase),
        and the ramps with their start and end times."""
        times, temps = [0.0, self.soak_s], [self.start_temp, self.start_temp]
        ramps: list[Ramp] = []
        now, temp = self.soak_s, self.start_temp
        for target, rate, hold in self.segments:
            duration = abs(target - temp) / rate * 3600.0
            ramps.append(
                Ramp(
                    t_start=now,
                    t_end=now + duration + hold,
                    temp_from=temp,
                    temp_to=target,
                    rate=float(rate * np.sign(target - temp)),
                )
            )
            now += duration
            times.append(now)
            temps.append(target)
            now += hold
            times.append(now)
            temps.append(target)
            temp = target
        return np.asarray(times), np.asarray(temps), ramps


def _staircase(t: np.ndarray, times: np.ndarray, temps: np.ndarray, step: float) -> np.ndarray:
    """The set point as jumps of ``step`` °C at the ramp's pace, taken from each ramp's start."""
    linear = np.interp(t, times, temps)
    if step <= 0:
        return linear
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    start = temps[k]
    moved = linear - start
    return start + np.sign(moved) * np.floor(np.abs(moved) / step + 1e-9) * step


def _handling(rng: np.random.Generator, tau: np.ndarray) -> np.ndarray:
    """A person turning the unit: a few smooth swings of tens of deg/s per axis."""
    duration = max(tau[-1], 1e-9) if len(tau) else 1.0
    amp = rng.uniform(20.0, 100.0, (3, 3)) * rng.choice((-1.0, 1.0), (3, 3))
    centre = rng.uniform(0.2, 0.8, (3, 3)) * duration
    width = rng.uniform(0.05, 0.1, (3, 3)) * duration
    z = (tau[:, None, None] - centre) / width
    return (amp * np.exp(-0.5 * z * z)).sum(axis=2)


def sweep_samples(
    protocol: SweepProtocol, unit: SweepUnit, rng: np.random.Generator
) -> tuple[dict[str, np.ndarray], SweepTruth]:
    """The log's columns (t, gyro_x/y/z, temp, ref_rate, mount codes) and the truth."""
    p = protocol
    fs = p.sample_rate
    times, temps, ramps = p.breakpoints()
    n = int(np.floor(times[-1] * fs)) + 1
    tau = np.arange(n) / fs
    chamber = _staircase(tau, times, temps, p.step_c)
    if p.lag_s > 0:  # the die starts settled at the start temperature
        a = np.exp(-1.0 / (p.lag_s * fs))
        die = lfilter([1 - a], [1, -a], chamber, zi=[p.start_temp * a])[0]
    else:
        die = chamber
    die_rate = np.gradient(die, tau) * 60.0 if n > 1 else np.zeros(n)
    axis, sign = "xyz".index(p.mount[1]), (1.0 if p.mount[0] == "+" else -1.0)
    w_true = np.zeros((n, 3))
    w_true[:, axis] = sign * p.rig_rate
    disturbances: list[Span] = []
    for start, duration in p.disturbances:
        sel = (tau >= start) & (tau < start + duration)
        if sel.any():
            w_true[sel] += _handling(rng, tau[sel] - start)
            disturbances.append(Span(t_start=p.t0 + start, t_end=p.t0 + start + duration))
    K = np.asarray(unit.K)
    gyro = w_true @ K.T + unit.drift(die, die_rate)
    gyro += rng.normal(0.0, 1.0, (n, 3)) * np.asarray(unit.noise)
    temp = die + rng.normal(0.0, unit.temp_noise, n)
    keep = np.ones(n, dtype=bool)
    for start, duration in p.gaps:
        keep &= ~((tau >= start) & (tau < start + duration))
    cols = {
        "t": p.t0 + tau[keep],
        "gyro_x": gyro[keep, 0].astype(np.float32),
        "gyro_y": gyro[keep, 1].astype(np.float32),
        "gyro_z": gyro[keep, 2].astype(np.float32),
        "temp": temp[keep].astype(np.float32),
        "ref_rate": np.full(int(keep.sum()), float(p.rig_rate)),
    }
    if p.mount_column:
        cols["mount"] = np.full(int(keep.sum()), MOUNTS.index(p.mount), dtype=np.int8)
    for r in ramps:
        r["t_start"] += p.t0
        r["t_end"] += p.t0
    truth = SweepTruth(
        sweeps=[Sweep(**r, t_ref=float(r["temp_from"])) for r in ramps],
        soak=Soak(t_start=p.t0, t_end=p.t0 + p.soak_s, temp=p.start_temp),
        disturbances=disturbances,
        gaps=[Span(t_start=p.t0 + s, t_end=p.t0 + s + d) for s, d in p.gaps],
        rows=int(keep.sum()),
        sample_rate=fs,
        mount=p.mount,
        rig_rate=float(p.rig_rate),
        die_temp_range=[float(die.min()), float(die.max())],
    )
    return cols, truth


def sweep_log(
    protocol: SweepProtocol, unit: SweepUnit, rng: np.random.Generator, name: str = "<simulated sweep>"
) -> tuple[RigLog, SweepTruth]:
    """The simulated log in memory, as :func:`gyrocal.io.log.read_log` would return it."""
    cols, truth = sweep_samples(protocol, unit, rng)
    batch = {k: (v.astype(np.float64) if k.startswith("gyro") or k == "temp" else v) for k, v in cols.items()}
    return RigLog(name, (batch,), len(batch["t"]), 0), truth


def render_sweep(protocol: SweepProtocol, unit: SweepUnit, rng: np.random.Generator, path) -> SweepTruth:
    """Write the log to ``path`` (Parquet, contract section 1) and return its truth: the
    sweeps (each ramp with its hold, start temperature ``t_ref``), the soak, disturbances,
    gaps and row count; JSON-plain. The unit and the protocol are not repeated in it
    (``simulate_unit`` stores them beside it)."""
    cols, truth = sweep_samples(protocol, unit, rng)
    arrays = {k: pa.array(v) for k, v in cols.items() if k != "mount"}
    if "mount" in cols:
        arrays["mount"] = pa.DictionaryArray.from_arrays(
            pa.array(cols["mount"]), pa.array(MOUNTS, type=pa.string())
        )
    pq.write_table(pa.table(arrays), path)
    return truth


__all__ = ["SweepUnit", "SweepProtocol", "render_sweep", "sweep_log", "sweep_samples"]
