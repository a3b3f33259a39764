"""Models the diagnosis compares: the configured one and its extensions, each fitted and
validated leaving temperature points out, and the config that writes them."""

from __future__ import annotations

import json
import math
import re
import shlex
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import pandas as pd

from ..fit.model import columns_of, observation_floor
from ..fit.thermal import fit_model
from ..fit.validate import CannotLeaveOut, ValidationFigures, own_power_ons, validate
from ..io.errors import GyrocalError
from ..pipeline.config import Settings
from ..terms import AXES, TERMS, make_term
from ..terms.effects import CANDIDATES
from .between import drift_chord


@dataclass
class Evaluation:
    """A model fitted and validated: what the diagnosis compares."""

    name: str
    terms: list[str]
    kind: str
    fitted: object
    summary: dict
    chi2: float
    dof: int


def evaluate(
    settings: Settings, obs: pd.DataFrame, name: str = "model", *, in_sample: bool = False
) -> Evaluation:
    """``settings.model`` fitted to ``obs`` and validated leaving temperature points out.
    ``in_sample``: where no point can be left out (a term whose shape lies within one
    point's stretch of time: without the point it is a copy of the points' biases), the
    summary of the fit's own residuals instead, marked ``held_out: "none"``."""
    m = settings.model
    model = m.build()
    # The same model on the same holds is asked for more than once (a ladder step that is
    # also a candidate): fitted and validated once. Entries keep their holds alive, so an
    # id is not reused while cached.
    key = (
        id(obs),
        tuple(t.spec_string() for t in model.terms),
        m.kind,
        m.interpolation,
        m.degree,
        m.reference_temperature,
        in_sample,
    )
    for held, k, ev in _EVALUATED:
        if held is obs and k == key:
            return replace(ev, name=name)
    fitted = fit_model(model, obs, kind=m.kind, method=m.interpolation, degree=m.degree)
    try:
        summary = validate(fitted.model, obs, fitted, reference_temperature=m.reference_temperature).summary
    except CannotLeaveOut:
        if not in_sample:
            raise
        summary = in_sample_summary(fitted, obs)
    ev = with_drift_chord(evaluation_of(settings, fitted, summary, name), obs)
    _EVALUATED.insert(0, (obs, key, ev))
    del _EVALUATED[EVALUATIONS_KEPT:]
    return ev


EVALUATIONS_KEPT = 16
_EVALUATED: list = []


def in_sample_summary(fitted, obs) -> ValidationFigures:
    """A validation summary's figures from a fit's own residuals: RMS, floor, and the floor
    as what a correct model would leave (its own fit removes a little more)."""
    from ..fit.thermal import in_sample

    resid, floor, rows = in_sample(fitted, len(obs))
    rms = float(np.sqrt(np.mean(resid[rows] ** 2)))
    floor_rms = float(np.sqrt(np.mean(floor[rows] ** 2)))
    return {
        "validation_rms": rms,
        "noise_floor": floor_rms,
        "expected_rms": floor_rms,
        "excess": rms / floor_rms,
        "excess_over_expected": rms / floor_rms,
        "held_out": "none",
        "holds_scored": int(rows.sum()),
    }


def evaluation_of(settings: Settings, fitted, summary: dict, name: str = "model") -> Evaluation:
    """A fit of ``settings.model`` and its validation summary, made elsewhere (the analyse
    job's fit and validate stages), as the diagnosis reads them."""
    chi2 = sum(sum(f.chi2.values()) for f in fitted.fits)
    dof = sum(sum(f.dof.values()) for f in fitted.fits)
    return Evaluation(
        name,
        [t.spec_string() for t in fitted.model.terms],
        settings.model.kind,
        fitted,
        _rezeroed(summary),
        chi2,
        dof,
    )


def _rezeroed(summary: dict) -> dict:
    """The figures the diagnosis judges a model by: where temperature points are logged on
    their own, each with the turn-on bias it may hold taken out
    (:func:`gyrocal.fit.validate.own_power_ons`), as the other session's power-ons are
    (:func:`.sessions._turn_on_offsets`). ``validation_rms_as_scored`` keeps the
    validation's own figure."""
    if "rezeroed_rms" not in summary:
        return summary
    rms = summary["rezeroed_rms"]
    return {
        **summary,
        "validation_rms_as_scored": summary["validation_rms"],
        "validation_rms": rms,
        "excess": rms / summary["noise_floor"] if summary["noise_floor"] > 0 else float("inf"),
        "excess_over_expected": rms / summary["expected_rms"]
        if summary["expected_rms"] > 0
        else float("inf"),
    }


