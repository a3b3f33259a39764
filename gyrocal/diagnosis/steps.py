"""The diagnosis as a sequence of named steps, each answering one question with a frozen
result (:mod:`.findings`); :func:`diagnose` runs them in order and builds the
:class:`.diagnosis.Diagnosis` once."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..fit.floor import with_upper_floor
from ..fit.model import columns_of, shares_wander
from ..io.errors import GyrocalError
from ..pipeline.config import Settings
from ..terms import AXES
from .approach import direction_of_approach
from .between import between_points, between_reason, seating_variance, tilted_per_point, tilted_reason
from .confounds import mounting_confound, rate_order_confound, time_temperature_confound
from .diagnosis import Diagnosis
from .effects import (
    Candidate,
    Judge,
    extended_all,
    gains_where_judged,
    practical_gain,
    practical_gain_next,
    rank_candidates,
    second_step,
    time_drift,
)
from .evaluation import (
    Evaluation,
    add_term_option,
    candidate_terms,
    config_line,
    evaluate,
    extended,
    fix_row,
    ladder,
    noise_only,
    with_drift_chord,
)
from .findings import (
    SENSOR_LEAD,
    Approach,
    BetweenPoints,
    ExcessTest,
    FloorsDiffer,
    LabTest,
    MountingTest,
    Negligible,
    TimeDrift,
    Unexplained,
    Where,
    WithinNoise,
    explained_by,
)
from .grain import grains
from .lab import (
    LAB_ADVICE,
    MOUNTING_ADVICE,
    lab_fixed,
    lab_reason,
    mounting_fixed,
    mounting_reason,
    reference_reason,
    seating_in_sample,
)
from .naming import (
    MOST,
    continuous_instead,
    fits_within_noise,
    free_shape,
    held_out_gain,
    judged_on,
    library_order,
    misses_levels,
    partial_offers,
    reaches_floor,
    takes_most_at_its_grain,
)
from .reading import readable
from .sessions import (
    CARRIES_WITHIN,
    POINT_MATCH,
    carries,
    carries_between,
    changed_alone,
    fails_between_only,
    fails_in_practice,
    offset_alone,
    practical_bar,
    rate_shaped,
    reference_scaled,
    seated_rms,
    seating_sigma,
    slow_noise,
    usable,
    wanders_most,
    white_bar,
)
from .stats import chance_bound, chi2_sf, explained_tolerance, floor_uncertainty
from .verdict import advice, coherent, input_kinds, unexplained, unseen_hysteresis
from .where import covariate_table, fit_quality, history_columns, one_way_points, shape_estimate

# The most useful terms each tried as the first of two missing effects: the one that
# gains most alone is not always part of the pair (a temperature lag's first-order form
# beats a die temperature alone, whose pair with a cubic bias is the effect).
PAIR_STARTS = 3


def diagnose(
    settings: Settings,
    obs: pd.DataFrame,
    other: pd.DataFrame | None = None,
    *,
    base: Evaluation | None = None,
) -> Diagnosis:
    """Diagnose ``settings.model`` on the observations (the questions of the package's
    docstring).

    ``other``, the observations of another session of the same unit, is what the user's
    calibration will meet: each model is then also judged by how it carries over to it
    (:func:`.sessions.carry_over`), and an excess whose pattern does not repeat there is
    noise. ``base``, the configured model already fitted and validated on ``obs``
    (:func:`.evaluation.evaluation_of`), is used rather than fitting again."""
    alpha = settings.diagnosis.significance
    if base is None:
        base = evaluate(settings, obs, "configured model")
    base = noise_only(with_drift_chord(base, obs))
    data = columns_of(obs)
    excess = excess_test(obs, base, alpha)
    judge = Judge(settings, obs, data, other, alpha, max(base.chi2 / base.dof - 1.0, 0.0))
    base_next = judge.carry(base)
    if base_next is not None and "error" in base_next:
        judge.other = None  # the other session cannot be used: judged on this one alone
    # A failure where the user meets the calibration leaves the question open however small
    # the held-out error: the other session resolves what the points left out could not.
    excess = replace(excess, next_fails=usable(base_next) and fails_in_practice(base_next))
    if (
        not excess.explains
        and carries(base_next)
        and excess.validation_rms <= CARRIES_WITHIN * excess.expected_rms
    ):
        # The calibration carries to the other session, and on the points left out it errs
        # within the bar it meets there (the bar itself: beside an in-sample excess beyond
        # chance, no room for the figure's own uncertainty): an excess the user never meets
        # (a floor from within the holds that understates this session's slow noise) is faint.
        excess = replace(excess, faint=True)
    before_holds = history_columns(obs, data)
    # One session alone: the slow wander its static data cannot rule out, before the
    # mounting is read (wander leaves offsets per mounting too).
    # the holds with the slow terms at their upper bound: one frame for both tests below
    upper = with_upper_floor(obs)
    within_noise = slow_noise_bound(settings, obs, upper, alpha, excess, base_next, before_holds["mounting"])
    outside = outside_the_sensor(obs, excess, base.dof, before_holds, base_next, within_noise)
    unrepeated = did_not_repeat(judge, base, excess, base_next, outside)
    # An excess that does not come back in the other session is still searched: an effect
    # of conditions the sessions do not share (a shorter soak, another order) holds there
    # through its term, which slow noise does not.
    explains = excess.explains
    library = library_search(judge, base, excess, base_next, explains)
    drift = (
        time_drift(judge, settings, obs, base, base_next, excess.tolerance, excess.bound)
        if not explains
        else None
    )
    where = where_it_lives(obs, data, excess, base, explains)
    named = name_a_term(judge, base, excess, library, drift, where, base_next, explains)
    found = when_nothing_is_named(judge, base, excess, outside, library, named, where, base_next, explains)
    # A shape that fits this session and fails on the other, where the calibration carries
    # over: this session's slow noise, which no term should carry (not a unit that changed).
    unrepeated_shape = _shape_left_behind(found, base_next)
    if unrepeated_shape is not None:
        explains = True
        found = replace(found, useful=(), shaped=(), why=None)
    if unrepeated and found.best is not None:
        unrepeated = False
    elif unrepeated:
        explains = True
        found = replace(found, useful=(), shaped=(), drift=None, why=None)
    white_bar = CARRIES_WITHIN * excess.expected_rms * excess.bound
    if (
        not usable(base_next)
        and explained_by(within_noise)
        and excess.validation_rms <= max(white_bar, within_noise.expected_rms * excess.bound)
    ):
        # beyond the white bar the held-out error speaks for a term too: the wander at the
        # points left out is not the wander the term's coefficients were fitted to
        held_out_speaks = excess.validation_rms > white_bar
        found, within_noise = beyond_slow_noise(
            settings, upper, alpha, found, within_noise, base if held_out_speaks else None
        )
    noise_explains = slow_noise_explains(excess, outside, found, within_noise, explains)
    if noise_explains:
        explains = True
        found = replace(found, useful=(), drift=None, why=None)
    why = found.why or too_small(excess, found.best, explains, noise_explains)
    if why is None and explains and found.best is None:
        why = _other_session_reason(judge, base_next)
    between = (
        between_points(
            base.fitted, alpha, seating_variance(obs, before_holds["mounting"], seating_sigma(settings))
        )
        if excess.fits and excess.resolvable and found.best is None and not noise_explains
        else None
    )
    if why is None and between is not None and between.fails and _between_matters(excess, base_next):
        points = obs["point"].to_numpy() if "point" in obs else np.zeros(len(obs))
        tilted = tilted_per_point(between, alpha, before_holds["mounting"], points, base.fitted)
        why = tilted_reason(between) if tilted else _between_reason(base, between)
    best = found.best
    if best is not None and settings.model.kind == "grid":
        best = continuous_instead(judge, best, base_next, excess.bound) or best
    timed = best is None and explained_by(found.drift)
    partial = (
        []
        if best or timed
        else partial_offers(
            [*found.useful, *found.shaped],
            base,
            base_next,
            where.lead,
            excess.bound,
            where.covariates,
            at_its_grain=None if usable(base_next) else lambda c: takes_most_at_its_grain(judge, c),
        )
    )
    return _diagnosis(
        judge,
        base,
        excess,
        outside,
        within_noise,
        where,
        found,
        best,
        partial,
        why,
        between,
        base_next,
        unrepeated=unrepeated,
        unrepeated_shape=unrepeated_shape,
        explains=explains,
        noise_explains=noise_explains,
        before_holds=before_holds,
    )


def excess_test(obs: pd.DataFrame, base: Evaluation, alpha: float) -> ExcessTest:
    """Does the model explain the data: its χ² test, half the significance. An excess within
    the noise floor's own uncertainty is no effect to name, however many holds make it
    significant: the model explains the data, and a faint pattern is noted; so is one within
    :data:`.sessions.CARRIES_WITHIN` times the floor in sample and of what a correct model
    leaves on the holds left out (up to that figure's own uncertainty), the bar a calibration
    meets on its next session. The held-out
    error is resolvable where it misses what a correct model leaves by more than the
    validation's own uncertainty (chance, over the holds scored): only then is there
    something for a term to take away, and a term's gain must exceed that uncertainty too."""
    quality = fit_quality(base, len(obs))
    fits = quality.excess_p_value >= alpha / 2
    factor = float(np.sqrt(quality.chi2_red["all"]))
    v0, expected = base.summary["validation_rms"], base.summary["expected_rms"]
    bound = chance_bound(base.summary["holds_scored"], alpha)
    return ExcessTest(
        quality=quality,
        alpha=alpha,
        fits=fits,
        faint=not fits
        and (
            factor - 1.0 <= floor_uncertainty(obs)
            or (factor <= CARRIES_WITHIN and v0 <= CARRIES_WITHIN * expected * bound)
        ),
        factor=factor,
        bound=bound,
        tolerance=explained_tolerance(obs, base.summary["holds_scored"], alpha),
        resolvable=v0 > expected * bound,
        validation_rms=v0,
        expected_rms=expected,
    )


@dataclass(frozen=True)
class OutsideTheSensor:
    """Findings no term of the sensor can hold: an effect fixed in the lab, seen through the
    turning table's angle, and an offset per mounting on the fixture."""

    lab: LabTest | None
    mounting: MountingTest | None

    @property
    def in_lab(self) -> bool:
        return explained_by(self.lab)

    @property
    def of_mounting(self) -> bool:
        return explained_by(self.mounting)

    @property
    def explains(self) -> bool:
        return self.in_lab or self.of_mounting


def outside_the_sensor(
    obs, excess: ExcessTest, dof: int, before_holds: dict, base_next=None, within_noise=None
) -> OutsideTheSensor:
    """An effect fixed in the lab follows the table's angle: it does not repeat between
    sessions (the table starts elsewhere) and is no effect of the sensor's. Each mounting on
    the fixture may leave its own offset, fresh every time: no term of the sensor carries it,
    and it does not repeat in another session (where it would read as slow noise or a unit
    that changed). Tried only where the model misses, the mounting only where the lab does
    not explain it; neither where the in-sample residuals are within the bar a calibration
    meets on its next session. Slow wander leaves offsets per mounting too: the mounting is
    no finding where the wander one session's static data cannot rule out explains its
    excess (``within_noise``), nor where the calibration carries to the other session within
    the bar (``base_next``): the fixture's scatter is then part of what a calibration of this
    rig meets, not what limits it."""
    if excess.explains or excess.factor <= CARRIES_WITHIN:
        return OutsideTheSensor(None, None)
    lab = lab_fixed(obs, excess.quality, dof, excess.alpha)
    mounting = None
    within = explained_by(within_noise) or carries(base_next)
    if not explained_by(lab) and "mount" in obs and not within:
        mounting = mounting_fixed(
            obs,
            excess.quality,
            dof,
            excess.alpha,
            before_holds["mounting"],
            before_holds.get("temp_direction"),
        )
    return OutsideTheSensor(lab, mounting)


def did_not_repeat(judge: Judge, base: Evaluation, excess: ExcessTest, base_next, outside) -> bool:
    """An excess that does not come back in the other session, whose residuals differ from
    this one's by more than the floor, is slow noise, not an effect; unless a history
    explains it here and carries to the other session (its pattern changes with the order a
    session visits its rates or temperatures)."""
    if (
        excess.explains
        or outside.explains
        or not usable(base_next)
        or base_next["unrepeated_p_value"] is None
        # residuals within the bar a calibration meets on its next session have no slow
        # noise worth a verdict; and a practical failure there is no wander of this one's
        or excess.factor <= CARRIES_WITHIN
    ):
        return False
    # A failure there that one change of bias, scale and axes takes whole is a change
    # between the sessions, not a wander: slow noise scatters hold by hold.
    return bool(
        base_next["repeat_p_value"] >= excess.alpha / 2
        and slow_noise(base_next, excess.alpha)
        and not changed_alone(base_next)
        and not _history_explains(judge, base, excess, base_next)
    )


def _history_explains(judge: Judge, base: Evaluation, excess: ExcessTest, base_next) -> bool:
    """Whether a term with a history (:func:`.shapes.history_shapes`, for the rows that carry
    the excess) explains it here and carries to the other session, as any named shape must:
    then the excess that did not come back there is no slow noise."""
    quality = excess.quality
    rows, _ = covariate_table(
        judge.obs, judge.data, np.nan_to_num(quality.z), quality.fitted_rows, base.dof, True
    )
    found, tried = free_shape(
        judge, base, rows, quality, base_next, excess.tolerance, excess.bound, inputs=("history", "t_mount")
    )
    # or takes most of what the configured model leaves on the other session, which slow
    # noise of this one's would not (what it leaves is a second question)
    return found is not None or any(
        c.status == "ranked" and usable(c.next_session) and held_out_gain(c, base, base_next) > MOST
        for c in tried
    )


def slow_noise_bound(
    settings: Settings,
    obs,
    upper: pd.DataFrame | None,
    alpha: float,
    excess: ExcessTest,
    base_next,
    mounting: np.ndarray | None = None,
) -> WithinNoise | None:
    """The χ² test with the slow wander the static data could not rule out at its upper
    bound: it may be all the excess is. Where the model misses and no other session tells:
    none is given, or it shares no cells with this one to compare the residuals' patterns
    (``repeat_p_value`` None) and its calibration carries there.

    Where the wander alone leaves an excess and the holds' ``mounting`` (stretches on one
    mount) shows mountings whose rotations differ, the fixture's seating at the rig's
    repeatability (:func:`.sessions.seating_sigma`) joins it: each mounting's rotation a
    random effect (:func:`.lab.seating_in_sample`), its part taken out of the holds and its
    own χ² (Σ ε²/σ²) added to what the model leaves, on the model's degrees of freedom. What
    a correct model leaves on the holds left out then counts the seating at the size fitted
    (a point's mean rotation, which a calibration absorbs in sample, errs there)."""
    if excess.explains or (
        usable(base_next) and (base_next["repeat_p_value"] is not None or fails_in_practice(base_next))
    ):
        return None
    if upper is None:
        return None
    wide = evaluate(settings, upper, "configured model, slow noise at its upper bound")
    chi2, expected = wide.chi2, float(wide.summary["expected_rms"])
    sigma = seating_sigma(settings)
    seated = (
        seating_in_sample(obs, excess.quality, mounting, sigma)
        if mounting is not None and chi2_sf(chi2, wide.dof) < alpha / 2
        else None
    )
    if seated is not None and seated.change > 0:
        unseated = upper.copy()
        for i, a in enumerate(AXES):
            unseated[f"gyro_{a}"] = upper[f"gyro_{a}"].to_numpy(float) - seated.part[:, i]
        chi2 = evaluate(
            settings, unseated, "configured model, slow noise at its upper bound, seating out"
        ).chi2
        # the rotations were fitted under the white floor, not the wander's covariance: the
        # sum is that objective at a rotation other than its best, never below its minimum
        chi2 += seated.penalty
        rates = obs.loc[excess.quality.fitted_rows, ["rate_x", "rate_y", "rate_z"]].to_numpy(float)
        turned = 2.0 / 3.0 * float(np.mean(np.sum(rates**2, axis=1)))  # Σ over the other axes, per output
        expected = float(np.hypot(expected, seated.change * np.sqrt(turned)))
    else:
        seated = None
    p_value = float(chi2_sf(chi2, wide.dof))
    return WithinNoise(
        excess_p_value=p_value,
        chi2_red=chi2 / wide.dof,
        expected_rms=expected,
        static_seconds=float(obs.attrs.get("static_seconds") or 0.0),
        explains=p_value >= alpha / 2,
        seating_change=None if seated is None else seated.change,
        seating_repeatability=None if seated is None else sigma,
    )


def beyond_slow_noise(
    settings: Settings,
    upper: pd.DataFrame | None,
    alpha: float,
    found: Found,
    within_noise: WithinNoise,
    held_out: Evaluation | None = None,
) -> tuple[Found, WithinNoise]:
    """One session whose excess the slow wander its static data cannot rule out accounts
    for (``within_noise``), and whose held-out error is within what a correct model leaves
    under that wander (so the held-out error alone cannot tell a term's effect from the
    wander's): a term offered must also take more than chance from what that wander leaves
    (``upper``: the holds with the slow terms at their upper bound), the χ² drop there on the
    coefficients it adds (half the significance), or it is a shape the wander may have made
    (holds close in time share it: offsets per mount on a protocol that mounts one axis after
    another are the wander's as much as a g-sensitivity's). Where the held-out error is beyond
    what white noise leaves (``held_out``, the configured model's evaluation, given then), a
    term that takes most of that excess on the points left out (:data:`.naming.MOST`) is kept
    too: its coefficients were fitted to other points, whose wander is not theirs. Those
    dropped are named in ``within_noise.drowned``."""
    offered = [c for c in (found.best, *found.useful, *found.shaped) if c is not None]
    if upper is None or not offered:
        return found, within_noise
    wide = evaluate(settings, upper, "configured model, slow noise at its upper bound")
    beyond: dict[str, bool] = {}
    drowned = []
    for c in offered:
        if c.term in beyond:
            continue
        if held_out is not None and c.validated and held_out_gain(c, held_out, None) > MOST:
            beyond[c.term] = True
            continue
        try:
            extended_settings = extended(settings, c.term)
            for term in c.together:
                extended_settings = extended(extended_settings, term)
            ev = evaluate(extended_settings, upper, f"{c.term}, slow noise at its upper bound")
        except GyrocalError:
            beyond[c.term] = True  # not to be judged this way: kept as found
            continue
        added = wide.dof - ev.dof
        p_value = float(chi2_sf(max(wide.chi2 - ev.chi2, 0.0), added)) if added > 0 else 0.0
        beyond[c.term] = p_value < alpha / 2
        if not beyond[c.term]:
            drowned.append((c.term, p_value))
    if not drowned:
        return found, within_noise
    kept = lambda cs: [c for c in cs if beyond[c.term]]  # noqa: E731
    best = found.best if found.best is not None and beyond[found.best.term] else None
    found = replace(found, best=best, useful=kept(found.useful), shaped=kept(found.shaped))
    return found, replace(within_noise, drowned=tuple(drowned))


@dataclass(frozen=True)
class LibrarySearch:
    """Every candidate of the library and the user's, added in turn (question 3): all of
    them, those ranked, and those useful (significant, with a practical gain, where the
    model misses), the most useful where the calibration is judged first."""

    candidates: list[Candidate]
    ranked: list[Candidate]
    useful: list[Candidate]


def library_search(
    judge: Judge, base: Evaluation, excess: ExcessTest, base_next, explains: bool
) -> LibrarySearch:
    """No name without a gain: a term is named, or reported as partial, only when the model
    misses what a correct one leaves and the term takes away a practical part of that."""
    settings = judge.settings
    candidates = rank_candidates(judge, base, candidate_terms(settings), base_next, excess.tolerance)
    ranked = [c for c in candidates if c.status == "ranked"]
    for c in ranked:
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
    # A library term's gain on the points left out counts beside the other session's: it
    # may be half of a pair that the other session needs whole (a die's lag with its bias
    # polynomial along a sweep).
    useful = [
        c
        for c in ranked
        if c.significant
        and not explains
        and (practical_gain(base, c, excess.bound) or gains_where_judged(base, c, base_next, excess.bound))
    ]
    if usable(base_next):  # what the user will meet: the other session first
        useful.sort(key=lambda c: c.next_session["validation_rms"] if usable(c.next_session) else np.inf)
    return LibrarySearch(candidates, ranked, useful)


def where_it_lives(obs, data, excess: ExcessTest, base: Evaluation, explains: bool) -> Where:
    """The excess shared out among the covariates whenever the fit shows one, also when it is
    judged noise: where it lives is what tells wander from an effect. A faint excess notes
    the covariate it follows beyond chance (Bonferroni over the rows)."""
    quality = excess.quality
    covariates, heat = covariate_table(
        obs, data, np.nan_to_num(quality.z), quality.fitted_rows, base.dof, not explains
    )
    negligible = None
    if excess.faint:
        row = min(covariates, key=lambda r: r["p_value"])
        p_row = min(1.0, row["p_value"] * len(covariates))
        negligible = Negligible(
            factor=excess.factor,
            held_out=excess.validation_rms / excess.expected_rms,
            floor_uncertainty=floor_uncertainty(obs),
            covariate=row["covariate"] if p_row < excess.alpha / 2 else None,
            p_value=p_row,
        )
    lead = next((r for r in covariates if (r["share_of_excess"] or 0) > 0), None)
    return Where(covariates, heat, lead, negligible)


@dataclass(frozen=True)
class Naming:
    """The term named among the library's and the user's (or a shape that beat it), every
    candidate tried so far, and the drift in time with the term it rivals, if any."""

    best: Candidate | None
    candidates: list[Candidate]
    drift: TimeDrift | None

    @property
    def blocked(self) -> bool:
        """A drift in time explains the excess: what fits it as per-mount steps, alone or in
        a pair (a temperature rate and a g-sensitivity fit a ramp so), cannot be named."""
        return explained_by(self.drift)


def name_a_term(
    judge, base, excess, library: LibrarySearch, drift, where: Where, base_next, explains
) -> Naming:
    """Named only when it explains the excess: what is left is what a correct model leaves.
    A term that only fits a drift's per-mount steps yields to the drift; two effects are
    tried where one does not do; a sharper shape, or one of the input that carries the
    excess, replaces a library term it beats."""
    best = _first_that_explains(library.useful, excess.alpha)
    if best is not None and explained_by(drift) and "time" not in input_kinds(best.term):
        # Within a soak the mounts follow each other in time: a term that is constant per
        # mount (a g-sensitivity) and a bias drifting in time can fit the same steps. When
        # the drift explains the excess too, the protocol cannot name either.
        drift, best = replace(drift, rival_of=best.term), None
    candidates = library.candidates
    if best is None and not explained_by(drift):  # a drift blocks per-mount pairs (Naming.blocked)
        best = _two_effects(judge, base, excess, library)
    elif best is not None and best.second_question and usable(base_next) and not explained_by(drift):
        # a single that passes as the fix the other session needs, leaving a pattern here,
        # may be half of a pair that leaves none: the pair where it does better there
        pair = _two_effects(judge, base, excess, library)
        if pair is not None and judged_on(pair, base_next) * excess.bound < judged_on(best, base_next):
            best = pair
    if best is not None and not best.part_of and excess.open and not explains:
        best, candidates = _sharper_shape(judge, base, excess, library, best, where, base_next, candidates)
    best = _library_first(best, library.ranked)
    if best is not None and not explains and not best.part_of:
        best, candidates = _shape_of_the_lead(
            judge, base, excess, library, best, where, base_next, candidates
        )
    return Naming(best, candidates, drift)


def _first_that_explains(useful: list[Candidate], alpha: float) -> Candidate | None:
    """The most useful term that explains the excess, tied with the others that do with a
    fit within its noise (a g-sensitivity and its square where the accelerometer reads about
    0 or 1 g): the data cannot tell them apart, whatever their figures' last digits say."""
    best = next((c for c in useful if c.explains_excess), None)
    if best is not None:
        best.tied_with = list(
            dict.fromkeys(
                [
                    *best.tied_with,
                    *(
                        c.term
                        for c in useful
                        if c is not best
                        and c.explains_excess
                        and fits_within_noise(c, alpha)
                        and fits_within_noise(best, alpha)
                    ),
                ]
            )
        )
    return best


def _two_effects(
    judge: Judge, base: Evaluation, excess: ExcessTest, library: LibrarySearch
) -> Candidate | None:
    """Two effects missing at once: one of the most useful terms, then each other on top.
    A pair starts from a term whose gain shows on the points left out: one useful by the
    other session alone takes its place as a single term, and pairs from it cost seconds
    for what the left-out points could not have told."""
    starts = [c for c in library.useful if practical_gain(base, c, excess.bound)]
    for first in starts[:PAIR_STARTS]:
        pair = second_step(judge, first, library.ranked, base.summary["validation_rms"], excess.tolerance)
        if pair is not None:
            return pair
    return None


def _sharper_shape(judge, base, excess, library, best, where, base_next, candidates):
    """A library shape of the rate may only approach a sharper one that the protocol's
    levels resolve (a range switch read as a cubic scale); library terms that pass the tests
    yet leave the calibration beyond the floor where it will be judged (a temperature rate
    standing in for a warm-up, the other session 8 times the floor) may stand in for a shape
    of another input. Those shapes are tried, and one that does better there, beyond that
    figure's own uncertainty, is offered instead."""
    of_rate = all(input_kinds(t) == {"rate"} for t in (best.term, *best.together))
    if not (of_rate or not reaches_floor(best, base_next, excess.bound)):
        return best, candidates
    rival, tried = free_shape(
        judge,
        base,
        where.covariates,
        excess.quality,
        base_next,
        excess.tolerance,
        excess.bound,
        library=library.ranked,
        inputs=("rate_own", "rate_cross", "history") if of_rate else None,
    )
    if rival is not None and (
        judged_on(rival, base_next) * excess.bound < judged_on(best, base_next)
        or (of_rate and misses_levels(best, tried, excess.alpha))
    ):
        return rival, candidates + tried
    return best, candidates


def _library_first(best: Candidate | None, ranked: list[Candidate]) -> Candidate | None:
    """Among terms the data cannot tell apart, the library's order names the likelier effect."""
    if best is None or not best.tied_with:
        return best
    group = [best, *(c for c in ranked if c.term in best.tied_with)]
    first = min(group, key=library_order)
    if first is best or not first.explains_excess:
        return best
    first.tied_with = list(dict.fromkeys([*first.tied_with, *(c.term for c in group if c is not first)]))
    return first


def _shape_of_the_lead(judge, base, excess, library, best, where, base_next, candidates):
    """A term that fits the excess without reading the input that carries it (the
    accelerometer, where the centripetal force follows the rate): the shapes of that input
    are tried, and one that explains it is offered instead."""
    if any(coherent(t, where.lead) for t in (best.term, *best.together)):
        return best, candidates
    rival, tried = free_shape(
        judge,
        base,
        where.covariates,
        excess.quality,
        base_next,
        excess.tolerance,
        excess.bound,
        library=library.ranked,
    )
    if rival is not None and coherent(rival.term, where.lead):
        return rival, candidates + tried
    return best, candidates


@dataclass(frozen=True)
class Found:
    """What the search ends with: the term named (if any), every candidate tried, why none
    was (if so), the terms of free shape that take a practical part of the excess, the
    library's useful terms and the drift in time still standing beside the finding."""

    best: Candidate | None
    candidates: list[Candidate]
    why: Unexplained | None
    shaped: list[Candidate] | tuple = ()
    useful: list[Candidate] | tuple = ()
    drift: TimeDrift | None = None


def when_nothing_is_named(
    judge, base, excess, outside, library, named: Naming, where, base_next, explains
) -> Found:
    """Where no term is named: the lab or the mounting account for the whole excess (what
    terms or a drift take of it is no part of the answer); otherwise, where the model
    misses, terms of free shape for the inputs that carry the excess, judged as the
    library's are, and why none could be offered."""
    best, useful, drift = named.best, library.useful, named.drift
    if best is not None:
        return Found(best, named.candidates, None, (), useful, drift)
    if outside.in_lab:
        return Found(None, named.candidates, lab_reason(outside.lab))
    if outside.of_mounting:
        # a fixture's seating is fresh at each mounting, each its own tilt: it makes no one
        # scale every axis of the other session shares, which is the reference's
        if excess.next_fails and reference_scaled(base_next):
            return Found(None, named.candidates, reference_reason(base_next))
        # A term of the sensor that takes most of the held-out error is a rival the
        # mounting's offsets mimic (each mount holds gravity one way): not the mounting's.
        if not any(held_out_gain(c, base, base_next) > MOST for c in useful):
            return Found(None, named.candidates, mounting_reason(outside.mounting))
    if not excess.open or explains:
        return Found(None, named.candidates, None, (), useful, drift)
    best, tried = free_shape(
        judge,
        base,
        where.covariates,
        excess.quality,
        base_next,
        excess.tolerance,
        excess.bound,
        time_only=named.blocked,
        library=library.ranked,
    )
    shaped = [
        c
        for c in tried
        if c.status == "ranked" and c.significant and gains_where_judged(base, c, base_next, excess.bound)
    ]
    why = unexplained(tried, where.covariates, usable(base_next)) if best is None else None
    if (
        best is None
        and excess.next_fails
        and not any(practical_gain_next(base_next, c, excess.bound) for c in [*useful, *shaped])
    ):
        # Nothing fitted to this session takes a practical part of the other session's
        # failure: that failure lies between the sessions, not in this session's excess.
        why = _other_session_reason(judge, base_next) or _changed_between(base_next)
    return Found(best, named.candidates + tried, why, shaped, useful, drift)


def _wanders_between(base_next) -> Unexplained:
    """Why the calibration fails on the other session where most of that failure moves
    within its temperature points (:func:`.sessions.wanders_most`): in time, which no shape
    in temperature and no change of the unit makes."""
    return Unexplained(
        reason="slow noise",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"on the other session the calibration errs {base_next['excess']:.3g} times the floor, "
            f"and most of it moves within that session's temperature points: with each point's "
            f"own bias and rates out, {base_next['within_points_rms'] / base_next['within_points_expected']:.3g} "
            "times what white noise leaves there. No shape in temperature and no change of the "
            "unit moves within a point: the bias or scale wanders in time, slow noise (a bias "
            "that switches between levels, a wander slower than the static stretches) that no "
            "calibration carries"
        ),
        would_tell="longer static stretches at power-on and between the points (the wander's Allan "
        "deviation), or a point held twice as long",
    )


