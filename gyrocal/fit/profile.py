"""Nonlinear parameters of effect terms (a time constant, a lag), fitted by profiling.

A term's ``profile`` names settings the model is not linear in, each with bounds. For a
given value the model is linear, so its least-squares fit gives the weighted residual sum
χ²(θ); the profile minimises it over θ: a log-spaced scan of the bounds (which guards
against local minima), then a bounded 1-D search around the best scan point. The standard
error comes from the profile's curvature, ``σ² = 2 s² / (d²χ²/dθ²)`` with ``s²`` the
reduced χ² (the coefficient covariances are scaled the same way), taken on log θ and
carried to θ. Several nonlinear parameters are profiled one after another, twice round.
Every value is judged on the temperature points the fit at the start values kept: a value
that loses a point would win on a smaller χ² for that alone, so it is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..io.errors import GyrocalError
from .model import Model

SCAN_POINTS = 13


def total_chi2(fitted) -> tuple[float, int]:
    return (float(sum(sum(f.chi2.values()) for f in fitted.fits)),
            int(sum(sum(f.dof.values()) for f in fitted.fits)))


def _with(model: Model, index: int, name: str, value: float) -> Model:
    terms = list(model.terms)
    terms[index] = terms[index].with_settings(**{name: float(value)})
    return Model(tuple(terms))


def profiled_fit(model: Model, fit_linear: Callable[[Model], object]):
    """The fit of ``model`` with its nonlinear settings at their best values; the fitted
    object's ``profiled`` lists each (term, parameter, value, stderr, bounds, at_bound)."""
    from scipy.optimize import minimize_scalar

    targets = [(i, name, bounds) for i, term in enumerate(model.terms)
               for name, bounds in term.nonlinear().items()]
    cache: dict = {}

    points: list = []   # the temperature points every value is judged on: at the start values

    def evaluate(m: Model):
        key = tuple(t.spec_string() for t in m.terms)
        if key not in cache:
            try:
                fitted = fit_linear(m)
                used = tuple(fitted.used_points())
                points.append(used) if not points else None
                # χ² over fewer points is smaller for that alone: such a value is refused.
                chi2 = total_chi2(fitted)[0] if used == points[0] else math.inf
                cache[key] = (chi2, fitted)
            except GyrocalError as exc:
                cache[key] = (math.inf, exc)
        return cache[key]

    current = model
    evaluate(model)  # fixes the points every value is judged on
    flat: set = set()
    for _ in range(2 if len(targets) > 1 else 1):
        for index, name, (lo, hi) in targets:
            def chi2_at(log_value, base=current, index=index, name=name):
                return evaluate(_with(base, index, name, math.exp(log_value)))[0]
            grid = np.linspace(math.log(lo), math.log(hi), SCAN_POINTS)
            values = [chi2_at(g) for g in grid]
            k = int(np.argmin(values))
            if not np.isfinite(values[k]):
                failure = evaluate(_with(current, index, name, math.exp(grid[k])))[1]
                raise failure if isinstance(failure, GyrocalError) else GyrocalError(
                    f"no value of {name} within {lo:g} to {hi:g} fits every temperature point")
            finite = [v for v in values if np.isfinite(v)]
            if max(finite) - min(finite) <= 1e-9 * max(abs(min(finite)), 1.0):
                flat.add((index, name))  # the data do not depend on it: keep the setting
                continue
            a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
            with np.errstate(invalid="ignore"):   # a refused value's χ² is inf, on purpose
                found = minimize_scalar(chi2_at, bounds=(a, b), method="bounded",
                                        options={"xatol": 1e-3})
            best = found.x if found.fun <= values[k] else grid[k]
            current = _with(current, index, name, math.exp(best))

    chi2, fitted = evaluate(current)
    if not np.isfinite(chi2):
        raise fitted if isinstance(fitted, GyrocalError) else GyrocalError(
            "the profiled fit leaves out temperature points the start values kept")
    dof = total_chi2(fitted)[1]
    s2 = chi2 / max(dof, 1)
    report = []
    for index, name, (lo, hi) in targets:
        value = float(getattr(current.terms[index], name, None)
                      if not hasattr(current.terms[index], "parameters")
                      else current.terms[index].parameters[name])
        term = current.terms[index]
        if (index, name) in flat:  # e.g. a temperature-rate window without the record
            report.append({"term": getattr(term, "label", None) or term.name, "parameter": name,
                           "value": value, "stderr": None, "bounds": [float(lo), float(hi)],
                           "at_bound": False, "identified": False})
            continue
        x0, h = math.log(value), 0.02
        near = [evaluate(_with(current, index, name, math.exp(x0 + d)))[0] for d in (-h, h)]
        curvature = (near[0] - 2 * chi2 + near[1]) / h ** 2
        sigma_log = math.sqrt(2 * s2 / curvature) if curvature > 0 and np.isfinite(curvature) else math.inf
        at_bound = value <= lo * 1.0001 or value >= hi / 1.0001
        report.append({"term": getattr(term, "label", None) or term.name, "parameter": name,
                       "value": value, "stderr": value * sigma_log if np.isfinite(sigma_log) else None,
                       "bounds": [float(lo), float(hi)], "at_bound": bool(at_bound),
                       "identified": True})
    object.__setattr__(fitted, "profiled", tuple(report))
    return fitted
