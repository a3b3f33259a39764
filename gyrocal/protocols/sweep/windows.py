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
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
import pandas as pd

from ...io.errors import ConfigError, SegmentationError
from ...io.holds import SlopeSums, regression_rate
from ...io.log import GYRO, MOUNTS, RigLog
from ...io.stamps import Sampling, sampling
from ...terms import AXES
from ..registry import checked_options

REASONS = {
    "incomplete": "fewer samples than a full window (a logging gap or the log's end)",
    "reference": "the reference rate is not the sweep's constant rate",
    "mount": "the mount column changes or differs from the sweep's mount",
    "motion": "the gyro scatters well beyond the noise, or next to such a window",
}
MIN_WINDOW_SAMPLES = 8  # a burst this short gives a mean but no scatter worth the name
OPTIONS = "the config's protocols: sweep: options:, or static: options:"


def _check_positive(name: str, value) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value <= 0
    ):
        raise ConfigError(f"split_sweeps setting {name} must be a positive number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class WindowSettings:
    """How a log is cut into windows and which are kept: the window settings of the sweep's
    or the static protocol's options (the config schema's ``$defs/<protocol>_options``)."""

    window_s: float  # s
    motion_factor: float  # a window scattering this many times the typical window is motion
    settle_windows: int  # windows dropped either side of motion
    fill: float  # share of a window's samples that makes it complete
    min_span: float  # °C the kept windows span at least
    min_windows: int

    @classmethod
    def of(cls, protocol: str = "sweep", **given) -> WindowSettings:
        """``given`` settings of ``protocol``, checked against the config schema and
        completed with its defaults (``point_span``, not a window setting, is left out)."""
        options = checked_options(protocol, given)
        return cls(**{f.name: options[f.name] for f in fields(cls)})


class Grid(NamedTuple):
    """The windows laid over a log: each restarts at a run between the logger's real gaps."""

    run_starts: np.ndarray  # first row of each run
    run_stops: np.ndarray
    run_span: np.ndarray  # s each run covers
    window_of: np.ndarray  # the grid window of each row
    starts: np.ndarray  # first row of each window holding samples
    counts: np.ndarray  # rows in each window
    owner: np.ndarray  # the window of each row, numbered among those holding samples
    expected: np.ndarray  # the rows a complete window holds: a whole window's, or a whole burst's
    burst: np.ndarray  # the window is a run shorter than a window


class WindowStats(NamedTuple):
    """Per window: the gyro's mean and scatter, temperature, reference and inner gaps."""

    gyro: np.ndarray  # (k, 3) mean
    std: np.ndarray  # (k, 3) sample standard deviation
    temp: np.ndarray  # mean
    temp_rate: np.ndarray  # °C/min
    ref: np.ndarray  # mean reference rate
    ref_span: np.ndarray
    inner_gap: np.ndarray  # s: the longest step between the window's samples
    t_end: np.ndarray


def sweep_windows(
    log: RigLog, *, t_ref: float | None = None, mount: str | None = None, protocol: str = "sweep", **settings
) -> pd.DataFrame:
    """One row per kept window of ``log``; see the module docstring. ``settings``: the
    window settings (:class:`WindowSettings`) of ``protocol``'s options, by default its
    defaults.

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
    cfg = WindowSettings.of(protocol, **settings)
    if mount is not None and mount not in MOUNTS:
        raise ConfigError(f"mount must be one of {' '.join(MOUNTS)}, got {mount!r}")
    t = log.column("t")
    if len(t) < 3:
        raise SegmentationError(f"not a sweep: {len(t)} rows, expected a long log", source=log.path)
    stamps = sampling(t)
    grid = _window_grid(log, t, stamps, cfg.window_s)
    stats = _window_statistics(log, t, grid)
    reason = np.full(len(grid.starts), "", dtype=object)
    _drop_incomplete(log, reason, grid, stats, cfg, len(t), 1.0 / stamps.rate)
    rig_rate, tol = _rig_rate(log, reason, stats, cfg)
    mount_code, mount_source = _sweep_mount(log, reason, grid, stats, mount, rig_rate, tol)
    _drop_motion(reason, stats, cfg)
    keep = reason == ""
    _refuse_too_few(log, reason, stats, cfg)
    t0 = float(stats.temp[keep][0]) if t_ref is None else float(t_ref)
    out = _window_table(t, grid, stats, keep, mount_code, t0)
    dropped = {r: int(np.count_nonzero(reason == r)) for r in REASONS}
    grid_windows = _grid_windows(t, grid, cfg.window_s)
    dropped["incomplete"] += grid_windows - len(grid.starts)
    out.attrs.update(
        t_ref=t0,
        window_s=cfg.window_s,
        sample_rate=stamps.rate,
        runs=len(grid.run_starts),
        bursts=int(np.count_nonzero(grid.run_span < cfg.window_s)),
        stamps=stamps.warning(),
        longest_stall_s=stamps.longest_stall_s,
        rig_rate=rig_rate,
        mount=MOUNTS[mount_code] if mount_code >= 0 else "",
        mount_source=mount_source,
        dropped=dropped,
        windows_total=grid_windows,
        rows=len(t),
        path=log.path,
    )
    return out


def _window_grid(log: RigLog, t: np.ndarray, stamps: Sampling, window_s: float) -> Grid:
    """Where do the windows lie? Windows restart at each run between the logger's real
    gaps, so that a chamber's bursts are not cut by a grid laid from the log's start; a run
    shorter than a window (a burst) is one window of its own length. t increases strictly,
    so windows are runs of rows."""
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
    run_starts, run_stops = stamps.run_starts, stamps.run_stops
    run_of = np.repeat(np.arange(len(run_starts)), run_stops - run_starts)
    run_t0 = t[run_starts]
    run_span = t[run_stops - 1] - run_t0 + dt
    local = np.floor((t - run_t0[run_of]) / window_s).astype(np.int64)
    run_windows = np.floor((t[run_stops - 1] - run_t0) / window_s).astype(np.int64) + 1
    window_of = np.r_[0, np.cumsum(run_windows)[:-1]][run_of] + local
    starts = np.flatnonzero(np.r_[True, window_of[1:] != window_of[:-1]])
    counts = np.diff(np.r_[starts, len(t)])
    owner = np.repeat(np.arange(len(starts)), counts)
    expected = np.minimum(window_s, run_span[run_of[starts]]) * stamps.rate
    burst = run_span[run_of[starts]] < window_s
    return Grid(run_starts, run_stops, run_span, window_of, starts, counts, owner, expected, burst)


def _window_statistics(log: RigLog, t: np.ndarray, grid: Grid) -> WindowStats:
    """Each window's sums over its samples, every one centred on the window's first sample
    (exact squares, no cancellation)."""
    starts, counts, owner = grid.starts, grid.counts, grid.owner

    def sums(x):
        return np.add.reduceat(x, starts, axis=0)

    gyro = np.column_stack([log.column(c) for c in GYRO]).astype(np.float64)
    dev = gyro - gyro[starts][owner]
    s1, s2 = sums(dev), sums(dev * dev)
    mean_dev = s1 / counts[:, None]
    var = np.maximum(s2 - s1 * mean_dev, 0.0) / np.maximum(counts - 1, 1)[:, None]
    g_mean = gyro[starts] + mean_dev
    del dev

    temp = log.column("temp").astype(np.float64)
    tt = t - t[starts][owner]
    TT = temp - temp[starts][owner]
    window_sums = SlopeSums(counts, sums(tt), sums(TT), sums(tt * tt), sums(tt * TT))

    ref = log.column("ref_rate").astype(np.float64)
    step = np.r_[0.0, np.diff(t)]
    step[starts] = 0.0
    return WindowStats(
        gyro=g_mean,
        std=np.sqrt(var),
        temp=temp[starts] + window_sums.temp / counts,
        temp_rate=regression_rate(window_sums),
        ref=sums(ref) / counts,
        ref_span=np.maximum.reduceat(ref, starts) - np.minimum.reduceat(ref, starts),
        inner_gap=np.maximum.reduceat(step, starts),
        t_end=t[np.r_[starts[1:], len(t)] - 1],
    )


def _drop_incomplete(
    log: RigLog, reason, grid: Grid, stats: WindowStats, cfg: WindowSettings, rows: int, dt: float
) -> None:
    """Which windows are incomplete: too few samples, a burst too short to show scatter, or
    a gap inside? None complete is no sweep."""
    incomplete = (
        (grid.counts < cfg.fill * grid.expected)
        | (grid.burst & (grid.counts < MIN_WINDOW_SAMPLES))
        | (stats.inner_gap > np.maximum(3.0 * dt, (1 - cfg.fill) * grid.expected * dt))
    )
    reason[incomplete] = "incomplete"
    if not (reason == "").any():
        raise SegmentationError(
            f"not a sweep: no complete {cfg.window_s:g}-s window in {rows} rows; "
            f"a shorter window_s fits shorter stretches ({OPTIONS})",
            source=log.path,
        )


def _rig_rate(log: RigLog, reason, stats: WindowStats, cfg: WindowSettings) -> tuple[float, float]:
    """The sweep's constant rig rate (the complete windows' median) and the tolerance about
    it; windows off it are dropped. None on it is no sweep."""
    ok = reason == ""
    rig_rate = float(np.median(stats.ref[ok]))
    tol = 0.005 + 1e-3 * abs(rig_rate)
    reason[ok & ((stats.ref_span > tol) | (np.abs(stats.ref - rig_rate) > tol))] = "reference"
    if not (reason == "").any():
        raise SegmentationError(
            f"not a sweep: no {cfg.window_s:g}-s window holds the reference rate constant", source=log.path
        )
    return rig_rate, tol


def _sweep_mount(
    log: RigLog, reason, grid: Grid, stats: WindowStats, mount: str | None, rig_rate: float, tol: float
) -> tuple[int, str]:
    """The sweep's mount (index into MOUNTS, -1 at rig rate 0) and where it came from: the
    argument, the mount column's commonest label, or the data. Windows whose label changes
    or contradicts it are dropped (a null label contradicts nothing)."""
    codes = None
    if "mount" in log:
        m = log.column("mount").astype(np.int16)
        lo, hi = np.minimum.reduceat(m, grid.starts), np.maximum.reduceat(m, grid.starts)
        usable = (reason == "") & (lo == hi) & (lo >= 0)
        codes = np.where(lo == hi, lo, -2)
    if mount is not None:
        mount_code, mount_source = MOUNTS.index(mount), "argument"
    elif codes is not None and usable.any():
        mount_code, mount_source = int(np.bincount(codes[usable]).argmax()), "column"
    elif abs(rig_rate) > tol:
        # Without a label, the axis with the largest mean output is taken to lie along the
        # rig axis; a bias larger than the rate fools this, hence the mount column or argument.
        level = np.median(stats.gyro[reason == ""], axis=0)
        axis = int(np.argmax(np.abs(level)))
        mount_code, mount_source = 2 * axis + int(level[axis] * rig_rate < 0), "data"
    else:
        mount_code, mount_source = -1, ""
    if codes is not None:
        conflict = (codes == -2) | ((codes >= 0) & (mount_code >= 0) & (codes != mount_code))
        reason[(reason == "") & conflict] = "mount"
    return mount_code, mount_source


def _drop_motion(reason, stats: WindowStats, cfg: WindowSettings) -> None:
    """Which windows show motion: scatter far above the axis's typical scatter, plus
    ``settle_windows`` neighbours either side?"""
    ok = reason == ""
    typical = np.median(stats.std[ok], axis=0) if ok.any() else np.full(3, np.inf)
    moving = ok & (stats.std > cfg.motion_factor * np.maximum(typical, 1e-12)).any(axis=1)
    if cfg.settle_windows > 0 and moving.any():
        k = len(reason)
        c = np.r_[0, np.cumsum(moving)]
        pos = np.arange(k)
        near = (
            c[np.minimum(pos + cfg.settle_windows + 1, k)] - c[np.maximum(pos - cfg.settle_windows, 0)]
        ) > 0
        moving = (reason == "") & near
    reason[moving] = "motion"


def _refuse_too_few(log: RigLog, reason, stats: WindowStats, cfg: WindowSettings) -> None:
    """Too few kept windows, or too narrow a temperature span over them, is no sweep."""
    keep = reason == ""
    n_keep = int(keep.sum())
    if n_keep < cfg.min_windows:
        counts_by = pd.Series(reason[~keep]).value_counts().to_dict()
        raise SegmentationError(
            f"not a sweep: {n_keep} usable {cfg.window_s:g}-s windows, expected at least "
            f"{cfg.min_windows} (dropped: {counts_by or 'none'}); window_s and min_windows "
            f"set them ({OPTIONS})",
            source=log.path,
        )
    temps = stats.temp[keep]
    span = float(temps.max() - temps.min())
    if span < cfg.min_span:
        raise SegmentationError(
            f"not a sweep: temperature spans {span:.3g} °C over the usable windows, "
            f"expected at least {cfg.min_span:g} °C",
            source=log.path,
        )


def _window_table(t, grid: Grid, stats: WindowStats, keep, mount_code: int, t0: float) -> pd.DataFrame:
    """The kept windows, ΔT counted from ``t0``."""
    expected = np.zeros((len(keep), 3))
    if mount_code >= 0:
        axis, sign = mount_code // 2, (1.0 if mount_code % 2 == 0 else -1.0)
        expected[:, axis] = sign * stats.ref
    err = stats.gyro - expected
    temps = stats.temp[keep]
    dT = temps - t0
    return pd.DataFrame(
        {
            "window": np.flatnonzero(keep),
            "t_start": t[grid.starts][keep],
            "t_end": stats.t_end[keep],
            "n": grid.counts[keep].astype(np.int64),
            "temp": temps,
            "dT": dT,
            "dT2": dT * dT,
            "temp_rate": stats.temp_rate[keep],
            "ref_rate": stats.ref[keep],
            **{f"gyro_{a}": stats.gyro[keep, i] for i, a in enumerate(AXES)},
            **{f"std_{a}": stats.std[keep, i] for i, a in enumerate(AXES)},
            **{f"err_{a}": err[keep, i] for i, a in enumerate(AXES)},
            "mount": MOUNTS[mount_code] if mount_code >= 0 else "",
        }
    )


def _grid_windows(t: np.ndarray, grid: Grid, window_s: float) -> int:
    """The windows of the grid, counting those a pause of a continuous log left without
    samples (a burst logger's pauses are its design, not lost windows)."""
    pause = t[grid.run_starts[1:]] - t[grid.run_stops[:-1] - 1]
    continuous = (grid.run_span[:-1] >= window_s) & (grid.run_span[1:] >= window_s)
    lost = int(np.sum(np.floor(pause[continuous] / window_s)))
    return int(grid.window_of[-1]) + 1 + lost


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
    out: list[pd.DataFrame] = []
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
