"""Which term to offer: among terms that explain the excess, the one the user will do best
with (judged where the calibration will be used), a sharper shape where the library's only
approaches one, a model continuous in temperature where the points' temperature moves, and
the terms that take away part of the excess where none explains it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..fit.model import columns_of
from ..io.errors import GyrocalError
from ..terms import AXES, make_term
from .effects import (
    Candidate,
    Judge,
    extended_all,
    gains_where_judged,
    rank_candidates,
    second_step,
)
from .evaluation import Evaluation, add_term_option, config_line, evaluate, extended, model_option, pooled
from .grain import at_the_grain
from .grammar import formula_of, screen
from .sessions import CARRIES_WITHIN, usable
from .shapes import at_bound, describe, describe_history, for_the_unit, shape_terms
from .stats import chance_bound, chi2_sf, f_sf, floor_uncertainty
from .verdict import coherent, input_kinds, shared_by_every_axis
from .where import SETTLING_ROW, input_values


def continuous_instead(judge: Judge, best: Candidate, base_next, bound) -> Candidate | None:
    """The named terms in the ladder's model continuous in temperature, where they do better.

    A grid fits each temperature point at one temperature and is applied at each hold's own,
    interpolated between the points. Where the temperature moves within a point (a unit
    that heats itself after power-on) an effect of time takes up the temperature's part in
    the fit, and the interpolation adds it again when applied. A continuous model fits what
    it applies. Offered instead where it does better where the calibration will be judged
    (the other session, or the holds left out), beyond that figure's own uncertainty."""
    settings, obs = judge.settings, judge.obs
    if "point" not in obs:
        return None
    moving = (obs.groupby("point")["temp"].agg(np.ptp) > MOVING_IN_POINT).any()
    if not moving and not absorbed_by_points(settings, obs, (best.term, *best.together)):
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
    if not figure * bound < judged_on(best, base_next):
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


def absorbed_by_points(settings, obs, terms) -> bool:
    """Whether the grid's own parameters at each point (a bias and a row of K: the output
    against 1 and the three rates) take up nearly all of the terms' columns: a term the grid
    absorbs point by point (a state the temperature's history sets once per point, as a
    hysteresis does) changes nothing the grid applies, and only a model continuous in
    temperature holds it apart from the points' own parameters."""
    try:
        for spec in terms:
            settings = extended(settings, spec)
        model = settings.model.build()
        data = model.transform_inputs(columns_of(obs))
    except GyrocalError:
        return False
    points = np.asarray(obs["point"])
    rates = np.column_stack([np.ones(len(obs)), *(np.asarray(data[f"rate_{a}"], float) for a in AXES)])
    try:
        design = model.design(data)
    except GyrocalError:
        return False
    wanted = {make_term(t).spec_string() for t in terms}
    names = [c for t in model.terms if t.spec_string() in wanted for c in t.coefficients()]
    for name in names:
        c = np.broadcast_to(np.asarray(design[name], dtype=float), (len(obs),))
        if not np.all(np.isfinite(c)) or not np.any(c):
            return False
        left = 0.0
        for p in np.unique(points):
            rows = points == p
            coef, *_ = np.linalg.lstsq(rates[rows], c[rows], rcond=None)
            left += float(np.sum((c[rows] - rates[rows] @ coef) ** 2))
        if left > ABSORBED * float(np.sum(c**2)):
            return False
    return True


# The share of a term's column the points' own parameters may leave for the grid to be
# said to absorb it: what remains is the temperature's wander within a point.
ABSORBED = 0.01


def judge_held_out(c: Candidate) -> str:
    return "temperature" if c.validated else "none"


# °C: a point whose temperature moves more than this while its holds are made is not held at
# one temperature (about thirty times a sensor's noise).
MOVING_IN_POINT = 0.5


def misses_levels(best: Candidate, tried: list[Candidate], alpha: float) -> bool:
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


def fits_within_noise(c: Candidate, alpha: float) -> bool:
    """The candidate's extended fit passes the χ² test of its residuals."""
    return c.chi2 is not None and c.df is not None and chi2_sf(c.chi2, c.df[1]) >= alpha / 2


def library_order(c: Candidate) -> int:
    """Where a candidate's term (or the term it is the part of) comes in the library's list."""
    from ..terms.effects import CANDIDATES

    names = [make_term(t).name for t in CANDIDATES]
    name = make_term(c.part_of or c.term).name
    return names.index(name) if name in names else len(names)


