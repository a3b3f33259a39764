"""Where the model fails and which physical effect is missing.
May import: io, terms, fit, pipeline, fleet.

One module per question: :mod:`.where` (where the model fails), :mod:`.effects` (which
effect is missing), :mod:`.sessions` (how a calibration carries over to another session),
:mod:`.verdict` (the verdict and the advice); :mod:`.lab` (an effect fixed in the lab, seen
through the turning table) and :mod:`.between` (a calibration that fits every temperature
point and misses between them) test for two findings no term can hold; :mod:`.evaluation`
fits and validates the models they compare, :mod:`.stats` holds the tails and bounds of the
tests.

Three questions, answered from the observations alone:

1. **Does the model explain the data?** The in-sample residuals of every fit, divided by
   each observation's noise floor, should scatter like unit normals: χ² against its
   degrees of freedom, overall and per output axis. When the session's noise model has bias
   instability or rate random walk, χ² and the F-tests below come from the generalised
   least-squares fits that account for the holds' shared wander (:func:`gyrocal.fit.model.fit`).
2. **Where does the excess live?** For every covariate the log offers (temperature, its
   rate, the reference rate, its magnitude and direction, the mount, the accelerometer,
   time, hold length), the share of the excess χ² that the covariate's bins account for,
   beyond what bins explain by chance. Ranked, plus heat maps (mount × rate, temperature ×
   rate).
3. **Which effect is missing?** Every candidate term (the library's, those the user names,
   those of the user's term files) is added to the model in turn; the extended model is
   refitted and validated the same way. Candidates are ranked by the validation RMS they
   reach; each gets a nested-model F-test against the base model and the fitted size of the
   effect in physical units. The significance level is family-wise: half goes to the χ²
   test of question 1, half is shared (Bonferroni) by the candidates, so on data the model
   explains the diagnosis raises a false alarm at most that often.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from ..fit.floor import with_upper_floor
from ..fit.model import columns_of, shares_wander
from ..io.errors import GyrocalError
from ..pipeline.config import Settings
from ..terms import AXES, make_term
from .between import between_points, between_reason
from .effects import (
    TIME_DRIFT,
    Candidate,
    Judge,
    extended_all,
    mark_ties,
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
    evaluation_of,
    extended,
    fix_row,
    ladder,
    model_option,
    pooled,
)
from .lab import LAB_ADVICE, MOUNTING_ADVICE, lab_fixed, lab_reason, mounting_fixed, mounting_reason
from .reading import readable
from .sessions import carry_over, repeat_p_value, shared_fraction, slow_noise, unrepeated_p_value, usable
from .shapes import at_bound, describe, describe_history, for_the_unit, shape_terms
from .stats import (
    chance_bound,
    chi2_ppf,
    chi2_sf,
    explained_tolerance,
    f_sf,
    fisher_combined,
    floor_uncertainty,
)
from .verdict import advice, coherent, drift_sentence, input_kinds, unexplained, unseen_hysteresis
from .verdict import verdict as make_verdict
from .where import (
    COVARIATES,
    SETTLING_ROW,
    covariate_table,
    fit_quality,
    history_columns,
    input_values,
    one_way_points,
    shape_estimate,
)

__all__ = [
    "COVARIATES",
    "TIME_DRIFT",
    "Candidate",
    "Diagnosis",
    "Evaluation",
    "add_term_option",
    "candidate_terms",
    "carry_over",
    "chance_bound",
    "chi2_ppf",
    "chi2_sf",
    "config_line",
    "diagnose",
    "evaluate",
    "evaluation_of",
    "explained_tolerance",
    "extended",
    "f_sf",
    "fisher_combined",
    "mark_ties",
    "repeat_p_value",
    "shared_fraction",
    "unrepeated_p_value",
]


@dataclass
class Diagnosis:
    base: Evaluation
    significance: float
    chi2_red: dict[str, float]  # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float
    explains: bool
    covariates: list[dict]
    candidates: list[Candidate]
    best: Candidate | None
    partial: list[Candidate]
    verdict: str
    heatmaps: dict
    residuals: pd.DataFrame  # observations + resid_, floor_, z_ per axis
    config_line: str = ""  # the model: lines that add the best candidate
    ladder: list[dict] = field(default_factory=list)
    within_noise: dict | None = None  # the χ² test with the slow noise at its upper bound
    next_session: dict | None = None  # the configured model on another session
    advice: list[str] = field(default_factory=list)
    time_drift: dict | None = None  # TIME_DRIFT's fit: the rival no term can beat
    shape_estimate: dict | None = None  # the residuals against the leading input
    unexplained: dict | None = None  # why no term of free shape was offered
    lab_fixed: dict | None = None  # the excess against the table's angle
    mounting: dict | None = None  # the excess against an offset per mounting
    between_points: dict | None = None  # interpolated against fitted, point by point
    factor: float | None = None  # the verdict's "times their noise floor"
    negligible: dict | None = None  # an excess within the floor's own uncertainty
    one_way: dict | None = None  # point (°C) -> the one direction it was reached in

    def to_dict(self) -> dict:
        s = self.base.summary
        return {
            "format": "gyrocal.diagnosis/1",
            "model": {"terms": self.base.terms, "kind": self.base.kind},
            "validation_rms": s["validation_rms"],
            "noise_floor": s["noise_floor"],
            "excess": s["excess"],
            "expected_rms": s["expected_rms"],
            "excess_over_expected": s["excess_over_expected"],
            "held_out": s["held_out"],
            "significance": self.significance,
            "chi2_red": self.chi2_red,
            "rms_over_floor": self.rms_over_floor,
            "excess_p_value": self.excess_p_value,
            "explains_the_data": self.explains,
            "factor": self.factor,
            "verdict": self.verdict,
            "within_noise_uncertainty": self.within_noise,
            "next_session": self.next_session,
            "advice": self.advice,
            "time_drift": self.time_drift,
            "shape_estimate": self.shape_estimate,
            "unexplained": self.unexplained,
            "lab_fixed": self.lab_fixed,
            "mounting": self.mounting,
            "between_points": self.between_points,
            "negligible_excess": self.negligible,
            "one_way_points": None
            if self.one_way is None
            else [{"temp": t, "direction": d} for t, d in self.one_way.items()],
            "best": None
            if self.best is None
            else {
                **self.best.to_dict(),
                "config_line": self.config_line,
                "option": " ".join(add_term_option(t) for t in (self.best.term, *self.best.together)),
            },
            "partial": [
                {
                    "term": c.term,
                    "reads": readable(c.term, c.profiled),
                    "validation_rms_with": c.validation_rms_with,
                    "expected_rms_with": c.expected_with,
                    "gain_pct": c.gain_pct,
                    "remaining_excess": c.validation_rms_with / c.expected_with if c.expected_with else None,
                    "part_of": c.part_of,
                    "option": c.option,
                    "config_line": c.config_line,
                    "excess_taken": c.excess_taken,
                    "offered": c.offered,
                    "validated": c.validated,
                    "family": c.family,
                    "leftover": c.leftover,
                    "next_session": c.next_session,
                }
                for c in self.partial
            ],
            "candidates": [c.to_dict() for c in self.candidates],
            "covariates": self.covariates,
            "ladder": self.ladder,
        }


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
    """Diagnose ``settings.model`` on the observations; see the module docstring.

    ``other``, the observations of another session of the same unit, is what the user's
    calibration will meet: each model is then also judged by how it carries over to it
    (:func:`carry_over`), and an excess whose pattern does not repeat there is noise.
    ``base``, the configured model already fitted and validated on ``obs``
    (:func:`evaluation_of`), is used rather than fitting again."""
    alpha = settings.diagnosis.significance
    if base is None:
        base = evaluate(settings, obs, "configured model")
    data = columns_of(obs)
    quality = fit_quality(base, len(obs))
    explains = quality.excess_p_value >= alpha / 2
    # An excess within the noise floor's own uncertainty is no effect to name, however many
    # holds make it significant: the model explains the data; a faint pattern is noted.
    factor = float(np.sqrt(quality.chi2_red["all"]))
    faint = not explains and factor - 1.0 <= floor_uncertainty(obs)
    explains = explains or faint
    judge = Judge(settings, obs, data, other, alpha, max(base.chi2 / base.dof - 1.0, 0.0))
    base_next = judge.carry(base)
    if base_next is not None and "error" in base_next:
        judge.other = None  # the other session cannot be used: judged on this one alone
    # An effect fixed in the lab follows the table's angle: it does not repeat between
    # sessions (the table starts elsewhere) and is no effect of the sensor's.
    lab = lab_fixed(obs, quality, base.dof, alpha) if not explains else None
    seen_in_lab = bool(lab and lab["explains"])
    # Each mounting on the fixture may leave its own offset, fresh every time: no term of the
    # sensor carries it, and it does not repeat in another session (where it would read as
    # slow noise or a unit that changed).
    before_holds = history_columns(obs, data)
    mounting = (
        mounting_fixed(
            obs, quality, base.dof, alpha, before_holds["mounting"], before_holds.get("temp_direction")
        )
        if not explains and not seen_in_lab and "mount" in obs
        else None
    )
    seen_mounting = bool(mounting and mounting["explains"])
    unrepeated = False
    tolerance = explained_tolerance(obs, base.summary["holds_scored"], alpha)
    if (
        not explains
        and not seen_in_lab
        and not seen_mounting
        and usable(base_next)
        and base_next["unrepeated_p_value"] is not None
    ):
        # An excess that does not come back in the other session, whose residuals differ
        # from this one's by more than the floor, is slow noise, not an effect; unless a
        # history explains it here and carries to the other session (its pattern changes
        # with the order a session visits its rates or temperatures).
        unrepeated = explains = (
            base_next["repeat_p_value"] >= alpha / 2
            and slow_noise(base_next, alpha)
            and not _history_explains(judge, base, quality, base_next, tolerance)
        )
    v0, expected = base.summary["validation_rms"], base.summary["expected_rms"]
    # The held-out error misses what a correct model leaves by more than the validation's
    # own uncertainty (chance, over the holds scored): only then is there something for a
    # term to take away, and a term's gain must exceed that uncertainty too.
    bound = chance_bound(base.summary["holds_scored"], alpha)
    resolvable = v0 > expected * bound
    within_noise = None
    if not explains and not usable(base_next):
        # Slow wander the static data could not rule out may be all the excess is.
        upper = with_upper_floor(obs)
        if upper is not None:
            wide = evaluate(settings, upper, "configured model, slow noise at its upper bound")
            within_noise = {
                "excess_p_value": float(chi2_sf(wide.chi2, wide.dof)),
                "chi2_red": wide.chi2 / wide.dof,
                "expected_rms": float(wide.summary["expected_rms"]),
                "static_seconds": float(obs.attrs.get("static_seconds") or 0.0),
            }
            within_noise["explains"] = within_noise["excess_p_value"] >= alpha / 2

    candidates = rank_candidates(judge, base, candidate_terms(settings), base_next, tolerance)
    ranked = [c for c in candidates if c.status == "ranked"]
    for c in ranked:
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
    # No name without a gain: a term is named, or reported as partial, only when the model
    # misses what a correct one leaves and the term takes away a practical part of that.
    useful = [c for c in ranked if c.significant and not explains and practical_gain(base, c, bound)]
    drift = time_drift(judge, settings, obs, base, base_next, tolerance, bound) if not explains else None
    # The excess is shared out among the covariates whenever the fit shows one, also when
    # it is judged noise: where it lives is what tells wander from an effect.
    covariates, heat = covariate_table(
        obs, data, np.nan_to_num(quality.z), quality.fitted_rows, base.dof, not explains
    )
    negligible = None
    if faint:
        row = min(covariates, key=lambda r: r["p_value"])
        p_row = min(1.0, row["p_value"] * len(covariates))  # Bonferroni over the rows
        negligible = {
            "factor": factor,
            "floor_uncertainty": floor_uncertainty(obs),
            "covariate": row["covariate"] if p_row < alpha / 2 else None,
            "p_value": p_row,
        }
    if usable(base_next):  # what the user will meet: the other session first
        useful.sort(key=lambda c: c.next_session["validation_rms"] if usable(c.next_session) else np.inf)
    # Named only when it explains the excess: what is left is what a correct model leaves.
    best = next((c for c in useful if c.explains_excess), None)
    if best is not None:
        # Terms of different sizes that each explain the excess with a fit within its noise
        # (a g-sensitivity and its square where the accelerometer reads about 0 or 1 g):
        # the data cannot tell them apart either, whatever their figures' last digits say.
        best.tied_with = list(
            dict.fromkeys(
                [
                    *best.tied_with,
                    *(
                        c.term
                        for c in useful
                        if c is not best
                        and c.explains_excess
                        and _fits_within_noise(c, alpha)
                        and _fits_within_noise(best, alpha)
                    ),
                ]
            )
        )
    if best is not None and drift is not None and drift["explains"] and "time" not in input_kinds(best.term):
        # Within a soak the mounts follow each other in time: a term that is constant per
        # mount (a g-sensitivity) and a bias drifting in time can fit the same steps. When
        # the drift explains the excess too, the protocol cannot name either.
        drift["rival_of"] = best.term
        best = None
    # A drift in time that explains the excess rules out naming what fits it as per-mount
    # steps, alone or in a pair (a temperature rate and a g-sensitivity fit a ramp so).
    blocked = drift is not None and drift["explains"]
    for first in useful[:PAIR_STARTS] if best is None and not blocked else ():
        # Two effects missing at once: one of the most useful terms, then each other on top.
        best = second_step(judge, first, ranked, base.summary["validation_rms"], tolerance)
        if best is not None:
            break
    of_rate = best is not None and all(input_kinds(t) == {"rate"} for t in (best.term, *best.together))
    if (
        best is not None
        and not best.part_of
        and resolvable
        and not explains
        and (of_rate or not _reaches_floor(best, base_next, bound))
    ):
        # A library shape of the rate may only approach a sharper one that the protocol's
        # levels resolve (a range switch read as a cubic scale); library terms that pass the
        # tests yet leave the calibration beyond the floor where it will be judged (a
        # temperature rate standing in for a warm-up, the other session 8 times the floor)
        # may stand in for a shape of another input. Those shapes are tried, and one that
        # does better there, beyond that figure's own uncertainty, is offered instead.
        rival, tried = free_shape(
            judge,
            base,
            covariates,
            quality,
            base_next,
            tolerance,
            bound,
            library=ranked,
            inputs=("rate_own", "rate_cross", "history") if of_rate else None,
        )
        if rival is not None and (
            _judged_on(rival, base_next) * bound < _judged_on(best, base_next)
            or (of_rate and _misses_levels(best, tried, alpha))
        ):
            best, candidates = rival, candidates + tried
    lead = next((r for r in covariates if (r["share_of_excess"] or 0) > 0), None)
    if best is not None and best.tied_with:
        # Terms the data cannot tell apart: the library's order names the likelier effect.
        group = [best, *(c for c in ranked if c.term in best.tied_with)]
        first = min(group, key=library_order)
        if first is not best and first.explains_excess:
            first.tied_with = list(
                dict.fromkeys([*first.tied_with, *(c.term for c in group if c is not first)])
            )
            best = first
    if (
        best is not None
        and not explains
        and not best.part_of
        and not any(coherent(t, lead) for t in (best.term, *best.together))
    ):
        # A term that fits the excess without reading the input that carries it (the
        # accelerometer, where the centripetal force follows the rate): the shapes of that
        # input are tried, and one that explains it is offered instead.
        rival, tried = free_shape(
            judge, base, covariates, quality, base_next, tolerance, bound, library=ranked
        )
        if rival is not None and coherent(rival.term, lead):
            best, candidates = rival, candidates + tried
    why, shaped = None, []
    if best is None and seen_in_lab:
        # The angle accounts for the whole excess: what terms or a drift take of it is no
        # part of the answer.
        why, useful, drift = lab_reason(lab), [], None
    elif best is None and seen_mounting:
        why, useful, drift = mounting_reason(mounting), [], None
    elif best is None and resolvable and not explains:
        # Nothing in the library explains it: terms of free shape for the inputs that
        # carry the excess, judged as the library's are.
        best, tried = free_shape(
            judge, base, covariates, quality, base_next, tolerance, bound, time_only=blocked, library=ranked
        )
        candidates = candidates + tried
        shaped = [
            c
            for c in tried
            if c.status == "ranked"
            and c.significant
            and (practical_gain(base, c, bound) if c.validated else practical_gain_next(base_next, c, bound))
        ]
        if best is None:
            why = unexplained(tried, covariates, usable(base_next))
    # One session whose in-sample excess the slow noise the static data cannot rule out
    # accounts for, whose held-out error is within what a correct model leaves under that
    # noise too, and that no term, no drift in time and no term of free shape takes a
    # practical part of: nothing in it asks for an effect (slow wander and a one-off
    # effect look alike in one session; another one tells them apart).
    noise_explains = bool(
        best is None
        and not explains
        and not seen_in_lab
        and not seen_mounting
        and within_noise is not None
        and within_noise["explains"]
        and (
            not resolvable
            or (
                v0 <= within_noise["expected_rms"] * tolerance
                and not useful
                and not shaped
                and not (drift and drift["explains"])
            )
        )
    )
    if noise_explains:
        explains, useful, drift, why = True, [], None, None
    if why is None and not explains and best is None and not resolvable and not noise_explains:
        # An in-sample excess whose held-out error is within what a correct model leaves,
        # up to the validation's own uncertainty: too small to name anything from.
        why = {
            "reason": "too small",
            "term": None,
            "text": (
                f"on the holds left out the model's error, {v0:.3g} deg/s, is within "
                f"what a correct model would leave ({expected:.3g}) up to the validation's "
                "own uncertainty: too small to attribute to an effect"
            ),
            "would_tell": "more holds where the excess lives (longer soaks, more rates or "
            "temperatures), or another session (--other-session)",
        }
    # A model that explains the data at its points may still fail between them, which only
    # leaving points out shows.
    # Only where the fit's own χ² test passes (not where slow noise was judged to account for
    # it) and the held-out error misses what a correct model leaves: no name without a gain.
    fit_passes = quality.excess_p_value >= alpha / 2
    between = (
        between_points(base.fitted, alpha)
        if fit_passes and resolvable and best is None and not noise_explains
        else None
    )
    if why is None and between is not None and between["fails"]:
        held_out = base.summary.get("excess_over_expected")
        left_out = (
            base.summary.get("held_out") == "temperature" and held_out is not None and np.isfinite(held_out)
        )
        why = between_reason(between, held_out if left_out else None)
    estimate = shape_estimate(obs, data, quality, lead) if lead is not None and not explains else None
    if best is not None and settings.model.kind == "grid":
        best = continuous_instead(judge, best, base_next, bound) or best
    # Otherwise, terms that take away a real part of it are reported as partial.
    timed = best is None and drift is not None and drift["explains"]
    # A drift in time that explains the excess is the finding: terms that fit a part of it
    # are not reported as partial explanations.
    partial = [] if best or timed else partial_offers(useful + shaped, base, base_next, lead, bound)
    # Where the holds share slow wander, RMS ÷ floor counts each hold as if its noise were its
    # own and can sit below 1 while the whitened χ² says the model misses: the verdict gives
    # sqrt(χ²/dof), the factor its test is made on.
    shown = (
        {**quality.rms_over_floor, "all": float(np.sqrt(quality.chi2_red["all"]))}
        if shares_wander(obs)
        else quality.rms_over_floor
    )
    text = make_verdict(
        base,
        best,
        explains,
        shown,
        covariates,
        "floor_x" in obs,
        partial,
        within_noise,
        unrepeated,
        base_next if usable(base_next) else None,
        None if timed else tolerance,
        noise_explains=noise_explains,
        unseparable=[c for c in candidates if c.status == "not identifiable"],
        finding=why["reason"] if why else None,
        negligible=negligible,
    )
    if timed:
        text += " " + drift_sentence(base, drift)
    if why is not None:
        why.setdefault("lead", "No term of free shape can be offered")
    if why is not None and not (why["reason"] == "too small" and "too small" in text):
        text += f" {why['lead']}: {why['text']}; {why['would_tell']} would tell."
    residuals = obs.reset_index(drop=True).assign(
        **{
            f"{q}_{a}": v[:, i]
            for q, v in (("resid", quality.resid), ("floor", quality.floor), ("z", quality.z))
            for i, a in enumerate(AXES)
        }
    )
    diag = Diagnosis(
        base,
        alpha,
        quality.chi2_red,
        quality.rms_over_floor,
        quality.excess_p_value,
        explains,
        covariates,
        candidates,
        best,
        partial,
        text,
        heat,
        residuals,
        config_line=config_line(extended_all(settings, best).model) if best else "",
    )
    diag.ladder = ladder(settings, obs, base, judge.carry if usable(base_next) else None)
    if best is not None:
        diag.ladder.append(fix_row(best, base))
    diag.within_noise = within_noise
    diag.next_session = base_next
    diag.advice = (
        [LAB_ADVICE]
        if seen_in_lab and best is None
        else [MOUNTING_ADVICE]
        if seen_mounting and best is None
        else advice(best, partial, candidates, covariates, explains, usable(base_next), drift)
    )
    diag.one_way, compared = _one_way(obs, data, before_holds, judge.other)
    blind = unseen_hysteresis(diag.one_way, compared)
    if blind:
        diag.advice = [*diag.advice, blind]
    diag.time_drift = drift
    diag.shape_estimate = estimate
    diag.unexplained = why
    diag.lab_fixed = lab
    diag.mounting = mounting
    diag.between_points = between
    diag.factor = shown["all"]
    diag.negligible = negligible
    return diag


def _one_way(obs, data, before, other) -> tuple[dict | None, bool]:
    """:func:`one_way_points` of this session, where the other session (if any) reached each
    point it shares with this one (within 2 °C) the same way too: only then is a hysteresis
    of the temperature out of the data's sight. With whether the other session was compared
    (it shares a point)."""
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


def _history_explains(judge: Judge, base: Evaluation, quality, base_next, tolerance) -> bool:
    """Whether a term with a history (:func:`gyrocal.diagnose.shapes.history_shapes`, for the
    rows that carry the excess) explains it here and carries to the other session, as any
    named shape must: then the excess that did not come back there is no slow noise."""
    rows, _ = covariate_table(
        judge.obs, judge.data, np.nan_to_num(quality.z), quality.fitted_rows, base.dof, True
    )
    bound = chance_bound(base.summary["holds_scored"], judge.alpha)
    found, _ = free_shape(judge, base, rows, quality, base_next, tolerance, bound, inputs=("history",))
    return found is not None


def continuous_instead(judge: Judge, best: Candidate, base_next, bound) -> Candidate | None:
    """The named terms in the ladder's model continuous in temperature, where they do better.

    A grid fits each temperature point at one temperature and is applied at each hold's own,
    interpolated between the points. Where the temperature moves within a point (a unit
    that heats itself after power-on) an effect of time takes up the temperature's part in
    the fit, and the interpolation adds it again when applied. A continuous model fits what
    it applies. Offered instead where it does better where the calibration will be judged
    (the other session, or the holds left out), beyond that figure's own uncertainty."""
    settings, obs = judge.settings, judge.obs
    if "point" not in obs or not (obs.groupby("point")["temp"].agg(np.ptp) > MOVING_IN_POINT).any():
        return None
    # The ladder's continuous step where the config has one; otherwise polynomials in ΔT as
    # curved as a point left out still allows (up to a cubic bias and a quadratic scale),
    # so that it is validated as the grid is, leaving temperature points out.
    step = next((s for s in settings.diagnosis.ladder if s["kind"] == "continuous"), None)
    points = int(obs["point"].nunique())
    if points < 3:
        return None
    temperature = (
        step["add"]
        if step
        else (
            f"bias_temp_poly(degree={min(3, points - 2)})",
            f"scale_temp_poly(degree={min(2, points - 2)})",
            "misalignment_temp",
        )
    )
    cont = replace(settings, model=replace(settings.model, kind="continuous"))
    for spec in (*temperature, best.term, *best.together):
        cont = extended(cont, spec)
    try:
        ev = evaluate(cont, judge.obs, "the same, continuous in temperature")
    except GyrocalError:
        return None
    nxt = judge.carry(ev) if usable(base_next) else None
    if usable(base_next) and not usable(nxt):
        return None
    if not usable(base_next) and ev.summary["held_out"] != judge_held_out(best):
        return None  # held out otherwise than the grid's figure: not to be compared
    figure = nxt["validation_rms"] if usable(nxt) else ev.summary["validation_rms"]
    if not figure * bound < _judged_on(best, base_next):
        return None
    v0 = best.base_rms or ev.summary["validation_rms"]
    return replace(
        best,
        validation_rms_with=ev.summary["validation_rms"],
        next_session=nxt,
        expected_with=ev.summary["expected_rms"],
        gain_pct=100.0 * (1 - ev.summary["validation_rms"] / v0),
        kind="continuous",
        config_line=config_line(cont.model),
        option=model_option(cont.model),
        model=cont.model.to_dict(),
        also=[],
    )


