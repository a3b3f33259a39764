"""Candidate terms from a grammar, screened out of sample.

A candidate is an input the log has (the axis's own rate, its magnitude, the other axes'
rates, the specific force, the temperature's rate and direction of travel, time since
power-on, the output's history), through a transform (a power, a sign, a saturation, a
threshold, a bump, a decay, a logarithm, a lag), acting on the bias or on the scale (the own rate times
it). Every one the log can feed is screened: its hold-mean regressor, with the configured
model's own columns at each temperature point projected out (bias, scale and misalignment
per point, what a grid fits), is fitted to the residuals leaving each temperature point out
in turn, and scored by what it takes away from the points it did not see (χ², in units of
the noise floor). A shape that lies within one point's stretch of time (a warm-up) cannot be
judged that way: it is scored in sample less a penalty of ln n per coefficient (BIC).
Nonlinear parameters are screened over a grid of their range; the best cell is the start of
the profile that fits the survivors (:mod:`gyrocal.fit.profile`).

The screen is cheap (a few thousand columns of one least-squares step each); the survivors
are fitted and judged like every other candidate (:func:`.effects.rank_candidates`).
"""

from __future__ import annotations

import ast
import itertools
import math
from dataclasses import dataclass

import numpy as np

from ..fit.model import Model, axis_of
from ..io.errors import GyrocalError
from ..terms import AXES, make_term
from .shapes import MAGNITUDE, Shape
from .stats import chi2_ppf

GRID = 9  # values of a nonlinear parameter screened (log-spaced over its bounds)
GRID_2D = 6  # per parameter where a transform has two (a place and a width)
KEEP = 3  # candidates of distinct inputs passed on to the fit


@dataclass(frozen=True)
class Input:
    """An input of the grammar: its label, how a formula reads it, the kind of input the
    verdict names, and whether it needs the session's record."""

    label: str
    formula: str
    kind: str
    history: bool = False
    shape_input: str = "history"  # the input a fitted shape is drawn against (.shapes)
    family: str | None = None  # the family a fitted term is told by, where not the transform's


@dataclass(frozen=True)
class Transform:
    """A transform of an input ``x``: its family, its formula, and the bounds of its nonlinear
    parameters given the input's range (``lo``, ``hi``) and a hold's length."""

    family: str
    formula: str
    bounds: object = None  # callable (lo, hi, hold) -> {name: [low, high]}

    def profile(self, lo: float, hi: float, hold: float) -> dict[str, list[float]]:
        return self.bounds(lo, hi, hold) if self.bounds else {}


def _place_width(lo, hi, hold):
    top = max(abs(lo), abs(hi), 1e-9)
    return {"m": [0.01 * top, top], "w": [0.005 * top, 0.5 * top]}


def _width(lo, hi, hold):
    top = max(abs(lo), abs(hi), 1e-9)
    return {"w": [0.01 * top, 2.0 * top]}


def _time_constant(lo, hi, hold):
    return {"tau": [max(hold / 2, 5.0), max(4.0 * hi, hold)]}


def _short_lag(lo, hi, hold):
    return {"tau": [0.2, max(2.0 * hold, 1.0)]}


def _long_lag(lo, hi, hold):
    return {"tau": [max(hold / 2, 1.0), max(hi, hold)]}


IDENTITY = Transform("linear", "{x}")
SQUARE = Transform("square", "({x}) ** 2")
SIGN = Transform("sign", "sign({x})")
SATURATION = Transform("saturation", "tanh(({x}) / w)", _width)
THRESHOLD = Transform("threshold", "1 + tanh((({x}) - m) / w)", _place_width)
BUMP = Transform("bump", "exp(-((({x}) - m) / w) ** 2)", _place_width)
DECAY = Transform("decay", "exp(-({x}) / tau)", _time_constant)
ABS = Transform("abs", "abs({x})")
SIGNED_SQUARE = Transform("signed_square", "({x}) * abs({x})")
LOG = Transform("log", "log(1 + ({x}) / tau)", _time_constant)  # a creep: slower than any decay

