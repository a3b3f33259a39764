"""Find the protocol's phases in a rig log from the data alone.

The log carries no labels (contract section 1). Working on fixed-size blocks of samples
(:mod:`gyrocal.io.blocks`), segmentation

1. splits the log where the reference rate changes (ramps) or the logger paused (gaps);
2. inside each constant-reference run, marks blocks where the gyro moves although the
   reference does not: a jump between neighbouring block means beyond the run's noise and
   what the reference's own wobble explains, or (table still) scatter inside a block well
   above the noise. That is a person handling the unit, or a knock; it is rejected, with a
   settling margin;
3. takes the quiet stretches left as holds and trims a transient from both ends; a very
   long still stretch is a soak, whose tail serves as the rate-0 hold;
4. checks each hold: steady (its halves agree), not saturated, the gyro agreeing with the
   reference, temperature stable, mount known (mount column, dominant gyro axis, or the
   neighbouring holds of the same mounting);
5. groups accepted holds into temperature points.

Block-level work is vectorised; hold statistics are ``reduceat`` sums over hold blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pandas as pd

from ...io import plausibility
from ...io.blocks import block_statistics
from ...io.errors import SegmentationError
from ...io.holds import (
    Segmentation,
    bucketed,
    hold_table,
    temperature_points,
    thirds_rate,
    thirds_rate_error,
    true_runs,
)
from ...io.log import GYRO, MOUNTS, RigLog, read_log
from ...terms import AXES
from .config import SegmentConfig

LOG_COLUMNS = ("mount", "accel_x", "accel_y", "accel_z")  # optional columns segmentation uses

REASONS = {
    "handling_motion": "the gyro moves while the reference rate is constant",
    "too_short": "shorter than the minimum hold",
    "reference_drift": "the reference rate drifts during the hold",
    "not_steady": "the gyro mean changes between the first and second half",
    "mount_changes": "the mount column changes during the hold",
    "mount_mismatch": "the mount column and the gyro disagree on the mount",
    "mount_undetermined": "the mount cannot be told from the data or the mount column",
    "gyro_disagrees": "the gyro reading is implausibly far from the reference rate",
    "saturated": "the gyro output is clipped at its full-scale range",
    "stuck_axis": "an output axis reads one value through the hold (stuck or disconnected)",
    "unstable_temperature": "the temperature changes faster than the stability limit",
}


def segment_file(path, config: SegmentConfig | None = None) -> tuple[RigLog, Segmentation]:
    """Read a log (only the columns segmentation uses) and segment it."""
    log = read_log(path, optional=LOG_COLUMNS)
    return log, segment(log, config)


def segment(log: RigLog, config: SegmentConfig | None = None) -> Segmentation:
    """Segment a log into constant-rate holds; see the module docstring.

    Holds should span a dozen blocks or more, so that trimming and settling margins (whole
    blocks) leave most of them; for a protocol of short holds the blocks are made shorter.
    """
    cfg = config or SegmentConfig()
    blk, size, dt = block_statistics(log, cfg.block_s)
    typical = _typical_rotating_run(blk, size, dt, cfg)
    if typical is not None and typical < 12 * size * dt and size > 4:
        blk, size, dt = block_statistics(log, max(typical / 12, 4 * dt))
    return _segment_blocks(log, blk, size, dt, cfg)


def _typical_rotating_run(blk, size, dt, cfg) -> float | None:
    """Median duration (s) of the runs of blocks at one constant non-zero reference rate."""
    r = blk.get("ref")
    if r is None or len(r) < 2:
        return None
    tol = cfg.rate_tol_abs + cfg.rate_tol_rel * np.abs(r)
    const = (blk["ref_span"] <= tol) & (np.abs(r) > tol)
    same = np.r_[False, np.abs(np.diff(r)) <= tol[1:]] & const & np.r_[False, const[:-1]]
    run_id = np.cumsum(const & ~same) - 1
    lengths = np.bincount(run_id[const]) if const.any() else np.array([])
    return float(np.median(lengths) * size * dt) if len(lengths) else None


def _median(values: np.ndarray, axis=None, limit: int = 50_000):
    """Median of a deterministic stride sample: robust levels need no more than 50k values."""
    step = max(1, len(values) // limit)
    return np.median(values[::step], axis=axis)


def _range_sums(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Sums over consecutive non-empty ranges beginning at ``starts``."""
    return np.add.reduceat(values, starts, axis=0)


