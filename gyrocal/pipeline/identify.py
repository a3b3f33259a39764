"""Terms beyond a protocol's own model, kept for a unit only where its data can tell them
apart from that model and they do not make its held-out error worse.

A term added fleet-wide (or for a batch) meets units without its effect. There, a profiled
parameter runs to a bound (a warm-up's time constant four times the session: the decay is
then a constant and a slope, the bias and a drift), or the term's columns nearly repeat the
model's own, and the bias becomes an extrapolation whose standard error grows thirtyfold.
The fit is no worse, but the parameters end of line judges and drift audits compare no
longer mean what they say. Such a term is dropped for that unit, with the reason recorded
(``added_terms`` and a ``term_dropped`` warning in the calibration file); every added term,
kept or dropped, also gets the held-out figure of the model with and without it, so that a
fleet-wide term shows, unit by unit, whether it helped. A term the data do identify may
still cost a unit held-out error (a nonlinearity, fitted to a unit that warms up, bends its
interpolation between temperature points): where the error with it exceeds the one without
it beyond chance, it is dropped too.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from typing import Any, TypedDict

import numpy as np
import pandas as pd

from ..fit.thermal import ContinuousFit, GridFit, JointGridFit, fit_model
from ..fit.validate import CannotLeaveOut, validate
from ..io.errors import GyrocalError, IdentifiabilityError, MissingInputError
from ..terms import AXES, make_term
from ..terms.signals import HOLD_INPUTS, SERIES_INPUTS
from .config import Settings

# A standard error of the protocol's own coefficients grown by more than this factor: the
# variance inflation factor of 10 that regression texts call serious collinearity. A term
# the data identify leaves them about as they were (a true warm-up: 0.9 to 1.1 times), one
# they cannot tell from the bias multiplies them by 30 to 50 (the demo's units).
MAX_INFLATION = math.sqrt(10.0)


class HeldOut(TypedDict):
    """A model's leave-temperature-out figures (its validation summary's; None where not
    finite), as a calibration file's ``added_terms`` records them with and without a term."""

    validation_rms: float | None
    noise_floor: float | None
    expected_rms: float | None
    excess: float | None
    excess_over_expected: float | None
    held_out: str | None  # what was held out: "temperature" or "hold"
    holds_scored: float | None


class BiasInSession(TypedDict):
    """Each temperature point's bias as the session measured it (:func:`bias_in_session`)."""

    terms: list[str]  # the session's terms it includes
    temperatures: list[float]
    bias: list[list[float]]  # per point, per output axis, deg/s
    stderr: list[list[float]]


@dataclass(frozen=True)
class AddedTerm:
    """One term beyond the protocol's own model, as a unit's data judge it."""

    term: str  # as configured
    kept: bool
    reason: str | None = None  # why it was dropped
    inflation: float | None = None  # the largest growth of an own coefficient's standard error
    inflated: str | None = None  # that coefficient
    with_term: HeldOut | None = None  # held-out figures of the model with the term
    without_term: HeldOut | None = None
    weakly: str | None = None  # kept for its gain though the data do not identify it: why

    def to_dict(self) -> dict[str, Any]:
        return {
            "term": self.term,
            "kept": self.kept,
            "reason": self.reason,
            "inflation": self.inflation,
            "inflated": self.inflated,
            "with": self.with_term,
            "without": self.without_term,
            **({"not_identified": self.weakly} if self.weakly else {}),
        }


@dataclass(frozen=True)
class Identified:
    """The model a unit is calibrated with: the settings without the dropped terms, its fit,
    and every added term's record."""

    settings: Settings
    fitted: object
    added: tuple[AddedTerm, ...]

    @property
    def dropped(self) -> list[str]:
        return [a.term for a in self.added if not a.kept]


def own_terms(protocol: str | None) -> set:
    """Identities of the terms every unit of the protocol is fitted with: its default model's."""
    return {t.identity for t in Settings().for_protocol(protocol).model.build().terms}


def added_terms(settings: Settings, protocol: str | None) -> list[str]:
    """The model's terms beyond the protocol's own, as the settings write them; in a model
    continuous in temperature, the terms of temperature it needs are its own."""
    own = own_terms(protocol)
    continuous = settings.model.kind == "continuous"
    terms = [make_term(spec) for spec in settings.model.term_specs()]
    return [
        t.spec_string()
        for t in terms
        if t.identity not in own and not (continuous and t.varies_with_temperature)
    ]


