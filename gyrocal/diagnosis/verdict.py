"""The verdict and the advice: what the diagnosis found, in sentences, and what to do next."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..terms import Restricted, make_term
from .findings import Negligible, TimeDrift, Unexplained, WithinNoise, explained_by
from .grain import grain_sentence
from .reading import readable
from .sessions import (
    CARRIES_WITHIN,
    CarryOver,
    carries_between,
    carry_expected,
    fails_between_only,
    fails_in_practice,
    offset_alone,
    offset_and_allowance,
    power_ons_alone,
    rate_shaped,
    reference_scaled,
    rezeroed_rms,
    seated_rms,
    usable,
)
from .stats import chance_bound, p_text

if TYPE_CHECKING:
    from .diagnosis import Diagnosis
    from .effects import Candidate
    from .evaluation import Evaluation


def verdict(diag: Diagnosis) -> str:
    """The diagnosis in sentences: on this session, on the other one (given one), the drift
    in time that explains it, and why no term was offered."""
    base_next = diag.next_session if usable(diag.next_session) else None
    timed = diag.best is None and explained_by(diag.time_drift)
    text = session_verdict(diag, base_next, None if timed else diag.tolerance)
    if diag.confound is not None:
        text += _confound_sentence(diag.confound)
    text += "".join(grain_sentence(g) for g in diag.grain)
    # what the calibration does there is told where no point of it matched one of this
    # session's (the pattern's repetition alone needs shared points)
    carried = diag.next_session if diag.next_session and "error" not in diag.next_session else None
    text += _other_session(diag, carried)
    if diag.floors_differ is not None and noise_covers_the_other(diag):
        f = diag.floors_differ
        text += (
            f" The other session's noise floor, from its own static data, is {f.ratio:.2f} times "
            f"this one's, beyond their own uncertainty (±{f.tolerance:.0%}), and its errors are "
            f"within {CARRIES_WITHIN:g} times what a correct model leaves under this session's "
            "noise: slow noise this session's static data caught (a bias that jumps, bursts) "
            "and the other's did not, in the other session's holds; not a change of the unit."
        )
    elif diag.floors_differ is not None:
        f = diag.floors_differ
        text += (
            f" The other session's noise floor, from its own static data, is {f.ratio:.2f} times "
            f"this one's, beyond their own uncertainty (±{f.tolerance:.0%}): the sensor's noise "
            "changed between sessions, or one session's static data hold something the other's "
            "do not; each session is judged against its own."
        )
    if timed:
        assert diag.time_drift is not None
        text += " " + drift_sentence(diag.base, diag.time_drift)
    text += _between_met(diag)
    text += _drift_chord_told(diag.base)
    why = diag.unexplained
    if why is not None and not (why.reason == "too small" and "too small" in text):
        text += f" {why.opening}: {why.text}; {why.would_tell} would tell."
    return text


def _between_met(diag: Diagnosis) -> str:
    """Where leaving a point out fails, but not as the calibration's user meets it
    (:func:`.steps._between_matters`): what each test says."""
    check, nxt = diag.between_points, diag.next_session
    if check is None or not check.fails or diag.unexplained is not None:
        return ""
    top = check.worst
    missed = (
        f" Leaving a point out, the calibration interpolated from the other points misses the "
        f"one at {top['temp']:.0f} °C ({top['coefficient']} by {abs(top['z']):.3g} standard "
        "errors)"
    )
    if carries_between(nxt):
        assert nxt is not None
        return missed + (
            f", but on the other session, {nxt['between_share']:.0%} of whose holds lie between "
            "this session's points, it carries over: the interpolation holds where the unit "
            "meets it (a point left out doubles the span the interpolation bridges)."
        )
    summary = diag.base.summary
    bar = CARRIES_WITHIN * chance_bound(summary["holds_scored"], diag.significance)
    return missed + (
        f", but the holds of the points left out then err "
        f"{summary['validation_rms'] / summary['expected_rms']:.2f} times what a correct model "
        f"would leave, within the bar a calibration meets on its next session ({CARRIES_WITHIN:g} "
        f"times, {bar:.2f} with what chance allows over its holds), although a point left out "
        "doubles the span the interpolation bridges: too small to act on."
    )


def _drift_chord_told(base: Evaluation) -> str:
    """Where leaving a point out interpolates it by a lower-order rule than the calibration
    uses (:func:`.between.drift_chord`) and the curvature that rule misses is above the noise
    floor: what the held-out figure counts as drift, and what would test it."""
    s = base.summary
    chord = s.get("drift_chord_rms")
    if chord is None or chord <= s["noise_floor"]:
        return ""
    points = s["temperature_points"]
    rule = " (a line where it runs a parabola)" if points == 3 else ""
    return (
        f" With {points} temperature points, a point left out is interpolated from the "
        f"{points - 1} others by a lower-order rule than the calibration's{rule}: the "
        f"temperature curvature between them, {chord:.3g} deg/s on the held-out holds, is "
        "counted as the smooth drift a correct model has, which no point left out can test; "
        "another temperature point would."
    )


def noise_covers_the_other(diag: Diagnosis) -> bool:
    """A model that explains this session whose calibration fails on the other within what
    this session's own (larger) noise leaves (:class:`.findings.FloorsDiffer`): slow noise."""
    return bool(
        diag.explains and diag.best is None and diag.floors_differ and diag.floors_differ.covers_other
    )


