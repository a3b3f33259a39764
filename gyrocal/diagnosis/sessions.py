"""The other session: a calibration judged as its user meets it, on another session of
the unit, and whether what a model leaves repeats there or differs by slow noise."""

from __future__ import annotations

from typing import NamedTuple, TypedDict

import numpy as np
import pandas as pd

from ..fit.floor import with_upper_floor
from ..fit.model import observation_floor
from ..fit.thermal import in_sample
from ..fit.validate import MIN_STRETCH_HOLDS, stretch_means, stretches_between_gaps
from ..io.errors import GyrocalError
from ..pipeline.config import Settings
from ..terms import AXES
from .stats import chance_bound, chi2_sf
from .where import mountings

SOAKED_SPREAD = 5.0  # °C: a temperature point's spread below which it is one soak


class CarryOver(TypedDict, total=False):
    """A calibration carried to another session of the unit (:func:`carry_over`): its
    figures there (:func:`gyrocal.fleet.drift.revalidate`), whether the pattern of its
    residuals repeats (:func:`repeat_p_value`), whether the sessions differ by slow noise
    (:func:`unrepeated_p_value`); ``left_p_value``, what a candidate leaves judged on both
    sessions (:meth:`.effects.Judge.explains`). Or ``error`` alone, where it could not be
    carried."""

    validation_rms: float
    noise_floor: float
    excess: float
    expected_rms: float
    wander_rms: float  # deg/s: expected_rms with the slow noise its static data cannot rule out
    holds: bool
    fails_in_practice: bool  # beyond chance and beyond CARRIES_WITHIN x what a correct model leaves
    turn_on_bias: dict[str, float]  # deg/s per axis: the other session's mean error, the power-on's bias
    power_ons: int  # stretches between the other session's log gaps, each with its own offsets
    largest_turn_on: float  # deg/s: the largest offset of an axis in any of them
    turn_on_allowance: float | None  # deg/s: the offset per axis a power-on's bias may take (None: any)
    rezeroed_rms: float  # deg/s: its RMS error with that bias taken out
    reference_scale: float  # one scale error shared by every axis, fitted to its errors
    rescaled_rms: float  # deg/s: its RMS error with that scale and the turn-on bias taken out
    rate_shaped_rms: float  # deg/s: the part of its errors (power-ons' out) in proportion to the rates
    rescaled_shaped_rms: float  # deg/s: that part with the one shared scale out too
    unseated_shaped_rms: float  # deg/s: rate_shaped_rms with each mounting's rotation out first
    seating_change: float | None  # rad: each mounting's rotation, the RMS of its coefficients
    seating_coefficients: int  # how many were fitted
    seating_allowance: float  # rad: what the fixture's seating may give that RMS (reseated)
    reseated_rms: float  # deg/s: rezeroed_rms with the rotations out too
    seating_rms: float  # deg/s: the part the rotations make, less the noise the fit took
    changed_rms: float  # deg/s: its RMS error less one change of bias, scale and axes for the session
    holds_scored: int
    bound: float  # how far above expected_rms its figures may lie by chance (stats.chance_bound)
    repeat_p_value: float | None
    unrepeated_p_value: float | None
    shared_fraction: float | None
    between_share: float  # its scored holds' share at temperatures between this session's points
    between_rms: float  # deg/s: its RMS error on those holds (NaN-free: absent without any)
    at_points_rms: float  # deg/s: its RMS error on the holds at this session's points
    between_expected: float  # deg/s: expected_rms on the holds between, by their floors
    at_points_expected: float  # deg/s: the same on the holds at the points
    within_points_rms: float  # deg/s: its errors less each of its points' own bias and rates
    within_points_expected: float  # deg/s: what a correct model leaves of them
    within_points_bound: float  # its chance bound, over the holds less the parameters spent
    left_p_value: float
    error: str


# What a calibration may leave on another session, over what a correct model would leave
# there, and still carry over in practice: the bar a fix meets on the unseen session.
CARRIES_WITHIN = 1.2


# A bias a unit takes anew at each power-on (its turn-on repeatability) and the calibration
# cannot carry. A MEMS gyroscope's is commonly tens to hundreds of hold-mean floors, so the
# log alone bounds it nowhere: without the sensor's specification an offset per axis of the
# other session's errors, of any size, is read as that power-on's bias. Given it (diagnosis:
# turn_on_repeatability, 1 sigma), an offset beyond this many sigmas is a change of the unit.
TURN_ON_SIGMAS = 3.0


def turn_on_allowance(settings: Settings, noise_floor: float) -> float | None:
    """The offset per axis (deg/s) another session's power-on may give the bias:
    :data:`TURN_ON_SIGMAS` times the sensor's turn-on repeatability where the settings give
    it (at least as many hold-mean floors, a floor's own offset being chance); None, any
    offset, where they do not."""
    spec = settings.diagnosis.turn_on_repeatability
    return None if spec is None else TURN_ON_SIGMAS * max(spec, noise_floor)


# A fixture seats the unit anew at each mounting, a good one to a few arcseconds (25 µrad is
# 5"): each mounting turns the unit's axes by its own small rotation, which no calibration
# carries to the next. Its 1 sigma per component, µrad, without the rig's figure
# (diagnosis: seating_repeatability).
SEATING_REPEATABILITY_URAD = 30.0