def _changed_between(base_next, alike: bool = False) -> Unexplained:
    """Why the calibration fails on the other session where no term fitted to this one takes
    a practical part of that failure, or (``alike``) where one change of bias, scale and axes
    for the whole other session fits every temperature it visits: the unit (or the rig's
    reference) changed between the sessions."""
    why = (
        "one change of bias, scale and axes, the same at each of its temperatures, brings it "
        f"to {base_next['changed_rms'] / base_next['expected_rms']:.3g} times what a correct model "
        "would leave"
        if alike
        else "no term fitted to this session takes a practical part of that"
    )
    return Unexplained(
        reason="does not carry over",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"on the other session the calibration errs {base_next['excess']:.3g} times the floor, "
            f"and {why}: the unit changed between the sessions (its bias, scale or axes), or the "
            "rig's reference did"
        ),
        would_tell="a third session (a drift continues, a one-off change does not)",
    )


def slow_noise_explains(
    excess: ExcessTest, outside, found: Found, within_noise: WithinNoise | None, explains: bool
) -> bool:
    """One session whose in-sample excess the slow noise the static data cannot rule out
    accounts for, whose held-out error is within what a correct model leaves under that
    noise too, and that no term, no drift in time and no term of free shape takes a
    practical part of: nothing in it asks for an effect (slow wander and a one-off effect
    look alike in one session; another one tells them apart)."""
    if found.best is not None or explains or outside.explains or not explained_by(within_noise):
        return False
    return not excess.open or (
        excess.validation_rms <= within_noise.expected_rms * excess.tolerance
        and not found.useful
        and not found.shaped
        and not explained_by(found.drift)
    )