def _range_index(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Concatenation of arange(lo[i], hi[i]) for all i, vectorised."""
    lengths = hi - lo
    offsets = np.repeat(lo - np.r_[0, np.cumsum(lengths)[:-1]], lengths)
    return np.arange(lengths.sum()) + offsets


class Runs(NamedTuple):
    """Step 1: where the log paused and where the reference rate stays constant."""

    in_gap: np.ndarray  # the block holds a logging pause
    gap_before: np.ndarray  # a logging pause precedes the block
    tol: np.ndarray  # how far the block's reference may move and still count as constant
    const: np.ndarray  # the block is at constant reference, without a pause
    run: np.ndarray  # the constant-reference run a block belongs to
    n_runs: int


class Motion(NamedTuple):
    """Step 2: where the gyro moves although the reference does not."""

    noise_log: np.ndarray  # the log's noise per sample and axis
    allowance: np.ndarray  # per run (dummy run last), the settling its output may show
    active: np.ndarray  # the block shows motion
    level: np.ndarray  # per run, the gyro's steady level
    gain: np.ndarray  # per run, the gyro's gain on the reference
    excursion: np.ndarray  # per active block, its distance from the run's steady value
    near_motion: np.ndarray  # within the settling margin of motion
    usable: np.ndarray  # constant reference and clear of motion


class Stretches(NamedTuple):
    """Step 3: the quiet stretches, soaks among them, and the hold each leaves."""

    starts: np.ndarray
    stops: np.ndarray
    typical: float  # s: the typical rotating stretch
    min_hold: float  # s
    soak_min: float  # s
    is_soak: np.ndarray
    h_start: np.ndarray  # where the hold begins (a soak's tail)
    trim: int  # blocks trimmed from both ends
    c0: np.ndarray  # the hold's first block after trimming
    c1: np.ndarray  # its stop block after trimming
    long_enough: np.ndarray


def _segment_blocks(log: RigLog, blk: dict, size: int, dt: float, cfg: SegmentConfig) -> Segmentation:
    nb = len(blk.get("t_first", ()))
    if nb < 8:
        raise SegmentationError(f"log too short to segment ({len(log)} rows)", source=log.path)
    if not dt > 0:
        raise SegmentationError("cannot determine the sample interval", source=log.path)
    block_dt = size * dt
    runs = _constant_runs(log, blk, size, dt, cfg)
    motion = _handling_motion(blk, runs, size, block_dt, cfg)
    st = _quiet_stretches(log, blk, motion, runs, block_dt, cfg)
    segments = _phase_segments(blk, runs, motion, st, block_dt)
    _refuse_without_long_holds(log, st, block_dt)
    c0, c1 = st.c0[st.long_enough], st.c1[st.long_enough]
    h = _hold_statistics(log, blk, size, c0, c1, runs, motion, cfg)
    checked = _check_holds(log, h, blk, c0, c1, runs, motion, cfg)
    accepted = checked.reason == ""
    for i in np.flatnonzero(~accepted):
        segments.append(("rejected", checked.reason[i], checked.detail[i], c0[i], c1[i]))
    for i in np.flatnonzero(accepted):
        segments.append(("hold", "", "", c0[i], c1[i]))
    if not accepted.any():
        _refuse_without_accepted_holds(log, h, checked.reason)
    # The table's angle at each hold's start, from its first sample: the reference rate
    # summed over the samples. An effect fixed in the lab shows through it (gyrocal.diagnosis.lab).
    table_angle = np.mod(np.r_[0.0, np.cumsum(blk["ref"] * block_dt, dtype=np.float64)][c0], 360.0)
    obs = _observation_table(h, accepted, checked, table_angle, cfg)
    seg = _segment_table(segments, blk["t_first"], blk["t_last"], blk["ref"], obs)
    info = dict(
        path=log.path,
        rows_read=log.rows_read,
        rows_dropped=log.rows_dropped,
        rows_used=len(log),
        sample_rate=1.0 / dt,
        block_samples=size,
        typical_hold_s=st.typical,
        min_hold_s=st.min_hold,
        soak_min_s=st.soak_min,
        noise_per_sample=motion.noise_log.tolist(),
        holds_accepted=int(accepted.sum()),
        rejected_by_reason=seg.loc[seg["kind"] == "rejected", "reason"].value_counts().sort_index().to_dict(),
        temperature_points=int(obs["point"].max()) + 1,
        has_mount_column="mount" in log,
    )
    timeline = bucketed(blk["t_first"], blk["t_last"], blk["temp"], blk["ref"], blk["gyro"].T)
    return Segmentation(obs, seg, _stable_periods(blk, block_dt, cfg), timeline, info)


def _constant_runs(log: RigLog, blk: dict, size: int, dt: float, cfg: SegmentConfig) -> Runs:
    """Where did the logger pause, and where is the reference rate constant? A gap is a
    pause in logging longer than gap_factor intervals; one shorter than gap_bridge_s does
    not interrupt a hold (the rig kept doing what it did)."""
    t_first, t_last, r = blk["t_first"], blk["t_last"], blk["ref"]
    pause_in = (t_last - t_first) - (size - 1) * dt
    pause_before = np.r_[0.0, t_first[1:] - t_last[:-1] - dt]
    gap_limit = max(cfg.gap_bridge_s, (cfg.gap_factor - 1) * dt)
    in_gap = pause_in > gap_limit
    gap_before = np.r_[False, pause_before[1:] > gap_limit]
    tol = np.maximum(cfg.rate_tol_abs + cfg.rate_tol_rel * np.abs(r), 3.0 * _median(blk["ref_span"]))
    const = (blk["ref_span"] <= tol) & ~in_gap
    level_step = np.r_[True, np.abs(np.diff(r)) > tol[1:]]
    new_run = const & (level_step | gap_before | ~np.r_[False, const[:-1]])
    run = np.cumsum(new_run) - 1
    n_runs = int(run[-1]) + 1 if new_run.any() else 0
    if n_runs == 0:
        raise SegmentationError("the reference rate is never constant: no hold to use", source=log.path)
    return Runs(in_gap, gap_before, tol, const, run, n_runs)


def _handling_motion(blk: dict, runs: Runs, size: int, block_dt: float, cfg: SegmentConfig) -> Motion:
    """Where does the gyro move at constant reference, and which blocks lie within the
    settling margin of such motion?

    An output that settles after a step of the table's rate (a slow pole, a part of the
    output that follows the rate through a lag) is the sensor's, not a hand's: a run where
    the table turns allows changes up to ``settling`` times the step into it (deg/s), block
    to block in proportion to the block's length over a second (a settling of time constant
    ≥ 1 s). Where the table stands still (handling, the static stretches the noise is
    measured on) nothing is allowed: a settling output is left out there."""
    const, run, n_runs, r = runs.const, runs.run, runs.n_runs, blk["ref"]
    var = blk["gyro_var"]
    ci = np.flatnonzero(const)
    noise_log = np.maximum(np.sqrt(np.median(var[ci[:: max(1, len(ci) // 50_000)]], axis=0)), 1e-9)
    run_ref = np.bincount(run[const], weights=r[const], minlength=n_runs) / np.maximum(
        np.bincount(run[const], minlength=n_runs), 1
    )
    step_into = np.abs(np.diff(np.r_[0.0, run_ref]))
    turning = np.abs(run_ref) > cfg.rate_tol_abs + cfg.rate_tol_rel * np.abs(run_ref)
    allowance = np.r_[cfg.settling * step_into * turning, 0.0]  # per run, dummy run last
    active, level, gain, excursion = _motion(
        const, run, n_runs, blk["gyro"], var, r, noise_log, size, cfg, allowance * min(block_dt, 1.0)
    )
    nb = len(const)
    settle = int(math.ceil(cfg.settle_s / block_dt))
    c_act = np.r_[0, np.cumsum(active)]
    pos = np.arange(nb)
    near_motion = (c_act[np.minimum(pos + settle + 1, nb)] - c_act[np.maximum(pos - settle, 0)]) > 0
    usable = const & ~near_motion
    return Motion(noise_log, allowance, active, level, gain, excursion, near_motion, usable)


def _quiet_stretches(
    log: RigLog, blk: dict, motion: Motion, runs: Runs, block_dt: float, cfg: SegmentConfig
) -> Stretches:
    """Which quiet constant-rate stretches are soaks, and what hold does each leave once
    trimmed? A very long still stretch is a soak, whose tail serves as the rate-0 hold."""
    usable = motion.usable
    key = np.where(usable, runs.run, -1)
    change = np.r_[True, key[1:] != key[:-1]]
    starts = np.flatnonzero(usable & change)
    stops = np.flatnonzero(usable & np.r_[change[1:], True]) + 1
    if not len(starts):
        raise SegmentationError("no quiet constant-rate stretch found", source=log.path)
    s_ref = blk["ref"][starts]
    s_tol = cfg.rate_tol_abs + cfg.rate_tol_rel * np.abs(s_ref)
    s_dur = (stops - starts) * block_dt
    rotating = np.abs(s_ref) > s_tol
    typical = float(np.median(s_dur[rotating] if rotating.any() else s_dur))
    min_hold = cfg.min_hold_s if cfg.min_hold_s is not None else 0.25 * typical
    soak_min = cfg.soak_min_s if cfg.soak_min_s is not None else 5.0 * typical
    is_soak = ~rotating & (s_dur >= soak_min)
    tail = max(int(round(typical / block_dt)), 1)
    h_start = np.where(is_soak, np.maximum(starts, stops - tail), starts)
    trim = int(math.ceil(cfg.trim_s / block_dt))
    c0, c1 = h_start + trim, stops - trim
    long_enough = (c1 - c0) * block_dt >= max(min_hold, block_dt)
    return Stretches(starts, stops, typical, min_hold, soak_min, is_soak, h_start, trim, c0, c1, long_enough)


def _phase_segments(blk: dict, runs: Runs, motion: Motion, st: Stretches, block_dt: float) -> list[tuple]:
    """Every phase before the holds are checked, as (kind, reason, detail, first block,
    stop block): ramps, gaps, handling motion and the settling after it, soaks, stretches
    too short to hold, and what trimming took off the holds."""
    segments: list[tuple] = []
    for b0, b1 in zip(*true_runs(~runs.const & ~runs.in_gap), strict=False):
        segments.append(("ramp", "", "", b0, b1))
    for b0, b1 in zip(*true_runs(runs.in_gap), strict=False):
        segments.append(("gap", "", "", b0, b1))
    for b0, b1 in zip(*true_runs(motion.active), strict=False):
        away = (
            f"gyro {motion.excursion[b0:b1].max():.3g} deg/s away from its steady value "
            f"at reference {blk['ref'][b0]:.4g} deg/s"
        )
        segments.append(("rejected", "handling_motion", away, b0, b1))
    for b0, b1 in zip(*true_runs(motion.near_motion & runs.const & ~motion.active), strict=False):
        segments.append(("transient", "", "settling after motion", b0, b1))
    for i in np.flatnonzero(st.is_soak):
        segments.append(("soak", "", "", st.starts[i], st.h_start[i]))
    for i in np.flatnonzero(~st.long_enough):
        left = f"{max(st.c1[i] - st.c0[i], 0) * block_dt:.3g} s after trimming, minimum {st.min_hold:.3g} s"
        segments.append(("rejected", "too_short", left, st.h_start[i], st.stops[i]))
    for i in np.flatnonzero(st.long_enough & (st.trim > 0)):
        segments.append(("transient", "", "trimmed", st.h_start[i], st.c0[i]))
        segments.append(("transient", "", "trimmed", st.c1[i], st.stops[i]))
    return segments


def _refuse_without_long_holds(log: RigLog, st: Stretches, block_dt: float) -> None:
    if not st.long_enough.any():
        longest = (st.c1 - st.c0)[~st.is_soak].max(initial=0) * block_dt
        raise SegmentationError(
            f"no constant-rate hold long enough: the longest lasts {max(longest, 0):.3g} s "
            f"after trimming, the minimum is {max(st.min_hold, block_dt):.3g} s",
            source=log.path,
        )


class Checked(NamedTuple):
    """Step 4: why each hold was rejected ("" where accepted) and the mount it was taken on."""

    reason: np.ndarray
    detail: np.ndarray
    mounts: np.ndarray  # index into MOUNTS, -1 where unknown
    source: np.ndarray  # where the mount came from: both, column, data, inherited


class _Verdicts:
    """The first failing check of each hold: its reason and the words that say why."""

    def __init__(self, k: int):
        self.reason = np.full(k, "", dtype=object)
        self.detail = np.full(k, "", dtype=object)

    def reject(self, mask: np.ndarray, code: str, text: Callable[[int], str]) -> None:
        mask = mask & (self.reason == "")
        self.reason[mask] = code
        for i in np.flatnonzero(mask):
            self.detail[i] = text(int(i))


def _check_holds(
    log: RigLog, h: dict, blk: dict, c0: np.ndarray, c1: np.ndarray, runs: Runs, motion: Motion, cfg
) -> Checked:
    """Which holds pass the checks, in order (the first failing one is the reason): steady
    reference and output, not saturated, no stuck axis, a known mount, the gyro agreeing
    with the reference, a stable temperature."""
    verdicts = _Verdicts(len(c0))
    reject = verdicts.reject
    reject(
        h["ref_drift"] > h["ref_tol"],
        "reference_drift",
        lambda i: f"reference spans {h['ref_drift'][i]:.3g} deg/s (tolerance {h['ref_tol'][i]:.3g})",
    )
    reject(
        h["not_steady"],
        "not_steady",
        lambda i: f"halves differ by {h['half_diff'][i]:.3g} deg/s (limit {h['half_limit'][i]:.3g})",
    )
    reject(
        h["saturated"] > cfg.saturation_fraction,
        "saturated",
        lambda i: f"{100 * h['saturated'][i]:.3g} % of samples at the output limit",
    )
    # No sensor's output holds one value to the bit through a hold while the others move:
    # an axis stuck or disconnected there, whose zero scatter would also zero its floor.
    stuck = (h["var"] == 0) & (h["n"] > 1)[:, None] & (h["var"] > 0).any(axis=1, keepdims=True)
    reject(
        stuck.any(axis=1),
        "stuck_axis",
        lambda i: f"{GYRO[int(np.argmax(stuck[i]))]} reads one value through the hold",
    )
    mounts, source = _assign_mounts(h, blk, c0, c1, motion.active, runs.in_gap, runs.gap_before, cfg, reject)
    axis = np.where(mounts >= 0, mounts // 2, 0)
    sign = np.where(mounts % 2 == 0, 1.0, -1.0)
    _check_agreement(log, h, verdicts, mounts, axis, sign, cfg)
    # A short hold's rate estimate is noisy: reject only rates significantly over the limit.
    # Each hold is fitted at its own temperature, so one still moving after a door's upset
    # (tenths of a °C/min) serves; one taken during a chamber's ramp reads a temperature its
    # die lags by degrees.
    reject(
        np.abs(h["temp_rate"]) - 3.0 * h["temp_rate_sd"] > cfg.hold_max_temp_rate,
        "unstable_temperature",
        lambda i: (
            f"{h['temp_rate'][i]:.3g} ± {h['temp_rate_sd'][i]:.2g} °C/min (limit {cfg.hold_max_temp_rate:g})"
        ),
    )
    return Checked(verdicts.reason, verdicts.detail, mounts, source)


def _check_agreement(
    log: RigLog, h: dict, verdicts: _Verdicts, mounts: np.ndarray, axis: np.ndarray, sign: np.ndarray, cfg
) -> None:
    """Does the gyro agree with the reference rate about the hold's mount? Most of an
    axis' holds off by one ratio is a unit or a sign, not a few bad holds: an error of the
    log (:func:`gyrocal.io.plausibility.rate_ratio_check`)."""
    rate_vec = np.zeros((len(mounts), 3))
    rate_vec[np.arange(len(mounts)), axis] = np.where(mounts >= 0, sign * h["ref"], 0.0)
    err = np.abs(h["mean"] - rate_vec)
    limit = cfg.agree_scale * np.abs(h["ref"])[:, None] + cfg.agree_bias
    verdicts.reject(
        (err > limit).any(axis=1) & (mounts >= 0),
        "gyro_disagrees",
        lambda i: (
            f"gyro {np.round(h['mean'][i], 3).tolist()} deg/s for reference "
            f"{h['ref'][i]:.4g} deg/s about {MOUNTS[mounts[i]]}"
        ),
    )
    turning = (mounts >= 0) & (np.abs(h["ref"]) > 10 * cfg.agree_bias)
    disagree = turning & (verdicts.reason == "gyro_disagrees")
    plausibility.rate_ratio_check(
        {
            "xyz"[a]: h["mean"][disagree & (axis == a), a] / (sign * h["ref"])[disagree & (axis == a)]
            for a in range(3)
        },
        {"xyz"[a]: int(np.count_nonzero(turning & (axis == a))) for a in range(3)},
        source=log.path,
    )


def _refuse_without_accepted_holds(log: RigLog, h: dict, reason: np.ndarray) -> None:
    counts = pd.Series(reason).value_counts()
    still = not np.any(h["ref"])
    raise SegmentationError(
        "no hold passed the checks ("
        + ", ".join(f"{k}: {v}" for k, v in counts.items())
        + ")"
        + (
            "; the reference rate is 0 throughout: a static log, not a turntable's (--protocol "
            "sweep for a temperature sweep, --protocol static for a unit lying still; gyrocal "
            "noise reads either)"
            if still
            else ""
        ),
        source=log.path,
    )


def _motion(const, run, n_runs, mean, var, r, noise_log, size, cfg, allowance=None):
    """Mark constant-reference blocks where the gyro moves; see the module docstring.

    Returns each block's activity, each run's steady gyro level and its gain on the
    reference, and each active block's distance from its run's steady value (deg/s).
    The first pass tests every block (those outside runs belong to a dummy run that is
    never active); a second re-estimates the noise and level of the runs that contained
    motion from their quiet blocks only, and tests those runs again.
    """
    nb = len(const)
    run_of = np.where(const, run, n_runs)  # dummy run n_runs: not constant
    active = np.zeros(nb, dtype=bool)
    level = np.zeros((n_runs + 1, 3))
    gain = np.zeros((n_runs + 1, 3))
    blocks = None  # None: all blocks, no gathers
    for _ in range(2):
        idx, m_b, v_b, r_b, c_b, a_b = (
            a if blocks is None else a[blocks] for a in (run_of, mean, var, r, const, active)
        )
        quiet = c_b & ~a_b
        count = np.bincount(idx, weights=quiet, minlength=n_runs + 1)
        noise = np.where(count[:, None] > 0, np.sqrt(_quiet_mean(v_b, idx, quiet, count)), noise_log)
        noise = np.clip(noise, noise_log / cfg.noise_cap, noise_log * cfg.noise_cap).astype(np.float32)
        runs = np.unique(idx)
        level[runs] = _quiet_mean(m_b, idx, quiet, count)[runs]
        r_run = _quiet_mean(r_b[:, None], idx, quiet, count)[:, 0]
        moving = np.abs(r_run) > cfg.rate_tol_abs
        # The gyro follows small reference wobble (table settling, rate ripple): the run's
        # measured gain takes out what the reference explains, leaving motion it does not.
        gain[runs] = np.where(
            moving[runs, None], level[runs] / np.where(moving[runs], r_run[runs], 1.0)[:, None], 0.0
        )
        resid = (m_b - gain[idx] * r_b[:, None]).astype(np.float32)
        sd = noise[idx]
        # Scatter inside a block is tested where the table stands still, which is where a
        # person handles the unit; on a turning table the gyro's scatter follows the
        # table's own wobble, and the jump test still sees a knock.
        scatter = (v_b > 9.0 * sd * sd).any(axis=1) & ~moving[idx]
        threshold = np.maximum(
            np.float32(cfg.motion_sigma * math.sqrt(2.0 / size)) * sd, np.float32(cfg.motion_floor)
        )
        if allowance is not None:
            threshold = threshold + allowance[idx, None].astype(np.float32)
        step = (np.abs(np.diff(resid, axis=0)) > threshold[1:]).any(axis=1)
        adjacent = np.ones(len(idx) - 1, dtype=bool) if blocks is None else np.diff(blocks) == 1
        jump = np.r_[False, step & (idx[1:] == idx[:-1]) & adjacent]
        found = (scatter | jump | np.r_[jump[1:], False]) & (idx < n_runs)
        if blocks is None:
            active = found
        else:
            active[blocks] = found
        with_motion = np.zeros(n_runs + 1, dtype=bool)
        with_motion[run_of[active]] = True
        with_motion[n_runs] = False
        blocks = np.flatnonzero(with_motion[run_of])
        if not len(blocks):
            break
    excursion = np.zeros(nb)
    a = np.flatnonzero(active)
    excursion[a] = np.abs(mean[a] - level[run[a]]).max(axis=1)
    return active, level[:n_runs], gain[:n_runs], excursion


def _quiet_mean(values: np.ndarray, run: np.ndarray, quiet: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Per-run mean of (k, m) block values over the run's quiet blocks."""
    # where, not a product: a block variance that overflowed to inf times 0 would be NaN.
    sums = np.column_stack(
        [
            np.bincount(run, weights=np.where(quiet, values[:, a], 0.0), minlength=len(count))
            for a in range(values.shape[1])
        ]
    )
    return sums / np.maximum(count, 1)[:, None]