def seating_sigma(settings: Settings) -> float:
    """The fixture's seating repeatability (rad, 1 sigma per component of a mounting's
    rotation): the settings' ``seating_repeatability``, :data:`SEATING_REPEATABILITY_URAD`
    without."""
    spec = settings.diagnosis.seating_repeatability
    return (SEATING_REPEATABILITY_URAD if spec is None else spec) * 1e-6


def practical_bar(nxt: CarryOver) -> float:
    """What a calibration may leave on the other session and still carry over (deg/s):
    :data:`CARRIES_WITHIN` times what a correct model would leave there, up to that figure's
    own uncertainty (the chance bound of its holds, as the in-sample test allows). What a
    correct model leaves there counts that session's slow noise as its own static data
    bound it, at the bound's top (``wander_rms``), as one session's own test does
    (:func:`.steps.slow_noise_bound`): the other session's floor computed as this one's."""
    return CARRIES_WITHIN * carry_expected(nxt) * nxt.get("bound", 1.0)


def carry_expected(nxt: CarryOver) -> float:
    """What a correct model leaves on the other session (deg/s), its slow noise counted at
    the top of what its static data allow."""
    return max(nxt["expected_rms"], nxt.get("wander_rms", 0.0))


def white_bar(nxt: CarryOver) -> float:
    """:func:`practical_bar` for white noise alone: :data:`CARRIES_WITHIN` times the other
    session's ``expected_rms``, up to its chance bound (deg/s)."""
    return CARRIES_WITHIN * nxt["expected_rms"] * nxt.get("bound", 1.0)


def rate_shaped(nxt: CarryOver, key: str = "rate_shaped_rms") -> bool:
    """Whether the other session's errors hold a part in proportion to the rates (a change
    of scale or axes, the power-ons' offsets out) that alone would fail the calibration under
    white noise: slow wander, a bias, does not follow the rate, so its allowance does not
    cover such a part. ``key``: that part as :func:`_turn_on_offsets` measured it; where the
    mountings' rotations are the fixture's seating (:func:`reseated`), what is left of it
    once they are out."""
    part = nxt.get(key)
    if part is None:
        return False
    if key == "rate_shaped_rms" and reseated(nxt):
        part = nxt.get("unseated_shaped_rms", part)  # the fixture's seating is no change of the unit
    within = nxt["expected_rms"] * np.sqrt(max((CARRIES_WITHIN * nxt.get("bound", 1.0)) ** 2 - 1.0, 0.0))
    return bool(part > within)


def fails_in_practice(nxt: CarryOver) -> bool:
    """The calibration fails on the other session beyond chance and beyond
    :func:`practical_bar` (the fixture's seating out, :func:`seated_rms`); within that, a
    difference the test resolves is too small to act on. Nor does it fail where only the power-ons' biases set it apart: offsets per axis
    within :func:`turn_on_allowance` whose removal brings it within the bar of what is left
    (:func:`_rezeroed_bar`: the white noise's, for offsets per stretch). Beyond the bar
    for white noise alone (:func:`white_bar`), a part in proportion to the rates
    (:func:`rate_shaped`) fails it whatever the slow wander allows."""
    if nxt["holds"]:
        return False
    if nxt["validation_rms"] <= white_bar(nxt):
        return False
    if rate_shaped(nxt):
        return True
    if seated_rms(nxt) <= practical_bar(nxt):
        return False
    return not turned_on(nxt)


def seated_rms(nxt: CarryOver) -> float:
    """The other session's RMS error (deg/s), without the mountings' rotations where they are
    the fixture's seating (:func:`reseated`; ``seating_rms`` counts the noise the fit took)."""
    v = nxt["validation_rms"]
    if not reseated(nxt) or nxt.get("seating_rms") is None:
        return v
    return float(np.sqrt(max(v**2 - nxt["seating_rms"] ** 2, 0.0)))


def offset_alone(nxt: CarryOver) -> bool:
    """Whether an offset per axis is all that sets the other session apart: with each axis'
    mean error taken out (per stretch between the log's gaps, each of which may hold a power-on:
    :func:`_turn_on_offsets`), what is left is within :func:`_rezeroed_bar`. Such an offset is
    the same at every temperature of a stretch, so it is no failure between the temperature
    points that the log could tell from a power-on's."""
    if not nxt.get("turn_on_bias") or nxt.get("rezeroed_rms") is None or rate_shaped(nxt):
        return False
    return bool(rezeroed_rms(nxt) <= _rezeroed_bar(nxt))


def reseated(nxt: CarryOver) -> bool:
    """Whether the other session's part in proportion to the rates, one rotation per
    mounting fitted (``seating_change``, the RMS of its coefficients), is within the
    fixture's seating repeatability: :func:`seating_sigma`, up to the chance bound of an RMS
    over that many coefficients (``seating_allowance``)."""
    change, allowance = nxt.get("seating_change"), nxt.get("seating_allowance")
    return change is not None and allowance is not None and bool(change <= allowance)


def _rms_bound(count: int, alpha: float) -> float:
    """How far the RMS of ``count`` draws of unit spread may lie above 1 by chance, at
    significance ``alpha``: sqrt(χ²_(1−α)(count) / count)."""
    from scipy.stats import chi2

    return float(np.sqrt(chi2.ppf(1.0 - alpha, count) / count)) if count > 0 else 1.0