# input -> transforms, and where each acts: a bias (the transform itself) or a scale (the
# own rate times it). The own rate's odd shapes are scales already.
RULES: tuple[tuple[Input, tuple[Transform, ...], tuple[str, ...]], ...] = (
    (Input("own rate", "rate_own", "rate", shape_input="rate_own"), (SATURATION, SIGN), ("bias",)),
    (
        Input("|rate|", "abs(rate_own)", "rate", shape_input="rate_own"),
        (SQUARE, BUMP, THRESHOLD),
        ("bias", "scale"),
    ),
    (
        Input("other axes' rate", "cross_rate", "rate", shape_input="rate_cross"),
        (SQUARE, ABS, SIGNED_SQUARE),
        ("cross",),
    ),
    (
        Input("specific force", "accel_own", "accel", family="square of the specific force"),
        (SQUARE,),
        ("bias",),
    ),
    # a proof mass the specific force deflects changes the drive-sense coupling: the scale
    # moves with the force along the axis (mounts with the axis up and down tell it)
    (
        Input("specific force along the axis", "accel_own", "accel", family="scale × specific force"),
        (IDENTITY,),
        ("scale",),
    ),
    (
        Input(
            "specific force × temperature", "accel_own * temp", "accel", family="specific force × temperature"
        ),
        (IDENTITY,),
        ("bias",),
    ),
    (
        Input("temperature rate", "temp_rate", "thermal", shape_input="temp_rate"),
        (SQUARE,),
        ("bias", "scale"),
    ),
    (Input("time since power-on", "t", "time", shape_input="t"), (DECAY, LOG), ("bias", "scale")),
    # a clamp or a strain that relaxes after each mounting (the log's handling marks it)
    (Input("time since the mounting", "t_mount", "time", shape_input="t_mount"), (DECAY,), ("bias", "scale")),
    (
        Input("the output's slow pole", "lag(rate_own, tau) - rate_own", "rate", True, family="slow pole"),
        (IDENTITY,),
        ("bias",),
    ),
    (
        Input("heat from turning", f"lag({MAGNITUDE}, tau)", "rate", True, family="heating by rotation"),
        (IDENTITY,),
        ("bias",),
    ),
    (
        Input(
            "the temperature's direction",
            "2 * (temp - play(temp, w)) / w",
            "thermal",
            True,
            family="hysteresis",
        ),
        (IDENTITY,),
        ("bias", "scale"),
    ),
)


# Parameters that an input's own formula carries, with their bounds (the transform's are
# the transform's).
def _play_width(lo, hi, hold):
    travel = max(hi - lo, 1e-9)
    narrowest = max(0.01 * travel, 0.3)
    return {"w": [narrowest, max(0.5 * travel, 2.0 * narrowest)]}


INPUT_BOUNDS = {
    "the output's slow pole": _short_lag,
    "heat from turning": _long_lag,
    "the temperature's direction": _play_width,
}


@dataclass(frozen=True)
class Screened:
    """A candidate screened: its shape (the spec at the grid's best cell), what its input is,
    and what it takes away from the points it did not see (χ² in floor units)."""

    shape: Shape
    input: Input
    where: str
    gain: float
    coefficients: int


def _range(obs, data, rule: Input) -> tuple[float, float] | None:
    x = rule.formula
    if x == "t":
        t = 0.5 * (np.asarray(data["t_start"]) + np.asarray(data["t_end"]))
        series = data.get("series")
        t0 = series.t0 if series is not None else float(np.min(data["t_start"]))
        return 0.0, float(np.max(t) - t0)
    if x == "t_mount":
        since = np.asarray(data["t_end"], float) - np.asarray(data["mounted_at"], float)
        return 0.0, float(np.max(since))
    if "rate_own" in x or x == "cross_rate":
        top = float(np.nanmax(np.abs([data[f"rate_{a}"] for a in AXES])))
        return (0.0, top) if top > 0 else None
    if x == "temp_rate" and "temp_rate" in data:
        v = np.abs(np.asarray(data["temp_rate"], dtype=float))
        return 0.0, float(np.nanmax(v))
    if "temp" in x and "temp" in data:
        v = np.asarray(data["temp"], dtype=float)
        return float(np.nanmin(v)), float(np.nanmax(v))
    return 0.0, 1.0