def with_drift_chord(ev: Evaluation, obs: pd.DataFrame) -> Evaluation:
    """The evaluation with what a correct model leaves on the points left out
    (``expected_rms``) counting the temperature curvature a leave-out from too few points
    cannot interpolate where the calibration does (:func:`.between.drift_chord`):
    ``drift_chord_rms``, the calibration's own difference at the scored holds, scored as the
    held-out error is (rezeroed where it is), less the part its coefficients' noise makes
    (which the bar holds already). Unchanged where a point left out is interpolated by the
    calibration's own rule, or nothing was left out."""
    summary = ev.summary
    if summary.get("held_out") != "temperature" or "drift_chord_rms" in summary:
        return ev
    chord = drift_chord(ev.fitted, obs)
    if chord is None or not chord[2].any():
        return ev
    errors, variance, use = chord
    mean_square = float(np.mean(np.square(errors[use])))
    if "rezeroed_rms" in summary:
        rezeroed = own_power_ons(obs, errors, observation_floor(columns_of(obs)), use)
        mean_square = mean_square if rezeroed is None else rezeroed[0] ** 2
    # the coefficients' covariance is scaled by the fit's χ²/dof: the noise's part is without
    # it (as in noise_only), a misfit's share of their scatter is no noise
    noise = float(np.mean(variance[use])) / max(ev.chi2 / max(ev.dof, 1), 1.0)
    rms = math.sqrt(max(mean_square - noise, 0.0))
    expected = math.hypot(summary["expected_rms"], rms)
    figures = {
        **summary,
        "drift_chord_rms": rms,
        "expected_rms": expected,
        "excess_over_expected": summary["validation_rms"] / expected if expected > 0 else float("inf"),
    }
    return replace(ev, summary=figures)


def noise_only(ev: Evaluation) -> Evaluation:
    """The configured model's evaluation with what a correct model would leave
    (``expected_rms``) made of the noise alone: the floor, and the calibration's uncertainty
    as the noise makes it. A fit's covariance is scaled by its χ²/dof, so a missing effect
    inflates the uncertainty it carries to every held-out hold, and the bar the excess is
    judged against rose with the very excess (a slow pole's misfit put it 80 times above the
    floor). The held-out part ``expected² − floor²`` is the calibration's; divided by χ²/dof
    where that exceeds 1. A candidate keeps its own bar: one that leaves a little misfit is
    judged by the tolerance on it, as before."""
    summary, chi2_red = ev.summary, ev.chi2 / max(ev.dof, 1)
    expected, floor = summary.get("expected_rms"), summary.get("noise_floor")
    if summary.get("held_out") == "none" or expected is None or not floor or chi2_red <= 1.0:
        return ev
    chord = summary.get("drift_chord_rms", 0.0)  # the drift's, not the noise's: kept whole
    calibration = max(expected**2 - floor**2 - chord**2, 0.0)
    bar = math.sqrt(floor**2 + calibration / chi2_red + chord**2)
    figures = {**summary, "expected_rms": bar, "excess_over_expected": summary["validation_rms"] / bar}
    return replace(ev, summary=figures)


def extended(settings: Settings, spec, kind: str | None = None) -> Settings:
    """The settings with ``spec`` added to the model (replacing a term of the same
    identity, so ``bias_temp_poly(degree=3)`` supersedes ``bias_temp_poly(degree=2)``)."""
    model = settings.model.with_terms((spec,))
    return replace(settings, model=replace(model, kind=kind or model.kind))


