"""The ``turntable`` protocol of seed 000 (Sections 3.2 and 4), rendered as a rig log.

At each chamber set point (Table 1): a chamber ramp, a soak, then for each mount a series
of constant-rate holds, forward and reverse (Table 2), joined by acceleration ramps. Between
mounts the table stops and a person re-mounts the unit: real rotation while ``ref_rate`` is 0,
and the chamber door is open meanwhile. Mounts are visited in zig-zag order across set points
(+x +y +z, then +z +y +x, ...) so no re-mount is needed between temperatures, as on a real
thermal turntable; the first rate-0 hold at a set point is therefore the tail of the soak.

Every duration, the sample rate and the set points are knobs: tests render logs of seconds,
benchmarks the full seed protocol. The log is rendered one set point at a time, each a Parquet
row group, with filter states carried across, so memory stays one set point's worth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any, NamedTuple, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter

from ..io.log import MOUNTS
from .unit import Electronics, GyroUnit

SEED000_TEMPERATURES = (-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0)
SEED000_RATES = (0.1, 1.0, 10.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)


@dataclass(frozen=True)
class Phase:
    """A stretch of the turntable's schedule (:meth:`TurntableProtocol.schedule`): the table's
    rate and the chamber's set point from its start to its end, the mount and the one the
    phase ends on, and the temperature point of a soak or a hold."""

    kind: str  # chamber, soak, pause, handling, hold or accel
    n: int  # samples
    rate_from: float
    rate_to: float
    set_from: float
    set_to: float
    mount: str
    next_mount: str
    point: int | None = None


class HoldTruth(TypedDict):
    t_start: float
    t_end: float
    mount: str
    rate: float  # deg/s
    set_point: float  # °C
    point: int


class HandlingTruth(TypedDict):
    """A re-mount by hand."""

    t_start: float
    t_end: float
    mount_from: str
    mount_to: str


class SoakTruth(TypedDict):
    t_start: float
    t_end: float
    set_point: float  # °C


class TurntableTruth(TypedDict):
    """The ground truth of a turntable log's schedule (:func:`render`); times in the log's t."""

    holds: list[HoldTruth]
    handling: list[HandlingTruth]
    soaks: list[SoakTruth]
    rows: int


@dataclass(frozen=True)
class TurntableProtocol:
    """Schedule of the rig and the thermal path from chamber to die. Times in s, rates deg/s."""

    temperatures: tuple[float, ...] = SEED000_TEMPERATURES
    rates: tuple[float, ...] = SEED000_RATES  # magnitudes; each is held forward and reverse
    mounts: tuple[str, ...] = ("+x", "+y", "+z")
    sample_rate: float = 100.0
    soak_s: float = 3600.0
    hold_s: float = 60.0
    accel: float = 50.0  # table acceleration between holds, deg/s²
    handling_s: float = 30.0
    pause_s: float = 3.0  # table stopped before the person reaches in
    chamber_ramp: float = 2.0  # °C/min between set points
    room_temp: float = 23.0
    air_tau_s: float = 60.0
    unit_tau_s: float = 600.0  # chamber air -> die (the sensor reads the die)
    self_heating: float = 2.0  # °C the powered die runs above its surroundings
    self_heating_tau_s: float = 900.0
    door_coupling: float = 0.05  # share of (room - set point) the air heads for, door open
    temp_noise: float = 0.02  # °C, sensor
    temp_lsb: float = 1.0 / 256.0  # °C, sensor
    settle_overshoot: float = 0.002  # table overshoot after a ramp, share of the step
    settle_tau_s: float = 0.15
    settle_hz: float = 3.0
    mount_column: bool = True
    accel_columns: bool = True

    @classmethod
    def quick(cls, **overrides) -> TurntableProtocol:
        """A protocol of seconds (for tests): same structure, thermal path scaled to fit."""
        base = dict(
            temperatures=(-20.0, 0.0, 20.0, 40.0),
            soak_s=40.0,
            hold_s=6.0,
            accel=400.0,
            handling_s=4.0,
            pause_s=1.0,
            chamber_ramp=600.0,
            air_tau_s=0.5,
            unit_tau_s=3.0,
            self_heating_tau_s=2.0,
            door_coupling=0.0,
        )
        base.update(overrides)
        return cls(**base)

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    def schedule(self) -> list[Phase]:
        """Phases in order: kind, samples, table rates, set points, mount, door."""
        fs = self.sample_rate
        n = lambda seconds: max(int(round(seconds * fs)), 1)  # noqa: E731
        phases: list[Phase] = []
        set_point = self.room_temp
        rate = 0.0
        mount = self.mounts[0]

        def add(kind, samples, point=None):
            phases.append(Phase(kind, samples, rate, rate, set_point, set_point, mount, mount, point))

        for k, temp in enumerate(self.temperatures):
            if abs(temp - set_point) > 0:
                add("chamber", n(abs(temp - set_point) / self.chamber_ramp * 60.0))
                set_point = float(temp)
                phases[-1] = replace(phases[-1], set_to=set_point)
            add("soak", n(self.soak_s), point=k)
            order = self.mounts if k % 2 == 0 else self.mounts[::-1]
            for new_mount in order:
                if new_mount != mount:
                    add("pause", n(self.pause_s))
                    add("handling", n(self.handling_s))
                    mount = new_mount
                    phases[-1] = replace(phases[-1], next_mount=mount)
                add("hold", n(self.hold_s), point=k)
                for target in [s * r for r in self.rates for s in (1.0, -1.0)] + [0.0]:
                    add("accel", n(abs(target - rate) / self.accel))
                    rate = float(target)
                    phases[-1] = replace(phases[-1], rate_to=rate)
                    if target != 0.0:
                        add("hold", n(self.hold_s), point=k)
        return phases


def _mount_axis(mount: str) -> tuple[int, float]:
    return "xyz".index(mount[1]), (1.0 if mount[0] == "+" else -1.0)


def _handling_motion(rng: np.random.Generator, n: int, fs: float) -> np.ndarray:
    """A person turning the unit in hand: a few smooth swings per axis plus tremor (deg/s)."""
    tau = np.arange(n) / fs
    duration = n / fs
    w = np.zeros((n, 3))
    for axis in range(3):
        for _ in range(3):
            amp = rng.uniform(20.0, 120.0) * rng.choice((-1.0, 1.0))
            centre = rng.uniform(0.2, 0.8) * duration
            width = rng.uniform(0.03, 0.08) * duration
            w[:, axis] += amp * np.exp(-0.5 * ((tau - centre) / width) ** 2)
    a = np.exp(-2 * np.pi * 8.0 / fs)  # tremor: white noise low-passed at 8 Hz
    w += lfilter([1 - a], [1, -a], rng.normal(0.0, 3.0, (n, 3)), axis=0)
    edge = min(0.15 * duration, 5.0)
    ramp = np.clip(np.minimum(tau, duration - tau) / edge, 0.0, 1.0)
    return w * (np.sin(0.5 * np.pi * ramp) ** 2)[:, None]


def _first_order(x: np.ndarray, tau_s: float, fs: float, state: float) -> tuple[np.ndarray, float]:
    a = np.exp(-1.0 / (tau_s * fs))
    y, zf = lfilter([1 - a], [1, -a], x, zi=[state * a])
    return y, float(y[-1])


def render(
    protocol: TurntableProtocol, unit: GyroUnit, rng: np.random.Generator, path, *, t0: float = 0.0
) -> TurntableTruth:
    """Write the log to ``path`` (Parquet) and return the ground truth of the schedule."""
    fs = protocol.sample_rate
    phases = protocol.schedule()
    electronics = Electronics(unit, fs, rng)
    thermal = _ThermalState(protocol.room_temp, protocol.room_temp)
    start = 0
    truth = _Truth()
    writer = None
    try:
        for lo, hi in _set_point_chunks(phases):
            motion = _chunk_motion(protocol, phases[lo:hi], rng, start, t0, truth)
            m = len(motion.table)
            idx = start + np.arange(m)
            t = t0 + idx / fs
            die, thermal = _die_temperature(protocol, motion, t, t0, thermal)
            sensor = _temperature_reading(protocol, die, rng)
            die_rate = np.gradient(die) * fs * 60.0  # °C/min, for the temp_rate effect
            gyro = electronics.measure(motion.w_true, die, motion.gravity, die_rate, t - t0)
            batch = _log_table(protocol, unit, rng, t, gyro, sensor, motion)
            if writer is None:
                writer = pq.ParquetWriter(path, _log_schema(protocol, batch.schema))
            writer.write_table(batch.cast(writer.schema), row_group_size=m)
            start += m
    finally:
        if writer is not None:
            writer.close()
    return TurntableTruth(holds=truth.holds, handling=truth.handling, soaks=truth.soaks, rows=start)


def _set_point_chunks(phases: list[Phase]) -> list[tuple[int, int]]:
    """The log's chunks, one per set point: the phases from one "chamber"/"soak" start to the
    next, as (first, past-the-end) indices."""
    chunk_starts = [
        i
        for i, p in enumerate(phases)
        if p.kind in ("chamber", "soak") and (i == 0 or phases[i - 1].kind != "chamber")
    ]
    return list(zip(chunk_starts, chunk_starts[1:] + [len(phases)], strict=False))


@dataclass
class _Truth:
    """The schedule's ground truth, phase by phase: holds, re-mounts and soaks."""

    holds: list[HoldTruth] = field(default_factory=list)
    handling: list[HandlingTruth] = field(default_factory=list)
    soaks: list[SoakTruth] = field(default_factory=list)

    def record(self, ph: Phase, t_first: float, t_last: float) -> None:
        if ph.kind == "handling":
            self.handling.append(
                HandlingTruth(t_start=t_first, t_end=t_last, mount_from=ph.mount, mount_to=ph.next_mount)
            )
        elif ph.kind == "hold":
            assert ph.point is not None  # a hold is at a temperature point
            self.holds.append(
                HoldTruth(
                    t_start=t_first,
                    t_end=t_last,
                    mount=ph.mount,
                    rate=ph.rate_to,
                    set_point=ph.set_to,
                    point=ph.point,
                )
            )
        elif ph.kind == "soak":
            self.soaks.append(SoakTruth(t_start=t_first, t_end=t_last, set_point=ph.set_to))