def rezeroed_rms(nxt: CarryOver) -> float:
    """What the other session errs with its power-ons' offsets out (deg/s), and with each
    mounting's rotation out too where those are the fixture's seating (:func:`reseated`)."""
    if reseated(nxt) and nxt.get("reseated_rms") is not None:
        return min(nxt["rezeroed_rms"], nxt["reseated_rms"])
    return nxt["rezeroed_rms"]


def _rezeroed_bar(nxt: CarryOver) -> float:
    """What the other session may leave once its offsets are out: :func:`practical_bar` for
    one offset per axis (the session's own power-on); :func:`white_bar` where each stretch
    between gaps has its own, for those offsets already take out every wander slower than a
    stretch, which the slow-noise allowance would count a second time (a warm-up or a
    wander read as power-ons leaves its course within the stretches)."""
    return white_bar(nxt) if nxt.get("power_ons", 1) > 1 else practical_bar(nxt)


def power_ons_alone(nxt: CarryOver) -> bool:
    """Whether the power-ons' offsets are what the other session misses by: its errors
    beyond what white noise leaves (:func:`white_bar`), within the bar of what is left without
    the offsets (:func:`turned_on`), and beyond :func:`practical_bar` with them or the offsets taking most
    of the excess over white noise."""
    v, e = nxt["validation_rms"], nxt["expected_rms"]
    if v <= white_bar(nxt) or not turned_on(nxt):
        return False
    return bool(v > practical_bar(nxt) or v**2 - nxt["rezeroed_rms"] ** 2 >= 0.5 * (v**2 - e**2))


def offset_and_allowance(nxt: CarryOver) -> tuple[float, float | None]:
    """The other session's largest offset of an axis, and what a power-on's bias may take
    (:func:`turn_on_allowance`, as :func:`carry_over` found it; None: any), deg/s."""
    largest = nxt.get("largest_turn_on", max(abs(v) for v in nxt["turn_on_bias"].values()))
    return largest, nxt.get("turn_on_allowance")


def turned_on(nxt: CarryOver) -> bool:
    """Whether the other session differs by the bias of its power-on alone: an offset per
    axis (:func:`offset_alone`) within :func:`turn_on_allowance`."""
    if not offset_alone(nxt):
        return False
    largest, allowance = offset_and_allowance(nxt)
    return allowance is None or bool(largest <= allowance)


def _turn_on_offsets(held, resumed: np.ndarray | None = None, mounting: np.ndarray | None = None) -> dict:
    """On the holds revalidation scores (``held``, :func:`gyrocal.fleet.drift.scored_hold_errors`):
    the other session's mean error per axis (weighted by each hold's floor), the bias the unit
    took at its power-on, and the RMS error left with it taken out (deg/s); and one scale
    error every axis shares fitted with those offsets, and what they leave. A reference rate
    read with a scale error (a table's tachometer) puts the same relative error on every
    axis' rate; a sensor's scales change each its own way.

    Given when the log last resumed before each hold (``resumed``, the chain's
    ``resumed_at``), each stretch between the log's gaps (:func:`gyrocal.fit.validate.stretches_between_gaps`) has its own
    offsets: the unit may have been powered anew in any gap, and the log cannot tell
    (``power_ons``, the stretches; ``largest_turn_on``, the largest offset of an axis in any
    of them). What is left counts the means taken out (``rezeroed_rms`` scaled by
    sqrt(N / (N − power_ons)) over N holds), as a fit's residuals count its parameters.

    Given each hold's ``mounting`` (the stretch of consecutive holds on one mount), each
    mounting's own rotation is fitted too (:func:`_seating`), for the fixture seats the unit
    anew each time."""
    use = held.scored & np.all(np.isfinite(held.errors), axis=1)
    e, w = held.errors[use], 1.0 / np.maximum(held.floor[use], 1e-300) ** 2
    if not len(e):
        return {}
    runs = stretches_between_gaps(None if resumed is None else resumed[use], len(e))
    count = int(runs.max()) + 1
    offsets = stretch_means(runs, e, w)
    offset = np.sum(e * w, axis=0) / np.sum(w, axis=0)
    rates = held.rates[use]
    centred = rates - stretch_means(runs, rates, w)[runs]
    power = float(np.sum(w * centred**2))
    rezeroed = e - offsets[runs]
    scale = float(np.sum(w * centred * rezeroed) / power) if power > 0 else 0.0
    left = rezeroed - scale * centred
    spent = np.sqrt(len(e) / (len(e) - count)) if len(e) > count else 1.0

    # A change of the sensor's scale and axes: each output's error against the three rates,
    # centred per stretch (weighted least squares by that output's floor), the part of the
    # errors in proportion to the rate
    by_output = [rates - stretch_means(runs, rates, w[:, i])[runs] for i in range(3)]

    def shaped(errors) -> float:
        part = np.zeros_like(errors)
        for i, own in enumerate(by_output):
            root = np.sqrt(w[:, i])
            coef = np.linalg.lstsq(own * root[:, None], errors[:, i] * root, rcond=None)[0]
            part[:, i] = own @ coef
        return float(np.sqrt(np.mean(part**2)))

    seated = _seating(rezeroed, w, rates, None if mounting is None else mounting[use], count)
    unseated = rezeroed - seated.part

    # One change of the unit for the whole session, the same at every temperature: an offset
    # and a row of the rate matrix per output (weighted least squares by that output's floor).
    design = np.column_stack([np.ones(len(e)), rates])
    changed = np.empty_like(e)
    for i in range(3):
        root = np.sqrt(w[:, i])
        coef = np.linalg.lstsq(design * root[:, None], e[:, i] * root, rcond=None)[0]
        changed[:, i] = e[:, i] - design @ coef
    kept = len(e) * 3
    spent_changed = np.sqrt(kept / (kept - 12)) if kept > 12 else 1.0

    return {
        "changed_rms": float(np.sqrt(np.mean(changed**2)) * spent_changed),
        "turn_on_bias": {a: float(v) for a, v in zip(AXES, offset, strict=True)},
        "power_ons": count,
        "largest_turn_on": float(np.max(np.abs(offsets))),
        "rezeroed_rms": float(np.sqrt(np.mean(rezeroed**2)) * spent),
        "reference_scale": scale,
        "rescaled_rms": float(np.sqrt(np.mean(left**2))),
        "rate_shaped_rms": shaped(rezeroed),
        "rescaled_shaped_rms": shaped(left),
        "unseated_shaped_rms": shaped(unseated),
        "seating_change": seated.change,
        "seating_coefficients": seated.coefficients,
        "reseated_rms": seated.left_rms,
        "seating_rms": seated.part_rms,
    }