def without(settings: Settings, specs) -> Settings:
    """``settings`` with the terms of ``specs`` (by identity) left out of the model; the
    fleet's model (:attr:`Settings.fleet`) stays what it was."""
    gone = {make_term(s).identity for s in specs}
    m = settings.model
    terms = tuple(t for t in m.terms if make_term(t).identity not in gone)
    expressions = tuple((label, value) for label, value in m.expressions if ("expression", label) not in gone)
    return replace(
        settings, model=replace(m, terms=terms, expressions=expressions), fleet_model=settings.fleet
    )


def fit_of(settings: Settings, obs: pd.DataFrame, source=None):
    m = settings.model
    return fit_model(m.build(), obs, kind=m.kind, method=m.interpolation, degree=m.degree, source=source)


class _Fits:
    """Each model fitted, and validated, once: the checks and the figures ask again."""

    def __init__(self, obs: pd.DataFrame, source):
        self.obs, self.source = obs, source
        self.fitted: dict[str, GridFit | ContinuousFit | JointGridFit] = {}
        self.held: dict[str, HeldOut | None] = {}

    @staticmethod
    def key(settings: Settings) -> str:
        return json.dumps([settings.model.term_specs(), settings.model.kind], sort_keys=True, default=str)

    def __call__(self, settings: Settings):
        key = self.key(settings)
        if key not in self.fitted:
            self.fitted[key] = fit_of(settings, self.obs, self.source)
        return self.fitted[key]

    def held_out(self, settings: Settings) -> HeldOut | None:
        """The model's leave-temperature-out figures (None where it cannot be fitted or
        validated on these observations)."""
        key = self.key(settings)
        if key not in self.held:
            try:
                fitted = self(settings)
                s = validate(
                    fitted.model,
                    self.obs,
                    fitted,
                    reference_temperature=settings.model.reference_temperature,
                    every_point=False,
                ).summary
                self.held[key] = HeldOut(
                    validation_rms=_finite(s.get("validation_rms")),
                    noise_floor=_finite(s.get("noise_floor")),
                    expected_rms=_finite(s.get("expected_rms")),
                    excess=_finite(s.get("excess")),
                    excess_over_expected=_finite(s.get("excess_over_expected")),
                    held_out=_finite(s.get("held_out")),
                    holds_scored=_finite(s.get("holds_scored")),
                )
            except (GyrocalError, CannotLeaveOut):
                self.held[key] = None
        return self.held[key]


def identify(
    settings: Settings, obs: pd.DataFrame, protocol: str | None, *, source=None, held_out: bool = True
) -> Identified:
    """Fit ``settings.model`` to a unit's observations, dropping each term beyond the
    protocol's own model that the data cannot identify (a profiled parameter at a bound of
    its search, a standard error of the protocol's own coefficients grown beyond
    :data:`MAX_INFLATION` times by it, parameters the fit refuses as not excited, inputs the
    log lacks, a calibration no longer validated by leaving temperature points out) unless it
    lowers the held-out error beyond chance (then it is kept, said to be not identified),
    and each that raises this unit's held-out error beyond chance, identified or not.
    Dropping one term can free another, so the check runs again until nothing more is
    dropped. ``held_out``: each added term's leave-temperature-out
    figures with and without it."""
    extra = added_terms(settings, protocol)
    fit = _Fits(obs, source)
    if not extra:
        return Identified(settings, fit(settings), ())
    own = without(settings, extra)
    reasons: dict[str, tuple[str, float | None, str | None]] = {}
    alpha = settings.diagnosis.significance
    while True:
        kept = [s for s in extra if s not in reasons]
        current = without(settings, reasons)
        try:
            fitted = fit(current)
        except (IdentifiabilityError, MissingInputError) as exc:
            culprits = _culprits(kept, exc)
            if not culprits:
                raise
            what = (
                "the data do not excite it"
                if isinstance(exc, IdentifiabilityError)
                else "the log lacks what it reads"
            )
            reasons.update({s: (f"{what} ({_message(exc)})", None, None) for s in culprits})
            continue
        share = _shares(fit, own, current, fitted, kept)
        found, weak = _judged(fit, current, fitted, kept, share, alpha)
        if not found:
            break
        reasons.update(found)
    records = []
    for spec in extra:
        reason = reasons.get(spec)
        growth: float | None
        growth, name = share[spec] if reason is None else (reason[1], reason[2])
        with_term = without_term = None
        if held_out:
            with_term = fit.held_out(without(settings, [s for s in reasons if s != spec]))
            without_term = fit.held_out(without(current, [spec]))
        records.append(
            AddedTerm(
                spec,
                reason is None,
                None if reason is None else reason[0],
                _finite(growth),
                name,
                with_term,
                without_term,
                weak.get(spec) if reason is None else None,
            )
        )
    return Identified(current, fitted, tuple(records))


