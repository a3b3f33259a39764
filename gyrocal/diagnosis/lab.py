"""An effect fixed in the lab, seen through the turning table.

A field that does not turn with the table (the Earth's rotation's horizontal part, a
motor's stray field, a table tilted off the vertical) reaches the sensor's axes as the
cosine and sine of the table's angle, with weights that depend on the mount. Over whole
turns it averages out; over a hold of a fraction of a turn, or at rest, it does not. No
term of the sensor describes it: where the table stood when the session began is not in
the log, so a fit of it does not carry over to another session. The diagnosis tests for
it so that it can say so, rather than call it noise or an effect of the rate.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..fit.validate import stretches_between_gaps
from .findings import SENSOR_LEAD, LabTest, MountingTest, Unexplained
from .sessions import turned_columns
from .stats import chi2_sf, f_sf, p_text


def angle_means(obs) -> np.ndarray:
    """(n, 2): each hold's mean cosine and sine of the table's angle, from its angle at the
    hold's start and its constant rate over its duration."""
    start = np.radians(obs["table_angle"].to_numpy(dtype=float))
    turn = np.radians(obs["ref_rate"].to_numpy(dtype=float) * obs["duration"].to_numpy(dtype=float))
    # The mean of cos and sin over [θ₀, θ₀ + φ] is their value at mid-hold times
    # sin(φ/2) / (φ/2): no cancellation for a hold that hardly turns, exact at rest.
    middle = start + turn / 2
    shrink = np.sinc(turn / (2 * np.pi))
    cos_mean, sin_mean = np.cos(middle) * shrink, np.sin(middle) * shrink
    return np.column_stack([cos_mean, sin_mean])


def _point_columns(obs, rows) -> tuple[np.ndarray, np.ndarray]:
    """Each temperature point's bias and rates as columns, as the base model has them (so
    that what a point's fit took of an effect is counted back: refitted, not the residuals
    alone regressed), and each fitted hold's point."""
    n = int(np.count_nonzero(rows))
    points = (
        np.unique(obs["point"].to_numpy()[rows], return_inverse=True)[1]
        if "point" in obs
        else np.zeros(n, dtype=int)
    )
    rates = np.column_stack([np.ones(n), obs.loc[rows, ["rate_x", "rate_y", "rate_z"]].to_numpy(float)])
    own = np.zeros((n, 4 * (points.max() + 1)))
    for k in range(4):
        own[np.arange(n), 4 * points + k] = rates[:, k]
    return own, points


def _refits(z, floor, own, extras):
    """Per output axis: the residual sum of squares and the rank of the whitened residuals
    refitted on the points' columns alone, then beside each set of ``extras`` in turn."""
    for i in range(z.shape[1]):
        ok = np.isfinite(z[:, i])
        w = 1.0 / floor[ok, i, None]
        base = own[ok] * w
        y = z[ok, i]
        designs = (base, *(np.column_stack([base, x[ok] * w]) for x in extras))
        solved = [np.linalg.lstsq(x, y, rcond=None) for x in designs]  # coefficients, _, rank, _
        yield (
            [float(np.sum((y - x @ r[0]) ** 2)) for x, r in zip(designs, solved, strict=False)],
            [r[2] for r in solved],
        )