def _offsets_told(nxt: CarryOver) -> str:
    """The other session's offsets in words: one per axis, or per stretch between its log's gaps."""
    offsets = ", ".join(f"{a} {v:+.2g}" for a, v in nxt["turn_on_bias"].items())
    runs = nxt.get("power_ons", 1)
    if runs <= 1:
        return f"an offset per axis ({offsets} deg/s)"
    return (
        f"offsets per axis for each of the {runs} stretches between gaps in its log (on average "
        f"{offsets}, up to {nxt['largest_turn_on']:.2g} deg/s)"
    )


def _power_ons(nxt: CarryOver) -> str:
    if nxt.get("power_ons", 1) <= 1:
        return "that power-on"
    return "each power-on the gaps may hold (the log cannot tell where the unit was switched off)"


def _seating_told(nxt: CarryOver) -> str:
    """The mountings' rotations against what the fixture's seating may give them."""
    return (
        f"{nxt['seating_change'] * 1e6:.0f} µrad RMS, within the {nxt['seating_allowance'] * 1e6:.0f} "
        "µrad the fixture's seating gives up to chance"
    )


def _left_told(nxt: CarryOver) -> str:
    """What the other session's errors leave with the power-on's offsets out, over what a
    correct model leaves there, with that session's slow noise where it counts."""
    left = rezeroed_rms(nxt)
    told = f"{left / nxt['expected_rms']:.2f} times what a correct model would leave for white noise"
    if left < nxt["rezeroed_rms"]:
        told += f" (each mounting's rotation out too: {_seating_told(nxt)}, diagnosis: seating_repeatability)"
    wander = nxt.get("wander_rms", 0.0)
    if wander > nxt["expected_rms"]:
        told += (
            f", {left / wander:.2f} times what it leaves with the slow noise that session's static "
            "data cannot rule out"
        )
    return told


def _other_session(diag: Diagnosis, base_next: CarryOver | None) -> str:
    """What the configured model's calibration does on the other session, where no term
    was named."""
    if base_next is not None and base_next["holds"] and diag.best is None and diag.explains:
        return (
            f" On the other session its calibration leaves {base_next['excess']:.3g} "
            "times the floor: it carries over."
        )
    if base_next is None or base_next["holds"] or diag.best is not None:
        return ""
    if diag.unrepeated and fails_in_practice(base_next) and not fails_between_only(base_next):
        return (
            f" On the other session the errors are {base_next['excess']:.3g} times the "
            "floor from the same noise: holds minutes apart scatter more than the floor "
            "from the static data says."
        )
    if explained_by(diag.approach):
        return _approach_sentence(base_next, diag.approach)
    if diag.explains and power_ons_alone(base_next):
        unbounded = base_next.get("turn_on_allowance") is None
        return (
            f" On the other session its calibration leaves {base_next['excess']:.3g} times the "
            f"floor, most of it {_offsets_told(base_next)}: the bias the unit took at "
            f"{_power_ons(base_next)}, which no calibration carries (a static stretch at power-on "
            f"zeroes it); without {'them' if base_next.get('power_ons', 1) > 1 else 'it'}, {_left_told(base_next)}: "
            "the calibration carries over."
            + (
                " (With no turn-on bias repeatability given, any offset reads so; given, as "
                "diagnosis: turn_on_repeatability, one beyond 3 sigma of it reads as a change of "
                "the unit.)"
                if unbounded
                else ""
            )
        )
    if diag.explains and not fails_in_practice(base_next):
        return (
            f" On the other session its calibration leaves {base_next['excess']:.3g} times the "
            "floor: more than the noise alone would, but within "
            f"{CARRIES_WITHIN:g} times what a correct model would leave there "
            f"({seated_rms(base_next) / carry_expected(base_next):.2f}"
            + (
                ", with the slow noise that session's static data cannot rule out"
                if carry_expected(base_next) > base_next["expected_rms"]
                else ""
            )
            + (
                f", each mounting's rotation out: {_seating_told(base_next)}"
                if seated_rms(base_next) < base_next["validation_rms"]
                else ""
            )
            + "), a difference too small to act on (a turn-on bias a little apart between "
            "power-ons, the fixture seating the unit anew): it carries over."
        )
    # the why that follows tells the failure (the mounting's, or between the points, which
    # leaves the unit changed as one reading): the sentence here claims no cause
    told = diag.unexplained is not None and diag.unexplained.reason in (
        "the mounting",
        "between temperature points",
        "slow noise",
    )
    if diag.explains and (reference_scaled(base_next) or told):
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} "
            "times the floor: it does not carry over."
        )
    if diag.explains and noise_covers_the_other(diag):
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} times its floor."
        )
    if diag.explains and offset_alone(base_next):
        largest, allowance = offset_and_allowance(base_next)
        assert allowance is not None  # turned_on() is true without one
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} times "
            f"the floor, {_offsets_told(base_next)} (without them {_left_told(base_next)}): "
            f"the unit changed between sessions, its bias by up to {largest:.3g} deg/s, "
            f"more than the {allowance:.3g} (3 sigma of the turn-on repeatability given, at least 3 floors) a power-on's "
            "bias is granted (a drift, or a sensor out of its specification; a third session tells)"
            + (
                # no point matched: a bias stepping between this session's points by the same
                # amount at every point the other visits reads alike
                "; or a bias that changes between this session's points by the same amount at "
                "each point the other session visits"
                if base_next.get("repeat_p_value") is None
                else ""
            )
            + "."
        )
    if diag.explains and rate_shaped(base_next):
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} "
            f"times the floor, {base_next['rate_shaped_rms']:.2g} deg/s of them in proportion to "
            "the rates (the power-ons' offsets out), which slow wander, a bias, does not make: "
            "it does not carry over, the unit's scale or axes changed between sessions "
            "(gyrocal revalidate says by how much, the fleet summary's drift page which "
            "parameters)."
        )
    if diag.explains:
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} "
            "times the floor: it does not carry over, the unit changed between sessions "
            "(run-to-run bias, drift; gyrocal revalidate says by how much, the fleet "
            "summary's drift page which parameters)."
        )
    return f" On the other session the errors are {base_next['excess']:.3g} times the floor."


