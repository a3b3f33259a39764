"""Independent generator of good and bad turntable rig logs for gyrocal.

Written only from the data contract (shared/spec/log-format.md) and the turntable paper
(shared/seeds/000, Sensors 2018, 18, 3004); gyrocal's own code and simulator were not read.
See NOTE.md for the physics and the list of kinds.

API
- ``good_log(path, seed=0, rate_hz=20.0)`` writes a plausible multi-temperature turntable log.
- ``KINDS``: ordered ``name -> (description, category, mutate)``; ``mutate(src_path, dst_path)``
  reads the good log at ``src_path`` and writes the bad file at ``dst_path``. Every mutation
  uses its own fixed seed (crc32 of its name), so the output depends only on the good log.
- ``EXPECT``: ``name -> (verdict, what a careful tool should do)``, verdict one of
  ``refuse`` / ``warn`` / ``accept``.
- ``write_all(folder, seed=0)`` writes good.parquet plus one ``<kind>.parquet`` per kind.
"""

from __future__ import annotations

import json
import zlib
from collections import OrderedDict
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

# --- protocol ---------------------------------------------------------------------------
# Fixed (independent of seed and sample rate) so that a mutation can find any phase of the
# good log from `t` alone, without hidden label columns in the file.
SETPOINTS = (-20.0, 5.0, 30.0, 55.0)  # chamber set points, degC
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")  # sensor axis along the (upward) rig axis
RATES = (5.0, 20.0, 60.0, 150.0, 300.0)  # hold rates, deg/s, each forward then reverse
HOLD_S, REST_S, HANDLE_S = 20.0, 4.0, 6.0
TABLE_ACCEL = 100.0  # turntable angular acceleration, deg/s^2
ROOM_C, CHAMBER_RATE, TAU_S = 22.0, 10.0 / 60.0, 150.0  # chamber slews 10 degC/min; unit lag
SOAK_SETTLE_S = 5 * TAU_S  # after the chamber arrives: lag error < 1 %
LSB = 1 / 65.5  # gyro quantum, deg/s (a +-500 deg/s range part)
UNITS_KEY = b"gyrocal.units"


class Seg(NamedTuple):
    t0: float
    t1: float
    temp: int  # index into SETPOINTS
    mount: str  # label written in the log
    phase: str  # soak | handling | rest | ramp | hold
    r0: float  # commanded table rate at t0 / t1 (deg/s)
    r1: float


def schedule() -> list[Seg]:
    segs: list[Seg] = []
    t, prev_sp, mount = 0.0, ROOM_C, MOUNTS[0]

    def add(dur, ti, m, ph, r0=0.0, r1=None):
        nonlocal t
        segs.append(Seg(t, t + dur, ti, m, ph, r0, r0 if r1 is None else r1))
        t += dur

    for ti, sp in enumerate(SETPOINTS):
        # The unit stays on the table (last mount) while the chamber slews and soaks.
        add(abs(sp - prev_sp) / CHAMBER_RATE + SOAK_SETTLE_S, ti, mount, "soak")
        prev_sp = sp
        for m in MOUNTS:
            if m != mount:
                # The operator types the new label once the unit is re-mounted, so handling
                # rows still carry the outgoing label (a realistic rig-software habit).
                add(HANDLE_S, ti, mount, "handling")
                mount = m
            add(REST_S, ti, m, "rest")
            r = 0.0
            for target in [s * x for x in RATES for s in (1.0, -1.0)] + [0.0]:
                add(abs(target - r) / TABLE_ACCEL, ti, m, "ramp", r, target)
                if target:
                    add(HOLD_S, ti, m, "hold", target)
                r = target
            add(REST_S, ti, m, "rest")
    return segs


def phases(t: np.ndarray):
    """Per-row (segment index, segments) for times t of the good log (seconds from 0)."""
    segs = schedule()
    idx = np.searchsorted(np.array([s.t0 for s in segs]), t, side="right") - 1
    return np.clip(idx, 0, len(segs) - 1), segs


# --- rotations --------------------------------------------------------------------------
def _skew(v):
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def _exp(v):
    """Rotation vectors (..., 3) -> matrices (..., 3, 3), Rodrigues."""
    th = np.linalg.norm(v, axis=-1)[..., None, None]
    k = _skew(v / np.where(th[..., 0] > 1e-12, th[..., 0], 1.0))
    return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * (k @ k)