def judged_on(c: Candidate, base_next) -> float:
    """A candidate's figure where its calibration will be judged: the other session's RMS
    when there is one, its held-out RMS otherwise."""
    if usable(base_next):
        return c.next_session["validation_rms"] if usable(c.next_session) else np.inf
    return c.validation_rms_with


def reaches_floor(c: Candidate, base_next, bound) -> bool:
    """Whether a candidate's figure where it will be judged is within that figure's own
    uncertainty of what a correct model leaves there."""
    if usable(base_next):
        nxt = c.next_session
        return usable(nxt) and nxt["validation_rms"] <= nxt["expected_rms"] * bound
    return c.validation_rms_with <= (c.expected_with or np.inf) * bound


def held_out_gain(c: Candidate, base: Evaluation, base_next) -> float:
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


CARRYING_SHARE = 0.1  # of the excess on a covariate row, for a term reading it to be coherent


def partial_offers(
    gaining: list[Candidate], base: Evaluation, base_next, lead, bound, rows=(), at_its_grain=None
) -> list[Candidate]:
    """Terms that take away a practical part of the excess without explaining it, the one
    that takes most first (at most three); the first is offered when it takes away most and
    reads an input that carries the excess: the leading covariate row's (``lead``) or that of
    another row of ``rows`` carrying at least :data:`CARRYING_SHARE` of it. Rows of one
    protocol move together (after a remount the table starts from rest, so the step into a
    hold follows the mounting), and the leading one is not always the effect's. Where the
    held-out points leave the first short of most, ``at_its_grain(c)`` may still offer it:
    judged at the grain its input varies over (one log: :func:`takes_most_at_its_grain`)."""
    ranked = sorted(gaining, key=lambda c: -held_out_gain(c, base, base_next))
    if ranked:
        # The library's term first where it takes about as much (within the figure's own
        # uncertainty) as a term of free shape, which has more coefficients to take it with.
        top = judged_on(ranked[0], base_next)
        library = next((c for c in ranked if not c.family and judged_on(c, base_next) <= top * bound), None)
        if library is not None:
            ranked.remove(library)
            ranked.insert(0, library)
    carrying = [lead, *(r for r in rows if (r.get("share_of_excess") or 0.0) >= CARRYING_SHARE)]
    for c in ranked:
        c.excess_taken = held_out_gain(c, base, base_next)
        c.offered = c is ranked[0] and c.excess_taken > MOST and any(coherent(c.term, r) for r in carrying)
    first = ranked[0] if ranked else None
    if first is not None and not first.offered and at_its_grain is not None:
        first.offered = any(coherent(first.term, r) for r in carrying) and at_its_grain(first)
    return ranked[:3]


def takes_most_at_its_grain(judge: Judge, c: Candidate) -> bool:
    """A term of the rate alone judged where it must carry, leaving each interior rate level
    out in turn (:func:`.grain.at_the_grain`): it takes most (:data:`MOST`) of what the
    configured model leaves there beyond the floor, which is itself beyond the bar a
    calibration meets on data it never saw. Not one the same on every axis
    (:func:`shared_by_every_axis`): the reference's, as likely as the sensor's. The points left out mix its effect with the
    interpolation's between temperatures, which no term of the rate takes away: that part
    is a second question, after the fix."""
    if input_kinds(c.term) != {"rate"} or shared_by_every_axis(c):
        return False
    grain = at_the_grain(judge.settings, extended_all(judge.settings, c), judge.obs, "rate level", c.profiled)
    if grain is None or grain.fix is None or grain.base <= CARRIES_WITHIN:
        return False
    c.grain = grain
    return bool((grain.base - grain.fix) / (grain.base - 1.0) > MOST)


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
) -> tuple[Candidate | None, list[Candidate]]:
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
    for found in _grammar(judge, quality, shapes):
        s = found.shape
        if (not time_only or s.input == "t") and (inputs is None or s.input in inputs):
            shapes[s.spec] = s
    if not shapes:
        return None, []
    tried = rank_candidates(judge, base, list(shapes), base_next, tolerance, in_sample=True)
    good = _shapes_that_explain(judge, base, shapes, tried, base_next, tolerance, bound, library)
    if not good:
        return None, tried

    def figure(g):  # what the user will meet: the other session first
        return judged_on(g[0], base_next)

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
    best.shape = _shape_sentence(judge, best, shape, covariates, quality)
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