def lab_fixed(obs, quality, dof: int, alpha: float) -> LabTest | None:
    """How much of the in-sample excess the table's angle accounts for: each output axis'
    whitened residuals refitted with the holds' mean cosine and sine of the angle (two
    coefficients per mount and axis) beside each temperature point's bias and rates; an
    F-test of the angle's gain against what is left, a χ² test of what is left, and one of
    what an offset per mount in the angle's place leaves. The model's other terms are not refitted: the test errs towards finding
    nothing. None where the log gives no angle or nothing is left to test against."""
    if "table_angle" not in obs or "mount" not in obs:
        return None
    rows = quality.fitted_rows
    z = quality.z[rows]
    floor = quality.floor[rows]
    angle = angle_means(obs)[rows]
    mounts = np.unique(obs["mount"].astype(str).to_numpy()[rows], return_inverse=True)[1]
    own, _ = _point_columns(obs, rows)
    # An effect constant per mount (one of gravity's direction) is not credited to the
    # angle: an offset per mount in place of the angle's columns must leave more than noise.
    offsets = np.eye(mounts.max() + 1)[mounts]
    lab = np.zeros((len(z), 2 * (mounts.max() + 1)))
    for k in range(2):
        lab[np.arange(len(z)), 2 * mounts + k] = angle[:, k]
    before = float(np.nansum(z**2))
    rss = np.zeros(3)  # points alone, with the angle, with the offsets
    added = np.zeros(2, dtype=int)  # the angle's and the offsets' columns beyond the points'
    for axis_rss, ranks in _refits(z, floor, own, (lab, offsets)):
        if ranks[1] <= ranks[0]:
            continue
        rss += axis_rss
        added += [ranks[1] - ranks[0], ranks[2] - ranks[0]]
    q, left_dof = int(added[0]), dof - int(added[0])
    gain, left = rss[0] - rss[1], rss[1]
    if q == 0 or left_dof <= 0 or not left > 0:
        return None
    f = (gain / q) / (left / left_dof)
    p_value = float(f_sf(f, q, left_dof))
    left_p = float(chi2_sf(left, left_dof))
    offsets_p = float(chi2_sf(rss[2], dof - int(added[1])))
    excess = max(before - dof, 0.0)
    return LabTest(
        p_value=p_value,
        parameters=q,
        chi2_before=before,
        chi2_after=float(left),
        dof=left_dof,
        share_of_excess=min(float(gain) / excess, 1.0) if excess > 0 else 0.0,
        left_p_value=left_p,
        offsets_p_value=offsets_p,
        explains=bool(p_value < alpha / 2 and left_p >= alpha / 2 and offsets_p < alpha / 2),
    )


def lab_reason(lab: LabTest) -> Unexplained:
    """The verdict's why and what would tell, for an excess the table's angle explains."""
    return Unexplained(
        reason="fixed in the lab",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"the residuals follow the table's angle ({100 * lab.share_of_excess:.0f} % of "
            f"the excess with its cosine and sine in each mount, F-test p "
            f"{p_text(lab.p_value)}): an effect fixed in the lab and seen through the "
            "turning table (the Earth's rotation, a stray field of the motor, a table "
            "tilted off the vertical), not one of the sensor; where the table stood "
            "when the session began is not in the log, so nothing fitted to it here "
            "holds on another session"
        ),
        would_tell=(
            "holds lasting whole turns at every rate, over which it averages out, "
            "or the table's angle logged from its encoder"
        ),
    )


def reference_reason(nxt) -> Unexplained:
    """The verdict's why where the other session differs by one scale error every axis
    shares (:func:`.sessions.reference_scaled`): the reference rate's, not the sensor's."""
    return Unexplained(
        reason="fixed in the lab",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"on the other session every axis reads the rates {1e6 * nxt['reference_scale']:+.0f} "
            "ppm apart from this calibration, the same on each (with that one scale and the "
            f"turn-on bias taken out, {nxt['rescaled_rms'] / nxt['expected_rms']:.2f} times what a "
            "correct model would leave): a scale of the reference rate, fixed in the lab (the "
            "table's tachometer or commanded rate read differently between the sessions), "
            "more likely than the sensor's, whose axes' scales change each its own way unless "
            "one drive loop or one reference voltage moves them all alike"
        ),
        would_tell="the table's rate checked against its encoder's count over whole turns in each session",
    )


LAB_ADVICE = (
    "Compensate an effect fixed in the lab on the rig, not in the sensor's calibration: "
    "make every hold last whole turns of the table (a rest at several table angles "
    "averages it too), or log the table's angle from its encoder and subtract the "
    "field there; the calibration as it stands holds for the sensor, with this "
    "effect's share of its error left in."
)


# The mounting is the primary answer where its offsets take nearly all of the excess
# (MOUNTING_DOMINANT) and no rival takes half of it (RIVAL_HALF), though what they leave is
# not within chance: a fixture's other scatter (slow wander, a door) is a second question.
MOUNTING_DOMINANT = 0.9
RIVAL_HALF = 0.5


