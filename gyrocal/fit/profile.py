"""Nonlinear parameters of effect terms (a time constant, a lag), fitted by profiling.

A term's ``profile`` names settings the model is not linear in, each with bounds. For a
given value the model is linear, so its least-squares fit gives the weighted residual sum
χ²(θ); the profile minimises it over θ. A term with two (a place and a width) starts from
the best cell of a joint log-spaced grid over both (:func:`_joint_start`), not from one
guess; then each parameter is scanned over its bounds (log-spaced, which guards against
local minima), zoomed around the best point (:func:`_zoom`), and several are moved jointly
(:func:`_polish`). The standard error is the wider of the curvature's,
``σ² = 2 s² / (d²χ²/dθ²)`` with ``s²`` the reduced χ² (on log θ, from the inverse of the
joint Hessian where there are several), and half the profile's interval where χ² stays
within ``s²`` of its minimum over every fit made (:func:`_profile_interval`), which also
names a rival valley that fits as well. Every value is judged on the temperature points the
fit at the start values kept: a value that loses a point would win on a smaller χ² for that
alone, so it is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol, TypeVar

import numpy as np

from ..io.errors import GyrocalError
from .model import FitResult, Model

SCAN_POINTS = 13
JOINT_POINTS = 9  # per parameter of a term's joint start grid (a place and a width: 81 fits)
ZOOM_POINTS = 5  # per bracket: each round halves it, at two new values
ZOOM_TOLERANCE = 1e-3  # of log θ: 0.1 % of the value
POLISH_STEP = 0.02  # the joint search's first steps, in log θ
POLISH_EVALUATIONS = 100
POLISH_CHI2 = 0.05  # a change of χ² that decides nothing


class LinearFit(Protocol):
    """What profiling reads of a fit at given settings (a :mod:`gyrocal.fit.thermal` fit):
    its least-squares fits and the temperature points they kept."""

    @property
    def fits(self) -> tuple[FitResult, ...]: ...

    def used_points(self) -> list[int]: ...


Fitted = TypeVar("Fitted", bound=LinearFit)


def total_chi2(fitted: LinearFit) -> tuple[float, int]:
    return (
        float(sum(sum(f.chi2.values()) for f in fitted.fits)),
        int(sum(sum(f.dof.values()) for f in fitted.fits)),
    )


def _with(model: Model, index: int, name: str, value: float) -> Model:
    terms = list(model.terms)
    terms[index] = terms[index].with_settings(**{name: float(value)})
    return Model(tuple(terms))


def _zoom(chi2_at, grid, values, k) -> float:
    """The minimum of χ²(log θ) near the scan's best point: the bracket of its neighbours is
    scanned on a finer grid, again and again around the best point, until it is narrower
    than :data:`ZOOM_TOLERANCE`. A grid, not a parabola: a switch's or a play operator's
    position makes χ² steep and kinked (each hold straddling it adds a kink), where an
    interpolating search stops in a side valley."""
    best, best_value = grid[k], values[k]
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    with np.errstate(invalid="ignore"):  # a refused value's χ² is inf, on purpose
        while b - a > ZOOM_TOLERANCE:
            xs = np.linspace(a, b, ZOOM_POINTS)
            vs = [chi2_at(x) for x in xs]
            j = int(np.argmin(vs))
            if vs[j] < best_value:
                best, best_value = xs[j], vs[j]
            centre = int(np.argmin(np.abs(xs - best)))
            a, b = xs[max(centre - 1, 0)], xs[min(centre + 1, len(xs) - 1)]
    return float(best)


def _value(model: Model, index: int, name: str) -> float:
    term = model.terms[index]
    return float(term.parameters[name] if hasattr(term, "parameters") else getattr(term, name))


def _polish(model: Model, free, evaluate, evaluations: int = POLISH_EVALUATIONS) -> Model:
    """The profile's values moved jointly (a simplex over log θ, clipped to the bounds): one
    parameter at a time stops where a valley runs diagonally and has a kink (a switch's
    place and width: moving either alone loses a hold the other would win back). Kept only
    where χ² falls."""
    from scipy.optimize import minimize

    lows = np.array([math.log(lo) for _, _, (lo, _) in free])
    highs = np.array([math.log(hi) for _, _, (_, hi) in free])

    def at(x):
        m = model
        for (i, n, _), v in zip(free, np.clip(x, lows, highs), strict=False):
            m = _with(m, i, n, math.exp(v))
        return m

    start = evaluate(model)[0]
    x0 = np.clip([math.log(_value(model, i, n)) for i, n, _ in free], lows, highs)
    # first steps inward from a bound, so that every vertex is a value of its own
    steps = np.where(x0 + POLISH_STEP > highs, -POLISH_STEP, POLISH_STEP)
    simplex = np.vstack([x0, x0 + np.diag(steps)])
    with np.errstate(invalid="ignore"):
        found = minimize(
            lambda x: evaluate(at(x))[0],
            x0,
            method="Nelder-Mead",
            options={
                "initial_simplex": simplex,
                "xatol": ZOOM_TOLERANCE,
                "fatol": POLISH_CHI2,
                "maxfev": evaluations,
            },
        )
    return at(found.x) if np.isfinite(found.fun) and found.fun < start else model


def _joint_start(current: Model, index: int, names: list, evaluate) -> tuple[Model, list[Model]]:
    """``current`` with the parameters of term ``index`` at the best cell of a joint
    log-spaced grid over their bounds, and the grid's two best valleys (local minima more
    than a cell apart), the starts of a rival's search. Scanned one at
    a time from a single start, a place and a width stop in the first valley the start's width
    sees (a bump's place scanned at a width far from its own finds a neighbouring level)."""
    axes = [np.exp(np.linspace(math.log(lo), math.log(hi), JOINT_POINTS)) for _, (lo, hi) in names]

    def at(a: int, b: int) -> Model:
        m = _with(current, index, names[0][0], axes[0][a])
        return _with(m, index, names[1][0], axes[1][b])

    grid = np.array([[evaluate(at(a, b))[0] for b in range(JOINT_POINTS)] for a in range(JOINT_POINTS)])
    if not np.isfinite(grid).any():
        return current, []
    padded = np.pad(grid, 1, constant_values=np.inf)
    neighbours = np.min(
        [padded[1 + da : 1 + da + JOINT_POINTS, 1 + db : 1 + db + JOINT_POINTS] for da, db in _AROUND], axis=0
    )
    minima = sorted(
        zip(*np.nonzero(np.isfinite(grid) & (grid <= neighbours)), strict=True), key=lambda c: grid[c]
    )
    a, b = minima[0]
    best = at(a, b) if grid[a, b] < evaluate(current)[0] else current
    others = [c for c in minima[1:] if max(abs(c[0] - a), abs(c[1] - b)) > 1]
    return best, [at(a, b), *(at(*others[0]) for _ in others[:1])]


_AROUND = [(da, db) for da in (-1, 0, 1) for db in (-1, 0, 1) if da or db]
RIVAL_EVALUATIONS = 40  # the polish of another valley's grid cell


def _rival(rivals: dict, target, current: Model, chi2: float, s2: float, evaluate) -> float | None:
    """The value of ``target``'s parameter in another valley of its term's joint grid (the
    start of :func:`_joint_start`'s two that lies more than a grid step from where the fit
    ended, polished), where it fits within Δχ² = s² of the minimum; None otherwise. The
    polish is made once per term (``rivals`` keeps it)."""
    index, name, _ = target
    starts = rivals.get(index)
    if not starts:
        return None
    if not isinstance(starts, tuple):
        free = [t for t in start_targets(current) if t[0] == index]
        far = [m for m in starts if not _near(m, current, free)]
        polished = [_polish(m, free, evaluate, RIVAL_EVALUATIONS) for m in far[:1]]
        rivals[index] = starts = next(
            ((m, evaluate(m)[0]) for m in polished if not _near(m, current, free)), (None, math.inf)
        )
    model, rival_chi2 = starts
    return _value(model, index, name) if model is not None and rival_chi2 <= chi2 + s2 else None


def _near(a: Model, b: Model, free) -> bool:
    """Whether two settings of the same parameters lie within a joint grid step of each other
    in every one of them."""
    return all(
        abs(math.log(_value(a, i, n) / _value(b, i, n))) <= math.log(hi / lo) / (JOINT_POINTS - 1)
        for i, n, (lo, hi) in free
    )


def start_targets(model: Model) -> list:
    """Each nonlinear setting of the model's terms: (term index, name, bounds)."""
    return [
        (i, name, bounds) for i, term in enumerate(model.terms) for name, bounds in term.nonlinear().items()
    ]


def _scan(current: Model, index: int, name: str, bounds, evaluate) -> tuple[Model, bool]:
    """``current`` with ``name`` of term ``index`` at its best value (a log-spaced scan of the
    bounds, then :func:`_zoom`), and whether χ² does not depend on it (kept as it is)."""
    lo, hi = bounds

    def chi2_at(log_value):
        return evaluate(_with(current, index, name, math.exp(log_value)))[0]

    grid = np.linspace(math.log(lo), math.log(hi), SCAN_POINTS)
    values = [chi2_at(g) for g in grid]
    k = int(np.argmin(values))
    if not np.isfinite(values[k]):
        failure = evaluate(_with(current, index, name, math.exp(grid[k])))[1]
        raise (
            failure
            if isinstance(failure, GyrocalError)
            else GyrocalError(f"no value of {name} within {lo:g} to {hi:g} fits every temperature point")
        )
    finite = [v for v in values if np.isfinite(v)]
    if max(finite) - min(finite) <= 1e-9 * max(abs(min(finite)), 1.0):
        return current, True
    return _with(current, index, name, math.exp(_zoom(chi2_at, grid, values, k))), False


def _log_errors(current: Model, free, chi2: float, s2: float, evaluate) -> tuple[dict, np.ndarray | None]:
    """σ of log θ for each free parameter, from the profile's curvature: the inverse of the
    Hessian of χ² over all of them where it is positive definite (parameters that share a
    valley, a switch's place and width, widen each other's errors), else each one's own
    curvature; inf where χ² does not curve upward. With the covariance of log θ where the
    Hessian gives one."""
    h = 0.02
    x0 = [math.log(_value(current, i, n)) for i, n, _ in free]

    def at(steps):
        m = current
        for (i, n, _), x, d in zip(free, x0, steps, strict=False):
            if d:
                m = _with(m, i, n, math.exp(x + d))
        return evaluate(m)[0]

    k = len(free)
    H = np.zeros((k, k))
    for a in range(k):
        e = np.zeros(k)
        e[a] = h
        H[a, a] = (at(-e) - 2 * chi2 + at(e)) / h**2
        for b in range(a):
            f = np.zeros(k)
            f[b] = h
            H[a, b] = H[b, a] = (at(e + f) - at(e - f) - at(f - e) + at(-e - f)) / (4 * h**2)
    own = {
        free[a][:2]: (math.sqrt(2 * s2 / H[a, a]) if H[a, a] > 0 and np.isfinite(H[a, a]) else math.inf)
        for a in range(k)
    }
    if k > 1 and np.all(np.isfinite(H)):
        try:
            np.linalg.cholesky(H)
        except np.linalg.LinAlgError:
            return own, None
        cov = 2 * s2 * np.linalg.inv(H)
        return {free[a][:2]: math.sqrt(cov[a, a]) for a in range(k)}, cov
    return own, None


def profiled_fit(model: Model, fit_linear: Callable[[Model], Fitted]) -> Fitted:
    """The fit of ``model`` with its nonlinear settings at their best values; the fitted
    object's ``profiled`` lists each (term, parameter, value, stderr, bounds, at_bound)."""
    targets = start_targets(model)
    cache: dict = {}

    points: list = []  # the temperature points every value is judged on: at the start values

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
    rivals: dict = {}  # term index: the start, then the polish, of another valley
    for index in sorted({i for i, _, _ in targets}):
        names = [(n, b) for i, n, b in targets if i == index]
        if len(names) == 2:
            current, rivals[index] = _joint_start(current, index, names, evaluate)
    flat: set = set()
    for index, name, bounds in targets:
        current, unchanged = _scan(current, index, name, bounds, evaluate)
        if unchanged:
            flat.add((index, name))
    if flat and len(flat) < len(targets):
        # flat at the others' start values (a width while the place is off the data): again,
        # now that they have moved
        for index, name, bounds in [t for t in targets if t[:2] in flat]:
            current, unchanged = _scan(current, index, name, bounds, evaluate)
            if not unchanged:
                flat.discard((index, name))
    free = [(i, n, b) for i, n, b in targets if (i, n) not in flat]
    if len(free) > 1:
        current = _polish(current, free, evaluate)
    chi2, fitted = evaluate(current)
    if not np.isfinite(chi2):
        raise (
            fitted
            if isinstance(fitted, GyrocalError)
            else GyrocalError("the profiled fit leaves out temperature points the start values kept")
        )
    dof = total_chi2(fitted)[1]
    s2 = chi2 / max(dof, 1)
    sigma, cov = _log_errors(current, free, chi2, s2, evaluate) if free else ({}, None)
    intervals = {
        t[:2]: _profile_interval(current, free, k, chi2, s2, cov, evaluate)._replace(
            rival=_rival(rivals, t, current, chi2, s2, evaluate)
        )
        for k, t in enumerate(free)
    }
    report = _report(current, targets, flat, sigma, intervals)
    object.__setattr__(fitted, "profiled", tuple(report))
    return fitted


class Interval(NamedTuple):
    """Where the profile of one parameter reaches Δχ² = s² below and above its minimum (log
    θ), and the best value of another valley that fits as well (None where there is none)."""

    low: float
    high: float
    rival: float | None = None


PROFILE_STEPS = 2  # secant steps to each end of a profile interval


def _profile_interval(current: Model, free, k: int, chi2: float, s2: float, cov, evaluate) -> Interval:
    """Where χ² rises by s² as parameter ``k`` moves from its minimum along the profile's
    trace (the others moved with it as their covariance says they follow: the least χ² at
    each value where the valley is quadratic), found by secant steps on the rise: a valley
    flatter or steeper than its curvature at the minimum widens or narrows the interval,
    which a curvature alone cannot say. A side the bounds cut before χ² rises ends at the
    bound."""
    x0 = np.array([math.log(_value(current, i, n)) for i, n, _ in free])
    lows = np.array([math.log(lo) for _, _, (lo, _) in free])
    highs = np.array([math.log(hi) for _, _, (_, hi) in free])
    if cov is not None:
        follow = cov[:, k] / cov[k, k]
        sigma = math.sqrt(cov[k, k])
    else:
        follow = np.eye(len(free))[k]
        sigma = math.sqrt(2 * s2) if len(free) else math.inf
    ends = []
    for side in (-1.0, 1.0):
        fallback = sigma if np.isfinite(sigma) and sigma > 0 else 0.1
        step = fallback
        for _ in range(PROFILE_STEPS):
            x = np.clip(x0 + side * step * follow, lows, highs)
            m = current
            for (i, n, _), v in zip(free, x, strict=True):
                m = _with(m, i, n, math.exp(v))
            rise = evaluate(m)[0] - chi2
            if not np.isfinite(rise) or rise <= 0:
                step = fallback  # not a minimum to this precision: the curvature's word
                break
            if x[k] != x0[k] + side * step * follow[k] and rise < s2:
                step = abs(x[k] - x0[k])  # the bound comes first: the data do not close it
                break
            step *= math.sqrt(s2 / rise)  # exact where the rise is quadratic in the step
        ends.append(x0[k] + side * step)
    return Interval(ends[0], ends[1])


def _report(current: Model, targets: list, flat: set, sigma: dict, intervals: dict) -> list[dict]:
    """Each profiled setting: its term and value, its standard error (None where flat, or not
    finite), its bounds, whether it ended at one, and whether the data identify it."""
    report = []
    for index, name, (lo, hi) in targets:
        value = _value(current, index, name)
        term = current.terms[index]
        if (index, name) in flat:  # e.g. a temperature-rate window without the record
            report.append(
                {
                    "term": getattr(term, "label", None) or term.name,
                    "parameter": name,
                    "value": value,
                    "stderr": None,
                    "bounds": [float(lo), float(hi)],
                    "at_bound": False,
                    "identified": False,
                }
            )
            continue
        at_bound = value <= lo * 1.0001 or value >= hi / 1.0001
        interval = intervals.get((index, name))
        # σ of log θ: the curvature's, or half the profile's interval where that is wider (a
        # valley flat or kinked beyond the curvature's step)
        sigma_log = sigma[(index, name)]
        if interval is not None:
            sigma_log = max(sigma_log, (interval.high - interval.low) / 2)
        entry = {
            "term": getattr(term, "label", None) or term.name,
            "parameter": name,
            "value": value,
            "stderr": value * sigma_log if np.isfinite(sigma_log) else None,
            "bounds": [float(lo), float(hi)],
            "at_bound": bool(at_bound),
            "identified": True,
        }
        if interval is not None:
            entry["interval"] = [math.exp(interval.low), math.exp(interval.high)]
            if interval.rival is not None:
                entry["rival"] = interval.rival
        report.append(entry)
    return report
