"""Find seed 001's constant-speed rotations in a servo log and average them over whole revolutions.

A rotation is a stretch where ``ref_rate`` (the servo's commanded speed) is constant and
non-zero; stretches at ``ref_rate`` 0 (pauses, the unit re-mounted by hand) are ignored
whatever the gyro does. Integrating ``|ref_rate|`` over ``t`` gives the servo angle; a
sample belongs to revolution r when the angle at its midpoint lies in [360 r, 360 (r + 1))
degrees, and only revolutions complete to within half a sample are kept. Averaging the gyro
over each whole revolution is Eq 8: the servo's speed ripple is periodic in the revolution
and cancels (Section II-B), white noise shrinks by the square root of the sample count.

All per-sample work is vectorised (cumulative sums, ``np.add.reduceat`` over the sample
ranges of whole revolutions); loops run over rotations only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pandas as pd

from ...io.errors import SegmentationError
from ...io.log import GYRO, MOUNTS, RigLog
from ...terms import AXES
from ..registry import checked_options, option_defaults

DIRECTIONS = MOUNTS  # the G-optimal design's six rotation directions (seed 001 Section II-B)
_OPTIONS = option_defaults("servo")


@dataclass(frozen=True)
class Rotations:
    """Whole revolutions of a servo log, one row each (rates deg/s, times s, temp °C).

    Columns: ``rotation`` (0-based, in time order), ``direction`` (``+x`` ...),
    ``revolution`` (0-based within the rotation), ``t_start``, ``t_end`` (first and last
    sample), ``n``, ``gyro_x/y/z`` (mean), ``gyro_x/y/z_std`` (standard deviation within the
    revolution: noise plus ripple), ``gyro_x/y/z_noise`` (white-noise level from successive
    differences, which the slow ripple does not reach), ``ref_rate`` (mean |ref_rate|),
    ``temp`` (mean).
    """

    revolutions: pd.DataFrame
    warnings: tuple[str, ...] = field(default_factory=tuple)
    source: str | None = None

    @property
    def directions(self) -> tuple[str, ...]:
        first = self.revolutions.groupby("rotation", sort=True)["direction"].first()
        return tuple(first.tolist())

    def observations(self) -> pd.DataFrame:
        """One row per rotation, averaged over its whole revolutions (sample-weighted, so
        equal to the mean over all its samples): the observations of Eq 7-8.

        Adds ``revolutions`` (count) and ``gyro_x/y/z_sem``, the standard error of the mean
        from the white-noise level."""
        r = self.revolutions
        g = r.groupby("rotation", sort=True)
        n = g["n"].sum()
        out = pd.DataFrame(
            {
                "rotation": n.index.to_numpy(),
                "direction": g["direction"].first().to_numpy(),
                "revolutions": g.size().to_numpy(),
                "n": n.to_numpy(),
                "t_start": g["t_start"].min().to_numpy(),
                "t_end": g["t_end"].max().to_numpy(),
            }
        )
        weighted = r[["gyro_x", "gyro_y", "gyro_z", "ref_rate", "temp"]].multiply(r["n"], axis=0)
        sums = weighted.groupby(r["rotation"], sort=True).sum()
        for col in ("gyro_x", "gyro_y", "gyro_z", "ref_rate", "temp"):
            out[col] = (sums[col] / n).to_numpy()
        for a in AXES:
            var = (r[f"gyro_{a}_noise"] ** 2 * r["n"]).groupby(r["rotation"], sort=True).sum() / n
            out[f"gyro_{a}_sem"] = np.sqrt(var / n).to_numpy()
        return out


def g_optimal_warnings(
    directions, means, *, speeds=None, max_tilt_deg: float = 20.0, speed_tol: float = 0.02
) -> list[str]:
    """Where the rotations depart from the G-optimal design of Section II-B: one rotation
    each way about each sensor axis (six), at one speed, about axes close to the sensor
    axes. ``means``: mean gyro vector per rotation (any unit); ``speeds``: servo speed per
    rotation (any unit). Returns one line per departure; empty for the design itself."""
    directions = [str(d) for d in directions]
    means = np.asarray(means, dtype=float).reshape(-1, 3) if len(directions) else np.zeros((0, 3))
    out = []
    if len(directions) != 6:
        out.append(
            f"the design has {len(directions)} rotations; the G-optimal design has six, "
            "one each way about each sensor axis"
        )
    for axis in AXES:
        if not any(d[1:] == axis for d in directions):
            out.append(f"no rotation about the sensor {axis} axis: k{axis} and b{axis} are not observed")
    for d in DIRECTIONS:
        count = directions.count(d)
        if count == 0 and any(x[1:] == d[1:] for x in directions):
            out.append(f"no {d} rotation: the {d[1:]} axis turns one way only")
        elif count > 1:
            out.append(f"{d} appears {count} times; the G-optimal design turns each way once")
    unknown = sorted(set(directions) - set(DIRECTIONS))
    if unknown:
        out.append(f"unknown direction label(s) {', '.join(unknown)}")
    for i, (d, m) in enumerate(zip(directions, means, strict=False)):
        norm = float(np.linalg.norm(m))
        if d not in DIRECTIONS or norm == 0.0:
            continue
        nominal = np.zeros(3)
        nominal[AXES.index(d[1])] = 1.0 if d[0] == "+" else -1.0
        tilt = math.degrees(math.acos(float(np.clip(m @ nominal / norm, -1.0, 1.0))))
        if tilt > max_tilt_deg:
            out.append(
                f"rotation {i} ({d}): the mean output is {tilt:.1f}° off the {d} axis "
                f"(limit {max_tilt_deg:g}°)"
            )
    if speeds is not None and len(speeds):
        s = np.abs(np.asarray(speeds, dtype=float))
        mid = float(np.median(s))
        if mid > 0 and (s.max() - s.min()) / mid > speed_tol:
            out.append(
                f"rotation speeds differ ({s.min():.4g} to {s.max():.4g}); the G-optimal "
                f"design uses one speed"
            )
    return out


def _runs(start: np.ndarray, member: np.ndarray) -> np.ndarray:
    """Run id (1-based) per sample from run-start flags; 0 where not a member."""
    return np.where(member, np.cumsum(start), 0)


class SpeedRuns(NamedTuple):
    """Stretches of constant non-zero ``ref_rate``: each sample's run (1-based, 0 outside)."""

    span: np.ndarray  # s each sample stands for: the interval up to the next one
    on: np.ndarray  # the sample lies in a run
    cont: np.ndarray  # the sample continues the run of the one before
    run: np.ndarray
    nominal: float  # s: the typical sample interval