def too_small(excess: ExcessTest, best, explains: bool, noise_explains: bool) -> Unexplained | None:
    """An in-sample excess whose held-out error is within what a correct model leaves, up to
    the validation's own uncertainty: too small to name anything from."""
    if explains or best is not None or excess.open or noise_explains:
        return None
    return Unexplained(
        reason="too small",
        term=None,
        text=(
            f"on the holds left out the model's error, {excess.validation_rms:.3g} deg/s, is within "
            f"what a correct model would leave ({excess.expected_rms:.3g}) up to the validation's "
            "own uncertainty: too small to attribute to an effect"
        ),
        would_tell="more holds where the excess lives (longer soaks, more rates or "
        "temperatures), or another session (--other-session)",
    )


def _other_session_reason(judge: Judge, base_next) -> Unexplained | None:
    """Why a calibration that explains this session fails on the other, where that says
    more than a change of the unit: one scale every axis shares (the reference's), or the
    other session's points all between this one's."""
    if usable(base_next) and reference_scaled(base_next):
        return reference_reason(base_next)
    return between_the_sessions(judge, base_next)


def _point_temperatures(obs: pd.DataFrame) -> np.ndarray:
    temp = obs["point_temp"] if "point_temp" in obs else obs["temp"]
    by = obs["point"].to_numpy() if "point" in obs else np.zeros(len(obs), dtype=int)
    return temp.groupby(by).median().to_numpy(float)