def _confound_sentence(confound) -> str:
    """Two readings the protocol moves together, told beside the fix."""
    rival = (
        f" Read as {confound.rival}, {readable(confound.rival_term)} explains it too (validation "
        f"RMS {confound.rival_rms:.3g} deg/s)."
        if confound.rival_term
        else ""
    )
    return (
        f" The fix reads {confound.reading}; {confound.tie}, so {confound.rival} groups them alike "
        f"({confound.share:.0%} of the excess follows it) and the data cannot tell the two "
        f"apart.{rival} {confound.would_tell[0].upper()}{confound.would_tell[1:]}."
    )


# What fits the direction of approach once points are reached from both sides.
DIRECTION_TERM = (
    "the direction's term, --add-term \"expression(label='temp_direction', formula='2 * (temp "
    "- play(temp, w)) / w', parameters={w: 1.0}, profile={w: [0.3, 20]})\", be fitted and "
    "carried."
)


def _approach_sentence(base_next: CarryOver, approach) -> str:
    """The other session's failure told by the direction each point was reached from."""
    steps = ", ".join(f"{v:+.3g} ({a})" for a, v in approach.shift.items())
    offsets = ", ".join(f"{v:+.3g} ({a})" for a, v in approach.offset.items())
    points = ", ".join(f"{t:g}" for t in approach.points)
    same = ", ".join(f"{t:g}" for t in approach.same)
    if approach.tied:
        return (
            f" On the other session the calibration's errors are {base_next['excess']:.3g} times "
            f"the floor, one offset at every point ({steps} deg/s; what it leaves p = "
            f"{approach.left_p_value:.2g}), and that session reached every point ({points} °C) "
            "from the other side: a bias that depends on the direction the temperature came "
            "from (thermal hysteresis) leaves exactly that, as would a bias the unit took anew "
            "at power-on, and these two sessions cannot tell them apart. Visiting some points "
            "from both sides (down after up, or a point revisited from the other side) would, "
            f"and lets {DIRECTION_TERM}"
        )
    return (
        f" On the other session the calibration's errors are {base_next['excess']:.3g} times "
        f"the floor, and they step with the direction the temperature came from: at the points "
        f"that session reached from the other side ({points} °C) the bias moved by {steps} "
        f"deg/s more than at those it reached the same way ({same} °C; offset {offsets} deg/s; "
        f"F-test p {p_text(approach.p_value)}, what is left p = {approach.left_p_value:.2g}"
        f"{f', within {CARRIES_WITHIN:g} times the floor of its holds' if approach.left_within_bar else ''}). "
        "A bias that depends on the direction the temperature came from (thermal hysteresis) "
        "is constant within each point of a session, so one session's calibration holds it in "
        "that point's bias and no term of it can be fitted there: visiting each point from "
        "both sides (down after up, or a point revisited from the other side) lets "
        f"{DIRECTION_TERM}"
    )


def drift_sentence(base: Evaluation, drift: TimeDrift) -> str:
    rival = (
        f" {drift.rival_of} fits it as well, and neither can be named: the mounts follow "
        "each other in time, so this protocol cannot tell an effect constant per mount from "
        "a drift."
        if drift.rival_of
        else ""
    )
    return (
        f"A bias drifting linearly in time within each temperature point explains the excess "
        f"(validation RMS {base.summary['validation_rms']:.3g} → {drift.validation_rms:.3g} deg/s, "
        f"what a correct model would leave: {drift.expected_rms:.3g}): the missing effect "
        f"is a drift in time, such as a warm-up or a ramp, not a library term.{rival}"
    )


def _separation(c) -> str:
    """What of a library term the protocol cannot separate, for the part it fitted, and
    what would."""
    term = make_term(c.term)
    remedy = "; ".join(SEPARATES[k] for k in sorted(input_kinds(c.term)) if k in SEPARATES)
    remedy = f" ({remedy})" if remedy else ""
    if isinstance(term, Restricted):
        dropped = ", ".join(f"{c.part_of}.{d}" for d in term.drop)
        return f"this protocol cannot separate {dropped} from the rest of the model{remedy}"
    # the other part a protocol can see: one set for the session (effects._one_set_for_the_session)
    return (
        f"some temperature point's holds cannot separate {c.part_of} from the rest of the "
        "model, so one set of its coefficients is fitted for the session, which cannot "
        f"follow its change with temperature{remedy}"
    )