class Seating(NamedTuple):
    """Each mounting's rotation fitted to the other session's errors (:func:`_seating`)."""

    part: np.ndarray  # (n, 3) deg/s: the errors the rotations make
    change: float | None  # rad: the RMS of the coefficients fitted (None: none fitted)
    coefficients: int  # how many
    left_rms: float  # deg/s: what is left, counting the parameters spent
    part_rms: float  # deg/s: the part, less the noise the fit took


def _seating(errors, weights, rates, mounting, offsets: int) -> Seating:
    """Each mounting's own small rotation (the fixture seats the unit anew each time): each
    output's errors against the rates of the *other* axes the mounting turns, a coefficient
    each, with an offset per mounting beside them so that rates of one sign do not read a
    bias as a tilt (weighted least squares; the offsets are not taken out: a bias that
    differs between mountings is no rotation). A scale, an output against its own rate, is
    no seating and stays in. A mounting with fewer than :data:`SEATING_MIN_HOLDS` holds keeps
    its errors. ``offsets``: the parameters already spent on the errors (the power-ons')."""
    n = len(errors)
    none = Seating(np.zeros_like(errors), None, 0, float(np.sqrt(np.mean(errors**2))) if n else 0.0, 0.0)
    if mounting is None or not n:
        return none
    groups, counts = np.unique(mounting, return_inverse=True, return_counts=True)[1:]
    one_hot = np.eye(counts.size)[groups] * (counts >= SEATING_MIN_HOLDS)[None, :]
    part, spent, coefficients = np.zeros_like(errors), float(offsets), []
    for i in range(3):
        tilts = turned_columns(mounting, rates, i, counts >= SEATING_MIN_HOLDS)
        if not tilts.shape[1]:
            continue
        design = np.column_stack([one_hot[:, one_hot.any(axis=0)], tilts])
        root = np.sqrt(weights[:, i])
        coef, _, rank, _ = np.linalg.lstsq(design * root[:, None], errors[:, i] * root, rcond=None)
        tilt = coef[design.shape[1] - tilts.shape[1] :]
        part[:, i] = tilts @ tilt
        coefficients.extend(tilt)
        spent += rank / 3.0
    if not coefficients or n - spent <= 1.0:
        return none
    left = errors - part
    # the fitted part holds its share of the noise: count it out of the part and back into
    # what is left (as a fit's residuals count its parameters)
    share = (spent - offsets) / n
    return Seating(
        part,
        float(np.sqrt(np.mean(np.square(coefficients)))),
        len(coefficients),
        float(np.sqrt(np.mean(left**2) * n / (n - spent))),
        float(np.sqrt(max(float(np.mean(part**2)) - share * float(np.mean(1.0 / weights)), 0.0))),
    )


# A rate a mounting turns, against the most a mounting turns any (in power).
TURNED_SHARE = 1e-4
# The holds a mounting needs for its rotation to be told from its offset.
SEATING_MIN_HOLDS = 3


def turned_columns(
    mounting: np.ndarray, rates: np.ndarray, output: int, keep: np.ndarray | None = None
) -> np.ndarray:
    """(n, k): per mounting, the rates of the axes other than ``output`` that it turns, a
    column each; a mounting's small rotation moves each into ``output`` by a coefficient of
    its own (radians). Columns a mounting hardly turns (:data:`TURNED_SHARE` of the most any
    turns, in power) are left out, and those of mountings ``keep`` (per mounting, in sorted
    order) leaves out."""
    groups = np.unique(mounting, return_inverse=True)[1]
    one_hot = np.eye(groups.max() + 1)[groups]
    if keep is not None:
        one_hot = one_hot * keep[None, :]
    others = np.delete(np.arange(3), output)
    columns = (one_hot[:, :, None] * rates[:, None, others]).reshape(len(rates), -1)
    power = np.sum(columns**2, axis=0)
    return columns[:, power > TURNED_SHARE * power.max(initial=0.0)]


