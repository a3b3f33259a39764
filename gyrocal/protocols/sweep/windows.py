"""Observations of a temperature sweep: consecutive fixed-length windows along the log.

A sweep log (contract, protocol ``sweep``) is one slow temperature ramp, or several, with the
rig at one constant rate. Each window of ``window_s`` seconds becomes one observation of the
drift at the window's mean temperature (seed 003, Section 3.2 step 2): the mean gyro output
minus the output the rig rate should give along the mount axis. The default window is the
paper's temperature-jump period t_p = 20 s (Eq 25), one 0.1 °C step of its 18 °C/h sweep.

ΔT is the paper's temperature variation (Eq 6; Section 3.2 step 2): the window's temperature
minus the reference temperature T0, the stable temperature the sweep starts from (its first
kept window unless ``t_ref`` is given).

Windows restart after each of the logger's real gaps (:mod:`gyrocal.io.stamps`), and a run
of samples shorter than a window (a chamber's 5-s burst every 5 minutes) is one window of its
own; the sample rate is samples over time within those runs, so that host stamps that arrive
in bunches do not shorten a window.

Windows are dropped, and counted by reason, when they are incomplete (a logging gap or the
log's end), when the reference rate is not the sweep's constant rate, when the mount column
changes, or when the gyro scatter inside them shows motion the reference does not (a person
handling the unit) together with ``settle_windows`` neighbours either side.
All statistics are ``reduceat`` sums over the samples; nothing loops per sample or window.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ...io.errors import ConfigError, SegmentationError
from ...io.holds import SlopeSums, regression_rate
from ...io.log import GYRO, MOUNTS, RigLog
from ...io.stamps import sampling

REASONS = {
    "incomplete": "fewer samples than a full window (a logging gap or the log's end)",
    "reference": "the reference rate is not the sweep's constant rate",
    "mount": "the mount column changes or differs from the sweep's mount",
    "motion": "the gyro scatters well beyond the noise, or next to such a window",
}
AXES = ("x", "y", "z")
MIN_WINDOW_SAMPLES = 8  # a burst this short gives a mean but no scatter worth the name
OPTIONS = "the config's protocols: sweep: options:, or static: options:"


def _check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value < 0
        or (value == 0 and not allow_zero)
    ):
        kind = "non-negative" if allow_zero else "positive"
        raise ConfigError(f"sweep window setting {name} must be a {kind} number, got {value!r}")
    return float(value)


def sweep_windows(
    log: RigLog,
    *,
    window_s: float = 20.0,
    t_ref: float | None = None,
    mount: str | None = None,
    motion_factor: float = 5.0,
    settle_windows: int = 1,
    fill: float = 0.9,
    min_span: float = 5.0,
    min_windows: int = 10,
) -> pd.DataFrame:
    """One row per kept window of ``log``; see the module docstring.

    Columns: ``window`` (index along the log), ``t_start``, ``t_end`` (s), ``n``, ``temp``
    (mean, °C), ``dT`` and ``dT2`` (ΔT and ΔT², °C and °C²), ``temp_rate`` (°C/min, the
    within-window slope), ``ref_rate`` (deg/s), ``gyro_x/y/z`` and ``std_x/y/z`` (mean and
    sample standard deviation, deg/s), ``err_x/y/z`` (mean minus the expected output, deg/s)
    and ``mount``. ``attrs`` holds ``t_ref``, ``window_s``, ``sample_rate``, ``rig_rate``,
    ``mount``, ``mount_source`` ("argument", "column", "data" or "" at rate 0),
    ``dropped`` (reason -> count), ``windows_total``, ``rows`` and ``path``.

    A window is complete when it holds at least ``fill`` of the samples a window should.
    Motion: a window whose standard deviation on any axis exceeds ``motion_factor`` times
    that axis's median over the complete windows. Raises :class:`SegmentationError` when
    the kept windows span less than ``min_span`` °C or number fewer than ``min_windows``.
    """
    window_s = _check_positive("window_s", window_s)
    motion_factor = _check_positive("motion_factor", motion_factor)
    if not 0 < fill <= 1:
        raise ConfigError(f"sweep window setting fill must be in (0, 1], got {fill!r}")
    if mount is not None and mount not in MOUNTS:
        raise ConfigError(f"mount must be one of {' '.join(MOUNTS)}, got {mount!r}")
    t = log.column("t")
    n_rows = len(t)
    if n_rows < 3:
        raise SegmentationError(f"not a sweep: {n_rows} rows, expected a long log", source=log.path)
    stamps = sampling(t)
    if not stamps.rate > 0:
        raise SegmentationError("cannot determine the sample interval", source=log.path)
    dt = 1.0 / stamps.rate
    per_window = window_s / dt
    if per_window < 2:
        raise SegmentationError(
            f"window of {window_s:g} s holds {per_window:.2g} samples at "
            f"{1 / dt:.3g} Hz; expected at least 2",
            source=log.path,
        )

    # Windows restart at each run between the logger's real gaps, so that a chamber's bursts
    # are not cut by a grid laid from the log's start; a run shorter than a window (a
    # burst) is one window of its own length. t increases strictly, so windows are runs.
    run_starts, run_stops = stamps.run_starts, stamps.run_stops
    run_rows = run_stops - run_starts
    run_of = np.repeat(np.arange(len(run_starts)), run_rows)
    run_t0 = t[run_starts]
    run_span = t[run_stops - 1] - run_t0 + dt
    local = np.floor((t - run_t0[run_of]) / window_s).astype(np.int64)
    run_windows = np.floor((t[run_stops - 1] - run_t0) / window_s).astype(np.int64) + 1
    wid = np.r_[0, np.cumsum(run_windows)[:-1]][run_of] + local
    starts = np.flatnonzero(np.r_[True, wid[1:] != wid[:-1]])
    counts = np.diff(np.r_[starts, n_rows])
    k = len(starts)
    owner = np.repeat(np.arange(k), counts)
    # the samples a complete window holds: a whole window's, or a whole burst's
    expected = np.minimum(window_s, run_span[run_of[starts]]) * stamps.rate

    def sums(x):
        return np.add.reduceat(x, starts, axis=0)

    gyro = np.column_stack([log.column(c) for c in GYRO]).astype(np.float64)
    dev = gyro - gyro[starts][owner]  # centred on each window's first sample: exact squares
    s1, s2 = sums(dev), sums(dev * dev)
    mean_dev = s1 / counts[:, None]
    var = np.maximum(s2 - s1 * mean_dev, 0.0) / np.maximum(counts - 1, 1)[:, None]
    g_mean = gyro[starts] + mean_dev
    g_std = np.sqrt(var)
    del dev

    temp = log.column("temp").astype(np.float64)
    tt = t - t[starts][owner]
    TT = temp - temp[starts][owner]
    window_sums = SlopeSums(counts, sums(tt), sums(TT), sums(tt * tt), sums(tt * TT))
    temp_rate = regression_rate(window_sums)
    temp_mean = temp[starts] + window_sums.temp / counts

    ref = log.column("ref_rate").astype(np.float64)
    ref_mean = sums(ref) / counts
    ref_span = np.maximum.reduceat(ref, starts) - np.minimum.reduceat(ref, starts)

    step = np.r_[0.0, np.diff(t)]
    step[starts] = 0.0
    inner_gap = np.maximum.reduceat(step, starts)
    t_end = t[np.r_[starts[1:], n_rows] - 1]

    # Reasons, first one wins.
    reason = np.full(k, "", dtype=object)
    burst = run_span[run_of[starts]] < window_s
    incomplete = (
        (counts < fill * expected)
        | (burst & (counts < MIN_WINDOW_SAMPLES))
        | (inner_gap > np.maximum(3.0 * dt, (1 - fill) * expected * dt))
    )
    reason[incomplete] = "incomplete"
    ok = reason == ""
    if not ok.any():
        raise SegmentationError(
            f"not a sweep: no complete {window_s:g}-s window in {n_rows} rows; "
            f"a shorter window_s fits shorter stretches ({OPTIONS})",
            source=log.path,
        )
    rig_rate = float(np.median(ref_mean[ok]))
    tol = 0.005 + 1e-3 * abs(rig_rate)
    reason[ok & ((ref_span > tol) | (np.abs(ref_mean - rig_rate) > tol))] = "reference"
    if not (reason == "").any():
        raise SegmentationError(
            f"not a sweep: no {window_s:g}-s window holds the reference rate constant", source=log.path
        )

    codes = None
    if "mount" in log:
        m = log.column("mount").astype(np.int16)
        lo, hi = np.minimum.reduceat(m, starts), np.maximum.reduceat(m, starts)
        usable = (reason == "") & (lo == hi) & (lo >= 0)
        codes = np.where(lo == hi, lo, -2)
    mount_source = ""
    if mount is not None:
        mount_code, mount_source = MOUNTS.index(mount), "argument"
    elif codes is not None and usable.any():
        mount_code, mount_source = int(np.bincount(codes[usable]).argmax()), "column"
    elif abs(rig_rate) > tol:
        # Without a label, the axis with the largest mean output is taken to lie along the
        # rig axis; a bias larger than the rate fools this, hence the mount column or argument.
        level = np.median(g_mean[reason == ""], axis=0)
        axis = int(np.argmax(np.abs(level)))
        mount_code = 2 * axis + int(level[axis] * rig_rate < 0)
        mount_source = "data"
    else:
        mount_code = -1
    if codes is not None:  # a null label contradicts nothing; a change inside a window does
        conflict = (codes == -2) | ((codes >= 0) & (mount_code >= 0) & (codes != mount_code))
        reason[(reason == "") & conflict] = "mount"

    # Motion: scatter far above the axis's typical scatter, plus settling neighbours.
    ok = reason == ""
    typical = np.median(g_std[ok], axis=0) if ok.any() else np.full(3, np.inf)
    moving = ok & (g_std > motion_factor * np.maximum(typical, 1e-12)).any(axis=1)
    if settle_windows > 0 and moving.any():
        c = np.r_[0, np.cumsum(moving)]
        pos = np.arange(k)
        near = (c[np.minimum(pos + settle_windows + 1, k)] - c[np.maximum(pos - settle_windows, 0)]) > 0
        moving = (reason == "") & near
    reason[moving] = "motion"

    keep = reason == ""
    expected = np.zeros((k, 3))
    if mount_code >= 0:
        axis, sign = mount_code // 2, (1.0 if mount_code % 2 == 0 else -1.0)
        expected[:, axis] = sign * ref_mean
    err = g_mean - expected
    n_keep = int(keep.sum())
    if n_keep < min_windows:
        counts_by = pd.Series(reason[~keep]).value_counts().to_dict()
        raise SegmentationError(
            f"not a sweep: {n_keep} usable {window_s:g}-s windows, expected at least "
            f"{min_windows} (dropped: {counts_by or 'none'}); window_s and min_windows "
            f"set them ({OPTIONS})",
            source=log.path,
        )
    temps = temp_mean[keep]
    span = float(temps.max() - temps.min())
    if span < min_span:
        raise SegmentationError(
            f"not a sweep: temperature spans {span:.3g} °C over the usable windows, "
            f"expected at least {min_span:g} °C",
            source=log.path,
        )
    t0 = float(temps[0]) if t_ref is None else float(t_ref)
    dT = temps - t0
    out = pd.DataFrame(
        {
            "window": np.flatnonzero(keep),
            "t_start": t[starts][keep],
            "t_end": t_end[keep],
            "n": counts[keep].astype(np.int64),
            "temp": temps,
            "dT": dT,
            "dT2": dT * dT,
            "temp_rate": temp_rate[keep],
            "ref_rate": ref_mean[keep],
            **{f"gyro_{a}": g_mean[keep, i] for i, a in enumerate(AXES)},
            **{f"std_{a}": g_std[keep, i] for i, a in enumerate(AXES)},
            **{f"err_{a}": err[keep, i] for i, a in enumerate(AXES)},
            "mount": MOUNTS[mount_code] if mount_code >= 0 else "",
        }
    )
    dropped = {r: int(np.count_nonzero(reason == r)) for r in REASONS}
    # windows a pause of a continuous log left without samples (a burst logger's pauses are
    # its design, not lost windows)
    pause = t[run_starts[1:]] - t[run_stops[:-1] - 1]
    continuous = (run_span[:-1] >= window_s) & (run_span[1:] >= window_s)
    lost = int(np.sum(np.floor(pause[continuous] / window_s)))
    grid_windows = int(wid[-1]) + 1 + lost
    dropped["incomplete"] += grid_windows - k
    out.attrs.update(
        t_ref=t0,
        window_s=window_s,
        sample_rate=stamps.rate,
        runs=len(run_starts),
        bursts=int(np.count_nonzero(run_span < window_s)),
        stamps=stamps.warning(),
        longest_stall_s=stamps.longest_stall_s,
        rig_rate=rig_rate,
        mount=MOUNTS[mount_code] if mount_code >= 0 else "",
        mount_source=mount_source,
        dropped=dropped,
        windows_total=grid_windows,
        rows=int(n_rows),
        path=log.path,
    )
    return out


def split_sweeps(
    windows: pd.DataFrame, *, min_rate: float = 0.05, smooth_s: float = 600.0, min_span: float = 5.0
) -> list[pd.DataFrame]:
    """Split a log's windows into its monotone temperature ramps (Section 3.2 step 1:
    train on one sweep, verify on another).

    The temperature rate is taken over ``smooth_s`` seconds around each window; windows
    faster than ``min_rate`` °C/min up or down set the direction, holds between ramps join
    the ramp before them (the paper's final stable hour belongs to its sweep), a leading
    hold the first ramp. Each sweep gets its own ΔT, counted from its first window
    (``attrs["t_ref"]``), a ``sweep`` column and ``attrs["direction"]`` (+1 up, −1 down).
    Ramps spanning less than ``min_span`` °C are left out; none left raises
    :class:`SegmentationError`.
    """
    _check_positive("min_rate", min_rate)
    _check_positive("smooth_s", smooth_s)
    need = {"t_start", "t_end", "temp"}
    if not need <= set(windows.columns):
        raise ConfigError(
            f"split_sweeps needs window columns {sorted(need)}, found {sorted(windows.columns)}"
        )
    source = windows.attrs.get("path")
    if len(windows) == 0:
        raise SegmentationError("no windows to split into sweeps", source=source)
    mid = ((windows["t_start"] + windows["t_end"]) / 2).to_numpy()
    temp = windows["temp"].to_numpy()
    lo = np.searchsorted(mid, mid - smooth_s / 2, side="left")
    hi = np.clip(np.searchsorted(mid, mid + smooth_s / 2, side="right") - 1, 0, len(mid) - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = 60.0 * (temp[hi] - temp[lo]) / (mid[hi] - mid[lo])
    rate = np.where(np.isfinite(rate), rate, 0.0)
    direction = np.where(rate > min_rate, 1, np.where(rate < -min_rate, -1, 0))
    pos = np.arange(len(direction))
    last = np.maximum.accumulate(np.where(direction != 0, pos, -1))
    filled = np.where(last >= 0, direction[np.maximum(last, 0)], 0)
    if (filled == 0).any() and (direction != 0).any():
        first = int(np.flatnonzero(direction != 0)[0])
        filled[:first] = direction[first]
    edges = np.flatnonzero(np.r_[True, filled[1:] != filled[:-1], True])
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=False):  # one iteration per ramp
        part = windows.iloc[a:b].copy()
        span = float(part["temp"].max() - part["temp"].min())
        if span < min_span or filled[a] == 0:
            continue
        t0 = float(part["temp"].iloc[0])
        part["dT"] = part["temp"] - t0
        part["dT2"] = part["dT"] ** 2
        part["sweep"] = len(out)
        part.attrs = dict(windows.attrs, t_ref=t0, direction=int(filled[a]))
        out.append(part.reset_index(drop=True))
    if not out:
        raise SegmentationError(
            f"no monotone temperature ramp spanning {min_span:g} °C or more "
            f"(rate threshold {min_rate:g} °C/min)",
            source=source,
        )
    return out