def _grammar(judge: Judge, quality, shapes: dict) -> list:
    """The grammar's candidates that pass its screen (:func:`.grammar.screen`), screened once
    per diagnosis, less those that compute what a shape already tried computes."""
    if judge.screened is None:
        judge.screened = screen(judge.obs, judge.data, quality, judge.alpha)
    tried = {formula_of(spec) for spec in shapes}
    return [s for s in judge.screened if formula_of(s.shape.spec) not in tried]


def _beyond_uncertainty(base: Evaluation, c: Candidate, bound: float) -> bool:
    """A held-out gain larger than the validation figure's own uncertainty (``bound``)."""
    v0 = base.summary["validation_rms"]
    return bool(c.validated and v0 - c.validation_rms_with > v0 * (1.0 - 1.0 / bound))


def _shapes_that_explain(judge, base, shapes, tried, base_next, tolerance, bound, library) -> list:
    """(candidate, shape) for each term of free shape, or pair of them, that takes away a
    practical part of the excess and explains it."""
    settings = judge.settings
    good, gaining, starts = [], [], []
    for c in tried:
        shape = shapes.get(c.part_of or c.term)
        if c.status != "ranked" or shape is None:
            continue
        c.option, c.config_line = add_term_option(c.term), config_line(extended(settings, c.term).model)
        c.family = shape.family
        gain = gains_where_judged(base, c, base_next, bound)
        if c.significant and gain:
            gaining.append(c)
            if c.explains_excess:
                good.append((c, shape))
        if c.significant and _beyond_uncertainty(base, c, bound):
            starts.append(c)
    # A single that passes only as the fix its other session needs, leaving a pattern here
    # (a second question), may be half of a pair: pairs are tried beside it.
    if (good and not all(g[0].second_question for g in good)) or not (gaining or starts):
        return good
    # Two shapes at once (a fast and a slow warm-up): the most useful, then each other. A
    # pair's first need not take a quarter of the excess alone (the practical gain a name
    # asks for): only more than the held-out figure's own uncertainty.
    gaining = sorted(starts or gaining, key=lambda c: c.validation_rms_with)
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
        pair = second_step(judge, first, partners, base.summary["validation_rms"], tolerance, in_sample=True)
        if pair is not None and _beats_the_singles(pair, gaining, base_next, judge.alpha):
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
    return good


def _beats_the_singles(pair: Candidate, singles: list[Candidate], base_next, alpha: float) -> bool:
    """A pair that explains this session is offered over a term alone only where it carries
    to the other session better than the best of them, beyond that figure's own uncertainty:
    a partner that takes up what one term leaves here and misses there fits this session's
    own leftovers. Without another session, every pair stands."""
    if not usable(base_next) or not usable(pair.next_session):
        return True
    alone = [c.next_session["validation_rms"] for c in singles if usable(c.next_session)]
    if not alone:
        return True
    bound = chance_bound(base_next["holds_scored"], alpha)
    return bool(pair.next_session["validation_rms"] * bound < min(alone))


def _shape_sentence(judge: Judge, best: Candidate, shape, covariates, quality) -> str:
    """The shape of a named term of free shape, as fitted, in a sentence."""
    settings, obs = judge.settings, judge.obs
    terms = [make_term(t) for t in (best.term, *best.together)]
    # The shape as fitted: its profiled parameters, not their start.
    terms[0] = _profiled(terms[0], best.profiled)
    values = {n: 0.0 for t in terms for n in t.coefficients()}
    if best.together:  # a pair: its coefficients as fitted together
        fitted = evaluate(extended_all(settings, best), obs, best.term, in_sample=True).fitted
        values.update({n: pooled(fitted.fits, n)[0] for n in values})
    else:
        values.update({z["coefficient"]: z["value"] for z in best.size})
    if shape.input != "history":
        x = input_values(obs, judge.data, shape.input)[quality.fitted_rows]
        return describe(terms, values, float(np.min(x)), float(np.max(x)), shape.input, shape.by)
    sentence = describe_history(terms[0], values, shape.family)
    settling = next((r for r in covariates if r["covariate"] == SETTLING_ROW), None)
    if shape.family == "slow pole" and settling and settling["p_value"] < judge.alpha / 2:
        parts = ", ".join(f"{v * 1e3:+.2g} ({a})" for a, v in settling["slope"].items())
        sentence += (
            f" Inside each hold the output changes from its first half to its second "
            f"by {parts} ×10⁻³ of the step into it (p = {settling['p_value']:.2g})."
        )
    return sentence


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