def reference_scaled(nxt: CarryOver) -> bool:
    """Whether the other session fails by one scale error every axis shares (beyond
    :func:`practical_bar`, and within it once that scale and the turn-on bias are taken
    out): the reference rate's scale, not the sensor's."""
    if not fails_in_practice(nxt) or nxt.get("rescaled_rms") is None:
        return False
    if rate_shaped(nxt):
        # the shared scale is the rates' part, or nearly all of it (what is left of that
        # part, the fixture's re-seating, is no rival); what is left follows no rate, and is
        # held to the bar one change of the unit is (changed_alone): a wander within the
        # stretches that the shared scale's reading neither makes nor needs to explain
        left = nxt["rescaled_shaped_rms"] ** 2 if rate_shaped(nxt, "rescaled_shaped_rms") else 0.0
        return bool(
            left <= (1.0 - SHARED_SCALE_DOMINANT) * nxt["rate_shaped_rms"] ** 2
            and nxt["rescaled_rms"] <= practical_bar(nxt)
        )
    bar = _rezeroed_bar(nxt)  # the offsets per stretch are taken out here too
    return bool(nxt["rescaled_rms"] <= bar < nxt["rezeroed_rms"])


# The share of the other session's part in proportion to the rates that one scale every axis
# shares must take to be read as the reference's (as the mounting's dominance is read).
SHARED_SCALE_DOMINANT = 0.9


def usable(nxt: CarryOver | None) -> bool:
    """A carry-over to another session that could be made: its figures judge a calibration
    whether or not the sessions share the cells that compare their residuals' patterns
    (``repeat_p_value`` None where they do not)."""
    return nxt is not None and "error" not in nxt


def carries(nxt: CarryOver | None) -> bool:
    """A carry-over that could be made, on which the calibration does not fail in practice
    (:func:`fails_in_practice`)."""
    return usable(nxt) and nxt is not None and not nxt["fails_in_practice"]


# The share of the other session's holds between this session's temperature points from
# which its carrying over answers what leaving a point out asks (a point's worth of holds
# in a session of three or four points).
BETWEEN_SHARE = 0.25


def carries_between(nxt: CarryOver | None) -> bool:
    """Whether the other session meets the calibration where only its interpolation reaches
    (at least :data:`BETWEEN_SHARE` of its holds between this session's points,
    ``between_share``) and the calibration carries over there: the interpolation holds as
    its user meets it, whatever leaving a point out, which doubles the spacing, says."""
    return carries(nxt) and nxt is not None and nxt.get("between_share", 0.0) >= BETWEEN_SHARE


def carry_over(settings: Settings, ev, obs: pd.DataFrame, other: pd.DataFrame) -> CarryOver:
    """``ev``'s calibration (the fit of ``settings`` extended by the candidate; its
    reference temperature is ``settings``') applied to another session of the unit
    (:func:`gyrocal.fleet.drift.revalidate`) and whether the pattern of its residuals repeats there
    (:func:`repeat_p_value`) or the sessions differ by slow noise (:func:`unrepeated_p_value`)."""
    from ..fleet.drift import revalidate, scored_hold_errors
    from ..pipeline.chain import calibrate_observations

    cal, _ = calibrate_observations(obs, settings, meta={}, fitted=ev.fitted, checks=False)
    r = revalidate(cal, other)
    held = scored_hold_errors(cal, other)
    # revalidation's expected RMS with the upper floors in place of the floors (the
    # calibration's share is the same)
    upper = with_upper_floor(other)
    wander_rms = r["expected_rms"]
    if upper is not None and held.scored.any():
        extra = observation_floor(upper)[held.scored] ** 2 - held.floor[held.scored] ** 2
        widened = float(np.sqrt(r["expected_rms"] ** 2 + np.mean(extra)))
        if np.isfinite(widened):  # upper floors the static data could bound
            wander_rms = max(widened, r["expected_rms"])
    errors, floor1 = held.errors, held.floor
    resid, floor0, rows = in_sample(ev.fitted, len(obs))
    z0, z1 = (resid / floor0)[rows], errors / floor1
    out: CarryOver = {
        "validation_rms": r["validation_rms"],
        "noise_floor": r["noise_floor"],
        "excess": r["excess"],
        "expected_rms": r["expected_rms"],
        "wander_rms": wander_rms,
        "holds": r["holds"],
        "holds_scored": r["holds_scored"],
        "bound": chance_bound(r["holds_scored"], settings.diagnosis.significance),
        "repeat_p_value": repeat_p_value(obs.iloc[rows], z0, other, z1),
        "unrepeated_p_value": unrepeated_p_value(obs.iloc[rows], z0, other, z1),
        "shared_fraction": shared_fraction(obs.iloc[rows], z0, other, z1),
    }
    out["between_share"] = between_share(obs, other["temp"].to_numpy(float)[held.scored])
    out.update(_split_at_points(obs, other["temp"].to_numpy(float), held, r["expected_rms"]))  # type: ignore[typeddict-item]
    out.update(_within_points(other, held, r["expected_rms"], settings.diagnosis.significance))  # type: ignore[typeddict-item]
    resumed = other["resumed_at"].to_numpy(float) if "resumed_at" in other else None
    mounting = mountings(other) if "mount" in other and "t_start" in other else None
    out.update(_turn_on_offsets(held, resumed, mounting))  # type: ignore[typeddict-item]
    out["turn_on_allowance"] = turn_on_allowance(settings, r["noise_floor"])
    if out.get("seating_change") is not None:
        count = int(out.get("seating_coefficients", 0))
        out["seating_allowance"] = seating_sigma(settings) * _rms_bound(
            count, settings.diagnosis.significance
        )
    if not all(
        np.isfinite(v) for v in [*out.values(), *out.get("turn_on_bias", {}).values()] if isinstance(v, float)
    ):
        raise GyrocalError("the other session's errors are not finite")
    out["fails_in_practice"] = fails_in_practice(out)
    return out