def session_verdict(diag: Diagnosis, base_next: CarryOver | None, tolerance: float | None) -> str:
    """The verdict on this session. A finding no term holds (:mod:`.lab`, :mod:`.between`)
    is stated by the sentence that follows it; ``tolerance``, None where a drift in time is
    the finding, lets a small held-out error be called too small to attribute."""
    base, best, factor = diag.base, diag.best, diag.factor
    finding = diag.unexplained.reason if diag.unexplained is not None else None
    if best is not None:
        return _named(base, best, base_next) + _force_of_mounts(diag)
    if diag.noise_explains:
        assert diag.within_noise is not None
        return _within_slow_noise(base, factor, diag.within_noise, base_next)
    if finding in ("fixed in the lab", "the mounting") and not diag.explains:
        # Where the excess lives among the sensor's inputs, or that it is too small, would
        # point at an effect of the sensor: the sentence that follows says what it is.
        return (
            f"The model does not explain the data: its in-sample residuals are {factor:.2f} "
            "times their noise floor, and no candidate term accounts for it."
        )
    if not diag.explains:
        return _not_explained(base, factor, diag.covariates, diag.partial, base_next, tolerance) + (
            _force_of_mounts(diag)
        )
    if diag.unrepeated_shape is not None:
        return (
            f"The model explains the data as the other session judges it: its in-sample "
            f"residuals are {factor:.2f} times their noise floor, no term can be offered for "
            f"them (the shape that fits them best, {diag.unrepeated_shape}), and the "
            "calibration carries over to the other session: the excess is this session's own, "
            "slow noise its static data did not resolve, which the calibration's user does not "
            "meet; nothing is missing."
        )
    if diag.unrepeated:
        assert base_next is not None
        return (
            f"The model explains the data: its in-sample residuals are {factor:.2f} times their "
            f"noise floor, but their pattern does not come back in the other session (p = "
            f"{base_next['repeat_p_value']:.2g}): the excess is slow noise the static data did not "
            "resolve, not a missing effect"
            + ("." if fails_in_practice(base_next) else "; nothing is missing.")
        )
    floor_by = "the sensor's noise model" if diag.noise_model else "white noise within the holds"
    if diag.negligible is not None:
        return _negligible(diag.negligible)
    if finding == "between temperature points":
        return (
            f"The model explains the data at its temperature points: its in-sample residuals "
            f"are {factor:.2f} times their noise floor, as {floor_by} would leave."
        )
    return (
        f"The model explains the data: its in-sample residuals are {factor:.2f} times "
        f"their noise floor, as {floor_by} would leave; nothing is missing."
    )


def _force_of_mounts(diag: Diagnosis) -> str:
    """Where the fix reads the specific force of a log with no accelerometer, whence it came."""
    frame = diag.residuals
    offer = diag.best or next((c for c in diag.partial if c.offered), None)
    terms = [offer.term, *offer.together] if offer is not None else []
    if "accel_source" not in frame or not any("accel" in term_reads(t) for t in terms):
        return ""
    return (
        " The log has no accelerometer: the specific force is the one each mount implies (the "
        "table's axis points up), without the fixture's small tilts or a centripetal force; "
        "applying the calibration needs an accelerometer in the log it compensates."
    )


def _named(base: Evaluation, best: Candidate, base_next: CarryOver | None) -> str:
    """The verdict where a term (or a pair) is named."""
    sizes = sorted(best.size, key=lambda z: -abs(z["value"]) / max(z["stderr"], 1e-300))
    top = (
        (
            f" (largest: {sizes[0]['coefficient']} = {sizes[0]['value']:.3g} ± "
            f"{sizes[0]['stderr']:.2g} {sizes[0]['unit']})"
        )
        if sizes
        else ""
    )
    tied = (
        f" This protocol cannot tell it from {', '.join(best.tied_with)}: they fit the data equally well."
        if best.tied_with
        else ""
    )
    carried = ""
    if base_next is not None and usable(best.next_session):
        carried = (
            f" On the other session the error falls from {base_next['excess']:.3g} to "
            f"{best.next_session['excess']:.3g} times the floor."
        )
    if best.kind == "continuous":
        carried += (
            " It is offered in a model continuous in temperature: the temperature "
            "moves within the points, and a grid fits each point at one temperature "
            "but is applied at each hold's own."
        )
    if best.second_question and best.leftover is not None:
        carried += (
            f" What it leaves still follows {best.leftover['covariate']} (p = "
            f"{best.leftover['p_value']:.2g}): a second question, after this fix, which another "
            "session answers (a package still settling at the start of each point repeats; slow "
            "noise does not)."
        )
    if best.family:
        return _free_shape_verdict(base, best, carried)
    name = (
        f"{best.part_of}, the part this protocol can see ({name_of(best)})" if best.part_of else name_of(best)
    )
    seen = (
        f" That is as much of {best.part_of} as this protocol shows, and what its "
        f"sessions need: {_separation(best)}."
        if best.part_of
        else ""
    )
    if best.together:
        return (
            f"Missing effects: {name} and "
            f"{', '.join(name_of(make_candidate(t)) for t in best.together)}. Adding both "
            f"lowers the validation RMS from {base.summary['validation_rms']:.3g} to "
            f"{best.validation_rms_with:.3g} deg/s{_bar(best, base)}; {readable(best.term, best.profiled)} alone takes it to "
            f"{best.alone_rms:.3g}." + seen + carried
        )
    return (
        f"Missing effect: {name}. Adding it lowers the validation RMS from "
        f"{base.summary['validation_rms']:.3g} to {best.validation_rms_with:.3g} deg/s "
        f"({best.gain_pct:.0f} % less; F-test p {p_text(best.p_value)}){_bar(best, base)}; its largest contribution to a hold is "
        f"{best.peak_effect:.3g} deg/s{top}.{seen}{tied}{carried}"
    )


def _held_out_ratio(base: Evaluation) -> float:
    s = base.summary
    return s["validation_rms"] / s["expected_rms"] if s["expected_rms"] > 0 else float("inf")