def _log(r):
    """One rotation matrix -> rotation vector, via a quaternion (robust near pi)."""
    tr = np.trace(r)
    if tr > 0:
        s = 2 * np.sqrt(tr + 1)
        q = np.array([s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + r[i, i] - r[j, j] - r[k, k])
        q = np.zeros(4)
        q[0] = (r[k, j] - r[j, k]) / s
        q[1 + i], q[1 + j], q[1 + k] = s / 4, (r[j, i] + r[i, j]) / s, (r[k, i] + r[i, k]) / s
    q *= np.sign(q[0]) or 1.0
    n = np.linalg.norm(q[1:])
    return q[1:] / n * 2 * np.arctan2(n, q[0]) if n > 1e-12 else np.zeros(3)


def _small_log(r):
    """Batch log for small rotations (sample-to-sample increments)."""
    c = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    th = np.arccos(c)
    f = np.where(th > 1e-9, th / np.sin(np.maximum(th, 1e-9)), 1.0) / 2
    return f[:, None] * np.stack(
        [r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], -1
    )


def axis_of(mount: str) -> np.ndarray:
    u = np.zeros(3)
    u["xyz".index(mount[1])] = 1.0 if mount[0] == "+" else -1.0
    return u


def _mount_rotation(mount: str, yaw: float) -> np.ndarray:
    """Sensor->world rotation that puts the mount's sensor axis on world +z (up)."""
    u = axis_of(mount)
    e = np.roll(np.abs(u), 1)  # any unit vector perpendicular to u
    r = np.stack([e, np.cross(u, e), u])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ r


# --- the good log -----------------------------------------------------------------------
def good_log(path, *, seed: int = 0, rate_hz: float = 20.0) -> Path:
    rng = np.random.default_rng(seed)
    segs = schedule()
    n = int(np.floor(segs[-1].t1 * rate_hz))
    t = np.arange(n) / rate_hz
    idx = np.searchsorted(np.array([s.t0 for s in segs]), t, side="right") - 1

    # Chamber: slews at CHAMBER_RATE to each set point, then holds it with a small control ripple.
    kt, kv, prev = [0.0], [ROOM_C], ROOM_C
    for s in segs:
        if s.phase == "soak":
            sp = SETPOINTS[s.temp]
            kt += [s.t0, s.t0 + abs(sp - prev) / CHAMBER_RATE]
            kv += [prev, sp]
            prev = sp
    chamber = np.interp(t, kt, kv) + 0.15 * np.sin(2 * np.pi * t / 420.0)
    # Unit temperature: first-order lag behind the chamber (exact discretisation).
    a = 1 - np.exp(-1 / (rate_hz * TAU_S))
    temp_true = np.empty(n)
    x = ROOM_C
    for i, c in enumerate(chamber.tolist()):
        temp_true[i] = x
        x += a * (c - x)

    # Table rate: piecewise linear through the schedule; the encoder is near-perfect.
    rt = np.array([[s.t0, s.t1] for s in segs]).ravel()
    rv = np.array([[s.r0, s.r1] for s in segs]).ravel()
    table = np.interp(t, rt, rv)
    moving = table != 0
    table_true = table * (1 + 2e-5 * np.sin(2 * np.pi * 1.3 * t))  # servo ripple
    ref = np.where(moving, table_true + rng.normal(0, 1e-3, n), 0.0)  # encoder reads 0 at rest

    # Orientation: each mount puts its sensor axis up; handling is a real rotation between them.
    omega = np.zeros((n, 3))
    accel = np.zeros((n, 3))
    labels = np.array([s.mount for s in segs], dtype=object)[idx]
    for k, s in enumerate(segs):
        rows = np.flatnonzero(idx == k)
        if s.phase != "handling":
            omega[rows] = table_true[rows, None] * axis_of(s.mount)
            accel[rows] = axis_of(s.mount)  # +1 g along the upward rig axis
            continue
        nxt = segs[k + 1].mount
        ra = _mount_rotation(s.mount, rng.uniform(0, 2 * np.pi))
        rb = _mount_rotation(nxt, rng.uniform(0, 2 * np.pi))
        phi = _log(ra.T @ rb)
        tt = np.append(t[rows], t[rows[-1]] + 1 / rate_hz)  # one extra for differences
        u = np.clip((tt - s.t0) / (s.t1 - s.t0), 0, 1)
        sm = 0.5 - 0.5 * np.cos(np.pi * u)
        win = np.sin(np.pi * u) ** 2
        amp, f, ph = rng.uniform(0.1, 0.3, 3), rng.uniform(0.5, 1.5, 3), rng.uniform(0, 2 * np.pi, 3)
        wob = win[:, None] * amp * np.sin(2 * np.pi * f * (tt - s.t0)[:, None] + ph)
        rpath = ra @ _exp(sm[:, None] * phi) @ _exp(wob)
        omega[rows] = np.degrees(_small_log(np.swapaxes(rpath[:-1], 1, 2) @ rpath[1:])) * rate_hz
        lin = win[:-1, None] * rng.normal(0, 0.1, 3)  # hand lifting the unit, g
        accel[rows] = np.einsum("nji,j->ni", rpath[:-1], [0, 0, 1.0]) + np.einsum(
            "nji,nj->ni", rpath[:-1], lin
        )

    # Gyro: w = K(T) w_true + B(T) + noise, K = S(T)(I + M).
    p = sensor_params(seed)
    d = (temp_true - 25.0)[:, None]
    gyro = (1 + p["s0"] + p["s1"] * d) * (omega + omega @ p["mis"].T) + p["b0"] + p["b1"] * d + p["b2"] * d**2
    gyro = np.round((gyro + rng.normal(0, 1, (n, 3)) * p["sig"]) / LSB) * LSB
    temp = np.round((temp_true + rng.normal(0, 0.05, n)) * 16) / 16  # 1/16 degC sensor
    accel = accel + rng.normal(0, 2e-3, 3) + rng.normal(0, 3e-3, (n, 3))

    f64 = pa.float64()
    tbl = pa.table(
        {
            "t": pa.array(t, f64),
            "gyro_x": pa.array(gyro[:, 0], f64),
            "gyro_y": pa.array(gyro[:, 1], f64),
            "gyro_z": pa.array(gyro[:, 2], f64),
            "temp": pa.array(temp, f64),
            "ref_rate": pa.array(ref, f64),
            "mount": pa.array(labels.tolist(), pa.string()),
            "accel_x": pa.array(accel[:, 0], f64),
            "accel_y": pa.array(accel[:, 1], f64),
            "accel_z": pa.array(accel[:, 2], f64),
        }
    )
    path = Path(path)
    pq.write_table(tbl, path)
    return path


def sensor_params(seed: int = 0) -> dict:
    """The unit's true error parameters for good_log(seed) (own RNG stream, for checking results).

    K(T) = diag(1 + s0 + s1 (T-25)) (I + mis);  B(T) = b0 + b1 (T-25) + b2 (T-25)^2;  noise sig.
    """
    rng = np.random.default_rng([seed, 1])
    mis = rng.normal(0, 1e-3, (3, 3))  # misalignment / non-orthogonality, rad
    np.fill_diagonal(mis, 0.0)
    return dict(
        s0=rng.uniform(-5e-3, 5e-3, 3),
        s1=rng.uniform(-5e-5, 5e-5, 3),
        mis=mis,
        b0=rng.uniform(0.1, 0.5, 3) * rng.choice([-1, 1], 3),
        b1=rng.uniform(0.003, 0.007, 3) * rng.choice([-1, 1], 3),  # deg/s/degC
        b2=rng.normal(0, 2e-5, 3),
        sig=rng.uniform(0.015, 0.04, 3),
    )


def K_at(p: dict, temp_c: float) -> np.ndarray:
    return np.diag(1 + p["s0"] + p["s1"] * (temp_c - 25.0)) @ (np.eye(3) + p["mis"])


# --- helpers for mutations --------------------------------------------------------------
def _col(tbl, name):
    return tbl.column(name).to_numpy()


def _set(tbl, name, values, typ=None):
    typ = typ or tbl.schema.field(name).type
    return tbl.set_column(tbl.schema.get_field_index(name), name, pa.array(values, typ))


def _scaled(tbl, cols, f):
    """``tbl`` with each of ``cols`` replaced by ``f`` of itself."""
    for c in cols:
        tbl = _set(tbl, c, f(_col(tbl, c)))
    return tbl


def _keep(tbl, mask):
    return tbl.filter(pa.array(np.asarray(mask, bool)))


def _seg_arrays(tbl):
    idx, segs = phases(_col(tbl, "t"))
    return (
        np.array([s.temp for s in segs])[idx],
        np.array([s.mount for s in segs])[idx],
        np.array([s.phase for s in segs])[idx],
        np.array([s.r0 for s in segs])[idx],
    )


def _units(tbl, text: str):
    meta = dict(tbl.schema.metadata or {})
    meta[UNITS_KEY] = text.encode()
    return tbl.replace_schema_metadata(meta)


KINDS: OrderedDict[str, tuple] = OrderedDict()
EXPECT: dict[str, tuple[str, str]] = {}


def _kind(name, category, description, verdict, expect, file_level=False):
    assert category in ("unreadable", "contract", "implausible")

    def deco(fn):
        if file_level:

            def mutate(src, dst):
                fn(Path(src), Path(dst), np.random.default_rng(zlib.crc32(name.encode())))
        else:

            def mutate(src, dst):
                out = fn(pq.read_table(src), np.random.default_rng(zlib.crc32(name.encode())))
                pq.write_table(out, dst)

        mutate.__name__ = mutate.__qualname__ = f"mutate_{name}"
        mutate.__doc__ = description
        KINDS[name] = (description, category, mutate)
        EXPECT[name] = (verdict, expect)
        return fn

    return deco


# --- unreadable ---------------------------------------------------------------------------
@_kind(
    "zero_byte", "unreadable", "an empty (0-byte) file", "refuse", "error: file is empty / not Parquet", True
)
def _(src, dst, rng):
    dst.write_bytes(b"")


@_kind(
    "truncated_parquet",
    "unreadable",
    "the first half of the good file's bytes (copy interrupted)",
    "refuse",
    "error: not a readable Parquet file (truncated)",
    True,
)
def _(src, dst, rng):
    b = src.read_bytes()
    dst.write_bytes(b[: len(b) // 2])


@_kind(
    "not_parquet_csv",
    "unreadable",
    "a CSV text export of the first 2000 rows, named .parquet",
    "refuse",
    "error: not Parquet (looks like text/CSV)",
    True,
)
def _(src, dst, rng):
    tbl = pq.read_table(src).slice(0, 2000)
    cols = {c: tbl.column(c).to_pylist() for c in tbl.column_names}
    lines = [",".join(cols)] + [",".join(str(cols[c][i]) for c in cols) for i in range(tbl.num_rows)]
    dst.write_text("\n".join(lines) + "\n")


@_kind(
    "garbage_with_magic",
    "unreadable",
    "PAR1 + 4 KiB of random bytes + PAR1 (magic right, body garbage)",
    "refuse",
    "error: corrupt Parquet",
    True,
)
def _(src, dst, rng):
    dst.write_bytes(b"PAR1" + rng.bytes(4096) + b"PAR1")


# --- contract -----------------------------------------------------------------------------
@_kind(
    "missing_ref_rate",
    "contract",
    "required column ref_rate dropped",
    "refuse",
    "error naming the missing column ref_rate",
)
def _(tbl, rng):
    return tbl.drop_columns(["ref_rate"])


@_kind(
    "missing_gyro_z",
    "contract",
    "required column gyro_z dropped",
    "refuse",
    "error naming the missing column gyro_z",
)
def _(tbl, rng):
    return tbl.drop_columns(["gyro_z"])


@_kind(
    "gyro_as_strings",
    "contract",
    "gyro_x/y/z stored as strings ('0.12345')",
    "refuse",
    "error: gyro columns must be float (got string)",
)
def _(tbl, rng):
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        tbl = _set(tbl, c, [f"{v:.5f}" for v in _col(tbl, c)], pa.string())
    return tbl


@_kind(
    "time_as_integers",
    "contract",
    "t stored as int64 milliseconds since start (logger ticks)",
    "refuse",
    "error: t must be float64 seconds or timestamp (got int64); never read ms as s",
)
def _(tbl, rng):
    return _set(tbl, "t", np.round(_col(tbl, "t") * 1000).astype(np.int64), pa.int64())


@_kind(
    "all_nan_gyro_axis",
    "contract",
    "gyro_y is NaN in every row (axis not logged)",
    "refuse",
    "error: gyro_y has no valid values (all rows would be dropped)",
)
def _(tbl, rng):
    return _set(tbl, "gyro_y", np.full(tbl.num_rows, np.nan))


@_kind(
    "time_backwards",
    "contract",
    "rows written newest first: t strictly decreasing",
    "refuse",
    "error: t not increasing (or, at most, sort with a warning)",
)
def _(tbl, rng):
    return tbl.take(pa.array(np.arange(tbl.num_rows)[::-1]))


@_kind(
    "duplicate_timestamps",
    "contract",
    "2 % of rows repeat the previous row's t (values differ)",
    "refuse",
    "error: t not strictly increasing, naming the count of duplicates",
)
def _(tbl, rng):
    t = _col(tbl, "t").copy()
    i = rng.choice(np.arange(1, len(t)), len(t) // 50, replace=False)
    t[i] = t[i - 1]
    return _set(tbl, "t", t)


@_kind(
    "shuffled_rows",
    "contract",
    "rows in random order",
    "refuse",
    "error: t not increasing (sorting silently would hide a broken logger)",
)
def _(tbl, rng):
    return tbl.take(pa.array(rng.permutation(tbl.num_rows)))


@_kind("empty_table", "contract", "correct schema, zero rows", "refuse", "error: log has no rows")
def _(tbl, rng):
    return tbl.slice(0, 0)


@_kind(
    "only_10_rows",
    "contract",
    "the first 10 rows only (0.5 s of soak)",
    "refuse",
    "error: far too little data / no holds found",
)
def _(tbl, rng):
    return tbl.slice(0, 10)


@_kind(
    "units_metadata_malformed",
    "contract",
    "gyrocal.units metadata is truncated JSON",
    "refuse",
    "error: gyrocal.units is not valid JSON (do not guess units)",
)
def _(tbl, rng):
    return _units(tbl, '{"gyro": "rad/s", "ref_rate": ')


@_kind(
    "units_metadata_unknown_unit",
    "contract",
    'gyrocal.units = {"gyro": "furlongs/s"}',
    "refuse",
    "error: unknown unit 'furlongs/s' for gyro",
)
def _(tbl, rng):
    return _units(tbl, '{"gyro": "furlongs/s", "ref_rate": "deg/s"}')


@_kind(
    "clock_reset",
    "contract",
    "mid-log the clock restarts at 0 and counts up again",
    "refuse",
    "error: t jumps backwards at row N (clock reset)",
)
def _(tbl, rng):
    t = _col(tbl, "t").copy()
    m = len(t) // 2
    t[m:] -= t[m]
    return _set(tbl, "t", t)


@_kind(
    "mount_labels_invalid",
    "contract",
    "mount written as 'X+', 'X-', ... instead of '+x', '-x'",
    "refuse",
    "error: unknown mount label 'X+' (or derive from gravity with a warning)",
)
def _(tbl, rng):
    return _set(tbl, "mount", [m[1].upper() + m[0] for m in _col(tbl, "mount")])


@_kind(
    "extra_unknown_columns",
    "contract",
    "adds humidity, operator and chamber_sp columns (allowed)",
    "accept",
    "calibrate as the good log; extra columns carried along, no error",
)
def _(tbl, rng):
    n = tbl.num_rows
    tbl = tbl.append_column("humidity", pa.array(rng.uniform(20, 30, n)))
    tbl = tbl.append_column("operator", pa.array(["jd"] * n, pa.string()))
    return tbl.append_column("chamber_sp", pa.array(np.full(n, 25.0), pa.float32()))


@_kind(
    "time_as_timestamp",
    "contract",
    "t as timestamp[ns, UTC] from 2026-11-20T08:00Z (allowed)",
    "accept",
    "calibrate exactly as the good log",
)
def _(tbl, rng):
    ns = np.datetime64("2026-11-20T08:00:00", "ns") + np.round(_col(tbl, "t") * 1e9).astype("timedelta64[ns]")
    return _set(tbl, "t", ns, pa.timestamp("ns", tz="UTC"))


@_kind(
    "units_rad_s_declared",
    "contract",
    "gyro and ref_rate in rad/s, declared in gyrocal.units (allowed)",
    "accept",
    "calibrate exactly as the good log (K and B reported in deg/s)",
)
def _(tbl, rng):
    for c in ("gyro_x", "gyro_y", "gyro_z", "ref_rate"):
        tbl = _set(tbl, c, np.radians(_col(tbl, c)))
    return _units(tbl, json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}))


@_kind(
    "nan_burst",
    "contract",
    "10 s of NaN in all gyro axes in the middle of a 150 deg/s hold",
    "accept",
    "drop and count the rows (contract); calibrate; report the count",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    i = np.flatnonzero((temp == 1) & (mount == "+y") & (phase == "hold") & (rate == 150.0))
    sel = i[len(i) // 4 : len(i) // 4 + int(round(10 * len(i) / HOLD_S))]
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        v = _col(tbl, c).copy()
        v[sel] = np.nan
        tbl = _set(tbl, c, v)
    return tbl


@_kind(
    "inf_values",
    "contract",
    "300 scattered +-inf values in random gyro axes",
    "accept",
    "drop and count the rows (contract); calibrate; report the count",
)
def _(tbl, rng):
    n = tbl.num_rows
    rows, axes = rng.choice(n, 300, replace=False), rng.integers(0, 3, 300)
    for a, c in enumerate(("gyro_x", "gyro_y", "gyro_z")):
        v = _col(tbl, c).copy()
        r = rows[axes == a]
        v[r] = np.inf * rng.choice([-1, 1], len(r))
        tbl = _set(tbl, c, v)
    return tbl


@_kind(
    "logging_gap_1h",
    "contract",
    "logger paused 1 h at the start of the 30 degC soak (allowed gap)",
    "accept",
    "calibrate as the good log (gaps are allowed); maybe note the gap",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    t = _col(tbl, "t").copy()
    t[np.argmax((temp == 2) & (phase == "soak")) :] += 3600.0
    return _set(tbl, "t", t)


# --- implausible --------------------------------------------------------------------------
@_kind(
    "stuck_gyro_axis",
    "implausible",
    "gyro_z constant (its first value) for the whole log",
    "refuse",
    "error: gyro_z never changes (dead/stuck axis)",
)
def _(tbl, rng):
    return _set(tbl, "gyro_z", np.full(tbl.num_rows, _col(tbl, "gyro_z")[0]))


@_kind(
    "values_1e30",
    "implausible",
    "50 scattered gyro_x samples read 1e30 (finite, absurd)",
    "warn",
    "drop as out of range with a warning naming the count, or refuse; never fit them",
)
def _(tbl, rng):
    v = _col(tbl, "gyro_x").copy()
    v[rng.choice(len(v), 50, replace=False)] = 1e30
    return _set(tbl, "gyro_x", v)


@_kind(
    "saturated_gyro",
    "implausible",
    "gyro clipped at +-250 deg/s while ref_rate reaches +-300",
    "warn",
    "detect clipping, exclude the saturated holds with a warning (or refuse)",
)
def _(tbl, rng):
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        tbl = _set(tbl, c, np.clip(_col(tbl, c), -250.0, 250.0))
    return tbl


@_kind(
    "single_temperature",
    "implausible",
    "only the 30 degC block (soak + all mounts) kept",
    "warn",
    "calibrate at one point with a warning that no temperature dependence can be fitted (or refuse)",
)
def _(tbl, rng):
    return _keep(tbl, _seg_arrays(tbl)[0] == 2)


@_kind(
    "gyro_rad_s_undeclared",
    "implausible",
    "gyro in rad/s, no gyrocal.units metadata",
    "refuse",
    "error/warning: scale factors ~0.0175 (= pi/180): gyro looks like rad/s",
)
def _(tbl, rng):
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        tbl = _set(tbl, c, np.radians(_col(tbl, c)))
    return tbl


@_kind(
    "ref_rate_rad_s_undeclared",
    "implausible",
    "ref_rate in rad/s, no metadata",
    "refuse",
    "error/warning: scale factors ~57.3: ref_rate looks like rad/s",
)
def _(tbl, rng):
    return _set(tbl, "ref_rate", np.radians(_col(tbl, "ref_rate")))


@_kind(
    "gyro_mdps",
    "implausible",
    "gyro in milli-degrees per second (x1000)",
    "refuse",
    "error/warning: scale factors ~1000: gyro looks like mdps",
)
def _(tbl, rng):
    return _scaled(tbl, ("gyro_x", "gyro_y", "gyro_z"), lambda v: v * 1000.0)


@_kind(
    "gyro_raw_counts",
    "implausible",
    "gyro as raw counts, 65.5 LSB per deg/s, stored as float",
    "refuse",
    "error/warning: scale factors ~65.5 with integer-valued samples: raw counts",
)
def _(tbl, rng):
    return _scaled(tbl, ("gyro_x", "gyro_y", "gyro_z"), lambda v: np.round(v / LSB))


@_kind(
    "ref_rate_negated",
    "implausible",
    "ref_rate sign convention reversed (left-handed rig axis)",
    "refuse",
    "error/warning: diagonal scale factors ~-1: reference sign convention reversed",
)
def _(tbl, rng):
    return _set(tbl, "ref_rate", -_col(tbl, "ref_rate"))


@_kind(
    "gyro_axis_inverted",
    "implausible",
    "gyro_y negated (left-handed unit / wiring)",
    "refuse",
    "error/warning: K_yy ~ -1, det K < 0: left-handed gyro triad",
)
def _(tbl, rng):
    return _set(tbl, "gyro_y", -_col(tbl, "gyro_y"))


@_kind(
    "gyro_axes_swapped_xy",
    "implausible",
    "gyro_x and gyro_y columns swapped",
    "refuse",
    "error/warning: K_xx, K_yy ~ 0 with |K_xy| ~ 1: axes permuted",
)
def _(tbl, rng):
    gx, gy = _col(tbl, "gyro_x"), _col(tbl, "gyro_y")
    return _set(_set(tbl, "gyro_x", gy), "gyro_y", gx)


@_kind(
    "temp_dropout_nan",
    "implausible",
    "temp NaN for a contiguous sixth of the log (from mid-log)",
    "warn",
    "drop and count the rows; warn that a sixth of the log (part of a temperature point) is lost",
)
def _(tbl, rng):
    v = _col(tbl, "temp").copy()
    n = len(v)
    v[n // 2 : n // 2 + n // 6] = np.nan
    return _set(tbl, "temp", v)


@_kind(
    "temp_stuck",
    "implausible",
    "temp frozen for a sixth of the log, from the start of the 30 degC soak",
    "warn",
    "warn/refuse: temp constant while the chamber moves; holds would get the wrong temperature",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    v = _col(tbl, "temp").copy()
    i = int(np.argmax((temp == 2) & (phase == "soak")))
    v[i : i + len(v) // 6] = v[i]
    return _set(tbl, "temp", v)


@_kind(
    "temp_kelvin",
    "implausible",
    "temp in kelvin (+273.15)",
    "refuse",
    "error: temperatures 250-330 'degC' are out of range (looks like kelvin)",
)
def _(tbl, rng):
    return _set(tbl, "temp", _col(tbl, "temp") + 273.15)


@_kind(
    "temp_error_codes",
    "implausible",
    "40 short bursts where temp reads 850.0 or -273.15 (sensor error codes)",
    "warn",
    "drop the error-code rows with a warning naming the count (or refuse); never fit them",
)
def _(tbl, rng):
    v = _col(tbl, "temp").copy()
    for k, s in enumerate(rng.choice(len(v) - 20, 40, replace=False)):
        v[s : s + rng.integers(1, 20)] = 850.0 if k % 2 else -273.15
    return _set(tbl, "temp", v)


@_kind(
    "accel_m_s2",
    "implausible",
    "accelerometer in m/s^2 instead of g (|a| ~ 9.81)",
    "warn",
    "warn that |accel| ~ 9.81 (m/s^2?); calibrate from labels, or refuse if accel is needed",
)
def _(tbl, rng):
    return _scaled(tbl, ("accel_x", "accel_y", "accel_z"), lambda v: v * 9.80665)


@_kind(
    "mount_labels_rotated",
    "implausible",
    "labels rotated x->y->z->x: '+x' written where gravity says +y",
    "refuse",
    "error/warning: mount labels contradict gravity (accelerometer) in every mount",
)
def _(tbl, rng):
    rot = {"x": "y", "y": "z", "z": "x"}
    return _set(tbl, "mount", [m[0] + rot[m[1]] for m in _col(tbl, "mount")])


@_kind(
    "sample_rate_jitter",
    "implausible",
    "timestamps jittered +-45 % of the sample period (still increasing)",
    "accept",
    "calibrate as the good log (hold means do not need even sampling); maybe a note",
)
def _(tbl, rng):
    t = _col(tbl, "t")
    dt = np.median(np.diff(t))
    return _set(tbl, "t", t + rng.uniform(-0.45, 0.45, len(t)) * dt)


@_kind(
    "dropped_samples_5pct",
    "implausible",
    "a random 5 % of rows removed",
    "accept",
    "calibrate as the good log; maybe note the irregular sampling",
)
def _(tbl, rng):
    return _keep(tbl, rng.random(tbl.num_rows) >= 0.05)


@_kind(
    "too_few_holds_one_temp",
    "implausible",
    "at 5 degC only the +x mount's holds remain (5 of 6 mounts cut)",
    "warn",
    "warn that 5 degC lacks mounts (K not observable there) and drop that grid point, or refuse",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    return _keep(tbl, ~((temp == 1) & (phase != "soak") & (mount != "+x")))


@_kind(
    "ref_rate_holds_scaled",
    "implausible",
    "ref_rate x2 during four holds (setpoint typo), gyro unchanged",
    "warn",
    "flag the four holds as inconsistent (residual outliers) and exclude them with a warning, or refuse",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    v = _col(tbl, "ref_rate").copy()
    for ti, m, r in ((0, "+y", 60.0), (1, "-z", -20.0), (2, "+x", 150.0), (3, "-y", -60.0)):
        sel = (temp == ti) & (mount == m) & (phase == "hold") & (rate == r)
        v[sel] *= 2.0
    return _set(tbl, "ref_rate", v)


@_kind(
    "ref_rate_holds_swapped",
    "implausible",
    "at 5 degC, +z: ref_rate of the +-20 and +-150 holds swapped",
    "warn",
    "flag the swapped holds (gyro/ref ratio ~7.5 or ~0.13) and exclude them with a warning, or refuse",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    v = _col(tbl, "ref_rate").copy()
    base = (temp == 1) & (mount == "+z") & (phase == "hold")
    for a, b in ((20.0, 150.0), (-20.0, -150.0)):
        sa, sb = base & (rate == a), base & (rate == b)
        v[sa], v[sb] = v[sa] * b / a, v[sb] * a / b
    return _set(tbl, "ref_rate", v)


@_kind(
    "missing_mount",
    "implausible",
    "every -y mount removed at every temperature (5 mounts left)",
    "accept",
    "calibrate (5 mounts still determine K), maybe a note on the unbalanced protocol",
)
def _(tbl, rng):
    return _keep(tbl, _seg_arrays(tbl)[1] != "-y")


@_kind(
    "missing_axis",
    "implausible",
    "both z mounts removed at every temperature: z never rotated",
    "refuse",
    "error: K's z column not observable (no rotation about z)",
)
def _(tbl, rng):
    temp, mount, phase, rate = _seg_arrays(tbl)
    return _keep(tbl, ~np.isin(mount, ["+z", "-z"]) | (phase == "soak"))


@_kind(
    "no_reverse_holds",
    "implausible",
    "all rows with ref_rate < 0 removed (forward holds only)",
    "accept",
    "calibrate (opposite mounts still give both signs); maybe note the missing reverse holds",
)
def _(tbl, rng):
    return _keep(tbl, _col(tbl, "ref_rate") >= 0)


# --- added later by gyrocal's developers (not independent of gyrocal; see NOTE.md) --------
@_kind(
    "time_in_ms",
    "implausible",
    "t written in milliseconds where the contract says seconds",
    "refuse",
    "error: the sample interval (50 s) and the session (108 days) are what no rig "
    "records; in ms they are 50 ms and 2.6 h",
)
def _(tbl, rng):
    return _scaled(tbl, ["t"], lambda t: t * 1e3)


@_kind(
    "time_in_us",
    "implausible",
    "t written in microseconds where the contract says seconds",
    "refuse",
    "error: samples 14 h apart over three centuries; in µs, 50 ms over 2.6 h",
)
def _(tbl, rng):
    return _scaled(tbl, ["t"], lambda t: t * 1e6)


def write_all(folder, seed: int = 0) -> dict[str, Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    good = good_log(folder / "good.parquet", seed=seed)
    out = {"good": good}
    for name, (_, _, mutate) in KINDS.items():
        dst = folder / f"{name}.parquet"
        mutate(good, dst)
        out[name] = dst
    return out
