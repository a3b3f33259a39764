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

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..fit.floor import with_upper_floor
from ..fit.model import columns_of, shares_wander
from ..pipeline.config import Settings
from ..terms import AXES, make_term
from .between import between_points, between_reason
from .effects import (TIME_DRIFT, Candidate, Judge, extended_all, mark_ties, practical_gain,
                      practical_gain_next, rank_candidates, second_step, time_drift)
from .evaluation import (Evaluation, add_term_option, candidate_terms, config_line, evaluate,
                         evaluation_of, extended, ladder, pooled)
from .lab import LAB_ADVICE, lab_fixed, lab_reason
from .sessions import (carry_over, repeat_p_value, shared_fraction, slow_noise, unrepeated_p_value,
                       usable)
from .shapes import describe, shape_terms
from .stats import chance_bound, chi2_ppf, chi2_sf, explained_tolerance, f_sf, fisher_combined
from .verdict import advice, drift_sentence, input_kinds, unexplained, verdict as make_verdict
from .where import COVARIATES, covariate_table, fit_quality, input_values, shape_estimate

__all__ = ["COVARIATES", "TIME_DRIFT", "Candidate", "Diagnosis", "Evaluation", "add_term_option",
           "candidate_terms", "carry_over", "chance_bound", "chi2_ppf", "chi2_sf", "config_line",
           "diagnose", "evaluate", "evaluation_of", "explained_tolerance", "extended", "f_sf",
           "fisher_combined", "mark_ties", "repeat_p_value", "shared_fraction", "unrepeated_p_value"]


@dataclass
class Diagnosis:
    base: Evaluation
    significance: float
    chi2_red: dict[str, float]               # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float
    explains: bool
    covariates: list[dict]
    candidates: list[Candidate]
    best: Candidate | None
    partial: list[Candidate]
    verdict: str
    heatmaps: dict
    residuals: pd.DataFrame                   # observations + resid_, floor_, z_ per axis
    config_line: str = ""                     # the model: lines that add the best candidate
    ladder: list[dict] = field(default_factory=list)
    within_noise: dict | None = None          # the χ² test with the slow noise at its upper bound
    next_session: dict | None = None          # the configured model on another session
    advice: list[str] = field(default_factory=list)
    time_drift: dict | None = None            # TIME_DRIFT's fit: the rival no term can beat
    shape_estimate: dict | None = None        # the residuals against the leading input
    unexplained: dict | None = None           # why no term of free shape was offered
    lab_fixed: dict | None = None             # the excess against the table's angle
    between_points: dict | None = None        # interpolated against fitted, point by point
    factor: float | None = None               # the verdict's "times their noise floor"

    def to_dict(self) -> dict:
        s = self.base.summary
        return {
            "format": "gyrocal.diagnosis/1",
            "model": {"terms": self.base.terms, "kind": self.base.kind},
            "validation_rms": s["validation_rms"], "noise_floor": s["noise_floor"],
            "excess": s["excess"], "expected_rms": s["expected_rms"],
            "excess_over_expected": s["excess_over_expected"], "held_out": s["held_out"],
            "significance": self.significance,
            "chi2_red": self.chi2_red, "rms_over_floor": self.rms_over_floor,
            "excess_p_value": self.excess_p_value, "explains_the_data": self.explains,
            "factor": self.factor,
            "verdict": self.verdict,
            "within_noise_uncertainty": self.within_noise,
            "next_session": self.next_session,
            "advice": self.advice,
            "time_drift": self.time_drift,
            "shape_estimate": self.shape_estimate,
            "unexplained": self.unexplained,
            "lab_fixed": self.lab_fixed,
            "between_points": self.between_points,
            "best": None if self.best is None else {
                **self.best.to_dict(), "config_line": self.config_line,
                "option": " ".join(add_term_option(t) for t in (self.best.term, *self.best.together))},
            "partial": [{"term": c.term, "validation_rms_with": c.validation_rms_with,
                         "expected_rms_with": c.expected_with, "gain_pct": c.gain_pct,
                         "remaining_excess": c.validation_rms_with / c.expected_with
                         if c.expected_with else None, "part_of": c.part_of,
                         "option": c.option, "config_line": c.config_line} for c in self.partial],
            "candidates": [c.to_dict() for c in self.candidates],
            "covariates": self.covariates,
            "ladder": self.ladder,
        }


# The most useful terms each tried as the first of two missing effects: the one that
# gains most alone is not always part of the pair (a temperature lag's first-order form
# beats a die temperature alone, whose pair with a cubic bias is the effect).
PAIR_STARTS = 3