def _shares(fit: _Fits, own: Settings, current: Settings, fitted, kept: list[str]) -> dict:
    """Each kept term's share of the growth of the protocol's own coefficients' standard
    errors (:func:`_inflation`: the factor and the coefficient): the growth it makes beside
    the others kept; where several share one collinearity, the one whose removal relieves it
    most carries the whole."""
    overall = _inflation(fit(own), fitted, own)
    share = {
        s: overall if len(kept) == 1 else _inflation(fit(without(current, [s])), fitted, own) for s in kept
    }
    if overall[0] > MAX_INFLATION and all(share[s][0] <= MAX_INFLATION for s in kept):
        first = min(kept, key=lambda s: _inflation(fit(own), fit(without(current, [s])), own)[0])
        share[first] = overall
    return share


def _judged(
    fit: _Fits, current: Settings, fitted, kept: list[str], share: dict, alpha: float
) -> tuple[dict[str, tuple[str, float | None, str | None]], dict[str, str]]:
    """The kept terms to drop, with why (and their growth of the standard errors), and those
    kept though not identified, for the gain they bring, with why they are not."""
    found: dict[str, tuple[str, float | None, str | None]] = {}
    weak: dict[str, str] = {}
    for spec in kept:
        why = _at_bound(fitted, spec)
        inflation, name = share[spec]
        if why is None and inflation > MAX_INFLATION:
            why = (
                f"it multiplies the standard error of {name} by {inflation:.3g} (beyond "
                f"{MAX_INFLATION:.3g}): the data cannot tell it from the model's own terms"
            )
        if why is None and fit.held_out(current) is None and fit.held_out(without(current, [spec])):
            why = (
                "with it no temperature point can be left out to validate the calibration, "
                "as it can without it"
            )
        worse = _hurts(current, spec, fit, alpha)
        if worse is not None:
            found[spec] = (worse, inflation, name)
        elif why is not None and not _helps(current, spec, fit, alpha):
            found[spec] = (
                why + ", and it does not lower the held-out error beyond chance",
                inflation,
                name,
            )
        elif why is not None:
            weak[spec] = why
    return found, weak


def bias_in_session(fitted, specs) -> BiasInSession | None:
    """Each temperature point's bias as the session measured it, where terms of the session
    (``specs``, kept though the data cannot tell them from the bias) make the fitted bias an
    extrapolation (a decay's value long after power-on): the bias plus those terms' mean
    over the point's holds, ``b_p + Σ c_j · mean_p(x_j)``, with its standard error from the
    joint fit's covariance. Identified whatever the terms' collinearity: what end of line
    judges and drift audits compare. None for a fit that is not one joint grid."""
    if not specs or fitted.kind != "grid" or not hasattr(fitted, "point_ids"):
        return None
    f = fitted.fit
    index = {n: j for j, n in enumerate(f.names)}
    terms = {make_term(s).identity for s in specs}
    coefficients = [
        n for t in fitted.model.terms if t.identity in terms for n in t.coefficients() if n in index
    ]
    design = fitted.design if fitted.design is not None else fitted.model.design(fitted.data)
    point = np.asarray(fitted.data["point"], dtype=int)
    values, stderr = [], []
    for p in fitted.point_ids:
        at = point == p
        row_v, row_s = [], []
        for axis in AXES:
            g = np.zeros(len(f.names))
            g[index[f"bias.{axis}.@{p}"]] = 1.0
            for name in coefficients:
                if name.split(".")[1] == axis:
                    g[index[name]] = float(
                        np.mean(np.broadcast_to(np.asarray(design[name], float), at.shape)[at])
                    )
            row_v.append(float(g @ f.values))
            row_s.append(float(np.sqrt(max(g @ f.covariance @ g, 0.0))))
        values.append(row_v)
        stderr.append(row_s)
    return BiasInSession(
        terms=sorted(specs),
        temperatures=[float(t) for t in fitted.grid.temperatures],
        bias=values,
        stderr=stderr,
    )


def _culprits(kept: list[str], exc: Exception) -> list[str]:
    """The added terms a fit's refusal names: by their coefficients (not excited), or by
    their spec in the message (an input the log lacks)."""
    unknown = re.search(r"(\w+) is not an input here", str(exc))
    if unknown and unknown.group(1) not in HOLD_INPUTS | SERIES_INPUTS:
        return []  # the term's own mistake, whatever the unit: the one-line error stands
    named = set(getattr(exc, "parameters", ()))
    return [
        s
        for s in kept
        if set(make_term(s).coefficients()) & named or (not named and make_term(s).spec_string() in str(exc))
    ]