def _within_slow_noise(
    base: Evaluation, factor: float, within_noise: WithinNoise, base_next: CarryOver | None = None
) -> str:
    wide = base.summary["validation_rms"] / within_noise.expected_rms
    told = (
        "Another session of the unit (--other-session) would tell slow wander from an effect."
        if base_next is None
        else "The other session shares no cell (temperature point, mount and rate) with this one "
        "to tell whether the pattern repeats; a session revisiting this one's points would."
    )
    return (
        f"The model explains the data as far as {'one session' if base_next is None else 'the sessions'} "
        f"can tell: its in-sample "
        f"residuals, {factor:.2f} times the floor from the static data, are within the "
        f"slow wander that {within_noise.static_seconds:.0f} s of static data cannot rule "
        f"out{_seating_beside(within_noise)} (reduced χ² {within_noise.chi2_red:.2f} with "
        f"{'them' if within_noise.seating_change is not None else 'it'}), on the holds left out its "
        f"error is {min(_held_out_ratio(base), wide):.2f} times what a correct model would leave with that "
        f"noise, and no term takes a practical part of it away{_drowned(within_noise)}. {told}"
    )


def _drowned(within_noise: WithinNoise) -> str:
    """Terms that beat white noise but not that wander (:func:`.steps.beyond_slow_noise`)."""
    if not within_noise.drowned:
        return ""
    terms = "; ".join(f"{readable(term)} (p {p_text(p)})" for term, p in within_noise.drowned)
    return (
        f" beyond what that wander may make: {terms} take more than white noise would leave, "
        "not more than chance from what the wander leaves (holds close in time share it)"
    )


def _seating_beside(within_noise: WithinNoise) -> str:
    """The fixture's seating where it joined the slow wander (:func:`.steps.slow_noise_bound`)."""
    if within_noise.seating_change is None or within_noise.seating_repeatability is None:
        return ""
    return (
        " and the fixture's seating (each mounting's own small rotation, "
        f"{1e6 * within_noise.seating_change:.0f} µrad RMS fitted against the rig's repeatability of "
        f"{1e6 * within_noise.seating_repeatability:.0f} µrad, diagnosis: seating_repeatability)"
    )


def _not_explained(base, factor, covariates, partial, base_next, tolerance) -> str:
    """The verdict where the model misses and no term is named: a partial term's share, or
    where the excess lives, or that it is too small to attribute."""
    lead = covariates[0] if covariates and (covariates[0]["share_of_excess"] or 0) > 0 else None
    where = (
        f"; the excess lives mostly with {lead['covariate']} ({100 * lead['share_of_excess']:.0f} % of it)"
        if lead
        else ""
    )
    if partial:
        return _partial(base, factor, partial[0], where, base_next)
    held_out = _held_out_ratio(base)
    small = ""
    if tolerance is not None and held_out <= tolerance:
        small = (
            f" On the holds left out its error is {held_out:.2f} times what a correct model "
            f"would leave, within that figure's uncertainty (up to {tolerance:.2f}): the "
            "excess is too small to attribute to an effect."
        )
    return (
        f"The model does not explain the data: its in-sample residuals are {factor:.2f} "
        "times their noise floor, and no candidate term accounts for it" + where + "." + small
    )


def _partial(base, factor, first, where: str, base_next) -> str:
    """The verdict where a term takes away part of the excess: offered where it takes most."""
    name = f"{first.part_of}, the part this protocol can see," if first.part_of else name_of(first)
    left = first.leftover or {}
    follows = (
        f" What it leaves follows {left['covariate']} (p = {left['p_value']:.2g})."
        if left.get("p_value", 1.0) < 0.01
        else ""
    )
    rest = (
        f" The rest may be {first.part_of} beyond what {_separation(first)}, or another effect."
        if first.part_of
        else ""
    )
    if first.offered:
        there = ""
        if base_next is not None and usable(first.next_session):
            there = (
                f"; on the other session the error falls from {base_next['excess']:.3g} "
                f"to {first.next_session['excess']:.3g} times the floor"
            )
        at_grain = (
            f" Left out one rate level at a time, it leaves {first.grain.fix:.3g} times the floor "
            f"on the holds it never saw, the configured model {first.grain.base:.3g}: most of the "
            "error where its input varies is gone; what the temperature points left out still "
            "miss is a second question, after it."
            if first.grain is not None
            else ""
        )
        figure = (
            f"validation RMS {first.base_rms:.3g} → {first.validation_rms_with:.3g} "
            f"deg/s, still {first.validation_rms_with / first.expected_with:.2g} times "
            "what a correct model would leave"
            if first.validated
            else f"in sample {first.base_rms:.3g} → {first.validation_rms_with:.3g} deg/s"
        )
        return (
            f"The model does not explain the data: its in-sample residuals are "
            f"{factor:.2f} times their noise floor{where}. No term explains all of it; "
            f"{name} takes away {100 * min(first.excess_taken, 1.0):.0f} % of the excess ({figure}"
            f"{there}): add it with {first.option}.{at_grain}{follows}{rest}"
        )
    outside = rest or (
        " What remains needs a term of its own shape (docs/effects.md)." if not follows else ""
    )
    shared = (
        " Its coefficient is the same on every axis, as an error of the reference rate (one "
        "table read by each axis in turn) gives and a sensor's axes, each with its own, would "
        "not: one log cannot tell the two apart; the table's rate checked against its "
        "encoder's count over whole turns, or a session on another table, would."
        if base_next is None and input_kinds(first.term) == {"rate"} and shared_by_every_axis(first)
        else ""
    )
    return (
        f"The model does not explain the data: its in-sample residuals are {factor:.2f} "
        f"times their noise floor. No library or listed term explains it; "
        f"{name} explains part of it (validation RMS {base.summary['validation_rms']:.3g}"
        f" → {first.validation_rms_with:.3g} deg/s, still {first.validation_rms_with / first.expected_with:.2g}"
        f" times what a correct model would leave){where}.{shared}{follows}{outside}"
    )