def judge_held_out(c: Candidate) -> str:
    return "temperature" if c.validated else "none"


# °C: a point whose temperature moves more than this while its holds are made is not held at
# one temperature (about thirty times a sensor's noise).
MOVING_IN_POINT = 0.5


def _misses_levels(best: Candidate, tried: list[Candidate], alpha: float) -> bool:
    """Whether a table over the protocol's levels of the own rate, which holds any function
    of it there (the library's shapes of the rate among them), leaves the named terms' fit
    behind beyond chance: a nested F-test of the table against them. A sharper shape than
    the library's (a range switch read as a cubic scale) fails it; the library's own does not."""
    table = next(
        (
            c
            for c in tried
            if c.status == "ranked" and c.family == "levels" and make_term(c.term).name == "levels"
        ),
        None,
    )
    if table is None or best.chi2 is None or table.chi2 is None:
        return False
    extra = best.df[1] - table.df[1]  # the table's coefficients beyond the named terms'
    if extra <= 0:
        return False
    f_stat = ((best.chi2 - table.chi2) / extra) / (table.chi2 / table.df[1])
    return f_sf(f_stat, extra, table.df[1]) < alpha / 2


def _fits_within_noise(c: Candidate, alpha: float) -> bool:
    """The candidate's extended fit passes the χ² test of its residuals."""
    return c.chi2 is not None and c.df is not None and chi2_sf(c.chi2, c.df[1]) >= alpha / 2