def _chance_bound(held: HeldOut, alpha: float) -> float:
    """How far a held-out RMS over ``held``'s holds may differ from another's by chance:
    ``sqrt(χ²_N(1 − α/2) / N)``, N the errors scored (three a hold), as the diagnosis
    judges a gain."""
    # the quantile as scipy.stats' chi2.ppf computes it, without scipy.stats' half-second import
    from scipy.special import gammaincinv

    n = 3 * int(held["holds_scored"] or 0)
    return math.sqrt(2.0 * gammaincinv(n / 2, 1.0 - alpha / 2) / n)


def _hurts(settings: Settings, spec: str, fit: _Fits, alpha: float) -> str | None:
    """Why ``spec`` is dropped whatever the data say of it: with it, the held-out error of
    this unit is larger than without it beyond that figure's own uncertainty (a term for
    another unit's effect that this one's interpolation between temperature points pays
    for). None where it is not."""
    with_term, without_term = fit.held_out(settings), fit.held_out(without(settings, [spec]))
    if not with_term or not without_term or not without_term.get("holds_scored"):
        return None
    rms, rms_without = with_term["validation_rms"], without_term["validation_rms"]
    if rms is None or rms_without is None or rms <= rms_without * _chance_bound(without_term, alpha):
        return None
    return (
        f"it raises the held-out error from {without_term['excess']:.3g} to "
        f"{with_term['excess']:.3g} times the floor, beyond chance"
    )


def _helps(settings: Settings, spec: str, fit: _Fits, alpha: float) -> bool:
    """Whether the model with ``spec`` leaves a held-out error below the one without it by
    more than that figure's own uncertainty over the holds scored (``sqrt(χ²_N(1 − α/2) /
    N)``, N the errors scored, as the diagnosis judges a gain): a drift the data cannot tell
    from the bias may still be what a unit's compensation needs."""
    with_term, without_term = fit.held_out(settings), fit.held_out(without(settings, [spec]))
    if not with_term or not without_term or not with_term.get("holds_scored"):
        return False
    rms, rms_without = with_term["validation_rms"], without_term["validation_rms"]
    return rms is not None and rms_without is not None and rms * _chance_bound(with_term, alpha) < rms_without


def _message(exc: BaseException) -> str:
    """An error's message without the file it names."""
    text = str(exc)
    return text.split(": ", 1)[1] if text.startswith("/") and ": " in text else text


def _label(spec) -> str:
    term = make_term(spec)
    inner = getattr(term, "term", term)
    return getattr(inner, "label", None) or inner.name


def _at_bound(fitted, spec) -> str | None:
    """Why a term's profiled parameter says it is not identified: at a bound of its search."""
    label = _label(spec)
    for p in getattr(fitted, "profiled", ()) or ():
        if p.get("term") == label and p.get("at_bound"):
            lo, hi = p["bounds"]
            side = "upper" if p["value"] >= math.sqrt(lo * hi) else "lower"
            return (
                f"{p['parameter']} = {p['value']:.4g} is at the {side} bound of its search "
                f"({lo:g} to {hi:g}): the data do not fix it"
            )
    return None


def _errors(fitted, names) -> dict:
    """(coefficient, temperature point) -> standard error as the calibration reports it."""
    fits = fitted.fits
    used = fitted.used_points()
    per_point = len(fits) > 1 and len(fits) == len(used)  # a grid's fits, one per point
    out = {}
    for k, f in enumerate(fits):
        for name, se in zip(f.names, f.stderr, strict=False):
            base, _, at = name.partition(".@")
            if base in names:
                out[(base, int(at) if at else (used[k] if per_point else None))] = float(se)
    return out


def _inflation(own_fit, fitted, own: Settings) -> tuple[float, str | None]:
    """The largest ratio of a protocol's own coefficient's standard error with the added
    terms to without, over its temperature points, and that coefficient. The errors are the
    reported ones, scaled by each fit's residual: a term that does not lower the held-out
    error (the only one dropped) leaves that scale as it was, and the ratio is then the
    square root of the variance inflation factor."""
    names = set(own.model.build().names)
    before, after = _errors(own_fit, names), _errors(fitted, names)
    ratios = [(after[k] / before[k], k[0]) for k in before if k in after and before[k] > 0]
    return max(ratios, default=(1.0, None))


def _finite(value):
    if isinstance(value, str) or value is None:
        return value
    value = float(value)
    return value if math.isfinite(value) else None