def candidate_terms(settings: Settings) -> list[str]:
    """The library's candidates and every term of the model's term files whose effect the
    model lacks, plus the candidates the user names (these may also supersede a term of
    the model, e.g. a higher degree); temperature-only terms only for continuous models."""
    model = settings.model.build()
    have = {t.spec_string() for t in model.terms}
    have_keys = {t.identity for t in model.terms}
    files = {str(Path(f).resolve()) for f in settings.model.term_files}
    user_file_terms = [n for n, cls in TERMS.items() if getattr(cls, "source_file", None) in files]
    requested = {make_term(spec).spec_string() for spec in settings.diagnosis.candidates}
    out = []
    for spec in [*CANDIDATES, *settings.diagnosis.candidates, *user_file_terms]:
        term = make_term(spec)
        label = term.spec_string()
        if label in have or label in out or (term.identity in have_keys and label not in requested):
            continue
        if settings.model.kind == "grid" and term.varies_with_temperature:
            continue
        out.append(label)
    return out


def pooled(fits, name: str) -> tuple[float, float]:
    """Inverse-variance mean of one coefficient over the fits (one per temperature point,
    or the single continuous fit) and its standard error."""
    # A joint grid fit holds a point-scope coefficient as ``<name>.@<point>``, one per point.
    pairs = [
        (f.values[j], f.stderr[j])
        for f in fits
        for j, n in enumerate(f.names)
        if n == name or n.split(".@")[0] == name
    ]
    v = np.array([p[0] for p in pairs])
    w = 1.0 / np.maximum(np.array([p[1] for p in pairs]), 1e-300) ** 2
    return float(np.sum(w * v) / np.sum(w)), float(np.sqrt(1.0 / np.sum(w)))


class CoefficientSize(TypedDict):
    """An added coefficient pooled over the fits (:func:`effect_size`)."""

    coefficient: str
    value: float
    stderr: float
    unit: str  # the term's


def effect_size(
    evaluation: Evaluation, spec: str, added: list[str], obs_data: dict
) -> tuple[list[CoefficientSize], float]:
    """Each added coefficient pooled over the fits, and the largest contribution of the
    added term to any observation (deg/s)."""
    fits = evaluation.fitted.fits
    unit = make_term(spec).unit
    size: list[CoefficientSize] = []
    for name in added:
        value, stderr = pooled(fits, name)
        size.append({"coefficient": name, "value": value, "stderr": stderr, "unit": unit})
    model = fits[0].model
    peak = 0.0
    for result, rows in zip(fits, evaluation.fitted.rows, strict=False):
        design = model.design({k: v[rows] for k, v in obs_data.items()})
        for a in AXES:
            contribution = sum(
                result.coef(n) * np.asarray(design[n])
                for n in result.names
                if n.split(".@")[0] in added and n.split(".")[1] == a
            )
            if np.ndim(contribution):
                peak = max(peak, float(np.max(np.abs(contribution))))
    return size, peak


class LadderRow(TypedDict, total=False):
    """A step of the ladder (:func:`ladder`, :func:`fix_row`): the model, its figures on the
    holds left out (in sample where ``in_sample``), the coefficients it adds, its excess on
    the other session (``next_excess``), or the ``error`` that kept it from being fitted."""

    name: str
    kind: str
    terms: list[str]
    validation_rms: float
    noise_floor: float
    expected_rms: float
    excess: float
    chi2_red: float | None
    parameters: list[dict[str, Any]]
    fix: bool
    in_sample: bool
    next_excess: float
    error: str


def ladder(settings: Settings, obs: pd.DataFrame, base: Evaluation, carry=None) -> list[LadderRow]:
    """The base model, then each configured step added to the one before; ``carry``
    (:meth:`gyrocal.diagnosis.effects.Judge.carry`, with another session) gives each the
    figure of its calibration there."""
    rows: list[LadderRow] = [_ladder_row(base, [], carry)]
    current = settings
    for step in settings.diagnosis.ladder:
        for spec in step["add"]:
            current = extended(current, spec, step["kind"])
        if step["kind"] and not step["add"]:
            current = replace(current, model=replace(current.model, kind=step["kind"]))
        try:
            ev = evaluate(current, obs, step["name"])
        except GyrocalError as exc:
            rows.append({"name": step["name"], "error": reason(exc)})
            continue
        except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: report it
            rows.append({"name": step["name"], "error": f"{type(exc).__name__}: {exc}"})
            continue
        added = [c for c in ev.fitted.names if c not in base.fitted.names]
        rows.append(_ladder_row(ev, added, carry))
    return rows


