"""Which effect is missing: every candidate term added to the model in turn, refitted,
validated and judged on what it leaves (in this session and, given one, in another)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..io.errors import GyrocalError, MissingInputError
from ..pipeline.config import Settings
from ..terms import AXES, Restricted, make_term, parse_spec
from ..terms.signals import SERIES_INPUTS
from .evaluation import (
    CoefficientSize,
    Evaluation,
    add_term_option,
    config_line,
    effect_size,
    evaluate,
    extended,
    identifiable_part,
    in_sample_summary,
    noise_only,
    reason,
)
from .findings import TimeDrift
from .sessions import SOAKED_SPREAD, CarryOver, carry_over, fails_in_practice, slow_noise, usable
from .stats import chance_bound, chi2_sf, f_sf, fisher_combined
from .where import TIME_LIKE, Leftover, leftover


@dataclass
class Candidate:
    term: str
    status: str  # ranked | not identifiable | missing inputs
    validation_rms_with: float | None = None
    p_value: float | None = None
    f_statistic: float | None = None
    df: tuple[int, int] | None = None
    gain_pct: float | None = None
    significant: bool = False
    size: list[CoefficientSize] = field(default_factory=list)
    peak_effect: float | None = None  # deg/s over the observations
    reason: str = ""
    expected_with: float | None = None  # what a correct model would leave, deg/s
    explains_excess: bool = False  # validation RMS within chance of that
    tied_with: list[str] = field(default_factory=list)  # fits this protocol cannot tell apart
    together: list[str] = field(default_factory=list)  # also missing: named with this one
    alone_rms: float | None = None  # validation RMS with this one alone
    leftover: Leftover | None = None  # the covariate its residuals still follow most
    # passed out of sample though what it leaves follows time within the points
    second_question: bool = False
    next_session: CarryOver | None = None  # how the extended model carries over
    chi2: float | None = None  # of the extended fit, for ties
    part_of: str | None = None  # the library term this is the protocol's part of
    seen_part: str | None = None  # not identifiable: the part fitted instead
    excited: bool = True  # its columns are not all zero on these holds
    validated: bool = True  # by leaving points out (else in-sample figures)
    option: str = ""  # the command-line option that adds it
    config_line: str = ""  # the model: lines of the config with it
    profiled: list = field(default_factory=list)  # its nonlinear settings as fitted
    family: str | None = None  # a term of free shape: smooth, decay, ...
    shape: str = ""  # named, of free shape: a sentence on its shape
    also: list = field(default_factory=list)  # other terms of free shape that explain it too
    base_rms: float | None = None  # the configured model's figure on the same holds
    excess_taken: float | None = None  # partial: share of the excess it takes away
    kind: str | None = None  # offered in a model of this kind (continuous)
    model: dict | None = None  # that model, as the config's model: section
    offered: bool = False  # partial: offered, taking away most of it
    grain: Any = None  # partial, one log: the rate-level grain it was judged at (.grain.Grain)

    def to_dict(self) -> dict[str, Any]:
        from .reading import readable

        out = {
            "term": self.term,
            "reads": readable(self.term, self.profiled),
            "status": self.status,
            "validation_rms_with": self.validation_rms_with,
            "p_value": self.p_value,
        }
        if self.status == "ranked":
            out.update(
                f_statistic=self.f_statistic,
                df=list(self.df),
                gain_pct=self.gain_pct,
                validated=self.validated,
                base_rms=self.base_rms,
                **({"kind": self.kind, "model": self.model} if self.kind else {}),
                significant=self.significant,
                size=self.size,
                peak_effect=self.peak_effect,
                expected_rms_with=self.expected_with,
                explains_excess=self.explains_excess,
                tied_with=self.tied_with,
                together=self.together,
                alone_rms=self.alone_rms,
                leftover=self.leftover,
                **({"second_question": True} if self.second_question else {}),
                next_session=self.next_session,
                part_of=self.part_of,
                option=self.option,
                config_line=self.config_line,
                profiled=self.profiled,
            )
            if self.family:
                out.update(
                    family=self.family,
                    shape=self.shape,
                    also=[
                        {
                            "term": c.term,
                            "reads": readable(c.term, c.profiled),
                            "family": c.family,
                            "option": c.option,
                            "config_line": c.config_line,
                            "profiled": c.profiled,
                            "validation_rms_with": c.validation_rms_with,
                        }
                        for c in self.also
                    ],
                )
        else:
            out["reason"] = self.reason
            if self.seen_part:
                out["seen_part"] = self.seen_part
        return out


LEFTOVER_FRACTION = 0.02  # of the configured model's excess χ²/dof: see Judge.explains
NEGLIGIBLE_OVER_FLOOR = 1.2  # structure left within this many times the floor is negligible


class Judge:
    """Whether a model leaves only what a correct one would, from one session or two.

    One session: its in-sample χ² is within chance or its validation RMS within chance of
    what a correct model leaves, *and* its residuals follow no covariate beyond chance (a
    term that soaks up most of an effect it is not, as a g-sensitivity on a linear time
    drift whose holds run in order of speed, leaves the rest lined up with time or rate).
    Two sessions: what its residuals still hold does not repeat in the other session, and
    it does not carry over worse than the configured model."""

    def __init__(self, settings, obs, data, other, alpha, base_excess: float):
        self.settings, self.obs, self.data, self.other, self.alpha = settings, obs, data, other, alpha
        self.base_excess = base_excess  # the configured model's χ²/dof − 1
        self.screened: list | None = None  # the grammar's candidates, screened once (.naming)
        if other is not None and ("revolution" in obs or "revolution" in other):
            self.other = None  # a servo session's hand mount leaves the true rate unknown
        # Time is not temperature only where each point soaks at one temperature (not a sweep).
        self.soaked = bool(
            "point" in obs
            and float(obs.groupby("point")["temp"].agg(lambda t: t.max() - t.min()).max()) < SOAKED_SPREAD
        )
        # The session's noise model has slow terms (bias instability, rate random walk):
        # holds close in time share their wander, which groups them by time.
        self.slow_known = any(
            float(np.nanmax(obs[f"{k}_{a}"])) > 0
            for k in ("flicker", "rrw")
            for a in AXES
            if f"{k}_{a}" in obs
        )

    def carry(self, ev: Evaluation) -> CarryOver | None:
        """:func:`carry_over` to the other session; None without one, ``{"error": ...}``
        when this model cannot be applied there (a term reading an input it lacks)."""
        if self.other is None:
            return None
        try:
            return carry_over(self.settings, ev, self.obs, self.other)
        except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: note it
            return {"error": reason(exc) if isinstance(exc, GyrocalError) else f"{type(exc).__name__}: {exc}"}

    def leftover(self, ev: Evaluation) -> Leftover:
        return leftover(self.obs, self.data, ev)

    def explains(self, ext: Evaluation, candidate: Candidate, base_next, tolerance) -> bool:
        half = self.alpha / 2
        candidate.second_question = False  # a pair starts as a copy of its first term
        candidate.leftover = left = self.leftover(ext)
        candidate.next_session = nxt = self.carry(ext) if usable(base_next) else None
        # Structure left over counts when it is real and not negligible. The right effect
        # fitted in a shape some per cent off leaves real but tiny structure; negligible is
        # small beside the effect (2 % of the excess, a shape about 15 % off in amplitude)
        # and beside the floor (within 1.2 times it). A wrong term that merely correlates
        # with the effect leaves more.
        sizeable = left["chi2_red_share"] > min(
            LEFTOVER_FRACTION * self.base_excess, NEGLIGIBLE_OVER_FLOOR**2 - 1.0
        )
        structure = sizeable and left["p_value"] < half
        validated = ext.summary["held_out"] != "none"
        in_chance = (
            float(chi2_sf(ext.chi2, ext.dof)) >= half
            or (validated and ext.summary["validation_rms"] <= ext.summary["expected_rms"] * tolerance)
            or (not validated and usable(nxt) and nxt["validation_rms"] <= nxt["expected_rms"] * tolerance)
        )
        # Slow noise lines residuals up with time and nothing else: structure in rate, mount
        # or temperature is an effect, and structure in time is one too unless slow noise is
        # known, from the static data's noise model or from two sessions that differ by more
        # than the floor (unrepeated_p_value).
        slow = self.slow_known or slow_noise(nxt, self.alpha)
        exempt = self.soaked and slow and left["covariate"] in TIME_LIKE
        if not usable(nxt):
            # A fit that could not be validated by leaving points out is judged by the
            # other session or not at all. One that reaches the floor out of sample is the
            # primary fix though what it leaves follows time within the points (a package
            # still settling, slow noise): that is a second question, which another session
            # answers (the verdict says so), not a reason to withhold the fix.
            # against the noise alone: a misfit that raises its own bar (the fit's covariance
            # scaled by its χ²/dof) is no fix that reaches the floor
            bar = noise_only(ext).summary["expected_rms"]
            held_out = validated and ext.summary["validation_rms"] <= bar * tolerance
            second = held_out and left["covariate"] in TIME_LIKE
            candidate.second_question = bool(structure and second and not exempt)
            return validated and in_chance and (not structure or exempt or second)
        # Two independent looks at what is left, combined (Fisher): its structure in this
        # session and its repetition in the other (where they share cells to compare). What
        # is left is within chance, or known to be slow noise; and the other session is no
        # worse than with the configured model.
        repeat = nxt["repeat_p_value"]
        combined = 1.0 if repeat is None else repeat
        if sizeable and not exempt:
            combined = left["p_value"] if repeat is None else fisher_combined(left["p_value"], repeat)
        nxt["left_p_value"] = combined
        # Where the calibration fails on the other session in practice, a term that leaves that
        # failure as it was answers this session's excess, not what the user meets.
        untouched = (
            fails_in_practice(base_next)
            and fails_in_practice(nxt)
            and not practical_gain_next(base_next, candidate, 1.0)
        )
        if (
            combined >= half
            and (in_chance or slow)
            and nxt["validation_rms"] <= base_next["validation_rms"]
            and not untouched
        ):
            return True
        # Where the configured model fails on the other session and this term carries the
        # calibration there, taking a practical part of that failure, it is the fix the
        # user needs; what it leaves in this session is a second question, after it.
        carried = (
            fails_in_practice(base_next)
            and not fails_in_practice(nxt)
            and practical_gain_next(base_next, candidate, 1.0)
        )
        candidate.second_question = bool(carried and structure)
        return bool(carried)


# A bias drifting linearly in time, fitted per temperature point on a grid: not an effect of
# the library but the rival every soaked protocol must rule out (a warm-up, a ramp).
TIME_DRIFT = {"name": "expression", "formula": "t"}


def time_drift(
    judge: Judge, settings, obs, base: Evaluation, base_next, tolerance, bound
) -> TimeDrift | None:
    """How far a bias drifting in time within each temperature point takes the held-out
    error, and whether it explains the excess as a named term would have to; None where time
    within a point is not separable from temperature (a sweep) or the fit cannot be made."""
    if not judge.soaked or "t_start" not in obs:
        return None
    try:
        ev = evaluate(extended(settings, TIME_DRIFT), obs, "bias drifting in time")
    except GyrocalError:
        return None
    probe = Candidate("expression(formula='t')", "ranked")
    explains = judge.explains(ev, probe, base_next, tolerance)
    gain = practical_gain(base, float(ev.summary["validation_rms"]), bound)
    return TimeDrift(
        validation_rms=ev.summary["validation_rms"],
        expected_rms=ev.summary["expected_rms"],
        explains=bool(explains and gain),
        option=add_term_option(make_term(TIME_DRIFT).spec_string()),
        config_line=config_line(extended(settings, TIME_DRIFT).model),
        leftover=probe.leftover,
        next_session=probe.next_session,
    )


def extended_all(settings: Settings, best: Candidate) -> Settings:
    for spec in (best.term, *best.together):
        settings = extended(settings, spec)
    return settings


def second_step(
    judge: Judge,
    first: Candidate,
    ranked: list[Candidate],
    base_rms: float,
    tolerance: float,
    *,
    in_sample: bool = False,
) -> Candidate | None:
    """``first`` with one more term that, added on top, explains the excess (F-test of the
    second addition, Bonferroni over the pairs tried) and lowers the held-out error by more
    than that figure's own uncertainty (:func:`chance_bound` of the holds scored): a second
    term earns its place on holds the fit did not see; None when no pair does."""
    settings, obs, alpha = judge.settings, judge.obs, judge.alpha
    try:
        start = evaluate(extended(settings, first.term), obs, first.term, in_sample=in_sample)
    except GyrocalError:
        return None
    start_next = judge.carry(start) if judge.other is not None else None
    others = [c for c in ranked if c is not first and c.term not in first.tied_with]
    found = []
    for c in others:
        try:
            ext = evaluate(extended(extended(settings, first.term), c.term), obs, c.term, in_sample=in_sample)
        except Exception:  # noqa: BLE001 - as for single candidates: not a pair to name
            continue
        df_num, df_den = start.dof - ext.dof + _added_nonlinear(start, ext), ext.dof
        if df_num <= 0 or df_den <= 0 or len(ext.fitted.used_points()) != len(start.fitted.used_points()):
            continue
        f_stat = ((start.chi2 - ext.chi2) / df_num) / (ext.chi2 / df_den)
        p = float(f_sf(f_stat, df_num, df_den))
        if p >= alpha / 2 / max(len(others), 1):
            continue
        held = ext.summary["held_out"] != "none"
        if (
            held
            and ext.summary["validation_rms"] * chance_bound(ext.summary["holds_scored"], alpha)
            >= first.validation_rms_with
        ):
            continue  # the second term must help on the holds left out, beyond chance
        if not held:  # nothing left out to judge it on here: the other session must gain
            there = judge.carry(ext) if usable(start_next) else None
            if not (
                usable(there)
                and there["validation_rms"] * chance_bound(start_next["holds_scored"], alpha)
                < start_next["validation_rms"]
            ):
                continue
        pair = replace(first, together=[c.term])
        if judge.explains(ext, pair, start_next, tolerance):
            found.append((ext.summary["validation_rms"], c.term, ext, pair))
    found = _carrying_pairs(judge, first, found, alpha)
    if not found:
        return None
    # What the user will meet decides: the other session where there is one; otherwise,
    # among the pairs as good as the best within the figure's own uncertainty, the one that
    # adds fewest coefficients (a flexible partner fits the session's own wander too).
    there = [
        f[3].next_session if usable(f[3].next_session) else judge.carry(f[2]) if usable(start_next) else None
        for f in found
    ]
    v_next = [t["validation_rms"] if usable(t) else np.inf for t in there]
    if np.isfinite(v_next).any():
        v, term, ext, pair = found[int(np.argmin(v_next))]
    else:
        top = min(f[0] for f in found)
        bound = chance_bound(min(f[2].summary["holds_scored"] for f in found), alpha)
        close = [f for f in found if f[0] <= top * bound]
        v, term, ext, pair = min(close, key=lambda f: (pair_df(start, f[2]), f[0]))
    return replace(
        pair,
        profiled=list(getattr(ext.fitted, "profiled", ()) or first.profiled),
        validation_rms_with=v,
        expected_with=ext.summary["expected_rms"],
        explains_excess=True,
        alone_rms=first.validation_rms_with,
        gain_pct=100.0 * (1 - v / base_rms),
        chi2=ext.chi2,
        df=(first.df[0] + pair_df(start, ext), ext.dof),
    )


def _carrying_pairs(judge: Judge, first: Candidate, found: list, alpha: float) -> list:
    """The pairs that carry to a rate level they never saw as well as ``first`` alone does,
    within chance (:func:`chance_bound` of the holds left out) or within
    :data:`~.grain.CARRIES_WITHIN`: a partner that fits its own session's levels and misses
    the one left out fits what the first leaves of this session, not an effect. Where the
    protocol allows no such grain, every pair stands."""
    from .grain import CARRIES_WITHIN, at_the_grain

    settings, obs = judge.settings, judge.obs
    alone = at_the_grain(settings, extended(settings, first.term), obs, "rate level", first.profiled)
    if alone is None or alone.fix is None:
        return found
    bar = max(alone.fix * chance_bound(alone.holds, alpha), CARRIES_WITHIN)
    kept = []
    for entry in found:
        ext, pair = entry[2], entry[3]
        fixed = extended(extended(settings, first.term), pair.together[0])
        profiled = getattr(ext.fitted, "profiled", ()) or ()
        grain = at_the_grain(settings, fixed, obs, "rate level", profiled)
        if grain is None or grain.fix is None or grain.fix <= bar:
            kept.append(entry)
    return kept


def pair_df(start: Evaluation, ext: Evaluation) -> int:
    """The coefficients (and profiled settings) a second term adds on top of the first."""
    return start.dof - ext.dof + _added_nonlinear(start, ext)


def practical_gain(base: Evaluation, c: Candidate | float, bound: float) -> bool:
    """A term (or a model reaching the validation RMS ``c``) takes away a practical part of
    the excess: the configured model's held-out error is above what a correct model leaves
    by more than the validation's own uncertainty (``bound``, :func:`chance_bound` of the
    holds scored), and the term lowers it by more than that uncertainty and by at least a
    quarter of the excess."""
    v0, expected = base.summary["validation_rms"], base.summary["expected_rms"]
    gain = v0 - (c if isinstance(c, float) else c.validation_rms_with)
    return v0 > expected * bound and gain > v0 * (1.0 - 1.0 / bound) and gain >= 0.25 * (v0 - expected)


def gains_where_judged(base: Evaluation, c: Candidate, base_next, bound: float) -> bool:
    """A practical gain where the calibration is judged: on the other session where the
    configured model fails there (:func:`practical_gain_next`), for that is what the user
    meets, and a term that leaves it failing as before fixes nothing they will see;
    otherwise on the points left out (:func:`practical_gain`), or on the other session
    for a term no point could be left out for. Terms of free shape are judged so; the
    library's count their held-out gain beside it (:func:`.steps.library_search`: half of a
    pair the other session needs whole)."""
    if usable(base_next) and fails_in_practice(base_next):
        return practical_gain_next(base_next, c, bound)
    if c.validated:
        return practical_gain(base, c, bound)
    return practical_gain_next(base_next, c, bound)


def practical_gain_next(base_next, c: Candidate, bound: float) -> bool:
    """:func:`practical_gain` on the other session: for a term no point could be left out
    for, what its calibration takes away there is the held-out gain."""
    if not (usable(base_next) and usable(c.next_session)):
        return False
    v0, expected = base_next["validation_rms"], base_next["expected_rms"]
    gain = v0 - c.next_session["validation_rms"]
    return v0 > expected * bound and gain > v0 * (1.0 - 1.0 / bound) and gain >= 0.25 * (v0 - expected)


def mark_ties(tested: list[Candidate]) -> None:
    """Candidates of as many coefficients whose extended fits the data cannot tell apart:
    their χ² within one of each other (a likelihood ratio under e^½), as where they add
    the same columns in this protocol's span (a quadratic and an asymmetric scale at one
    speed; a g-sensitivity and its square where the accelerometer reads 0 or 1 g)."""
    for c in tested:
        c.tied_with = [
            o.term
            for o in tested
            if o is not c
            and o.df == c.df
            and abs(o.chi2 - c.chi2) <= max(1e-6 * max(c.chi2, 1e-300), TIE_CHI2)
        ]


TIE_CHI2 = 1.0


def rank_candidates(
    judge: Judge, base: Evaluation, names: list[str], base_next, tolerance, *, in_sample: bool = False
) -> list[Candidate]:
    """Every candidate added to the configured model in turn, refitted, validated, tested
    against the model (nested F-test, Bonferroni over the candidates tested) and judged
    (:meth:`Judge.explains`); ranked by the validation RMS they reach, then the candidates
    that could not be fitted, with their reason. A library term the protocol cannot
    identify is followed by the part of it the protocol can see, judged the same way."""
    alpha = judge.alpha
    candidates: list[Candidate] = []
    tested = []
    queue = [(spec, None) for spec in names]
    in_sample_base: list = []  # the configured model's in-sample figure, made when needed
    while queue:
        spec, part_of = queue.pop(0)
        candidate, unfitted = _try(
            judge, base, spec, part_of, base_next, tolerance, in_sample, in_sample_base
        )
        candidates.append(candidate)
        if candidate.status == "ranked":
            tested.append(candidate)
        elif unfitted and part_of is None:
            part = _seen_part(judge.settings, judge.obs, spec)
            if part is not None:
                queue.insert(0, (part, spec))
        elif candidate.reason == FEWER_POINTS and part_of is None:
            shared = _one_set_for_the_session(spec)
            if shared is not None:
                queue.insert(0, (shared, spec))
    for c in tested:  # Bonferroni over the candidates actually tested
        c.significant = c.p_value < alpha / 2 / max(len(tested), 1)
    for c in candidates:  # the full term's reason stays with the part that was fitted
        if c.status == "not identifiable":
            c.seen_part = next((t.term for t in tested if t.part_of == c.term), None)
    mark_ties(tested)
    ranked = sorted(tested, key=lambda c: c.validation_rms_with)
    return ranked + [c for c in candidates if c.status != "ranked"]


def _try(
    judge: Judge, base, spec, part_of, base_next, tolerance, in_sample, in_sample_base
) -> tuple[Candidate, bool]:
    """One candidate added to the model, fitted, tested and judged; or why it could not be,
    with whether the fit itself refused it (then a part of it may be identifiable)."""
    settings, obs, data = judge.settings, judge.obs, judge.data
    term = make_term(spec)
    if term.moving_temperature and judge.soaked:
        why = "the temperature holds still within every point: it changes nothing there"
        return Candidate(spec, "not identifiable", reason=why), False
    series = "series" in data
    missing = sorted(
        c
        for c in term.needs
        if c not in data and not c.startswith("rate_") and not (series and c in SERIES_INPUTS)
    )
    if missing:
        return Candidate(spec, "missing inputs", reason=f"needs {', '.join(missing)}"), False
    try:
        ext = evaluate(extended(settings, spec), obs, spec, in_sample=in_sample)
    except MissingInputError as exc:
        return Candidate(spec, "missing inputs", reason=reason(exc)), False
    except GyrocalError as exc:
        excited = _excited(extended(settings, spec), term, data)
        return Candidate(spec, "not identifiable", reason=reason(exc), excited=excited), True
    except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: report it
        return Candidate(spec, "failed", reason=f"{type(exc).__name__}: {exc}"), False
    df_num, df_den = base.dof - ext.dof + _added_nonlinear(base, ext), ext.dof
    problem = (
        FEWER_POINTS
        if len(ext.fitted.used_points()) != len(base.fitted.used_points())
        else "it adds no coefficient to the model"
        if df_num <= 0
        else "it leaves no degree of freedom"
        if df_den <= 0
        else None
    )
    if problem:
        return Candidate(spec, "not identifiable", reason=problem), False
    f_stat = ((base.chi2 - ext.chi2) / df_num) / (ext.chi2 / df_den)
    added = [c for c in ext.fitted.names if c not in base.fitted.names]
    size, peak = effect_size(ext, spec, added, data)
    v0, v1 = base.summary["validation_rms"], ext.summary["validation_rms"]
    if ext.summary["held_out"] == "none":
        # Scored in sample (no point could be left out): beside the configured model's
        # in-sample figure, on the same holds, never beside its held-out one.
        if not in_sample_base:
            in_sample_base.append(in_sample_summary(base.fitted, obs)["validation_rms"])
        v0 = in_sample_base[0]
    candidate = Candidate(
        spec,
        "ranked",
        v1,
        float(f_sf(f_stat, df_num, df_den)),
        float(f_stat),
        (df_num, df_den),
        100.0 * (1 - v1 / v0),
        False,
        size,
        peak,
        expected_with=ext.summary["expected_rms"],
        base_rms=v0,
    )
    candidate.chi2 = ext.chi2
    candidate.validated = ext.summary["held_out"] != "none"
    candidate.part_of = part_of
    candidate.profiled = list(getattr(ext.fitted, "profiled", ()) or ())
    candidate.explains_excess = judge.explains(ext, candidate, base_next, tolerance)
    return candidate, False


def _added_nonlinear(base: Evaluation, ext: Evaluation) -> int:
    """The profiled settings (a time constant) an extension adds: parameters of the F-test
    as its coefficients are."""
    return len(_profiled(ext) - _profiled(base))


def _profiled(ev: Evaluation) -> set:
    """The nonlinear settings a fit found by profiling and the data identified."""
    return {
        (p["term"], p["parameter"])
        for p in getattr(ev.fitted, "profiled", ()) or ()
        if p.get("identified", True)
    }


FEWER_POINTS = "it leaves fewer temperature points"


def _one_set_for_the_session(spec) -> str | None:
    """A per-point term as one set of coefficients for the whole session (``scope=global``):
    where some point's holds cannot separate the term's coefficients from the base ones (a
    point with few rate levels, say), a per-point fit drops that point, while one set fitted
    over all points needs only that the points together excite it. What it cannot carry is
    the effect's change with temperature, which its held-out score then shows."""
    term = make_term(spec)
    if term.coefficient_scope != "point" or isinstance(term, Restricted):
        return None
    return make_term({**parse_spec(term.spec_string()), "scope": "global"}).spec_string()


def _seen_part(settings, obs, spec) -> str | None:
    try:
        return identifiable_part(settings, obs, spec)
    except GyrocalError:
        return None


def _excited(settings, term, data) -> bool:
    """Whether any of ``term``'s columns is not zero on the holds."""
    try:
        model = settings.model.build()
        design = model.design(model.transform_inputs(data))
    except Exception:  # noqa: BLE001 - a term that cannot even be evaluated: say nothing of it
        return False
    return any(np.any(np.asarray(design[c]) != 0) for c in term.coefficients() if c in design)