class WholeRevolutions(NamedTuple):
    """Each sample's revolution within its run, and which runs turn whole revolutions."""

    rev: np.ndarray  # revolution of each sample (a float until the runs are known usable)
    keep: np.ndarray  # the sample lies in a whole revolution of a usable run
    starts: np.ndarray  # each run's first sample
    total: np.ndarray  # deg each run turns
    cuttable: np.ndarray  # the run turns less than half a revolution per sample
    usable: np.ndarray  # the run turns min_revolutions whole ones and can be cut


def find_rotations(
    log: RigLog,
    *,
    min_revolutions: int = _OPTIONS["min_revolutions"],
    rate_tol_abs: float = 0.01,
    rate_tol_rel: float = 5e-3,
    gap_factor: float = 3.0,
    max_tilt_deg: float = 20.0,
) -> Rotations:
    """Rotations of whole revolutions in a servo log (see the module docstring).

    ``ref_rate`` counts as constant within ``rate_tol_abs + rate_tol_rel·|ref_rate|``
    (deg/s) of the stretch's median; a sample interval over ``gap_factor`` times the
    typical one ends a rotation. ``min_revolutions`` is checked against the config schema
    (``protocols.servo.options``). Raises :class:`SegmentationError` when no stretch covers
    a whole revolution or fewer than six rotations have ``min_revolutions`` whole ones.
    """
    checked_options("servo", {"min_revolutions": min_revolutions})
    t = log.column("t")
    ref = log.column("ref_rate").astype(float)
    if len(t) < 2:
        raise SegmentationError(
            f"the log has {len(t)} sample(s); a servo rotation needs many", source=log.path
        )
    runs = _constant_speed_runs(t, ref, rate_tol_abs, rate_tol_rel, gap_factor)
    if int(runs.run.max()) == 0:
        raise SegmentationError(
            "ref_rate is never constant and non-zero: no servo rotation found", source=log.path
        )
    whole = _whole_revolutions(ref, runs, min_revolutions)
    warnings = _unused_runs(log, t, ref, runs, whole, min_revolutions)
    gyro = np.column_stack([log.column(c).astype(float) for c in GYRO])
    table, sel, rotation_of = _revolution_table(t, ref, gyro, log.column("temp").astype(float), runs, whole)
    directions, rot_mean = _directions(log, ref, gyro, sel, rotation_of, warnings)
    table.insert(1, "direction", np.asarray(directions, dtype=object)[table["rotation"].to_numpy()])
    if len(directions) < 6:
        raise SegmentationError(
            f"found {len(directions)} rotation{'s' if len(directions) != 1 else ''} of at least "
            f"{min_revolutions} whole revolution{'s' if min_revolutions != 1 else ''} at constant "
            f"ref_rate ({' '.join(directions)}); the servo protocol needs six (±x, ±y, ±z)",
            source=log.path,
        )
    speeds = table.groupby("rotation")["ref_rate"].mean().to_numpy()
    warnings += g_optimal_warnings(directions, rot_mean, speeds=speeds, max_tilt_deg=max_tilt_deg)
    return Rotations(table, tuple(warnings), log.path)