def _ladder_row(ev: Evaluation, added: list[str], carry=None) -> LadderRow:
    params = [
        dict(zip(("coefficient", "value", "stderr"), (name, *pooled(ev.fitted.fits, name)), strict=False))
        for name in added
    ]
    s = ev.summary
    nxt = carry(ev) if carry is not None else None
    return {
        "name": ev.name,
        "kind": ev.kind,
        "terms": ev.terms,
        "validation_rms": s["validation_rms"],
        "noise_floor": s["noise_floor"],
        "expected_rms": s["expected_rms"],
        "excess": s["excess"],
        "chi2_red": ev.chi2 / ev.dof,
        "parameters": params,
        **({"next_excess": nxt["excess"]} if nxt and "excess" in nxt else {}),
    }


def fix_row(best, base: Evaluation) -> LadderRow:
    """The ladder's step of the fix the diagnosis names: the configured model with it, as
    the diagnosis fitted and judged it."""
    floor = base.summary["noise_floor"]
    terms = [*base.terms, best.term, *best.together] if not best.model else best.model["terms"]
    nxt = best.next_session if best.next_session and "excess" in best.next_session else None
    return {
        "name": "+ the fix named below",
        "kind": best.kind or base.kind,
        "terms": terms,
        "validation_rms": best.validation_rms_with,
        "noise_floor": floor,
        "expected_rms": best.expected_with,
        "excess": best.validation_rms_with / floor,
        "chi2_red": best.chi2 / best.df[1] if best.chi2 is not None and best.df else None,
        "parameters": [{k: z[k] for k in ("coefficient", "value", "stderr")} for z in best.size],
        "fix": True,
        "in_sample": not best.validated,
        **({"next_excess": nxt["excess"]} if nxt else {}),
    }


def yaml_scalar(text: str) -> str:
    """``text`` as one YAML scalar, pasted as printed: plain where YAML reads it back as that
    string (a name; not ``yes``, ``null`` or a number), in single quotes otherwise (a spec
    string's own strings are in double quotes)."""
    import yaml

    if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", text) and yaml.safe_load(text) == text:
        return text
    return f"'{text}'" if "'" not in text else json.dumps(text)


def config_line(model) -> str:
    """The ``model:`` lines of the config for ``model`` (a ModelSettings): ``terms: [...]``
    and, when it has any, ``expressions: {...}``. Specs other than plain names are quoted."""
    quote = yaml_scalar
    terms = [make_term(t).spec_string() for t in model.terms]
    lines = ["terms: [" + ", ".join(quote(t) for t in terms) + "]"]
    if model.kind != "grid":
        lines.insert(0, f"kind: {model.kind}")
    if model.expressions:
        lines.append(
            "expressions: {" + ", ".join(f"{k}: {json.dumps(v)}" for k, v in model.expressions) + "}"
        )
    return "\n".join(lines)


def unit_config_line(device: str, settings: Settings, fix: dict) -> str:
    """The lines of the config that give one unit the fix ``fix`` (an offered term as the
    diagnosis writes it: ``term``, ``together``, or a whole ``model``), under ``models:``:
    the terms it adds where the unit has the fleet's model; where it takes an entry already
    (a batch's, a pattern's: a device's own comes first), that entry's settings with the
    whole list of terms."""
    terms = [fix["term"], *(fix.get("together") or ())]
    entry = dict(settings.unit_model[1]) if settings.unit_model else {}
    entry.pop("add", None)
    if fix.get("model"):
        entry.update(kind=fix["model"]["kind"], terms=list(fix["model"]["terms"]), expressions=None)
    elif settings.unit_model is None:
        return f"models:\n  {yaml_scalar(device)}: {{add: [{', '.join(map(yaml_scalar, terms))}]}}"
    else:
        changed = settings.model.with_terms(tuple(terms))
        entry.update(terms=[make_term(t).spec_string() for t in changed.term_specs()], expressions=None)
    return f"models:\n  {yaml_scalar(device)}: {_flow(entry)}"