def library_order(c: Candidate) -> int:
    """Where a candidate's term (or the term it is the part of) comes in the library's list."""
    from ..terms.effects import CANDIDATES

    names = [make_term(t).name for t in CANDIDATES]
    name = make_term(c.part_of or c.term).name
    return names.index(name) if name in names else len(names)


def _judged_on(c: Candidate, base_next) -> float:
    """A candidate's figure where its calibration will be judged: the other session's RMS
    when there is one, its held-out RMS otherwise."""
    if usable(base_next):
        return c.next_session["validation_rms"] if usable(c.next_session) else np.inf
    return c.validation_rms_with


def _reaches_floor(c: Candidate, base_next, bound) -> bool:
    """Whether a candidate's figure where it will be judged is within that figure's own
    uncertainty of what a correct model leaves there."""
    if usable(base_next):
        nxt = c.next_session
        return usable(nxt) and nxt["validation_rms"] <= nxt["expected_rms"] * bound
    return c.validation_rms_with <= (c.expected_with or np.inf) * bound


def _held_out_gain(c: Candidate, base: Evaluation, base_next) -> float:
    """The share of the configured model's excess over what a correct model leaves that a
    term takes away where it is judged: on the other session when there is one (what the
    calibration will meet), on the holds left out otherwise (the same holds as the model's),
    on the other session alone for a term no point could be left out for."""
    if usable(base_next) and usable(c.next_session):
        v0, e0, v1 = base_next["validation_rms"], base_next["expected_rms"], c.next_session["validation_rms"]
    elif c.validated:
        v0, e0, v1 = base.summary["validation_rms"], base.summary["expected_rms"], c.validation_rms_with
    else:
        return 0.0
    return (v0 - v1) / (v0 - e0) if v0 > e0 else 0.0