def _constant_speed_runs(t, ref, rate_tol_abs: float, rate_tol_rel: float, gap_factor: float) -> SpeedRuns:
    """Where is ``ref_rate`` constant and non-zero? Stretches within the tolerance from
    sample to sample, without a gap; then, within each, the samples at its median rate, so
    that a slow ramp leading in or out is not counted as constant speed."""
    n = len(t)
    dt = np.diff(t)
    nominal = float(np.median(dt))
    # Each sample stands for the interval up to the next one (the typical interval across a gap).
    span = np.append(np.where(dt > gap_factor * nominal, nominal, dt), nominal)
    tol = rate_tol_abs + rate_tol_rel * np.abs(ref)
    moving = np.abs(ref) > rate_tol_abs
    joined = np.zeros(n, dtype=bool)  # sample i continues the stretch of i - 1
    joined[1:] = moving[1:] & moving[:-1] & (np.abs(np.diff(ref)) <= tol[1:]) & (dt <= gap_factor * nominal)
    first_pass = _runs(moving & ~joined, moving)
    ids = first_pass[moving]
    median = pd.Series(ref[moving]).groupby(ids).median()
    level = np.zeros(n)
    level[moving] = median.reindex(ids).to_numpy()
    on = moving & (np.abs(ref - level) <= rate_tol_abs + rate_tol_rel * np.abs(level))
    cont = np.zeros(n, dtype=bool)
    cont[1:] = on[1:] & on[:-1] & (first_pass[1:] == first_pass[:-1])
    return SpeedRuns(span, on, cont, _runs(on & ~cont, on), nominal)


def _whole_revolutions(ref, runs: SpeedRuns, min_revolutions: int) -> WholeRevolutions:
    """Which revolution does each sample belong to? The servo angle (deg) within each run
    at every sample's start and midpoint, integrated from ``|ref_rate|``; only revolutions
    complete to within half a sample count."""
    on, cont, run = runs.on, runs.cont, runs.run
    step = np.where(on, np.abs(ref) * runs.span, 0.0)
    csum = np.cumsum(step)
    starts = np.flatnonzero(on & ~cont)
    last = np.flatnonzero(on & ~np.r_[cont[1:], False])  # each run's final sample
    offset = (csum - step)[starts]
    angle_start = np.where(on, csum - step - offset[np.maximum(run - 1, 0)], 0.0)
    mid = angle_start + 0.5 * step
    total = csum[last] - offset
    half_sample = 0.5 * step[last]
    whole = np.floor((total + half_sample) / 360.0)  # whole revolutions per run
    rev = np.floor(mid / 360.0)  # floats: counted as integers only once the runs are usable
    keep = on & (rev < whole[np.maximum(run - 1, 0)])
    # Revolutions are cut by integrating ref_rate from sample to sample: a run turning half a
    # revolution or more per sample cannot be cut (and may count more than an int64 holds).
    cuttable = np.maximum.reduceat(step, starts) < 180.0
    usable = (whole >= min_revolutions) & cuttable
    keep &= usable[np.maximum(run - 1, 0)]
    return WholeRevolutions(rev, keep, starts, total, cuttable, usable)


def _unused_runs(
    log: RigLog, t, ref, runs: SpeedRuns, whole: WholeRevolutions, min_revolutions: int
) -> list[str]:
    """A warning for each run of half a revolution or more that is not used; an error when
    no run is."""
    warnings = []
    for r in np.flatnonzero(~whole.usable & (whole.total >= 180.0)):
        warnings.append(
            f"rotation at t={t[whole.starts[r]]:.2f} s covers {whole.total[r] / 360.0:.2f} revolutions, "
            + (
                f"fewer than {min_revolutions} whole; not used"
                if whole.cuttable[r]
                else "half a revolution or more per sample: cannot be cut; not used"
            )
        )
    if not whole.keep.any() and not whole.cuttable.all():
        raise SegmentationError(
            f"ref_rate turns the servo half a revolution or more per sample "
            f"(up to {np.abs(ref[runs.on]).max():.3g} deg/s at {1 / runs.nominal:.3g} Hz): "
            "no revolution can be cut",
            source=log.path,
        )
    if not whole.keep.any():
        longest = float(whole.total.max())
        raise SegmentationError(
            f"no stretch of constant non-zero ref_rate covers a whole revolution (longest: {longest:.1f}°)",
            source=log.path,
        )
    return warnings