def between_the_sessions(judge: Judge, base_next) -> Unexplained | None:
    """Where the calibration fails on the other session in practice beyond an offset per axis,
    and only between this session's points (:func:`.sessions.fails_between_only`: it carries
    at the points both visit), it does not hold between its points. Where the other
    session's points all lie between this one's (none within :data:`.sessions.POINT_MATCH`
    of them, so no pattern can be compared), it does not, or the unit changed, and only a
    point both sessions visit tells which."""
    if judge.other is None or base_next is None or "error" in base_next or not fails_in_practice(base_next):
        return None
    if offset_alone(base_next):  # the same offset at every temperature: the bias moved
        return None
    if wanders_most(base_next):
        return _wanders_between(base_next)
    here, there = _point_temperatures(judge.obs), _point_temperatures(judge.other)
    if here.size < 2 or not there.size:
        return None
    apart = np.abs(there[:, None] - here[None, :]).min(axis=1) > POINT_MATCH
    inside = (there > here.min()) & (there < here.max())
    if fails_between_only(base_next):
        # both sessions measured some points: the calibration carries there and fails between
        return Unexplained(
            reason="between temperature points",
            term=None,
            lead=SENSOR_LEAD,
            text=(
                "on the other session the calibration carries over at this session's temperature "
                f"points ({base_next['at_points_rms'] / base_next['at_points_expected']:.3g} times "
                "what a correct model would leave there for white noise, within the bar with the "
                "slow wander that session's static data cannot rule out) and errs between them, "
                f"where it interpolates ({base_next['between_rms'] / base_next['between_expected']:.3g} "
                "times, beyond that bar): the sensor changes between the points more sharply than they resolve (a "
                "bias or scale of its own shape in temperature), not the unit between sessions"
            ),
            would_tell="more temperature points where the other session errs",
        )
    if not (apart.all() and inside.all()):
        return None
    if there.size >= 2 and changed_alone(base_next):
        # one change for the whole session fits every point alike: a shape of the sensor
        # between this session's points would differ from one temperature to the next
        return _changed_between(base_next, alike=True)
    points = ", ".join(f"{t:.3g}" for t in np.sort(there))
    return Unexplained(
        reason="between temperature points",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"the other session's temperature points ({points} °C) all lie between this "
            f"session's, where its calibration interpolates, and it errs there "
            f"{base_next['validation_rms'] / base_next['expected_rms']:.3g} times what a correct "
            "model would leave: the sensor changes between the points more sharply than they "
            "resolve (a bias or scale of its own shape in temperature), or the unit changed "
            "between the sessions"
        ),
        would_tell="a session visiting this session's points and the ones between",
    )