def _temperature_turns(data) -> bool:
    """Whether the record's temperature travels several widths and turns back: a direction
    that never changes is each point's bias."""
    series = data.get("series")
    if series is None or not hasattr(series, "record"):
        return False
    temp = np.asarray(series.temp, dtype=float)
    if temp.size < 3:
        return False
    smooth = np.convolve(temp, np.ones(5) / 5, mode="valid")
    step = np.diff(smooth[:: max(len(smooth) // 2000, 1)])
    big = step[np.abs(step) > 0.02]
    return big.size > 0 and bool(np.any(big > 0) and np.any(big < 0))


def _available(rule: Input, data) -> bool:
    if rule.formula == "t_mount":
        # mounted more than once in the session: else it is time since power-on
        return "mounted_at" in data and np.unique(np.asarray(data["mounted_at"], float)).size > 1
    if "accel_own" in rule.formula and not all(f"accel_{a}" in data for a in AXES):
        return False
    if rule.formula == "temp_rate" and "temp_rate" not in data:
        return False
    if rule.history:
        series = data.get("series")
        if series is None or not hasattr(series, "record"):
            return False
        if "play(temp" in rule.formula:
            return _temperature_turns(data)
        return all(f"gyro_{a}" in series.record for a in AXES)
    return True


def _grid(bounds: dict) -> list[dict]:
    """Log-spaced values over each parameter's bounds, jointly."""
    if not bounds:
        return [{}]
    count = GRID if len(bounds) == 1 else GRID_2D
    axes = {k: np.exp(np.linspace(math.log(lo), math.log(hi), count)) for k, (lo, hi) in bounds.items()}
    return [
        {k: float(f"{v:.3g}") for k, v in zip(axes, values, strict=True)}
        for values in itertools.product(*axes.values())
    ]


def _spec(rule: Input, transform: Transform, where: str, parameters: dict, bounds: dict) -> str:
    if where == "cross":  # the library's term of the other axes' rates, in the transform's shape
        return make_term({"name": "cross_rate", "shape": transform.family}).spec_string()
    f = transform.formula.replace("{x}", rule.formula)
    formula = f if where == "bias" else f"rate_own * ({f})"
    label = "g_" + "_".join(
        [transform.family, rule.label.replace(" ", "_").replace("|", "").replace("'", ""), where]
    )
    label = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in label)
    return make_term(
        {
            "name": "expression",
            "label": label,
            "formula": formula,
            "parameters": parameters,
            **({"profile": bounds} if bounds else {}),
        }
    ).spec_string()


def formula_of(spec: str) -> str:
    """What a spec computes, whatever its label, start values and parentheses: its formula's
    syntax tree with the parameters' names, or its spec where it is not a formula."""
    term = make_term(spec)
    formula = getattr(term, "formula", None)
    return ast.dump(ast.parse(formula, mode="eval")) if formula else term.spec_string()


def _columns(spec: str, data) -> dict[str, np.ndarray] | None:
    try:
        return Model((make_term(spec),)).design(data)
    except (GyrocalError, FloatingPointError, ValueError, ZeroDivisionError, OverflowError):
        return None


def _projector(rates: np.ndarray, points: np.ndarray, weights: np.ndarray):
    """Per output axis, a function that takes a (holds × k) array of weighted columns to its
    part the configured model cannot hold: what is left after the least-squares fit of each
    temperature point's bias, scale and misalignment (1 and the three rates, weighted)."""
    groups = [np.flatnonzero(points == p) for p in np.unique(points)]
    bases = []
    for i in range(len(AXES)):
        q = []
        for rows in groups:
            x = np.column_stack([np.ones(len(rows)), rates[rows]]) * weights[rows, i : i + 1]
            u, s, _ = np.linalg.svd(x, full_matrices=False)
            q.append(u[:, s > s[0] * 1e-9] if s.size and s[0] > 0 else u[:, :0])
        bases.append(q)

    def project(values: np.ndarray, i: int) -> np.ndarray:
        out = np.empty_like(values)
        for rows, q in zip(groups, bases[i], strict=True):
            v = values[rows]
            out[rows] = v - q @ (q.T @ v)
        return out

    return project, groups


def _gain(c: np.ndarray, z: np.ndarray, groups) -> tuple[float, bool]:
    """What columns ``c`` (holds × k, projected and weighted) take away from the residuals
    ``z`` (projected, in floor units) out of sample: the least-squares fit without each
    point, judged on that point, summed; and whether that could be done (the columns vary in
    two points at least). Else the in-sample gain."""
    varies = [rows for rows in groups if np.any(np.abs(c[rows]) > 1e-12 * (np.abs(c).max() + 1e-300))]
    if len(varies) < 2:
        beta, *_ = np.linalg.lstsq(c, z, rcond=None)
        return float(z @ z - np.sum((z - c @ beta) ** 2)), False
    total = 0.0
    for rows in groups:
        keep = np.ones(len(z), dtype=bool)
        keep[rows] = False
        beta, *_ = np.linalg.lstsq(c[keep], z[keep], rcond=None)
        left = z[rows] - c[rows] @ beta
        total += float(z[rows] @ z[rows] - left @ left)
    return total, True


def screen(obs, data, quality, alpha: float, exclude=()) -> list[Screened]:
    """Every candidate of the grammar the log can feed, screened against the residuals of the
    configured model (``quality``, :func:`.where.fit_quality`); those that take away more
    than chance would (χ² beyond its 1 − ``alpha`` quantile) from the points they did not see,
    the best of each input first, at most :data:`KEEP`. ``exclude``: formulas already tried."""
    finite = np.all(np.isfinite(quality.z), axis=1) & np.all(
        np.isfinite(quality.floor) & (quality.floor > 0), axis=1
    )
    rows = quality.fitted_rows & finite
    if "point" not in data or rows.sum() < 8:
        return []
    sub = {
        k: (v[rows] if isinstance(v, np.ndarray) and v.shape[:1] == rows.shape else v)
        for k, v in data.items()
    }
    points = np.asarray(sub["point"])
    rates = np.column_stack([sub[f"rate_{a}"] for a in AXES])
    weights = 1.0 / quality.floor[rows]
    project, groups = _projector(rates, points, weights)
    z = np.column_stack([project(quality.z[rows][:, i : i + 1], i)[:, 0] for i in range(len(AXES))])
    hold = float(np.median(obs["duration"])) if "duration" in obs else 20.0
    n = int(rows.sum()) * len(AXES)
    best: dict[str, Screened] = {}
    for rule, transforms, places in RULES:
        if not _available(rule, sub):
            continue
        span = _range(obs, sub, rule)
        if span is None:
            continue
        for transform, where in itertools.product(transforms, places):
            own = INPUT_BOUNDS.get(rule.label)
            bounds = {**(own(*span, hold) if own else {}), **transform.profile(*span, hold)}
            bounds = {k: [float(f"{lo:.3g}"), float(f"{hi:.3g}")] for k, (lo, hi) in bounds.items()}
            for values in _grid(bounds):
                spec = _spec(rule, transform, where, values, bounds)
                if formula_of(spec) in exclude:
                    continue
                found = _screened(spec, sub, project, groups, z, weights, n)
                if found is None:
                    continue
                gain, k = found
                key = rule.label
                if key not in best or gain > best[key].gain:
                    family = rule.family or transform.family
                    by = "rate_own" if where == "scale" else None
                    best[key] = Screened(
                        Shape(spec, "parametric", family, rule.shape_input, by), rule, where, gain, k
                    )
    passed = [s for s in best.values() if s.gain > chi2_ppf(1.0 - alpha, s.coefficients)]
    return sorted(passed, key=lambda s: -s.gain)[:KEEP]


def _screened(spec: str, data, project, groups, z, weights, n: int) -> tuple[float, int] | None:
    columns = _columns(spec, data)
    if not columns:
        return None
    total, k, judged = 0.0, 0, True
    for i, axis in enumerate(AXES):
        mine = [v for name, v in columns.items() if axis_of(name) == axis]
        if not mine or not all(np.all(np.isfinite(v)) for v in mine):
            continue
        c = project(np.column_stack(mine) * weights[:, i : i + 1], i)
        # unit columns (the gain does not depend on their scale): one a decay has taken to
        # denormal numbers would make the fit's coefficient overflow
        norms = np.linalg.norm(c, axis=0)
        usable = np.isfinite(norms) & (norms > 1e-100)
        if not usable.any():
            continue
        c = c[:, usable] / norms[usable]
        gain, out_of_sample = _gain(c, z[:, i], groups)
        judged &= out_of_sample
        total += gain
        k += c.shape[1]
    if k == 0:
        return None
    return (total if judged else total - k * math.log(n)), k