@dataclass(frozen=True)
class _ChunkMotion:
    """One chunk's samples: the table's rate, the chamber set point, whether the door is
    open, the true rate and gravity in the unit's frame, and the mount's code in MOUNTS."""

    table: np.ndarray
    set_point: np.ndarray
    door: np.ndarray
    w_true: np.ndarray
    gravity: np.ndarray
    mount_code: np.ndarray


def _chunk_motion(
    protocol: TurntableProtocol, chunk: list[Phase], rng: np.random.Generator, start: int, t0: float, truth
) -> _ChunkMotion:
    """The chunk's phases sample by sample (``start``: its first sample's index in the log);
    each phase's truth goes to ``truth``. Draws the handling motion from ``rng``."""
    fs = protocol.sample_rate
    m = sum(p.n for p in chunk)
    motion = _ChunkMotion(
        table=np.zeros(m),
        set_point=np.empty(m),
        door=np.zeros(m, dtype=bool),
        w_true=np.zeros((m, 3)),
        gravity=np.zeros((m, 3)),
        mount_code=np.empty(m, dtype=np.int8),
    )
    pos = 0
    prev_step = 0.0
    for ph in chunk:
        k = ph.n
        sl = slice(pos, pos + k)
        tau = np.arange(k) / fs
        motion.table[sl], prev_step = _table_rate(protocol, ph, tau, prev_step)
        motion.set_point[sl] = ph.set_from + (ph.set_to - ph.set_from) * (tau + 1 / fs) * fs / k
        axis, sign = _mount_axis(ph.mount)
        motion.w_true[sl, axis] = sign * motion.table[sl]
        motion.gravity[sl, axis] = sign
        motion.mount_code[sl] = MOUNTS.index(ph.mount)
        if ph.kind == "handling":
            _remount(rng, ph, motion, pos, tau, fs)
        truth.record(ph, t0 + (start + pos) / fs, t0 + (start + pos + k - 1) / fs)
        pos += k
    return motion