def _shape_left_behind(found: Found, base_next) -> str | None:
    """The shape of free form that fits this session best, where no term could be offered
    (it does not hold on the other session, or leaves what it cannot reach) and the
    configured calibration carries over there (:func:`.sessions.fails_in_practice`; for a
    shape that does hold there, with no term that takes a practical part of the excess and
    within the bar without reading offsets as power-ons): what it
    took here was this session's own slow noise, which its user never meets. The shape in
    words and why it was not offered, or None."""
    why = found.why
    if why is None or found.best is not None or not carries(base_next):
        return None
    if why.reason != "does not carry over" and (
        found.useful or found.shaped or seated_rms(base_next) > practical_bar(base_next)
    ):
        # a term that takes a practical part of it is offered as it stands; and where the
        # calibration carries by the power-ons' offsets alone, the shape may be what they hide
        return None
    best = next((c for c in found.candidates if c.term == why.term), None)
    if not why.term:
        return None
    shape = readable(why.term, best.profiled if best is not None else ())
    told = "does not hold on the other session" if why.reason == "does not carry over" else why.reason
    return f"{shape}, which {told}"


def _between_matters(excess: ExcessTest, base_next) -> bool:
    """Whether a failure between the temperature points matters as the calibration's user
    meets it: the holds of points left out err beyond the bar a calibration meets on its
    next session (:data:`.sessions.CARRIES_WITHIN` times what a correct model leaves, up to
    that figure's chance bound), although a point left out doubles the span the
    interpolation bridges; and the other session, where it lies between this one's points,
    does not carry the calibration over (:func:`.sessions.carries_between`)."""
    beyond = excess.validation_rms > CARRIES_WITHIN * excess.expected_rms * excess.bound
    return beyond and not carries_between(base_next)