# A term that takes away more than this share of the excess is offered though it leaves a
# part: most of what the user's calibration would miss, gone.
MOST = 0.5


def partial_offers(gaining: list[Candidate], base: Evaluation, base_next, lead, bound) -> list[Candidate]:
    """Terms that take away a practical part of the excess without explaining it, the one
    that takes most first (at most three); the first is offered when it takes away most and
    reads the input that carries the excess (``lead``, the leading covariate row)."""
    ranked = sorted(gaining, key=lambda c: -_held_out_gain(c, base, base_next))
    if ranked:
        # The library's term first where it takes about as much (within the figure's own
        # uncertainty) as a term of free shape, which has more coefficients to take it with.
        top = _judged_on(ranked[0], base_next)
        library = next((c for c in ranked if not c.family and _judged_on(c, base_next) <= top * bound), None)
        if library is not None:
            ranked.remove(library)
            ranked.insert(0, library)
    for c in ranked:
        c.excess_taken = _held_out_gain(c, base, base_next)
        c.offered = c is ranked[0] and c.excess_taken > MOST and coherent(c.term, lead)
    return ranked[:3]


def free_shape(
    judge: Judge,
    base: Evaluation,
    covariates,
    quality,
    base_next,
    tolerance,
    bound,
    *,
    time_only: bool = False,
    library=(),
    inputs=None,
):
    """The best term of free shape (:mod:`.shapes`) that explains the excess, with its shape
    described and the parametric families that explain it as well; and every one tried.
    ``time_only``: where a drift in time explains the excess, only shapes of time (others
    would fit it as per-mount steps). ``library``: the library's candidates as ranked, each
    a partner a shape may need (the turning axis's rate squared on the other outputs, and
    on its own the library's quadratic scale). ``inputs``: only shapes of these inputs."""
    settings, obs, data = judge.settings, judge.obs, judge.data
    shapes = {
        s.spec: s
        for s in shape_terms(settings, obs, data, covariates, quality.fitted_rows)
        if (not time_only or s.input == "t") and (inputs is None or s.input in inputs)
    }
    if not shapes:
        return None, []
    tried = rank_candidates(judge, base, list(shapes), base_next, tolerance, in_sample=True)
    good, gaining = [], []
    for c in tried:
        shape = shapes.get(c.part_of or c.term)
        if c.status != "ranked" or shape is None:
            continue
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
        c.family = shape.family
        gain = practical_gain(base, c, bound) if c.validated else practical_gain_next(base_next, c, bound)
        if c.significant and gain:
            gaining.append(c)
            if c.explains_excess:
                good.append((c, shape))
    if not good and gaining:
        # Two shapes at once (a fast and a slow warm-up): the most useful, then each other.
        gaining.sort(key=lambda c: c.validation_rms_with)
        ranked = [c for c in tried if c.status == "ranked" and c.term in shapes]
        for first in gaining[:2]:
            # An empirical term already spans every shape of its input: it pairs only with
            # shapes of another input (or the same one times the rate).
            own = shapes[first.part_of or first.term]
            partners = [
                c
                for c in ranked
                if not (
                    shapes[c.term].input == own.input
                    and shapes[c.term].by == own.by
                    and "empirical" in (shapes[c.term].kind, own.kind)
                )
            ]
            partners += [c for c in library if c.significant]
            pair = second_step(
                judge, first, partners, base.summary["validation_rms"], tolerance, in_sample=True
            )
            if pair is not None:
                good.append((pair, own))
        if len(good) > 1 and not usable(base_next):
            # Pairs alike within the figure's own uncertainty: the one with fewest coefficients.
            top = min(g[0].validation_rms_with for g in good)
            good = [
                min(
                    (g for g in good if g[0].validation_rms_with <= top * bound),
                    key=lambda g: (g[0].df[0], g[0].validation_rms_with),
                )
            ]
    if not good:
        return None, tried

    def figure(g):  # what the user will meet: the other session first
        return _judged_on(g[0], base_next)

    good.sort(key=figure)
    # Never a formula whose parameter ended at a bound of its search: the data do not fix it.
    good = [g for g in good if not at_bound(g[0].profiled)] or good
    # The empirical term where it does as well as the best within that figure's own
    # uncertainty (it reads as a table of its input), the families that do as well beside it;
    # but a formula where it does as well as that term within the noise floor's own
    # uncertainty: a unit keeps a decay and its time constant better than a session's spline.
    best, shape = next(
        (g for g in good if g[1].kind == "empirical" and figure(g) <= figure(good[0]) * bound), good[0]
    )
    close = figure((best,)) * (1.0 + floor_uncertainty(obs))
    best, shape = next((g for g in good if g[1].kind == "parametric" and figure(g) <= close), (best, shape))
    terms = [make_term(t) for t in (best.term, *best.together)]
    # The shape as fitted: its profiled parameters, not their start.
    terms[0] = _profiled(terms[0], best.profiled)
    values = {n: 0.0 for t in terms for n in t.coefficients()}
    if best.together:  # a pair: its coefficients as fitted together
        fitted = evaluate(extended_all(settings, best), obs, best.term, in_sample=True).fitted
        values.update({n: pooled(fitted.fits, n)[0] for n in values})
    else:
        values.update({z["coefficient"]: z["value"] for z in best.size})
    if shape.input == "history":
        best.shape = describe_history(terms[0], values, shape.family)
        settling = next((r for r in covariates if r["covariate"] == SETTLING_ROW), None)
        if shape.family == "slow pole" and settling and settling["p_value"] < judge.alpha / 2:
            parts = ", ".join(f"{v * 1e3:+.2g} ({a})" for a, v in settling["slope"].items())
            best.shape += (
                f" Inside each hold the output changes from its first half to its second "
                f"by {parts} ×10⁻³ of the step into it (p = {settling['p_value']:.2g})."
            )
    else:
        x = input_values(obs, data, shape.input)[quality.fitted_rows]
        best.shape = describe(terms, values, float(np.min(x)), float(np.max(x)), shape.input, shape.by)
    # Only what does as well, within the figure's own uncertainty, is said to explain it too.
    best.also = [
        c
        for c, _ in good
        if c is not best and not at_bound(c.profiled) and figure((c,)) <= figure((best,)) * bound
    ]
    for c in (best, *best.also):  # written for the unit, not for this session's log
        c.term = for_the_unit(c.term, c.profiled)
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
    return best, tried


def _profiled(term, profiled):
    """``term`` with its formula's parameters at their profiled values."""
    inner = getattr(term, "term", term)
    # The model's own profiled terms (a library lag's tau) are in the list too: this term's only.
    found = {
        p["parameter"]: p["value"]
        for p in profiled or ()
        if "value" in p and p.get("term") == getattr(inner, "label", None)
    }
    if not getattr(inner, "parameters", None) or not found:
        return term
    return term.with_settings(**{k: float(v) for k, v in found.items() if k in inner.parameters})