def _negligible(negligible: Negligible) -> str:
    faint = (
        f"; the residuals follow {negligible.covariate} beyond chance (p = "
        f"{negligible.p_value:.2g}), a pattern too faint to matter"
        if negligible.covariate
        else ""
    )
    if negligible.factor - 1.0 <= negligible.floor_uncertainty:
        return (
            f"The model explains the data: its in-sample residuals are {negligible.factor:.2f} "
            f"times their noise floor, within that floor's own uncertainty (±"
            f"{100 * negligible.floor_uncertainty:.0f} % from the static data){faint}; "
            "nothing is missing."
        )
    above = (
        " (above the bar a session alone is held to: the calibration carries to the other "
        "session, and a floor from within the holds understates slow noise)"
        if negligible.factor > CARRIES_WITHIN
        else ""
    )
    return (
        f"The model explains the data in practice: its in-sample residuals are "
        f"{negligible.factor:.2f} times their noise floor{above} and on the holds left out "
        f"{negligible.held_out:.2f} times what a correct model would leave, within the "
        f"{CARRIES_WITHIN:g} times a calibration must meet on its next session up to that "
        f"figure's own uncertainty{faint}; "
        "nothing worth a term is missing."
    )


def name_of(c) -> str:
    """A candidate as a reader wants it: the library's name with its formula, or the
    formula of a term of free shape with its parameters."""
    text = readable(c.term, c.profiled)
    inner = make_term(c.term)
    plain = getattr(inner, "term", inner).name
    return f"{plain} ({text})" if plain not in FREE_SHAPE_TERMS else text


# What a term of free shape is, by its family.
FAMILY_NAMES = {
    "smooth": "An empirical term",
    "levels": "A table over the protocol's levels",
    "square": "A square",
    "abs": "A magnitude",
    "signed_square": "A square with its sign",
    "log": "A logarithm",
    "slow pole": "A slow pole of the own rate",
    "heating by rotation": "A lag of the rate's magnitude",
    "heating by rotation power": "A lag of the rate's magnitude squared",
    "hysteresis": "A play operator of the temperature",
    "hysteresis relaxing": "A Duhem hysteresis of the temperature",
    "switch with hysteresis": "A switch of the temperature with hysteresis",
}


def _free_shape_verdict(base, best, carried: str) -> str:
    """A term of free shape named: the shape in words, what it reaches, and the parametric
    forms that explain it as well."""
    also = "".join(
        f" {'As a formula' if c.family not in ('smooth', 'levels') else 'Empirically'}, "
        f"{name_of(c)} explains it as well (validation RMS {c.validation_rms_with:.3g} deg/s)."
        for c in best.also[:2]
    )
    what = FAMILY_NAMES.get(best.family, f"A {best.family} formula")
    together = (
        " with " + ", ".join(name_of(make_candidate(t)) for t in best.together) if best.together else ""
    )
    return (
        f"Missing effect, outside the library: {best.shape} {what}, {name_of(best)}{together}, "
        f"lowers the validation RMS from {base.summary['validation_rms']:.3g} "
        f"to {best.validation_rms_with:.3g} deg/s{_bar(best, base)}.{also}{carried}"
    )


def _bar(best, base: Evaluation) -> str:
    """What a correct model would leave, beside the fix's held-out figure. Where the fix's own
    uncertainty on a point left out exceeds the configured model's whole error (a spline of
    time over a point's stretch), that figure says nothing: the fit's own residuals judge
    it (and the other session), and the verdict says so."""
    if best.expected_with is not None and best.expected_with > base.summary["validation_rms"]:
        return (
            "; without a temperature point its coefficients are undetermined there (what a "
            f"correct model would leave: {best.expected_with:.3g}), so its fit's own residuals "
            "judge it, and another session where there is one"
        )
    return f", what a correct model would leave ({best.expected_with:.3g})"


def make_candidate(term: str):
    """A term named beside another, read as a candidate is."""
    from types import SimpleNamespace

    return SimpleNamespace(term=term, profiled=())


# Terms the diagnosis makes up for a shape (their failures are said in the verdict instead).
FREE_SHAPE_TERMS = ("smooth", "expression", "levels", "cross_rate")

# What separates effects of each kind of input, for a protocol that cannot tell them apart.
SEPARATES = {
    "accel": "mounts that put gravity along each axis in both directions (the six-mount "
    "protocol) separate orientation effects from the bias",
    "rate": "holds at several speeds in both directions on every axis separate the even and "
    "odd shapes of the rate",
    "thermal": "two sweeps at different ramp rates separate the temperature's rate and lag "
    "from the temperature itself",
    "time": "revisiting the first temperature point at the end of the session separates "
    "drift in time from temperature; another session (--other-session) tells a "
    "drift that repeats from slow noise",
    "mount": "mounting both faces of each axis (the six-mount protocol) separates a tilt that "
    "stays with the fixture's face from the sensor's misalignment; remounting the unit "
    "separates what stays with the mounting from what stays with the sensor",
}


# Three sense elements share a nonlinearity of one sign to this relative spread only by
# chance; the reference rate's error, seen through each axis' scale (1 ± 1 %), does so always.
SHARED_SPREAD = 0.1


def shared_by_every_axis(c: Candidate) -> bool:
    """Whether a term's coefficient is the same on every axis (one sign, within
    :data:`SHARED_SPREAD` of their mean, or within three standard errors of it): what an
    error of the reference rate gives, one table read by every axis in turn, where a
    sensor's axes each have their own. From one log the two cannot be told apart."""
    values = np.array([s["value"] for s in c.size], float)
    errors = np.array([s["stderr"] for s in c.size], float)
    if values.size != 3 or not np.all(np.isfinite(values)) or np.ptp(np.sign(values)) != 0:
        return False
    mean = abs(float(values.mean()))
    if not mean > 3 * float(errors.max()):  # a coefficient the data hardly fix is no sign of sameness
        return False
    return bool(np.all(np.abs(values - values.mean()) <= SHARED_SPREAD * mean + 3 * errors))