def _between_reason(base: Evaluation, between: BetweenPoints) -> Unexplained:
    """A model that explains the data at its points may still fail between them, which only
    leaving points out shows; the held-out error is cited where points were left out."""
    held_out = base.summary.get("excess_over_expected")
    left_out = (
        base.summary.get("held_out") == "temperature" and held_out is not None and np.isfinite(held_out)
    )
    return between_reason(between, held_out if left_out else None)


FLOOR_SIGMAS = 3.0


def _floors_differ(judge, base, base_next) -> FloorsDiffer | None:
    """The two sessions' floors, each from its own static data the same way, where they
    differ beyond their own uncertainty: a finding the verdict states (the sensor's noise
    changed, or something shaped one session's static data), not a divisor to hide in."""
    if not usable(base_next) or judge.other is None:
        return None
    ratio = float(base_next["noise_floor"]) / float(base.summary["noise_floor"])
    spread = float(np.hypot(floor_uncertainty(judge.obs), floor_uncertainty(judge.other)))
    if spread <= 0:
        return None
    tolerance = FLOOR_SIGMAS * spread
    if abs(np.log(ratio)) <= np.log1p(tolerance):
        return None
    # within the bar for this session's white noise (the other's wander allowance comes
    # from the static data whose floor is in question); a part in proportion to the rates is
    # no noise's
    covers = (
        ratio < 1.0
        and fails_in_practice(base_next)
        and not rate_shaped(base_next)
        and base_next["validation_rms"] <= white_bar(base_next) / ratio
    )
    return FloorsDiffer(ratio, tolerance, bool(covers))