REPEAT_DRAWS = 9999
POINT_MATCH = 3.0  # °C: soaked points of two sessions closer than this are the same point


def _point_medians(obs: pd.DataFrame) -> np.ndarray:
    """Each temperature point's median temperature (°C), in point order."""
    return obs.groupby(obs["point"].to_numpy())["temp"].median().to_numpy(float)


def between_share(obs: pd.DataFrame, temps: np.ndarray) -> float:
    """The share of ``temps`` (the other session's holds) inside this session's span of
    temperature points and further than :data:`POINT_MATCH` from every one of them: where
    the calibration is met by its interpolation alone, as leaving a point out tests it."""
    if "point" not in obs or not len(temps):
        return 0.0
    points = _point_medians(obs)
    if points.size < 2:
        return 0.0
    inside = (temps > points.min()) & (temps < points.max())
    apart = np.abs(temps[:, None] - points[None, :]).min(axis=1) > POINT_MATCH
    return float(np.mean(inside & apart))


def _within_points(other: pd.DataFrame, held, expected: float, alpha: float) -> dict:
    """The other session's errors less what its own points' parameters take (a bias and a
    row of K at each point: whatever the calibration misses as a function of temperature, a
    shape between this session's points or a change of the unit, is one such set a point)
    and less an offset per mount and rate the table held (any function of the rate, and a
    fixture's tilt or gravity's pull at each mount, shared by the points), and what a correct
    model leaves of them there (``expected`` scaled by the holds' floors and by the parameters
    spent). What is left moves in time, or with the temperature within a point. Empty unless
    the holds outnumber the parameters by :data:`gyrocal.fit.validate.MIN_STRETCH_HOLDS`."""
    if "point" not in other:
        return {}
    use = held.scored & np.all(np.isfinite(held.errors), axis=1)
    points = np.asarray(other["point"])
    labels, counts = np.unique(points[use], return_counts=True)
    kept_points = labels[counts >= 1 + held.rates.shape[1] + MIN_STRETCH_HOLDS]
    rows = use & np.isin(points, kept_points)
    if not rows.any():
        return {}
    rates = held.rates[rows]
    blocks = [
        (points[rows] == p)[:, None] * np.column_stack([np.ones(len(rates)), rates]) for p in kept_points
    ]
    # a level is a mount at a rate the protocol set (two digits: a jittering reference stays
    # one level), so a fixture's tilt or gravity's pull at each mount is a level's too
    decade = 10.0 ** np.floor(np.log10(np.maximum(np.abs(rates), 1e-3)))
    nominal = np.round(rates / decade, 1) * decade
    mount = (
        np.unique(other["mount"].astype(str).to_numpy()[rows], return_inverse=True)[1]
        if "mount" in other
        else 0
    )
    key = np.column_stack([nominal, np.broadcast_to(mount, len(rates))])
    levels = np.unique(key, axis=0, return_inverse=True)[1].ravel()
    design = np.column_stack([*blocks, np.eye(levels.max() + 1)[levels]])
    coef, *_ = np.linalg.lstsq(design, held.errors[rows], rcond=None)
    left = held.errors[rows] - design @ coef
    free = int(rows.sum()) - int(np.linalg.matrix_rank(design))
    if free < MIN_STRETCH_HOLDS:
        return {}
    scale = float(np.sqrt(np.mean(held.floor[rows] ** 2) * free / rows.sum() / np.mean(held.floor[use] ** 2)))
    out = {
        "within_points_rms": float(np.sqrt(np.mean(left**2))),
        "within_points_expected": expected * scale,
        "within_points_bound": chance_bound(free, alpha),
    }
    return out if all(np.isfinite(v) and v > 0 for v in out.values()) else {}


def wanders_within_points(nxt: CarryOver | None) -> bool:
    """Whether the other session's errors move within its temperature points beyond the bar
    a correct model sets (:data:`CARRIES_WITHIN`, up to the chance bound of what is left),
    once each point's own bias and rates and a function of the mount and rate are out: what
    no function of temperature, of the rate or of the mount makes, nor one change of the
    unit, but a bias or scale that wanders in time."""
    if not usable(nxt) or nxt is None or "within_points_rms" not in nxt:
        return False
    bar = CARRIES_WITHIN * nxt["within_points_expected"] * nxt["within_points_bound"]
    return bool(nxt["within_points_rms"] > bar)


def wanders_most(nxt: CarryOver | None) -> bool:
    """Whether the wander within the other session's points (:func:`wanders_within_points`)
    is most of its failure: its excess over white noise at least half of the whole session's."""
    if not wanders_within_points(nxt):
        return False
    assert nxt is not None
    within = nxt["within_points_rms"] ** 2 - nxt["within_points_expected"] ** 2
    return bool(within >= 0.5 * (nxt["validation_rms"] ** 2 - nxt["expected_rms"] ** 2))