def input_kinds(term: str) -> set[str]:
    """The kinds of input a term reads beyond the temperature's value (:func:`term_reads`)."""
    return term_reads(term) - {"temperature"}


def unseen_hysteresis(one_way: dict | None, two_sessions: bool) -> str | None:
    """The advice where every temperature point saw the temperature travel one way
    (:func:`gyrocal.diagnosis.where.one_way_points`): a hysteresis of the temperature hides
    in the points' biases, and only a session that reaches a point from the other side tells."""
    if not one_way:
        return None
    ways = set(one_way.values())
    how = "rising" if ways == {1} else "falling" if ways == {-1} else "one way within each point"
    where = (
        "in both sessions, each point the same way" if two_sessions else "and it did not turn back within any"
    )
    return (
        f"Every temperature point was reached with the temperature {how}, {where}: a bias "
        "that depends on the direction the temperature came from (thermal hysteresis) sits "
        "in each point's bias here, so this protocol cannot see it, and a session reaching a "
        "point from the other side would meet it in full. Visiting a point from both sides "
        "(down after up, or back to a point passed) would show it."
    )


def advice(
    best, partial, candidates, covariates, explains: bool, has_other: bool, drift: TimeDrift | None = None
) -> list[str]:
    """What to do next, in sentences: what would separate effects this protocol confounds
    (and that either one compensates what it sees), where an unexplained excess lives and
    how to write the effect, and when another session would decide."""
    out = []
    if best is None and explained_by(drift):
        out.append(
            f"Write the drift as a term of t: {drift.option} fits "
            "a bias drifting linearly within each point, and a term file can give it the "
            "shape of the drift (docs/effects.md, section 7)"
            + (
                "; visiting the first mount again at the end of a point separates a drift "
                f"from {drift.rival_of}"
                if drift.rival_of
                else ""
            )
            + "."
        )
    if best is not None and best.tied_with:
        kinds = set().union(*(input_kinds(t) for t in (best.term, *best.tied_with)))
        out.append(
            f"{best.term} and {', '.join(best.tied_with)} fit this session equally well: "
            f"either compensates what this protocol sees (validation RMS "
            f"{best.validation_rms_with:.3g} deg/s). To tell them apart: "
            + "; ".join(SEPARATES[k] for k in sorted(kinds) if k in SEPARATES)
            + "."
        )
    if best is not None and best.part_of:
        out.append(
            f"{best.option} adds what this protocol can see of {best.part_of}; a "
            f"calibration made so holds for sessions of the same protocol. To fit all of it: "
            + "; ".join(SEPARATES[k] for k in sorted(input_kinds(best.term)) if k in SEPARATES)
            + "."
        )
    if explains or best is not None:
        return out
    # A term the holds do not excite at all (a scale on a rig that does not turn) shows
    # nothing in them either: only one the protocol sees but cannot separate is worth a word.
    blocked = [
        c
        for c in candidates
        if c.status == "not identifiable"
        and c.excited
        and not getattr(c, "family", None)
        and make_term(c.term).name not in FREE_SHAPE_TERMS
    ]
    for c in blocked:
        kinds = input_kinds(c.term)
        if kinds:
            seen = (
                f" (the part it can see, {c.seen_part}, is ranked with the candidates)"
                if getattr(c, "seen_part", None)
                else ""
            )
            out.append(
                f"{c.term} cannot be fitted from this protocol ({c.reason}){seen}: "
                + "; ".join(SEPARATES[k] for k in sorted(kinds) if k in SEPARATES)
                + "."
            )
    for c in partial[:1]:
        if c.leftover is not None:
            out.append(
                f"With {c.term} the residuals still follow {c.leftover['covariate']} "
                f"(p = {c.leftover['p_value']:.2g}): the effect is likely another shape "
                "of that covariate; write it as a term (docs/effects.md)."
            )
    lead = covariates[0]["covariate"] if covariates and (covariates[0]["share_of_excess"] or 0) > 0 else None
    if lead is not None and lead.startswith("time") and not explained_by(drift):
        out.append(
            "The excess follows time: a warm-up or a drift. Write it as a term of t with "
            "a global coefficient (docs/effects.md, section 7, works one through); " + SEPARATES["time"] + "."
        )
    if not has_other:
        out.append(
            "Diagnose with another session of the unit (--other-session) to judge the "
            "candidates by how they carry over to it, as a calibration will be used."
        )
    return out


def term_inputs(term: str) -> set[str]:
    """The inputs a term reads: a formula what it names (its probe reads a rate for the
    column's length), another term what its probe reads."""
    made = make_term(term)
    inner = getattr(made, "term", made)
    return set(inner.needs if hasattr(inner, "formula") else made.inputs())


def term_reads(term: str) -> set[str]:
    """The kinds of input a term reads: time, temperature (its value), thermal (its rate or
    lag), rate, accel."""
    made = make_term(term)
    inner = getattr(made, "term", made)
    # the record behind a history of the rates or the accelerometer is no thermal input
    inputs = term_inputs(term)
    if inputs & {"rate_history", "accel_history"} and not inputs & {"temp", "temp_rate"}:
        inputs.discard("temp_lag")
    kinds = set()
    if "lag(" in getattr(inner, "formula", ""):
        kinds.add("time")  # a lag follows its input's past: it changes with time in a hold
    if any(i.startswith("accel") for i in inputs):
        kinds.add("accel")
    if any(i.startswith("rate_") or i == "ref_rate" for i in inputs):
        kinds.add("rate")
    if inputs & {"temp_rate", "temp_lag"}:
        kinds.add("thermal")
    if "temp" in inputs:
        kinds.add("temperature")
    if "t" in inputs:
        kinds.add("time")
    if "t_mount" in inputs:
        kinds |= {"time", "mount"}
    if getattr(inner, "reads_face", False):
        kinds.add("mount")
    return kinds