def _approach(judge, base, base_next, here: dict | None) -> Approach | None:
    """Where the configured model's calibration does not carry over to the other session:
    whether its errors there step with the direction each point was reached from
    (:func:`.approach.direction_of_approach`)."""
    if not usable(base_next) or not fails_in_practice(base_next) or judge.other is None:
        return None
    from ..fleet.drift import hold_errors
    from ..pipeline.chain import calibrate_observations

    try:
        cal, _ = calibrate_observations(judge.obs, judge.settings, meta={}, fitted=base.fitted, checks=False)
        errors, floor = hold_errors(cal, judge.other)
    except GyrocalError:
        return None
    return direction_of_approach(judge.obs, judge.other, errors, floor, judge.alpha, here)


def _one_way(obs, data, before, other) -> tuple[dict | None, bool]:
    """:func:`.where.one_way_points` of this session, where the other session (if any)
    reached each point it shares with this one (within 2 °C) the same way too: only then is a
    hysteresis of the temperature out of the data's sight. With whether the other session
    was compared (it shares a point)."""
    here = one_way_points(obs, data, before)
    if here is None or other is None:
        return here, False
    there = one_way_points(other, columns_of(other))
    if there is None:
        return None, True
    temps = np.array(list(here))
    shared = False
    for temp, way in there.items():
        near = np.abs(temps - temp) <= 2.0
        shared = shared or bool(near.any())
        if near.any() and any(here[float(t)] != way for t in temps[near]):
            return None, True
    return here, shared


