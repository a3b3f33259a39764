"""The shape of an effect outside the library.

When no library term explains the excess, the inputs that carry it (the leading rows of
:func:`gyrocal.diagnosis.where.covariate_table`, products with the own rate included) are
given terms of free shape: an empirical term (:class:`gyrocal.terms.empirical.Smooth`, a
natural cubic spline of the input, times the own rate for a product) and parametric
families of that input (a decay, a power law, a step, a bump, a saturation), their
nonlinear parameters profiled. They are judged exactly as the library's terms
(:func:`gyrocal.diagnosis.effects.rank_candidates`), and the one named comes with a sentence
on its shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..terms import AXES, make_term
from .where import INPUT_OF, SETTLING_ROW, SHAPE_KNOTS, input_values, knots_for

LEADING = 2  # inputs of the leading covariate rows given terms of free shape
# The input a term of free shape reads for each input of the covariate table: time within
# a point is read as time since power-on (the term must mean the same in apply), |rate|
# and the rate's direction as the own rate.
TERM_INPUT = {
    "t": "t",
    "t_point": "t",
    "temp": "temp",
    "temp_rate": "temp_rate",
    "abs_rate": "rate_own",
    "rate_own": "rate_own",
    "rate_cross": "rate_cross",
}
UNITS = {
    "t": "s",
    "t_mount": "s",
    "temp": "°C",
    "temp_rate": "°C/min",
    "rate_own": "deg/s",
    "rate_cross": "deg/s",
}
# A protocol holds its rates at a few levels when no more than this many distinct ones: a
# table over them resolves any shape of the rate where its next session will be.
MAX_RATE_LEVELS = 24


@dataclass(frozen=True)
class Shape:
    """A term of free shape the diagnosis tries: its spec, what it is, and its input."""

    spec: str
    kind: str  # empirical | parametric
    family: str  # smooth, levels, decay, power, step, bump, saturation, threshold, ...
    input: str
    by: str | None = None


def _round(bounds: dict) -> dict:
    return {k: [float(f"{v:.3g}") for v in b] for k, b in bounds.items()}


def _families(name: str, lo: float, hi: float, hold: float) -> list[tuple[str, str, dict]]:
    """Parametric families of one input: (family, formula of ``{x}``, profile bounds). Bounds
    are positive (the profile scans them on a log scale): a location is measured from just
    below the lowest value seen."""
    span = max(hi - lo, 1e-9)
    origin = float(f"{lo - 0.01 * span:.4g}")
    # ``{x} - origin`` written as a reader would: "t + 10.3", not "t - -10.3".
    base = f"{{x}} - {origin!r}" if origin >= 0 else f"{{x}} + {-origin!r}"
    if name == "t":
        # A decay within minutes of power-on and one over the session, apart: two at once
        # (a fast and a slow warm-up) are then two terms the profile keeps distinct.
        split = min(600.0, 0.2 * hi)
        return [
            ("decay", "exp(-{x} / tau)", {"tau": [split, 4.0 * hi]}),
            ("fast decay", "exp(-{x} / tau)", {"tau": [max(hold / 2, 5.0), split]}),
            ("power", "(1 + {x} / t0) ** (-p)", {"t0": [1.0, hi], "p": [0.05, 4.0]}),
            (
                "step",
                f"tanh(({base} - m) / {float(f'{max(hold / 4, 1.0):.2g}')!r})",
                {"m": [0.005 * span, 1.01 * span]},
            ),
        ]
    if name == "temp":
        return [
            (
                "bump",
                f"exp(-(({base} - m) / w) ** 2)",
                {"m": [0.005 * span, 1.01 * span], "w": [0.02 * span, span]},
            ),
            (
                "step",
                f"tanh(({base} - m) / w)",
                {"m": [0.005 * span, 1.01 * span], "w": [0.005 * span, 0.5 * span]},
            ),
        ]
    if name == "rate_own":
        top = max(abs(lo), abs(hi))
        # Sharp shapes of |rate| (a mode excited near one rate, a range switch): a bump of the
        # bias and a step of the scale, where and how wide profiled.
        return [
            ("saturation", "tanh({x} / w)", {"w": [0.01 * top, 10.0 * top]}),
            (
                "bump",
                "exp(-((abs({x}) - m) / w) ** 2)",
                {"m": [0.01 * top, top], "w": [0.002 * top, 0.5 * top]},
            ),
            (
                "threshold",
                "{x} * (1 + tanh((abs({x}) - m) / w))",
                {"m": [0.01 * top, top], "w": [0.002 * top, 0.5 * top]},
            ),
        ]
    return []


# Seconds: a time constant since power-on as a unit has one, from a die warming itself
# (tens of seconds) to a package settling in a chamber (hours). An offered term of time
# searches these, whatever the session that found it, so its next session finds its own.
TIME_CONSTANT_S = (10.0, 14400.0)
TIME_CONSTANTS = ("tau", "t0")


def at_bound(profiled) -> bool:
    """Whether a fitted term's profiled parameter ended at a bound of its search: the data do
    not fix it, and a fix resting on it is no fix."""
    return any(p.get("at_bound") for p in profiled or ())


def for_the_unit(spec: str, profiled=()) -> str:
    """An offered term of free shape written for the unit rather than the session it was
    found in: a formula with profiled settings starts from its fitted values (a calibration
    that profiles them again from the grid's start may stop at another optimum), and one of
    time since power-on searches its time constants over :data:`TIME_CONSTANT_S`; a spline
    of time on knots rounded to two significant figures. Other terms as they are."""
    term = make_term(spec)
    inner = getattr(term, "term", term)
    if inner is not term:  # a restricted term: its part stays as the diagnosis fitted it
        return spec
    if inner.name == "smooth" and inner.input == "t":
        knots = sorted({float(f"{k:.2g}") for k in inner.knots})
        return term.with_settings(knots=knots).spec_string() if len(knots) == len(inner.knots) else spec
    if inner.name != "expression" or not inner.profile:
        return spec
    fitted = {
        p["parameter"]: p["value"] for p in profiled or () if p.get("term") == inner.label and "value" in p
    }
    parameters = {k: float(f"{fitted.get(k, v):.3g}") for k, v in inner.parameters.items()}
    of_time = "t" in inner.needs
    bounds = {
        k: (list(TIME_CONSTANT_S) if of_time and k in TIME_CONSTANTS else list(b))
        for k, b in inner.profile.items()
    }
    if any(not lo <= parameters[k] <= hi for k, (lo, hi) in bounds.items() if k in parameters):
        return spec
    return make_term({**inner.spec(), "parameters": parameters, "profile": bounds}).spec_string()


def rate_levels(values: np.ndarray) -> list[float] | None:
    """The distinct levels of a rate at the holds (signed, 0 included), where the protocol
    holds a few (3 to :data:`MAX_RATE_LEVELS`); None otherwise."""
    v = np.asarray(values, dtype=float)
    distinct = np.unique(np.round(v[np.isfinite(v)], 6))
    if not 3 <= distinct.size <= MAX_RATE_LEVELS:
        return None
    return [float(x) for x in distinct]


def _cross_shapes(values: np.ndarray) -> list[Shape]:
    """Terms of the turning axis's rate seen on the other outputs: its square, its
    magnitude, its square with its sign, and a table over the protocol's levels."""
    shapes = [
        Shape(make_term({"name": "cross_rate", "shape": s}).spec_string(), "parametric", s, "rate_cross")
        for s in ("square", "abs", "signed_square")
    ]
    levels = rate_levels(values)
    if levels is not None and len(levels) >= 3:
        spec = make_term({"name": "cross_rate", "shape": "levels", "values": levels}).spec_string()
        shapes.append(Shape(spec, "empirical", "levels", "rate_cross"))
    return shapes


def shape_terms(
    settings, obs: pd.DataFrame, data: dict, covariates: list[dict], fitted_rows: np.ndarray
) -> list[Shape]:
    """Terms of free shape for the inputs of the leading covariate rows that carry part of
    the excess (at most :data:`LEADING` inputs)."""
    shapes: list[Shape] = []
    seen: set = set()
    hold = float(np.median(obs["duration"])) if "duration" in obs else 1.0
    for row in covariates:
        if not (row.get("share_of_excess") or 0) > 0:
            continue
        product = row.get("product")
        if product and product["axes"] != "own axis":
            continue
        label = product["input"] if product else row["covariate"].split(" = ")[0]
        source = INPUT_OF.get(label)
        name = TERM_INPUT.get(source)
        by = "rate_own" if product else None
        if name is None or (name, by) in seen or (name in ("rate_own", "rate_cross") and by):
            continue
        if name == "temp" and settings.model.kind == "grid":
            continue  # a shape of temperature alone is each grid point's bias (or scale)
        seen.add((name, by))
        values = input_values(obs, data, name)[fitted_rows]
        if name == "rate_cross":
            shapes += _cross_shapes(values)
            if len(seen) >= LEADING:
                break
            continue
        if name == "rate_own":
            levels = rate_levels(values)
            if levels is not None:
                # Signed where it matters: an odd shape (the reference rate's row) is a scale
                # that changes with the rate, an even one (|rate|) a bias.
                odd = source == "rate_own"
                table = make_term({"name": "levels", "values": levels, "by": "rate_own" if odd else None})
                shapes.append(
                    Shape(table.spec_string(), "empirical", "levels", name, "rate_own" if odd else None)
                )
        # A rate's shape turns within tens of deg/s of zero (a saturation, a dead band) and is
        # seen at many rates in both directions: two knots more than for time or temperature.
        knots = knots_for(values, SHAPE_KNOTS + 2 if name == "rate_own" else SHAPE_KNOTS)
        if knots is None:
            continue
        # The model holds the linear part already where the scale (a rate) or a temperature
        # polynomial is in it: the spline's own would be the same column.
        linear = not (
            name == "rate_own" or (name == "temp" and _has(settings, "bias_temp_poly") and by is None)
        )
        smooth = make_term({"name": "smooth", "input": name, "knots": knots, "by": by, "linear": linear})
        shapes.append(Shape(smooth.spec_string(), "empirical", "smooth", name, by))
        lo, hi = float(np.min(values)), float(np.max(values))
        for family, formula, profile in _families(name, lo, hi, hold):
            formula = formula.replace("{x}", name)
            if by:
                formula = f"rate_own * {formula}"
            label_ = f"{family.replace(' ', '_')}_{name}" + ("_by_rate" if by else "")
            bounds = _round(profile)
            start = {k: float(f"{np.sqrt(lo_ * hi_):.3g}") for k, (lo_, hi_) in bounds.items()}
            spec = make_term(
                {
                    "name": "expression",
                    "label": label_,
                    "formula": formula,
                    "parameters": start,
                    "profile": bounds,
                }
            ).spec_string()
            shapes.append(Shape(spec, "parametric", family, name, by))
        if by:
            spec = make_term(
                {"name": "expression", "label": f"product_{name}", "formula": f"rate_own * {name}"}
            ).spec_string()
            shapes.append(Shape(spec, "parametric", "product", name, by))
        if len(seen) >= LEADING:
            break
    return shapes + history_shapes(obs, data, covariates, settings.diagnosis.significance / 2)


# Effects with a history, by the rows that carry their excess: the output through
# a slow pole of the own rate (it settles over seconds after every step of the table), heat
# from turning (a first-order lag of the rate's magnitude, shared by the package's three
# axes), a memory of each axis' own speed (the same lag of its own |rate|), and the
# temperature's direction of travel (a play operator of width w).
RATE_ROWS = ("|rate|", "reference rate", "direction", "step into the hold", "previous hold's rate")
TEMPERATURE_ROWS = (
    "temperature",
    "temperature rate",
    "temperature's direction",
    "time within a temperature point",
)
SQUARED = "rate_x**2 + rate_y**2 + rate_z**2"
MAGNITUDE = f"sqrt({SQUARED})"


def history_shapes(
    obs: pd.DataFrame, data: dict, covariates: list[dict], level: float = 0.005
) -> list[Shape]:
    """Terms with a history for the rows that carry part of the excess, where the session's
    record holds what they read (the gyro's output for the rates; a temperature that turns
    back at least once for its direction)."""
    series = data.get("series")
    if series is None or not hasattr(series, "record"):
        return []
    carrying = {
        name.split(" (")[0]
        for row in covariates
        if (row.get("share_of_excess") or 0) > 0
        for name in row["covariate"].split(" = ")
    }
    # The output settling within its holds in proportion to the step into them, beyond chance
    # at ``level`` (the diagnosis' α/2) whatever the hold means say.
    if any(row["covariate"] == SETTLING_ROW and row["p_value"] < level for row in covariates):
        carrying.add("step into the hold")
    hold = float(np.median(obs["duration"])) if "duration" in obs else 20.0
    span = float(series.t[-1] - series.t[0]) if len(series.t) > 1 else hold
    shapes = []
    if carrying & set(RATE_ROWS) and all(f"gyro_{a}" in series.record for a in AXES):
        shapes.append(
            _expression(
                "slow_pole",
                "lag(rate_own, tau) - rate_own",
                {"tau": [0.2, max(2.0 * hold, 1.0)]},
                "slow pole",
            )
        )
        # The heat a turn makes: friction torque times speed (the magnitude) or a viscous
        # drag's power (its square).
        slow = {"tau": [max(hold / 2, 1.0), max(span, hold)]}
        shapes.append(_expression("rotation_heat", f"lag({MAGNITUDE}, tau)", slow, "heating by rotation"))
        shapes.append(
            _expression("rotation_power", f"lag({SQUARED}, tau)", slow, "heating by rotation power")
        )
        # A memory of each axis' own speed (charge a sense loop builds while it turns fast,
        # its own axis only): the bias follows the magnitude of its own rate through a lag.
        shapes.append(_expression("rate_memory", "lag(abs(rate_own), tau)", slow, "memory of its own rate"))
    if carrying & set(TEMPERATURE_ROWS):
        from ..terms.signals import play_operator

        temp = np.asarray(series.temp, dtype=float)
        travel = float(np.ptp(temp)) if temp.size else 0.0
        narrowest = max(0.01 * travel, 0.3)
        state = 2.0 * (temp - play_operator(temp, narrowest)) / narrowest if travel > 0 else temp * 0
        # Tried only where the temperature travels several of the narrowest widths and turns
        # back over one at least: a direction that never changes is the bias's own (or each
        # point's), and ripple within a width moves no operator.
        if travel >= 4.0 * narrowest and np.min(state) < -0.5 < 0.5 < np.max(state):
            # The direction as a switch over a width (a play operator, as a backlash), or as a
            # state relaxing over a width of travel (a Duhem model, as a strained package).
            widths = {"w": [narrowest, max(0.5 * travel, 2.0 * narrowest)]}
            shapes.append(
                _expression("temp_direction", "2 * (temp - play(temp, w)) / w", widths, "hysteresis")
            )
            shapes.append(_expression("temp_duhem", "duhem(temp, w)", widths, "hysteresis relaxing"))
            # A switch with hysteresis (a firmware's table that changes at a temperature, back
            # below it): a step of the play operator's output, where and how wide profiled, its
            # place m measured from just below the coldest temperature (T0, held).
            origin = float(f"{float(np.min(temp)) - 0.01 * travel:.4g}")
            shapes.append(
                _expression(
                    "temp_switch",
                    "sign(play(temp, w) - T0 - m)",
                    {"m": [0.005 * travel, 1.01 * travel], **widths},
                    "switch with hysteresis",
                    fixed={"T0": origin},
                )
            )
    return shapes


def _expression(label: str, formula: str, profile: dict, family: str, fixed=None) -> Shape:
    bounds = _round(profile)
    start = {k: float(f"{np.sqrt(lo_ * hi_):.3g}") for k, (lo_, hi_) in bounds.items()}
    start.update(fixed or {})
    spec = make_term(
        {"name": "expression", "label": label, "formula": formula, "parameters": start, "profile": bounds}
    ).spec_string()
    return Shape(spec, "parametric", family, "history")


def describe_history(term, coefficients: dict, family: str) -> str:
    """A sentence on a fitted term with a history: its time constant or width, and its size
    on each output axis in the units a reader checks against the sensor."""
    inner = getattr(term, "term", term)
    k = [coefficients.get(f"{inner.label}.{a}", 0.0) for a in AXES]
    p = inner.parameters
    if family == "slow pole":
        sizes = ", ".join(f"{v * 1e3:+.3g} ({a})" for a, v in zip(AXES, k, strict=False))
        return (
            f"part of each output follows its own rate through a slow pole of "
            f"{_quantity(p['tau'], 's')}: after a step of the rate it settles by "
            f"{sizes} ×10⁻³ of the step."
        )
    if family.startswith("heating by rotation"):
        power = family.endswith("power")
        sizes = ", ".join(
            f"{v * (400.0**2 if power else 400.0):+.3g} ({a})" for a, v in zip(AXES, k, strict=False)
        )
        what = "the rate's magnitude squared" if power else "the rate's magnitude"
        return (
            f"a bias that follows the heat of turning, {what} through a lag of "
            f"{_quantity(p['tau'], 's')}: {sizes} deg/s after a long turn at 400 deg/s."
        )
    if family == "switch with hysteresis":
        sizes = ", ".join(f"{2 * v:+.3g} ({a})" for a, v in zip(AXES, k, strict=False))
        at = p.get("T0", 0.0) + p["m"]
        return (
            f"a bias step at a temperature, with hysteresis: {sizes} deg/s above "
            f"{_quantity(at + p['w'] / 2, '°C')} rising, back below "
            f"{_quantity(at - p['w'] / 2, '°C')} falling."
        )
    if not family.startswith("hysteresis"):  # a term of the grammar: its formula and sizes
        sizes = ", ".join(f"{v:+.3g} ({a})" for a, v in zip(AXES, k, strict=False))
        return f"a bias that follows {family}: {sizes} deg/s per unit of {inner.formula}."
    turns = (
        "it turns over once the temperature has gone back"
        if family == "hysteresis"
        else "it turns over by 63 % once the temperature has gone back"
    )
    if inner.formula.startswith("rate_own *"):  # the grammar's scale: the own rate times it
        sizes = ", ".join(f"±{abs(v) * 1e6:.3g} ({a})" for a, v in zip(AXES, k, strict=False))
        return (
            f"a scale factor that depends on the temperature's direction of travel (hysteresis): "
            f"{sizes} ppm, rising against falling; {turns} {_quantity(p['w'], '°C')}."
        )
    sizes = ", ".join(f"±{abs(v):.3g} ({a})" for a, v in zip(AXES, k, strict=False))
    return (
        f"a bias that depends on the temperature's direction of travel (hysteresis): {sizes} "
        f"deg/s, rising against falling; {turns} {_quantity(p['w'], '°C')}."
    )


def _reads_history(term) -> bool:
    from ..terms.user import HISTORIES

    formula = getattr(getattr(term, "term", term), "formula", "")
    return any(f"{h}(" in formula for h in HISTORIES)


def _has(settings, term_name: str) -> bool:
    return any(t.name == term_name for t in settings.model.build().terms)


def shape_of(
    term, coefficients: dict, lo: float, hi: float, axis: str, points: int = 201
) -> tuple[np.ndarray, np.ndarray]:
    """The fitted function of its input on one output axis (per unit own rate for a term
    by the rate), over [lo, hi]."""
    x = np.linspace(lo, hi, points)
    inner = getattr(term, "term", term)
    if inner.name in ("smooth", "levels"):
        return x, inner.shape(coefficients, x, axis)
    if inner.name == "cross_rate":
        # The turning axis's rate on this output: of the two other axes, the larger effect.
        curves = [cross_shape(inner, coefficients, x, axis, b) for b in AXES if b != axis]
        return x, max(curves, key=lambda y: float(np.max(np.abs(y - np.median(y)))))
    from ..terms.user import evaluate

    name = next((n for n in ("t", "t_mount", "temp", "temp_rate") if n in inner.needs), "rate_own")
    data = {name: x, "rate_own": x if name == "rate_own" else np.ones_like(x)}
    if "rate_own" in inner.formula and name != "rate_own":
        data["rate_own"] = np.ones_like(x)
    values = np.broadcast_to(evaluate(inner.formula, data, inner.parameters), x.shape)
    return x, coefficients[f"{inner.label}.{axis}"] * values


def cross_shape(term, coefficients: dict, x: np.ndarray, axis: str, turning: str) -> np.ndarray:
    """A cross_rate term's effect on output ``axis`` while axis ``turning`` turns at ``x``."""
    from ..terms.empirical import level_basis

    if term.shape == "levels":
        c = np.array(
            [coefficients[f"{term.label}.{axis}.{turning}.k{k + 1}"] for k in range(2, len(term.values))]
        )
        return level_basis(x, term.values, (0, 1)) @ c
    value = coefficients[f"{term.label}.{axis}.{turning}"]
    return value * {"square": x**2, "signed_square": x * np.abs(x)}.get(term.shape, np.abs(x))


SHAPED = ("smooth", "levels", "cross_rate", "expression")


def _quantity(value: float, unit: str) -> str:
    if unit == "s" and abs(value) >= 120:
        return f"{value / 60:.3g} min"
    return f"{value:.3g} {unit}"


# How far above the line from zero to its largest value an odd term may lie at the smallest
# rate judged (20 of 400 deg/s) and still vanish with the rate as a scale does.
LINEAR_FROM_ZERO = 4.0


def odd_in_own_rate(term) -> bool:
    """Whether a term added to the output is an odd function of each axis' own rate alone
    that vanishes with it: f(ω) = ω·g(|ω|), a scale that changes with the rate's magnitude (a
    scale nonlinearity) however its formula is written. An even one is a bias of |ω| (a
    rectification), and one that keeps its size down to small rates (a sign) a bias that
    flips with the direction. Judged on the term's own columns, one axis turning at a time;
    False for a term that reads any other input."""

    class RatesOnly(dict):
        def __missing__(self, key):
            raise KeyError(key)

    made = make_term(term) if isinstance(term, str | dict) else term
    w = np.linspace(-400.0, 400.0, 41)
    try:
        for turning, axis in enumerate(AXES):
            data = RatesOnly(
                {f"rate_{a}": w if i == turning else np.zeros_like(w) for i, a in enumerate(AXES)}
            )
            cols = made.columns(data)
            own = [np.asarray(v, float) for k, v in cols.items() if k.split(".")[1:2] == [axis]]
            rest = [np.asarray(v, float) for k, v in cols.items() if k.split(".")[1:2] != [axis]]
            if not own or any(np.any(np.abs(v) > 1e-12 * (1.0 + np.max(np.abs(own[0])))) for v in rest):
                return False
            for v in own:
                size = float(np.max(np.abs(v)))
                if size == 0.0 or not np.allclose(v, -v[::-1], atol=1e-9 * size):
                    return False
                # it vanishes with the rate: a bias that flips with the direction (a sign, a
                # saturation far below the rates) is no scale
                if abs(v[w.size // 2 + 1]) > LINEAR_FROM_ZERO * size * w[w.size // 2 + 1] / w[-1]:
                    return False
    except Exception:  # noqa: BLE001 - a term that needs more than the rates reads another input
        return False
    return True


def describe(terms, coefficients: dict, lo: float, hi: float, input_name: str, by) -> str:
    """A sentence on a fitted shape: where it is largest against its value at the session's
    end (time) or its median (other inputs), how large on each output axis, and by when a
    decay halves."""
    unit_x = UNITS.get(input_name, "")
    unit_y = "×10⁻⁶ of the scale" if by else "deg/s"
    x = np.linspace(lo, hi, 201)
    # A library term named beside the shape (a quadratic scale) is not part of it.
    # A history beside it is told apart (describe_history): it is no function of the input.
    terms = [t for t in terms if getattr(t, "term", t).name in SHAPED and not _reads_history(t)]
    peaks, halves = [], []
    for axis in AXES:
        y = sum(shape_of(term, coefficients, lo, hi, axis)[1] for term in terms) * (1e6 if by else 1.0)
        timed = input_name in ("t", "t_mount")
        rel = y - (y[-1] if timed else np.median(y))
        # A scale change is told where it matters, where it moves the output most (times
        # the own rate), not near zero rate, where the holds barely see it.
        k = int(np.argmax(np.abs(rel) * (np.abs(x) if by and input_name == "rate_own" else 1.0)))
        peaks.append((x[k], rel[k]))
        after = np.flatnonzero(np.abs(rel[k:]) <= 0.5 * abs(rel[k]))
        halves.append(x[k + after[0]] if timed and after.size and k < len(x) - 1 else None)
    where = (
        "time since power-on"
        if input_name == "t"
        else {
            "t_mount": "time since the mounting",
            "temp": "the temperature",
            "temp_rate": "the temperature's rate",
            "rate_own": "the axis's own rate",
            "rate_cross": "the rate of the axis that turns, on the other outputs",
        }.get(input_name, input_name)
    )
    odd = input_name == "rate_own" and not by and terms and all(odd_in_own_rate(t) for t in terms)
    kind = "a scale change" if by else "a scale nonlinearity (odd in the rate)" if odd else "a bias"
    reference = (
        "its value at the session's end"
        if input_name == "t"
        else "its value long after"
        if input_name == "t_mount"
        else "its median"
    )
    sizes = ", ".join(f"{v:+.3g} ({a})" for a, (_, v) in zip(AXES, peaks, strict=False))
    places = {_quantity(p, unit_x) for p, _ in peaks}
    at = (
        f"at {places.pop()}"
        if len(places) == 1
        else "at "
        + ", ".join(f"{_quantity(p, unit_x)} ({a})" for a, (p, _) in zip(AXES, peaks, strict=False))
    )
    text = f"{kind} that follows {where}: {sizes} {unit_y} {at}, against {reference}"
    known = [h for h in halves if h is not None]
    if known:
        text += f"; half of it by {_quantity(float(np.median(known)), unit_x)}"
    return text + f" (over {_quantity(lo, unit_x)} to {_quantity(hi, unit_x)})."