def _hold_statistics(log, blk, size, c0, c1, runs: Runs, motion: Motion, cfg) -> dict:
    """Per-hold sums over the blocks ``c0:c1`` of each hold: means, variances, steadiness,
    temperature rate.

    A hold's scatter is its blocks' own scatter plus the blocks' spread about the hold mean;
    block means are taken relative to the run's steady level first, so the sums hold
    noise-sized numbers and lose nothing to cancellation.
    """
    r, mean, var = blk["ref"], blk["gyro"], blk["gyro_var"]
    lead = runs.run[c0]  # each hold's run
    level, gain, allowance = motion.level[lead], motion.gain[lead], motion.allowance[lead]
    lengths = c1 - c0
    first = np.r_[0, np.cumsum(lengths)[:-1]]  # where each hold starts among the hold blocks
    hb = _range_index(c0, c1)
    owner = np.repeat(np.arange(len(c0)), lengths)
    n = lengths * size
    dev = mean[hb] - level[owner]
    hold_dev = _range_sums(dev, first) / lengths[:, None]
    within = _range_sums(var[hb].astype(np.float64), first) * (size - 1)
    between = _range_sums((dev - hold_dev[owner]) ** 2, first) * size
    hold_var = (within + between) / (n - 1)[:, None]
    hold_mean = level + hold_dev
    r_hb = r[hb]
    ref = _range_sums(r_hb, first) / lengths
    temp = _range_sums(blk["temp"][hb].astype(np.float64), first) / lengths
    ref_drift = np.maximum.reduceat(r_hb, first) - np.minimum.reduceat(r_hb, first)

    # Steadiness: the first and second halves of the hold agree, once the part the
    # reference explains (gyro gain times reference change) is taken out.
    first_half = np.arange(len(hb)) - np.repeat(first, lengths) < np.repeat(lengths // 2, lengths)
    n1 = (lengths // 2) * size
    n2 = n - n1
    resid = dev - gain[owner] * (r_hb - ref[owner])[:, None]
    d1 = _range_sums(np.where(first_half[:, None], resid, 0.0), first) / np.maximum(lengths // 2, 1)[:, None]
    d2 = _range_sums(np.where(first_half[:, None], 0.0, resid), first) / (lengths - lengths // 2)[:, None]
    half_diff = np.abs(d2 - d1)
    steady_limit = (
        cfg.motion_sigma * np.sqrt(hold_var) * np.sqrt(1.0 / np.maximum(n1, 1) + 1.0 / n2)[:, None]
        + cfg.motion_floor
    )
    half_limit = steady_limit + allowance[:, None]
    settling = (half_diff > steady_limit).any(axis=1)
    if settling.any():
        hold_var = np.where(settling[:, None], _settled_scatter(log, c0, c1, size, settling), hold_var)
    worst = np.argmax(half_diff - half_limit, axis=1)
    rows = np.arange(len(c0))
    rate, rate_sd = _hold_temp_rate(blk, c0, c1)
    out = dict(
        n=n,
        mean=hold_mean,
        var=hold_var,
        ref=ref,
        temp=temp,
        temp_rate=rate,
        temp_rate_sd=rate_sd,
        t_start=blk["t_first"][c0],
        t_end=blk["t_last"][c1 - 1],
        ref_drift=ref_drift,
        ref_tol=runs.tol[c0],
        not_steady=(half_diff > half_limit).any(axis=1) & (lengths >= 2),
        half_diff=half_diff[rows, worst],
        half_limit=half_limit[rows, worst],
        # The output's change from the hold's first half to its second (signed, per
        # axis): what a slow pole leaves after the step into the hold.
        settle=np.where((lengths >= 2)[:, None], d2 - d1, np.nan),
        saturated=_saturation(blk, size, c0, c1, n, hold_mean, hold_var, log, cfg.full_scale),
    )
    if "accel" in blk:
        out["accel"] = _hold_accel(blk["accel"], hb, first)
    return out


def _settled_scatter(log, c0, c1, size: int, settling: np.ndarray) -> np.ndarray:
    """The per-sample variance of each hold whose output settles (rows of the others NaN),
    from its samples' second differences: ``x[i+1] − 2x[i] + x[i−1]`` has variance 6σ² for
    white noise, and a settling's slope cancels in it, its curvature (the step over τ², times
    the sample interval squared) far below the noise. A block's own variance or the spread of
    block means holds the slope (slope² × block² / 12), and most where the step into the hold
    is largest: a floor made of them would be made of the effect."""
    out = np.full((len(c0), len(GYRO)), np.nan)
    settling_holds = np.flatnonzero(settling)
    parts = log.row_ranges(GYRO, [(c0[h] * size, c1[h] * size) for h in settling_holds])
    for h, part in zip(settling_holds, parts, strict=True):  # per hold, each vectorised
        x = np.column_stack([np.asarray(part[g], dtype=np.float64) for g in GYRO])
        if len(x) >= 3:
            d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
            out[h] = np.nanmean(d2**2, axis=0) / 6.0
    return out


def _hold_accel(accel: np.ndarray, hb: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Each hold's mean specific force over its blocks that have accelerometer data."""
    acc = accel[hb].astype(np.float64)
    have = np.isfinite(acc)
    with np.errstate(invalid="ignore"):
        return _range_sums(np.where(have, acc, 0.0), first) / _range_sums(have * 1.0, first)


def _hold_temp_rate(blk, c0, c1) -> tuple[np.ndarray, np.ndarray]:
    """Temperature rate (°C/min) of each hold and its standard error from the log's
    block-to-block temperature scatter."""
    temp = blk["temp"]
    t_mid = (blk["t_first"] + blk["t_last"]) / 2
    block_noise = 1.4826 * _median(np.abs(np.diff(temp))) / math.sqrt(2.0)
    return thirds_rate(temp, t_mid, c0, c1), thirds_rate_error(block_noise, t_mid, c0, c1)


def _saturation(blk, size, c0, c1, n, mean, var, log, full_scale) -> np.ndarray:
    """Share of each hold's samples at the output limit.

    The limit is ``full_scale`` (within 0.1 %) when the sensor's range is configured;
    otherwise the log's extreme output values, which a clipped hold piles samples onto: the
    extreme level then holds more samples than the level next to it, where an unclipped
    noise tail holds fewer (a quantised output reaches its extreme value several times a
    hold without being clipped). Without the range a sensor quieter than one quantisation
    step could pile samples onto its top level unclipped, so configure ``full_scale`` for
    such sensors. Only holds within eight standard deviations of a limit are read back and
    counted.
    """
    share = np.zeros(len(c0))
    if full_scale:
        hi = np.full(3, 0.999 * full_scale)
        lo = -hi
    else:
        hi, lo = blk["gyro_max"], blk["gyro_min"]
    reach = 8.0 * np.sqrt(var)
    near = ((mean + reach >= hi) | (mean - reach <= lo)).any(axis=1)
    near = np.flatnonzero(near)
    samples = log.row_ranges(GYRO, [(c0[i] * size, c1[i] * size) for i in near]) if near.size else []
    for i, x in zip(near, samples, strict=False):
        worst = max(_piled(x[name], hi[a], lo[a], bool(full_scale)) for a, name in enumerate(GYRO))
        share[i] = worst / n[i] if (worst >= 2 or full_scale) else 0.0
    return share


def _piled(x: np.ndarray, hi: float, lo: float, known_range: bool) -> int:
    """Samples at a limit; without a known range, only a limit level holding at least
    twice the samples of the level next to it counts (a pile, not a tail)."""
    most = 0
    for at_limit, inside, nearest in ((x >= hi, x < hi, np.max), (x <= lo, x > lo, np.min)):
        count = int(np.count_nonzero(at_limit))
        if count and not known_range and inside.any():
            rest = x[inside]
            if count < 2 * int(np.count_nonzero(rest == nearest(rest))):
                count = 0
        most = max(most, count)
    return most


def _assign_mounts(h, blk, c0, c1, active, in_gap, gap_before, cfg, reject):
    """Mount index per hold from the mount column and/or the gyro; -1 where unknown."""
    k = len(c0)
    from_data = np.full(k, -1)
    strong = np.abs(h["ref"]) >= cfg.mount_min_rate
    ax = np.argmax(np.abs(h["mean"]), axis=1)
    sgn = np.sign(h["mean"][np.arange(k), ax] * h["ref"])
    from_data[strong] = (2 * ax + (sgn < 0))[strong]

    from_column = np.full(k, -1)
    if "mount_first" in blk:
        first = blk["mount_first"].astype(int)
        mixed = first != blk["mount_last"]
        change = np.r_[0, np.cumsum(mixed | np.r_[False, first[1:] != first[:-1]])]
        changes = ((change[c1] - change[c0 + 1]) > 0) | mixed[c0]
        from_column = np.where(changes, -2, first[c0])
        reject(changes, "mount_changes", lambda i: "mount label changes inside the hold")
    both = (from_column >= 0) & (from_data >= 0)
    reject(
        both & (from_column != from_data),
        "mount_mismatch",
        lambda i: f"mount column says {MOUNTS[from_column[i]]}, gyro says {MOUNTS[from_data[i]]}",
    )

    mounts = np.where(from_column >= 0, from_column, from_data)
    source = np.where(
        both, "both", np.where(from_column >= 0, "column", np.where(from_data >= 0, "data", ""))
    )
    # Holds too slow to tell their mount inherit it from their neighbours in the same
    # mounting, which ends at handling motion or a logging gap.
    session = np.cumsum(active | in_gap | gap_before)[c0]
    before, after = _nearest_known(mounts, session)
    agree = np.where(before < 0, after, np.where((after < 0) | (after == before), before, -1))
    inherit = (mounts == -1) & (agree >= 0)
    mounts = np.where(inherit, agree, mounts)
    source = np.where(inherit, "inherited", source)
    reject(
        mounts == -1,
        "mount_undetermined",
        lambda i: "too slow to tell the mount and no agreeing neighbour or mount column",
    )
    return mounts, source


def _nearest_known(values: np.ndarray, session: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each position, the nearest value >= 0 before (and after) it in the same
    session, or -1: a forward and a backward fill that stop at session boundaries."""
    n = len(values)
    pos = np.arange(n)
    last = np.maximum.accumulate(np.where(values >= 0, pos, -1))
    nxt = np.minimum.accumulate(np.where(values >= 0, pos, n)[::-1])[::-1]
    before = np.where(
        (last >= 0) & (session[np.maximum(last, 0)] == session), values[np.maximum(last, 0)], -1
    )
    after = np.where(
        (nxt < n) & (session[np.minimum(nxt, n - 1)] == session), values[np.minimum(nxt, n - 1)], -1
    )
    return before, after


def _stable_periods(blk, block_dt, cfg) -> pd.DataFrame:
    """Stretches where the temperature rate stays under the limit, on a grid of windows."""
    temp = blk["temp"]
    nb = len(temp)
    width = min(max(int(round(cfg.temp_window_s / block_dt)), 3), nb)
    step = max(width // 4, 1)
    lo = np.arange(0, nb - width + 1, step)
    t_mid = (blk["t_first"] + blk["t_last"]) / 2
    stable = np.abs(thirds_rate(temp, t_mid, lo, lo + width)) <= cfg.max_temp_rate
    a, b = true_runs(stable)
    first, last = lo[a], np.minimum(lo[b - 1] + width, nb)
    p = np.r_[0.0, np.cumsum(temp, dtype=np.float64)]
    return pd.DataFrame(
        {
            "t_start": blk["t_first"][first],
            "t_end": blk["t_last"][last - 1],
            "temp": (p[last] - p[first]) / (last - first),
        }
    )


def _specific_force_of_mounts(mounts: np.ndarray) -> dict[str, np.ndarray]:
    """The specific force each hold's mount implies where no accelerometer is logged, g:
    the turntable's axis points up (the log contract), so a unit mounted with axis ``+a``
    along it feels +1 g along ``a`` and nothing along the others. Terms of the specific
    force (an acceleration sensitivity) then read it as from an accelerometer; the fixture's
    small tilts and the centripetal force of a unit off the table's centre (ω²r, which an
    accelerometer would see) are left out. ``accel_source`` says so; a hold whose mount is
    unknown gets none (NaN)."""
    mounts = np.asarray(mounts, dtype=int)
    out: dict[str, np.ndarray] = {}
    for c in AXES:
        along = np.where(mounts == MOUNTS.index(f"+{c}"), 1.0, 0.0)
        along = np.where(mounts == MOUNTS.index(f"-{c}"), -1.0, along)
        out[f"accel_{c}"] = np.where(mounts >= 0, along, np.nan)
    out["accel_source"] = np.full(mounts.size, "mount", dtype=object)
    return out


def _observation_table(h: dict, accepted: np.ndarray, checked: Checked, table_angle, cfg) -> pd.DataFrame:
    """The accepted holds in the hold schema, with the turntable's own columns: the table's
    angle, the accelerometer where logged, and each axis' settling within the hold.
    Temperature points: holds closer than ``temp_gap`` in temperature belong together."""
    a = accepted
    own = {"table_angle": table_angle[a]}
    if "accel" in h:
        own.update({f"accel_{c}": h["accel"][a, i] for i, c in enumerate(AXES)})
    else:
        own.update(_specific_force_of_mounts(checked.mounts[a]))
    own.update({f"settle_{c}": h["settle"][a, i] for i, c in enumerate(AXES)})
    return hold_table(
        t_start=h["t_start"][a],
        t_end=h["t_end"][a],
        n=h["n"][a],
        mount=np.array([MOUNTS[m] for m in checked.mounts[a]], dtype=object),
        mount_source=checked.source[a],
        ref_rate=h["ref"][a],
        gyro=h["mean"][a],
        std=np.sqrt(h["var"][a]),
        temp=h["temp"][a],
        temp_rate=h["temp_rate"][a],
        own=own,
        **temperature_points(h["temp"][a], gap=cfg.temp_gap)._asdict(),
    )


def _segment_table(segments, t_first, t_last, r, obs) -> pd.DataFrame:
    kinds, reasons, details, first, stop = (list(x) for x in zip(*segments, strict=False))
    b0, b1 = np.asarray(first, dtype=int), np.asarray(stop, dtype=int)
    keep = b1 > b0
    b0, b1 = b0[keep], b1[keep]
    p = np.r_[0.0, np.cumsum(r)]
    seg = pd.DataFrame(
        {
            "kind": np.asarray(kinds, dtype=object)[keep],
            "reason": np.asarray(reasons, dtype=object)[keep],
            "detail": np.asarray(details, dtype=object)[keep],
            "t_start": t_first[b0],
            "t_end": t_last[b1 - 1],
            "ref_rate": (p[b1] - p[b0]) / (b1 - b0),
        }
    )
    seg = seg.sort_values(["t_start", "kind"], kind="stable").reset_index(drop=True)
    hold = np.full(len(seg), -1)
    is_hold = np.flatnonzero(seg["kind"].to_numpy() == "hold")
    starts = obs["t_start"].to_numpy()  # accepted holds, in time order like the segments
    hold[is_hold] = obs["hold"].to_numpy()[np.searchsorted(starts, seg["t_start"].to_numpy()[is_hold])]
    seg["hold"] = hold
    return seg