def diagnose(settings: Settings, obs: pd.DataFrame, other: pd.DataFrame | None = None, *,
             base: Evaluation | None = None) -> Diagnosis:
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
    judge = Judge(settings, obs, data, other, alpha, max(base.chi2 / base.dof - 1.0, 0.0))
    base_next = judge.carry(base)
    if base_next is not None and "error" in base_next:
        judge.other = None    # the other session cannot be used: judged on this one alone
    # An effect fixed in the lab follows the table's angle: it does not repeat between
    # sessions (the table starts elsewhere) and is no effect of the sensor's.
    lab = lab_fixed(obs, quality, base.dof, alpha) if not explains else None
    seen_in_lab = bool(lab and lab["explains"])
    unrepeated = False
    if not explains and not seen_in_lab and usable(base_next) and base_next["unrepeated_p_value"] is not None:
        # An excess that does not come back in the other session, whose residuals differ
        # from this one's by more than the floor, is slow noise, not an effect.
        unrepeated = explains = base_next["repeat_p_value"] >= alpha / 2 and slow_noise(base_next, alpha)
    tolerance = explained_tolerance(obs, base.summary["holds_scored"], alpha)
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
            within_noise = {"excess_p_value": float(chi2_sf(wide.chi2, wide.dof)),
                            "chi2_red": wide.chi2 / wide.dof,
                            "expected_rms": float(wide.summary["expected_rms"]),
                            "static_seconds": float(obs.attrs.get("static_seconds") or 0.0)}
            within_noise["explains"] = within_noise["excess_p_value"] >= alpha / 2

    candidates = rank_candidates(judge, base, candidate_terms(settings), base_next, tolerance)
    ranked = [c for c in candidates if c.status == "ranked"]
    for c in ranked:
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
    # No name without a gain: a term is named, or reported as partial, only when the model
    # misses what a correct one leaves and the term takes away a practical part of that.
    useful = [c for c in ranked if c.significant and not explains
              and practical_gain(base, c, bound)]
    drift = time_drift(judge, settings, obs, base, base_next, tolerance, bound) if not explains else None
    # The excess is shared out among the covariates whenever the fit shows one, also when
    # it is judged noise: where it lives is what tells wander from an effect.
    covariates, heat = covariate_table(obs, data, np.nan_to_num(quality.z), quality.fitted_rows,
                                       base.dof, not explains)
    if usable(base_next):  # what the user will meet: the other session first
        useful.sort(key=lambda c: c.next_session["validation_rms"] if usable(c.next_session) else np.inf)
    # Named only when it explains the excess: what is left is what a correct model leaves.
    best = next((c for c in useful if c.explains_excess), None)
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
    lead = next((r for r in covariates if (r["share_of_excess"] or 0) > 0), None)
    why, shaped = None, []
    if best is None and seen_in_lab:
        # The angle accounts for the whole excess: what terms or a drift take of it is no
        # part of the answer.
        why, useful, drift = lab_reason(lab), [], None
    elif best is None and resolvable and not explains:
        # Nothing in the library explains it: terms of free shape for the inputs that
        # carry the excess, judged as the library's are.
        best, tried = free_shape(judge, base, covariates, quality, base_next, tolerance, bound,
                                 time_only=blocked)
        candidates = candidates + tried
        shaped = [c for c in tried if c.status == "ranked" and c.significant and (
            practical_gain(base, c, bound) if c.validated else practical_gain_next(base_next, c, bound))]
        if best is None:
            why = unexplained(tried, covariates, usable(base_next))
    # One session whose in-sample excess the slow noise the static data cannot rule out
    # accounts for, whose held-out error is within what a correct model leaves under that
    # noise too, and that no term, no drift in time and no term of free shape takes a
    # practical part of: nothing in it asks for an effect (slow wander and a one-off
    # effect look alike in one session; another one tells them apart).
    noise_explains = bool(
        best is None and not explains and not seen_in_lab and within_noise is not None
        and within_noise["explains"]
        and (not resolvable or (v0 <= within_noise["expected_rms"] * tolerance and not useful
                                and not shaped and not (drift and drift["explains"]))))
    if noise_explains:
        explains, useful, drift, why = True, [], None, None
    if why is None and not explains and best is None and not resolvable and not noise_explains:
        # An in-sample excess whose held-out error is within what a correct model leaves,
        # up to the validation's own uncertainty: too small to name anything from.
        why = {"reason": "too small", "term": None,
               "text": (f"on the holds left out the model's error, {v0:.3g} deg/s, is within "
                        f"what a correct model would leave ({expected:.3g}) up to the validation's "
                        "own uncertainty: too small to attribute to an effect"),
               "would_tell": "more holds where the excess lives (longer soaks, more rates or "
                             "temperatures), or another session (--other-session)"}
    # A model that explains the data at its points may still fail between them, which only
    # leaving points out shows.
    # Only where the fit's own χ² test passes (not where slow noise was judged to account for
    # it) and the held-out error misses what a correct model leaves: no name without a gain.
    fit_passes = quality.excess_p_value >= alpha / 2
    between = (between_points(base.fitted, alpha)
               if fit_passes and resolvable and best is None and not noise_explains else None)
    if why is None and between is not None and between["fails"]:
        held_out = base.summary.get("excess_over_expected")
        left_out = base.summary.get("held_out") == "temperature" and held_out is not None \
            and np.isfinite(held_out)
        why = between_reason(between, held_out if left_out else None)
    estimate = shape_estimate(obs, data, quality, lead) if lead is not None and not explains else None
    # Otherwise, terms that take away a real part of it are reported as partial.
    timed = best is None and drift is not None and drift["explains"]
    # A drift in time that explains the excess is the finding: terms that fit a part of it
    # are not reported as partial explanations.
    partial = [] if best or timed else useful[:3]
    # Where the holds share slow wander, RMS ÷ floor counts each hold as if its noise were its
    # own and can sit below 1 while the whitened χ² says the model misses: the verdict gives
    # sqrt(χ²/dof), the factor its test is made on.
    shown = ({**quality.rms_over_floor, "all": float(np.sqrt(quality.chi2_red["all"]))}
             if shares_wander(obs) else quality.rms_over_floor)
    text = make_verdict(base, best, explains, shown, covariates, "floor_x" in obs,
                        partial, within_noise, unrepeated, base_next if usable(base_next) else None,
                        None if timed else tolerance, noise_explains=noise_explains,
                        unseparable=[c for c in candidates if c.status == "not identifiable"],
                        finding=why["reason"] if why else None)
    if timed:
        text += " " + drift_sentence(base, drift)
    if why is not None:
        why.setdefault("lead", "No term of free shape can be offered")
    if why is not None and not (why["reason"] == "too small" and "too small" in text):
        text += f" {why['lead']}: {why['text']}; {why['would_tell']} would tell."
    residuals = obs.reset_index(drop=True).assign(
        **{f"{q}_{a}": v[:, i] for q, v in (("resid", quality.resid), ("floor", quality.floor),
                                             ("z", quality.z)) for i, a in enumerate(AXES)})
    diag = Diagnosis(base, alpha, quality.chi2_red, quality.rms_over_floor, quality.excess_p_value,
                     explains, covariates, candidates, best, partial, text, heat, residuals,
                     config_line=config_line(extended_all(settings, best).model) if best else "")
    diag.ladder = ladder(settings, obs, base)
    diag.within_noise = within_noise
    diag.next_session = base_next
    diag.advice = [LAB_ADVICE] if seen_in_lab and best is None else \
        advice(best, partial, candidates, covariates, explains, usable(base_next), drift)
    diag.time_drift = drift
    diag.shape_estimate = estimate
    diag.unexplained = why
    diag.lab_fixed = lab
    diag.between_points = between
    diag.factor = shown["all"]
    return diag