def _split_at_points(obs: pd.DataFrame, temps: np.ndarray, held, expected: float) -> dict:
    """The other session's RMS error on its scored holds at this session's temperature points
    (within :data:`POINT_MATCH`) and on those between them, each with what a correct model
    leaves there (``expected`` scaled by the holds' floors); empty unless each has at least
    :data:`gyrocal.fit.validate.MIN_STRETCH_HOLDS` holds."""
    if "point" not in obs:
        return {}
    points = _point_medians(obs)
    use = held.scored & np.all(np.isfinite(held.errors), axis=1)
    if points.size < 2 or not use.any():
        return {}
    t = temps[use]
    near = np.abs(t[:, None] - points[None, :]).min(axis=1) <= POINT_MATCH
    between = ~near & (t > points.min()) & (t < points.max())
    if near.sum() < MIN_STRETCH_HOLDS or between.sum() < MIN_STRETCH_HOLDS:
        return {}  # a hold or two at a point decide nothing
    e, f = held.errors[use], held.floor[use]
    scale = lambda m: expected * float(np.sqrt(np.mean(f[m] ** 2) / np.mean(f**2)))  # noqa: E731
    return {
        "between_rms": float(np.sqrt(np.mean(e[between] ** 2))),
        "at_points_rms": float(np.sqrt(np.mean(e[near] ** 2))),
        "between_expected": scale(between),
        "at_points_expected": scale(near),
    }


def changed_alone(nxt: CarryOver | None) -> bool:
    """Whether one change of the unit, the same at every temperature of the other session (an
    offset and a rate matrix per output: ``changed_rms``), brings its errors within
    :func:`practical_bar` where they fail: a shape of the sensor between this session's
    points would differ from one temperature to the next."""
    if not usable(nxt) or nxt is None or not nxt["fails_in_practice"] or "changed_rms" not in nxt:
        return False
    return bool(nxt["changed_rms"] <= practical_bar(nxt))


def fails_between_only(nxt: CarryOver | None) -> bool:
    """Whether the other session fails where only the calibration's interpolation reaches and
    carries where this session measured: its holds between this session's points err beyond
    :func:`practical_bar` (scaled to their floors) while those at the points are within it.
    The unit did not change (it carries at the points); the calibration does not hold
    between them."""
    if not usable(nxt) or nxt is None or "between_rms" not in nxt or not nxt["fails_in_practice"]:
        return False
    bar = practical_bar(nxt) / nxt["expected_rms"]
    return bool(
        nxt["between_rms"] > bar * nxt["between_expected"]
        and nxt["at_points_rms"] <= bar * nxt["at_points_expected"]
    )


def _cells(obs: pd.DataFrame, soaked_spread: float = SOAKED_SPREAD) -> pd.DataFrame:
    """Each hold's cell, the key two sessions of one protocol share (temperature, mount,
    rate and, along a sweep, the direction the temperature moves), and its block of
    neighbouring cells (10 °C × mount) whose errors a slow wander shares."""
    temp = obs["temp"].to_numpy(float)
    point_temp = obs["point_temp"].to_numpy(float) if "point_temp" in obs else temp
    if "point" in obs:
        spread = obs.groupby(obs["point"].to_numpy())["temp"].transform(lambda t: t.max() - t.min())
        soaked = spread.to_numpy() < soaked_spread
    else:
        soaked = np.zeros(len(obs), dtype=bool)
    # Holds of one soaked point share its temperature; along a sweep, 2 °C bins and the
    # direction of the ramp (on a soak the temperature rate is noise: no direction).
    tbin = np.where(soaked, point_temp, 2.0 * np.round(temp / 2.0))
    rate = obs["temp_rate"].to_numpy(float) if "temp_rate" in obs else np.zeros(len(obs))
    rising = np.where(soaked, 0.0, np.sign(np.round(np.nan_to_num(rate), 1)))
    return pd.DataFrame(
        {
            "temp": tbin,
            "soaked": soaked,
            "mount": obs["mount"].astype(str).to_numpy(),
            "rate": np.round(obs["ref_rate"].to_numpy(float), 1),
            "rising": rising,
        }
    )


def _snap(cells1: pd.DataFrame, cells0: pd.DataFrame) -> pd.DataFrame:
    """Session 1's soaked point temperatures moved to session 0's nearest, when within
    :data:`POINT_MATCH` (set points drift a little between sessions)."""
    points0 = np.unique(cells0.loc[cells0["soaked"], "temp"])
    if points0.size == 0:
        return cells1
    t = cells1["temp"].to_numpy(float)
    nearest = points0[np.abs(t[:, None] - points0[None, :]).argmin(axis=1)]
    snap = cells1["soaked"].to_numpy() & (np.abs(nearest - t) <= POINT_MATCH)
    return cells1.assign(temp=np.where(snap, nearest, t))


KEY = ["temp", "mount", "rate", "rising"]