def mounting_fixed(
    obs, quality, dof: int, alpha: float, stretch: np.ndarray, direction: np.ndarray | None = None
) -> MountingTest | None:
    """How much of the in-sample excess an offset per mounting accounts for: each output
    axis' whitened residuals refitted with one offset and one misalignment (its share of
    the turning rate) per stretch of holds on one mount (``stretch``,
    :func:`gyrocal.diagnosis.where.history_columns`) beside each temperature
    point's bias and rates. The mounting explains the excess when its offsets' gain passes
    an F-test, what they leave is within chance, and neither of its rivals does as well:
    one offset per mount for the whole session (an effect of the orientation, which a
    sensor term holds), a drift in time within each point (which the mountings follow
    in order) and, given the temperature's ``direction`` of travel at each hold, an offset
    per direction within each point (a hysteresis, where a point is visited from both
    sides: its mountings differ by the way the temperature came) and an offset per stretch
    between the log's gaps (a power-on in each, where the gaps fall at the mountings). It
    explains it too where
    it takes nearly all of the excess (:data:`MOUNTING_DOMINANT`) and the best rival not
    half (:data:`RIVAL_HALF`, ``rival_share``): the fixture's seating is the primary answer,
    what it leaves a second question. None where there is nothing to test."""
    if "mount" not in obs:
        return None
    rows = quality.fitted_rows
    z, floor = quality.z[rows], quality.floor[rows]
    groups = np.unique(np.asarray(stretch)[rows], return_inverse=True)[1]
    mounts = np.unique(obs["mount"].astype(str).to_numpy()[rows], return_inverse=True)[1]
    if groups.max() + 1 <= mounts.max() + 1:
        return None  # each mount mounted once: the mounting is the orientation
    own, points = _point_columns(obs, rows)
    t = obs.loc[rows, "t_start"].to_numpy(float)
    drift = np.zeros((len(z), points.max() + 1))
    drift[np.arange(len(z)), points] = (t - t.min()) / 3600.0
    way = np.zeros((len(z), points.max() + 1))
    if direction is not None:
        way[np.arange(len(z)), points] = np.asarray(direction, dtype=float)[rows] > 0
    # A mounting seats the unit at its own tilt as well as its own strain: the turning rate
    # leaks into the other outputs by a misalignment of its own. Each reading gets its
    # rates' share alike: per mounting, per mount, per point's drift.
    rate = obs.loc[rows, "ref_rate"].to_numpy(float)[:, None] / max(
        float(np.nanmax(np.abs(obs["ref_rate"]))), 1e-9
    )
    with_rate = lambda x: np.column_stack([x, x * rate])  # noqa: E731
    # A power-on in each gap of the log gives each stretch between gaps an offset of its own:
    # where the gaps fall at the mountings, their offsets are the power-ons' as well.
    resumed = obs["resumed_at"].to_numpy(float)[rows] if "resumed_at" in obs else None
    runs = stretches_between_gaps(resumed, len(z))
    rivals = (
        with_rate(np.eye(groups.max() + 1)[groups]),
        with_rate(np.eye(mounts.max() + 1)[mounts]),
        with_rate(drift),
        way,
        np.eye(runs.max() + 1)[runs],
    )
    before = float(np.nansum(z**2))
    rss, added = np.zeros(6), np.zeros(5, dtype=int)  # points alone, then with each
    for axis_rss, ranks in _refits(z, floor, own, rivals):
        rss += axis_rss
        added += [r - ranks[0] for r in ranks[1:]]
    q, left_dof = int(added[0]), dof - int(added[0])
    if q <= 0 or left_dof <= 0 or not rss[1] > 0:
        return None
    f = ((rss[0] - rss[1]) / q) / (rss[1] / left_dof)
    p_value = float(f_sf(f, q, left_dof))
    left_p = float(chi2_sf(rss[1], left_dof))
    orientation_p = float(chi2_sf(rss[2], dof - int(added[1])))
    drift_p = float(chi2_sf(rss[3], dof - int(added[2])))
    direction_p = float(chi2_sf(rss[4], dof - int(added[3])))
    power_on_p = float(chi2_sf(rss[5], dof - int(added[4]))) if added[4] > 0 else 0.0
    excess = max(before - dof, 0.0)
    share = min(float(rss[0] - rss[1]) / excess, 1.0) if excess > 0 else 0.0
    rival_share = min(float(rss[0] - min(rss[2:])) / excess, 1.0) if excess > 0 else 0.0
    return MountingTest(
        p_value=p_value,
        parameters=q,
        mountings=int(groups.max() + 1),
        chi2_after=float(rss[1]),
        dof=left_dof,
        share_of_excess=share,
        left_p_value=left_p,
        orientation_p_value=orientation_p,
        drift_p_value=drift_p,
        direction_p_value=direction_p,
        rival_share=rival_share,
        explains=bool(
            p_value < alpha / 2
            and (
                (left_p >= alpha / 2 and max(orientation_p, drift_p, direction_p, power_on_p) < alpha / 2)
                or (share >= MOUNTING_DOMINANT and rival_share < RIVAL_HALF)
            )
        ),
    )