def _revolution_table(t, ref, gyro, temp, runs: SpeedRuns, whole: WholeRevolutions):
    """Whole revolutions as contiguous sample ranges, in time order: their means, scatter
    and white-noise level (from successive differences inside a revolution: the ripple is
    slow). Returns the table, the selected samples and each one's rotation."""
    sel = np.flatnonzero(whole.keep)
    rev = whole.rev[sel].astype(int)  # revolution of each selected sample
    usable_index = np.cumsum(whole.usable) - 1  # run -> rotation index
    rotation_of = usable_index[runs.run[sel] - 1]
    key = rotation_of.astype(np.int64) * (int(rev.max()) + 1) + rev
    bounds = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[bounds, len(sel)])
    seg = np.repeat(np.arange(len(bounds)), counts)  # revolution id per selected sample
    g = gyro[sel]
    mean = np.add.reduceat(g, bounds, axis=0) / counts[:, None]
    dev = g - mean[seg]
    std = np.sqrt(np.add.reduceat(dev * dev, bounds, axis=0) / np.maximum(counts - 1, 1)[:, None])
    same = (seg[1:] == seg[:-1]) & (sel[1:] == sel[:-1] + 1)
    d2 = np.where(same[:, None], np.diff(g, axis=0) ** 2, 0.0)
    pairs = np.bincount(seg[1:], weights=same.astype(float), minlength=len(bounds))
    noise = np.sqrt(
        np.column_stack([np.bincount(seg[1:], weights=d2[:, j], minlength=len(bounds)) for j in range(3)])
        / (2.0 * np.maximum(pairs, 1))[:, None]
    )
    table = pd.DataFrame(
        {
            "rotation": rotation_of[bounds],
            "revolution": rev[bounds],
            "t_start": t[sel][bounds],
            "t_end": t[sel][bounds + counts - 1],
            "n": counts,
            **{f"gyro_{a}": mean[:, i] for i, a in enumerate(AXES)},
            **{f"gyro_{a}_std": std[:, i] for i, a in enumerate(AXES)},
            **{f"gyro_{a}_noise": noise[:, i] for i, a in enumerate(AXES)},
            "ref_rate": np.add.reduceat(np.abs(ref[sel]), bounds) / counts,
            "temp": np.add.reduceat(temp[sel], bounds) / counts,
        }
    )
    return table, sel, rotation_of


def _directions(
    log: RigLog, ref, gyro, sel, rotation_of, warnings: list[str]
) -> tuple[list[str], np.ndarray]:
    """The direction of each rotation: the mount column with the sign of ref_rate, else
    the data (the axis of its largest mean output). Returns the directions and each
    rotation's mean output; a disagreement is a warning."""
    g = gyro[sel]
    rot_bounds = np.flatnonzero(np.r_[True, rotation_of[1:] != rotation_of[:-1]])
    n_rot = len(rot_bounds)
    rot_first = sel[rot_bounds]
    rot_mean = np.add.reduceat(g, rot_bounds, axis=0) / np.diff(np.r_[rot_bounds, len(sel)])[:, None]
    dominant = np.argmax(np.abs(rot_mean), axis=1)
    sign = np.sign(rot_mean[np.arange(n_rot), dominant])
    from_data = [("+" if s >= 0 else "-") + AXES[a] for a, s in zip(dominant, sign, strict=False)]
    directions = list(from_data)
    if "mount" not in log:
        return directions, rot_mean
    mount = log.column("mount")
    lo = np.minimum.reduceat(mount[sel], rot_bounds)
    hi = np.maximum.reduceat(mount[sel], rot_bounds)
    for i in range(n_rot):
        if lo[i] < 0 or lo[i] != hi[i]:
            if lo[i] != hi[i]:
                warnings.append(
                    f"rotation {i}: the mount column changes during the rotation; direction taken from the gyro"
                )
            continue
        label = MOUNTS[int(lo[i])]
        ref_sign = 1.0 if ref[rot_first[i]] > 0 else -1.0
        mount_sign = 1.0 if label[0] == "+" else -1.0
        directions[i] = ("+" if ref_sign * mount_sign > 0 else "-") + label[1]
        if directions[i] != from_data[i]:
            warnings.append(
                f"rotation {i}: mount column and ref_rate say {directions[i]}, the gyro says {from_data[i]}"
            )
    return directions, rot_mean