def free_shape(judge: Judge, base: Evaluation, covariates, quality, base_next, tolerance, bound, *,
               time_only: bool = False):
    """The best term of free shape (:mod:`.shapes`) that explains the excess, with its shape
    described and the parametric families that explain it as well; and every one tried.
    ``time_only``: where a drift in time explains the excess, only shapes of time (others
    would fit it as per-mount steps)."""
    settings, obs, data = judge.settings, judge.obs, judge.data
    shapes = {s.spec: s for s in shape_terms(settings, obs, data, covariates, quality.fitted_rows)
              if not time_only or s.input == "t"}
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
            partners = [c for c in ranked if not (
                shapes[c.term].input == own.input and shapes[c.term].by == own.by
                and "empirical" in (shapes[c.term].kind, own.kind))]
            pair = second_step(judge, first, partners, base.summary["validation_rms"], tolerance,
                               in_sample=True)
            if pair is not None:
                good.append((pair, own))
                break
    if not good:
        return None, tried
    if usable(base_next):
        good.sort(key=lambda g: g[0].next_session["validation_rms"] if usable(g[0].next_session) else np.inf)
    else:
        good.sort(key=lambda g: g[0].validation_rms_with)
    # The empirical term when it explains, the parametric families that do as well beside it.
    best, shape = next((g for g in good if g[1].kind == "empirical"), good[0])
    terms = [make_term(t) for t in (best.term, *best.together)]
    values = {n: 0.0 for t in terms for n in t.coefficients()}
    if best.together:   # a pair: its coefficients as fitted together
        fitted = evaluate(extended_all(settings, best), obs, best.term, in_sample=True).fitted
        values.update({n: pooled(fitted.fits, n)[0] for n in values})
    else:
        values.update({z["coefficient"]: z["value"] for z in best.size})
    x = input_values(obs, data, shape.input)[quality.fitted_rows]
    best.shape = describe(terms, values, float(np.min(x)), float(np.max(x)), shape.input, shape.by)
    best.also = [c for c, _ in good if c is not best]
    return best, tried