def mounting_reason(found: MountingTest) -> Unexplained:
    """The verdict's why and what would tell, for an excess an offset per mounting explains."""
    return Unexplained(
        reason="the mounting",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"the residuals are offsets per mounting ({100 * found.share_of_excess:.0f} % of "
            f"the excess with one offset and one misalignment for each of the {found.mountings} "
            f"stretches of holds on one mount, F-test p {p_text(found.p_value)}), which neither "
            "the mount's orientation, a drift in time, the temperature's direction nor a power-on "
            f"in each gap of the log accounts for as well (the best of them {100 * found.rival_share:.0f} %): "
            "each mounting on the fixture leaves its own bias and tilt (the fixture's "
            "repeatability, a strain of the package), fresh every time, which no term of the "
            "sensor carries to the next mounting"
            + (
                f"; what it leaves is beyond chance (p {p_text(found.left_p_value)}), a second "
                "question after it (the rig's other scatter)"
                if found.left_p_value < 0.01
                else ""
            )
        ),
        would_tell=(
            "the same mount revisited within a point (its offset comes back or it "
            "does not), or a fixture that clamps the same way each time"
        ),
    )


MOUNTING_ADVICE = (
    "An offset per mounting is the fixture's, not the sensor's: it sets how well any "
    "calibration of this rig can do. Compare the unit's bias over repeated mountings "
    "at one temperature; a fixture that clamps the same way each time, or holds "
    "averaged over several mountings, bring it down."
)


class SeatingFit(NamedTuple):
    """Each mounting's small rotation, fitted in sample as a random effect
    (:func:`seating_in_sample`)."""

    part: np.ndarray  # (n, 3) deg/s: the errors the rotations make (zero on rows not fitted)
    penalty: float  # Σ ε² / σ²: the rotations' own χ², beside the residuals'
    change: float  # rad: the RMS of the rotations fitted
    coefficients: int


def seating_in_sample(obs, quality, stretch: np.ndarray, sigma: float) -> SeatingFit | None:
    """The fixture's seating in the session's own residuals: each mounting's rotation a random
    effect of 1σ ``sigma`` (rad, the rig's repeatability) beside each temperature point's bias
    and rates, fitted per output axis by penalised least squares (the rotations' prior as
    rows of the design: min ‖z − Xβ − Sε‖² + ‖ε‖²/σ², whitened by the hold's floor). The
    minimum is the χ² of generalised least squares with the seating's covariance σ² S Sᵀ
    added to the noise's: its degrees of freedom are the model's, for a random effect spends
    none. A point's own rates take each point's mean rotation (a calibration absorbs that),
    so what the rotations fit is how mountings at one point differ. None where no mounting
    turns a rate into another output."""
    rows = quality.fitted_rows
    if not rows.any() or sigma <= 0:
        return None
    z, floor = quality.z[rows], quality.floor[rows]
    own, _ = _point_columns(obs, rows)
    rates = obs.loc[rows, ["rate_x", "rate_y", "rate_z"]].to_numpy(float)
    mounting = np.asarray(stretch)[rows]
    part = np.zeros((len(obs), 3))
    fitted_rows = np.flatnonzero(rows)
    rotations: list[np.ndarray] = []
    for i in range(3):
        ok = np.isfinite(z[:, i])
        tilts = turned_columns(mounting[ok], rates[ok], i)
        if not tilts.shape[1]:
            continue
        w = 1.0 / floor[ok, i]
        design = np.block(
            [
                [own[ok] * w[:, None], tilts * w[:, None]],
                [np.zeros((tilts.shape[1], own.shape[1])), np.eye(tilts.shape[1]) / sigma],
            ]
        )
        target = np.concatenate([z[ok, i], np.zeros(tilts.shape[1])])
        coef = np.linalg.lstsq(design, target, rcond=None)[0]
        rotation = coef[own.shape[1] :]
        part[fitted_rows[ok], i] = tilts @ rotation
        rotations.append(rotation)
    if not rotations:
        return None
    eps = np.concatenate(rotations)
    return SeatingFit(part, float(np.sum(eps**2)) / sigma**2, float(np.sqrt(np.mean(eps**2))), eps.size)