def _shared_cells(obs0, z0, obs1, z1):
    """Per cell both sessions have: the mean residual of each (n, 3), the number of holds
    averaged in each, and the cell's block; session 1's offset per axis removed. None when
    fewer than 6 blocks are shared."""
    c0 = _cells(obs0)
    c1 = _snap(_cells(obs1), c0)

    def means(cells, z):
        frame = pd.concat(
            [
                cells[KEY].reset_index(drop=True),
                pd.DataFrame(np.nan_to_num(np.asarray(z, float)), columns=list(AXES)),
            ],
            axis=1,
        )
        grouped = frame.groupby(KEY, sort=True)
        return grouped[list(AXES)].mean(), grouped.size()

    m0, k0 = means(c0, z0)
    m1, k1 = means(c1, z1)
    m1 = m1 - m1.mean()
    shared = m0.index.intersection(m1.index)
    if shared.empty:
        return None
    block = (
        np.floor(shared.get_level_values("temp").to_numpy(float) / 10.0).astype(int).astype(str)
        + "|"
        + shared.get_level_values("mount").to_numpy().astype(str)
    )
    if np.unique(block).size < 6:
        return None
    return (
        m0.loc[shared].to_numpy(),
        m1.loc[shared].to_numpy(),
        k0.loc[shared].to_numpy(float),
        k1.loc[shared].to_numpy(float),
        block,
    )


def repeat_p_value(
    obs0: pd.DataFrame, z0: np.ndarray, obs1: pd.DataFrame, z1: np.ndarray, draws: int = REPEAT_DRAWS
) -> float | None:
    """How likely, were the two sessions' residuals independent, a pattern that repeats as
    much as this one. Two-sided: a model wrong in a way that depends on the session's
    conditions (a lag at another ramp rate) can leave the pattern reversed.

    The residuals ``z`` (hold error ÷ floor, per axis) are averaged per cell shared by the
    sessions, and each block's mean per axis is removed from both: what is compared is the
    pattern within blocks (over rate, direction, time within a point), which a wander across
    blocks (bias instability, a random walk over the session) leaves alone. The statistic is
    |Σ z0·z1| over cells and axes. Its null distribution flips the sign of session 1's cells
    a whole block and axis at a time: wander within a block correlates its holds within a
    session, not across sessions, so flipping blocks keeps that correlation. Draws from a
    fixed seed: the same data give the same p. None when fewer than 6 blocks are shared."""
    shared = _shared_cells(obs0, z0, obs1, z1)
    if shared is None:
        return None
    a, b, _, _, block = shared
    labels, codes = np.unique(block, return_inverse=True)

    def within(m):
        sums = np.stack(
            [np.bincount(codes, weights=m[:, i], minlength=labels.size) for i in range(3)], axis=1
        )
        return m - (sums / np.bincount(codes, minlength=labels.size)[:, None])[codes]

    products = within(a) * within(b)  # (cells, 3)
    per_block = np.stack(
        [np.bincount(codes, weights=products[:, i], minlength=labels.size) for i in range(products.shape[1])],
        axis=1,
    ).ravel()
    observed = per_block.sum()
    signs = np.random.default_rng(0).choice((-1.0, 1.0), size=(draws, per_block.size))
    null = signs @ per_block
    return float((1 + np.count_nonzero(np.abs(null) >= abs(observed) * (1 - 1e-12))) / (draws + 1))


def unrepeated_p_value(obs0, z0, obs1, z1) -> float | None:
    """Whether the sessions differ by more than white noise. Per shared cell, the
    difference of the two sessions' mean residuals over its standard deviation for white
    noise at the floor, ``sqrt(1/k0 + 1/k1)`` for cells of k0 and k1 holds, is a unit normal
    when what is left repeats; a χ² excess is noise between holds that the floor leaves out:
    slow wander. (Session 0's in-sample residuals scatter a little less than unit normals, by
    the fit's leverage: the test errs towards finding no wander.)"""
    shared = _shared_cells(obs0, z0, obs1, z1)
    if shared is None:
        return None
    a, b, k0, k1, _ = shared
    d = ((a - a.mean(axis=0)) - b) / np.sqrt(1.0 / k0 + 1.0 / k1)[:, None]
    return float(chi2_sf(float(np.sum(d**2)), d.size - 3))


# Above this share of their pattern in common, two sessions' residuals repeat: slow noise,
# independent between sessions, leaves about none in common (two independent wanders can
# correlate by chance, seldom this much).
REPEATS_SHARE = 0.5


def shared_fraction(obs0, z0, obs1, z1) -> float | None:
    """How much of the two sessions' residual pattern over the cells they share is common:
    ``1 − Σ(a − b)² / Σ(a² + b²)``, ``a`` and ``b`` the cell means less each session's mean
    per axis. About 0 for independent noise, slow wander included, and 1 for a pattern
    that repeats. Whole blocks count here (:func:`repeat_p_value` leaves their means out):
    an effect constant over a block, as a g-sensitivity on one mount is, repeats as whole
    blocks. None when fewer than 6 blocks are shared."""
    shared = _shared_cells(obs0, z0, obs1, z1)
    if shared is None:
        return None
    a, b = shared[0] - shared[0].mean(axis=0), shared[1] - shared[1].mean(axis=0)
    power = float(np.sum(a**2 + b**2))
    return float(1.0 - np.sum((a - b) ** 2) / power) if power > 0 else 0.0


def slow_noise(nxt, alpha: float) -> bool:
    """The sessions differ by more than the floor (:func:`unrepeated_p_value`) and do not
    share their pattern (:func:`shared_fraction`): slow noise, not an effect."""
    return (
        usable(nxt)
        and nxt["unrepeated_p_value"] is not None
        and nxt["unrepeated_p_value"] < alpha / 2
        and (nxt.get("shared_fraction") is None or nxt["shared_fraction"] < REPEATS_SHARE)
    )