def _advice(outside, found, best, partial, where, explains, base_next, blind) -> list[str]:
    """What to do next: compensate on the rig a finding outside the sensor; otherwise the
    advice on the terms; and a hysteresis of the temperature the session could not see."""
    if outside.in_lab and best is None:
        told = [LAB_ADVICE]
    elif outside.of_mounting and best is None:
        told = [MOUNTING_ADVICE]
    else:
        told = advice(
            best, partial, found.candidates, where.covariates, explains, usable(base_next), found.drift
        )
    return [*told, blind] if blind else told


def _diagnosis(
    judge,
    base,
    excess,
    outside,
    within_noise,
    where,
    found,
    best,
    partial,
    why,
    between,
    base_next,
    *,
    unrepeated,
    explains,
    noise_explains,
    before_holds,
    unrepeated_shape=None,
) -> Diagnosis:
    """The findings put together once: the residuals, the ladder, the advice."""
    settings, obs, quality = judge.settings, judge.obs, excess.quality
    # Where the holds share slow wander, RMS ÷ floor counts each hold as if its noise were its
    # own and can sit below 1 while the whitened χ² says the model misses: the verdict gives
    # sqrt(χ²/dof), the factor its test is made on.
    factor = float(np.sqrt(quality.chi2_red["all"])) if shares_wander(obs) else quality.rms_over_floor["all"]
    residuals = obs.reset_index(drop=True).assign(
        **{
            f"{q}_{a}": v[:, i]
            for q, v in (("resid", quality.resid), ("floor", quality.floor), ("z", quality.z))
            for i, a in enumerate(AXES)
        }
    )
    approach = (
        _approach(judge, base, base_next, one_way_points(obs, judge.data, before_holds))
        if best is None
        else None
    )
    floors = _floors_differ(judge, base, base_next)
    confound = rate_order_confound(
        obs, judge.data, best, found.candidates, where.covariates, judge.alpha, before_holds["previous_rate"]
    ) or time_temperature_confound(judge.data, best, found.candidates, where.covariates)
    confound = confound or mounting_confound(
        obs, best, where.covariates, before_holds["mounting"], usable(base_next)
    )
    grain = grains(settings, extended_all(settings, best), obs, best.profiled) if best is not None else ()
    steps = ladder(settings, obs, base, judge.carry if usable(base_next) else None)
    if best is not None:
        steps.append(fix_row(best, base))
    one_way, compared = _one_way(obs, judge.data, before_holds, judge.other)
    told = _advice(
        outside, found, best, partial, where, explains, base_next, unseen_hysteresis(one_way, compared)
    )
    return Diagnosis(
        base=base,
        significance=excess.alpha,
        chi2_red=quality.chi2_red,
        rms_over_floor=quality.rms_over_floor,
        excess_p_value=quality.excess_p_value,
        explains=explains,
        covariates=where.covariates,
        candidates=found.candidates,
        best=best,
        partial=partial,
        heatmaps=where.heatmaps,
        residuals=residuals,
        config_line=config_line(extended_all(settings, best).model) if best else "",
        ladder=steps,
        within_noise=within_noise,
        next_session=base_next,
        advice=told,
        time_drift=found.drift,
        shape_estimate=shape_estimate(obs, judge.data, quality, where.lead)
        if where.lead is not None and not explains
        else None,
        unexplained=why,
        lab_fixed=outside.lab,
        mounting=outside.mounting,
        between_points=between,
        factor=factor,
        negligible=where.negligible,
        one_way=one_way,
        approach=approach,
        confound=confound,
        floors_differ=floors,
        grain=grain,
        tolerance=excess.tolerance,
        noise_model="floor_x" in obs,
        unrepeated=unrepeated,
        noise_explains=noise_explains,
        unrepeated_shape=unrepeated_shape,
    )