def _flow(value) -> str:
    """A YAML flow collection of plain settings, each string a pasteable scalar."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{yaml_scalar(str(k))}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if isinstance(value, str):
        return yaml_scalar(value)
    return "null" if value is None else json.dumps(value)


def with_unit_lines(doc: dict[str, Any], device: str | None, settings: Settings) -> dict[str, Any]:
    """A diagnosis' JSON with each offered fix's ``unit_config_line`` for ``device``, and its
    ``config_line`` (the whole fleet's ``model:``) made from the fleet's model rather than
    this unit's (:attr:`gyrocal.pipeline.config.Settings.fleet`)."""
    offers = [
        doc.get("best"),
        *((doc.get("best") or {}).get("also") or ()),
        *(p for p in doc.get("partial") or () if p.get("offered")),
    ]
    for offer in filter(None, offers):
        if not offer.get("model"):
            fleet = settings.fleet.with_terms((offer["term"], *(offer.get("together") or ())))
            offer["config_line"] = config_line(fleet)
        if device:
            offer["unit_config_line"] = unit_config_line(device, settings, offer)
    return doc


def add_term_option(term: str) -> str:
    return "--add-term " + shlex.quote(term)


def model_option(model) -> str:
    """The command-line option that sets the whole model (a ModelSettings): its kind and
    terms, for a fix that changes more than the terms."""
    doc = {"kind": model.kind, "terms": [make_term(t).spec_string() for t in model.terms]}
    return "--settings-json " + shlex.quote(json.dumps({"model": doc}))


def reason(exc: BaseException) -> str:
    """An error's message without the file it names (the diagnosis reports on one log)."""
    text = str(exc)
    return text.split(": ", 1)[1] if text.startswith("/") and ": " in text else text


def identifiable_part(settings: Settings, obs: pd.DataFrame, spec: str) -> str | None:
    """``spec`` restricted to the coefficients this protocol can tell apart from the rest of
    the model (:class:`gyrocal.terms.Restricted`): its columns, weighted by the holds'
    floors as the fit weights them, added one by one in the term's order, each kept only
    while the model's design stays as well conditioned as a fit requires (a third of
    :data:`gyrocal.fit.model.MAX_CONDITION`, for margin). A grid model's point coefficients are
    judged at every point, and a coefficient dependent at any is dropped. None when every
    coefficient can be fitted (the term is not the problem) or none can."""
    from ..fit.model import MAX_CONDITION, axis_of, observation_floor
    from ..terms import Restricted

    term = make_term(spec)
    base = settings.model.build()
    model = extended(settings, spec).model.build()
    data = model.transform_inputs(columns_of(obs))
    design = model.design(data)
    floor = observation_floor(data)
    n = len(floor)
    point = np.asarray(data["point"], dtype=int) if "point" in data else np.zeros(n, dtype=int)
    grid = settings.model.kind == "grid"
    points = np.unique(point) if grid else np.array([0])

    def per_point(name, global_scope):
        column = np.broadcast_to(np.asarray(design[name], dtype=float), (n,))
        if not grid or global_scope:
            return [column]
        return [np.where(point == p, column, 0.0) for p in points]

    scope = {t.spec_string(): t.coefficient_scope == "global" for t in model.terms}
    global_of = {c: scope[t.spec_string()] for t in model.terms for c in t.coefficients()}
    dependent = set()
    for i, axis in enumerate(AXES):
        w = 1.0 / floor[:, i]
        kept = [
            c * w
            for name in base.names
            if axis_of(name) == axis
            for c in per_point(name, global_of.get(name, False))
        ]
        kept = [c / np.linalg.norm(c) for c in kept if np.linalg.norm(c) > 0]
        for name in term.coefficients():
            if axis_of(name) != axis:
                continue
            trial = [c * w for c in per_point(name, global_of[name])]
            trial = [c / np.linalg.norm(c) for c in trial if np.linalg.norm(c) > 0]
            if not trial:
                dependent.add(name)
                continue
            s = np.linalg.svd(np.column_stack(kept + trial), compute_uv=False)
            if s[-1] <= s[0] / (MAX_CONDITION / 3):
                dependent.add(name)
            else:
                kept += trial
    if not dependent or len(dependent) == len(term.coefficients()):
        return None
    prefix = term.name + "."
    return Restricted(
        term, [c.removeprefix(prefix) for c in term.coefficients() if c in dependent]
    ).spec_string()