def _table_rate(
    protocol: TurntableProtocol, ph: Phase, tau: np.ndarray, prev_step: float
) -> tuple[np.ndarray, float]:
    """The table's rate over the phase, and the rate step it ends with (0 unless it
    accelerates). A phase after an acceleration starts with the table's settling overshoot."""
    k = len(tau)
    if ph.kind == "accel":
        return np.linspace(ph.rate_from, ph.rate_to, k + 1)[1:], ph.rate_to - ph.rate_from
    rate = np.full(k, ph.rate_to, dtype=float)
    if prev_step:
        rate += (
            protocol.settle_overshoot
            * prev_step
            * np.exp(-tau / protocol.settle_tau_s)
            * np.sin(2 * np.pi * protocol.settle_hz * tau)
        )
    return rate, 0.0


def _remount(
    rng: np.random.Generator, ph: Phase, motion: _ChunkMotion, pos: int, tau: np.ndarray, fs: float
) -> None:
    """A handling phase at ``pos``: the door open, the unit turned in hand, gravity swinging
    to the next mount, whose code the second half of the phase carries."""
    k = len(tau)
    sl = slice(pos, pos + k)
    motion.door[sl] = True
    motion.w_true[sl] = _handling_motion(rng, k, fs)
    new_axis, new_sign = _mount_axis(ph.next_mount)
    blend = (tau / tau[-1])[:, None] if k > 1 else np.ones((1, 1))
    g_new = np.zeros(3)
    g_new[new_axis] = new_sign
    g = (1 - blend) * motion.gravity[sl] + blend * g_new
    motion.gravity[sl] = g / np.linalg.norm(g, axis=1, keepdims=True)
    motion.mount_code[pos + k // 2 : pos + k] = MOUNTS.index(ph.next_mount)


class _ThermalState(NamedTuple):
    """The chamber air's and the die's temperature at the end of the last chunk, °C."""

    air: float
    die: float


def _die_temperature(
    protocol: TurntableProtocol, motion: _ChunkMotion, t: np.ndarray, t0: float, state: _ThermalState
) -> tuple[np.ndarray, _ThermalState]:
    """The die's temperature over the chunk: the air follows the set point (pulled toward the
    room while the door is open), the die the air, plus the powered die's self-heating."""
    fs = protocol.sample_rate
    set_point = motion.set_point
    air_target = np.where(
        motion.door, set_point + protocol.door_coupling * (protocol.room_temp - set_point), set_point
    )
    air, air_state = _first_order(air_target, protocol.air_tau_s, fs, state.air)
    die, die_state = _first_order(air, protocol.unit_tau_s, fs, state.die)
    die += protocol.self_heating * (1 - np.exp(-(t - t0) / protocol.self_heating_tau_s))
    return die, _ThermalState(air_state, die_state)


def _temperature_reading(
    protocol: TurntableProtocol, die: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """The temperature sensor's reading of the die: its noise, quantised to its LSB."""
    sensor = die + rng.normal(0.0, protocol.temp_noise, len(die))
    return np.round(sensor / protocol.temp_lsb) * protocol.temp_lsb


MOUNT_DICTIONARY = pa.array(MOUNTS, type=pa.string())


def _log_table(
    protocol: TurntableProtocol,
    unit: GyroUnit,
    rng: np.random.Generator,
    t: np.ndarray,
    gyro: np.ndarray,
    sensor: np.ndarray,
    motion: _ChunkMotion,
) -> pa.Table:
    """The chunk's rows of the log; the accelerometer's noise is drawn from ``rng``."""
    cols = {
        "t": pa.array(t),
        "gyro_x": gyro[:, 0],
        "gyro_y": gyro[:, 1],
        "gyro_z": gyro[:, 2],
        "temp": pa.array(sensor.astype(np.float32)),
        "ref_rate": pa.array(motion.table),
    }
    if protocol.mount_column:
        cols["mount"] = pa.DictionaryArray.from_arrays(pa.array(motion.mount_code), MOUNT_DICTIONARY)
    if protocol.accel_columns:
        accel = motion.gravity + rng.normal(0.0, unit.accel_noise, (len(t), 3))
        for i, c in enumerate("xyz"):
            cols[f"accel_{c}"] = pa.array(accel[:, i].astype(np.float32))
    return pa.table(
        {k: (v if isinstance(v, (pa.Array, pa.ChunkedArray)) else pa.array(v)) for k, v in cols.items()}
    )


def _log_schema(protocol: TurntableProtocol, schema: pa.Schema) -> pa.Schema:
    """The log's schema from its first chunk's: the mount column as int8 dictionary codes."""
    if protocol.mount_column:
        mount_type = pa.dictionary(pa.int8(), pa.string())
        schema = schema.set(schema.get_field_index("mount"), pa.field("mount", mount_type))
    return schema