def covariate_reads(label: str) -> set[str]:
    """The kinds of input a term must read to follow a covariate row of where-it-fails
    (confounded covariates: any of theirs; a product: the rate and its input)."""
    kinds: set[str] = set()
    for name in label.split(" = "):
        base = name.split(" (")[0]
        if base.startswith("rate × "):
            kinds |= {"rate"} | covariate_reads(base.removeprefix("rate × "))
        elif base in ("time", "time within a temperature point", "hold duration"):
            # time, and what follows it through the temperature's history (a sweep's point
            # is crossed rising, then falling)
            kinds |= {"time", "thermal"}
        elif base in ("temperature", "temperature rate"):
            kinds |= {"temperature", "thermal"}
        elif base in ("|rate|", "reference rate", "direction", "step into the hold", "previous hold's rate"):
            kinds.add("rate")
        elif base == "temperature's direction":
            kinds |= {"temperature", "thermal"}
        elif base in ("mount", "rotating axis", "mounting") or base.startswith("accel"):
            # the mounting's holds follow each other in time too
            kinds |= {"accel", "rate", "mount"} | ({"time"} if base == "mounting" else set())
    return kinds


def coherent(term: str, lead: dict | None) -> bool:
    """Whether a term reads the input where-it-fails says carries the excess (its leading
    row); any term is, with no leading row."""
    return lead is None or bool(term_reads(term) & covariate_reads(lead["covariate"]))


# What a protocol would add to tell an effect of each kind of covariate apart.
WOULD_TELL = {
    "time": "another session of the unit (--other-session), whose warm-up starts again, or "
    "a temperature point revisited at the end of the session",
    "temperature": "more temperature points (a sweep, or a grid finer where the excess lives)",
    "rate": "holds at more speeds, in both directions, on every axis",
    "mount": "mounts that put each axis up and down (the six-mount protocol)",
}


def _covariate_kind(label: str) -> str:
    if "time" in label or "duration" in label:
        return "time"
    if "temperature" in label:
        return "temperature"
    if "rate" in label or "direction" in label or "step" in label:
        return "rate"
    return "mount"


def unexplained(tried, covariates, has_other: bool) -> Unexplained | None:
    """Why no term of free shape could be offered, and what protocol would tell: terms
    that fit the excess but could not be validated by leaving points out (their shape
    lies within one point's stretch of time), terms that gain here but not on the other
    session, terms that take away part of it and leave it following another covariate, or
    none that describes it as a function of one input. None without terms tried."""
    row = next((r for r in covariates if (r["share_of_excess"] or 0) > 0), None)
    lead = row["covariate"] if row else None
    kind = _covariate_kind(lead or "")
    # A reason cites only shapes of the input that carries the excess.
    ranked = [c for c in tried if c.status == "ranked" and coherent(c.term, row)]
    if not ranked:
        return (
            None
            if not any(c.status == "ranked" for c in tried)
            else Unexplained(
                reason="no shape of one input",
                term=None,
                text=f"no term of free shape of {lead} takes it away",
                would_tell=WOULD_TELL[kind],
            )
        )
    unvalidated = [c for c in ranked if not c.validated and c.significant]
    if unvalidated and not has_other:
        c = min(unvalidated, key=lambda c: c.validation_rms_with)
        return Unexplained(
            reason="unvalidated",
            term=c.term,
            text=f"{readable(c.term, c.profiled)} fits it within this session (in-sample RMS "
            f"{c.validation_rms_with:.3g} "
            "deg/s), but its shape lies within one temperature point's stretch of time, which "
            "leaving that point out to validate cannot check",
            would_tell=WOULD_TELL["time"],
        )
    best = min(ranked, key=lambda c: c.validation_rms_with)
    left = best.leftover or {}
    follows = left.get("covariate") if left.get("p_value", 1.0) < 0.01 else None
    # "Does not carry over" only of a shape that explains this session: one that leaves
    # an excess here too, still following another covariate, is the wrong shape.
    carried = has_other and best.next_session and "validation_rms" in best.next_session
    if carried and (best.explains_excess or not follows):
        return Unexplained(
            reason="does not carry over",
            term=best.term,
            text=f"the shape that fits best, {readable(best.term, best.profiled)}, does not hold "
            "on the other session "
            f"({best.next_session.get('excess', float('nan')):.3g} times its floor): the effect "
            "is not the same function of its input from one session to the next",
            # Another session is what showed this: what would tell is an input that
            # follows the effect in both.
            would_tell="a logged input that follows it in both sessions (a temperature "
            "nearer its source, the rig's own state such as its motor's "
            "temperature), or a protocol that repeats the same history in "
            "every session",
        )
    if follows:
        return Unexplained(
            reason="depends on more than one input",
            term=best.term,
            text=f"the shape that fits best, {readable(best.term, best.profiled)}, leaves residuals "
            "that still follow "
            f"{follows}: the effect depends on more than the one input a term of free shape "
            "reads",
            would_tell=WOULD_TELL[_covariate_kind(follows)],
        )
    return Unexplained(
        reason="no shape of one input",
        term=None,
        text=f"no smooth function of {lead or 'the inputs tried'} describes it",
        would_tell=WOULD_TELL[kind],
    )
