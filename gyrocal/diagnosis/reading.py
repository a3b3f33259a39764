"""Terms as a reader wants them: formulas with their parameters and uncertainties, where
the config spells them for the parser (``A·exp(−t/τ), τ = 907 ± 10 s`` for
``expression(label='decay_t', formula='exp(-t / tau)', parameters={'tau': 906.9}, ...)``).
The config line and the option stay beside them, for copying."""

from __future__ import annotations

import ast

from ..terms import make_term

# How inputs read in a formula, and their units.
SYMBOLS = {
    "t": ("t", "s"),
    "temp": ("T", "°C"),
    "temp_rate": ("dT/dt", "°C/min"),
    "rate_own": ("ω", "deg/s"),
    "accel_own": ("f", "g"),
    **{f"rate_{a}": (f"ω_{a}", "deg/s") for a in "xyz"},
    **{f"accel_{a}": (f"f_{a}", "g") for a in "xyz"},
    "ref_rate": ("ω_ref", "deg/s"),
}
GREEK = {
    "tau": "τ",
    "alpha": "α",
    "beta": "β",
    "gamma": "γ",
    "delta": "δ",
    "omega": "Ω",
    "sigma": "σ",
    "mu": "μ",
    "lambda_": "λ",
    "theta": "θ",
}
LIBRARY = {
    "bias": "B",
    "scale": "(K_aa − 1) ω_a",
    "misalignment": "K_ab ω_b",
    "scale_quadratic": "k ω²",
    "scale_cubic": "k ω³",
    "scale_asymmetry": "k |ω|",
    "g_sensitivity": "Σ_b G_ab f_b",
    "g_squared": "Σ_b K_ab f_b²",
    "temp_rate": "c dT/dt",
    "temp_lag": "c (T_τ − T)",
    "bias_temp_poly": "Σ_k c_k ΔT^k",
    "scale_temp_poly": "ω Σ_k s_k ΔT^k",
    "misalignment_temp": "Σ_b m_ab ω_b ΔT",
    "misalignment_faces": "Σ_b D_ab s ω_b",
}
_OPS = {ast.Add: " + ", ast.Sub: " − ", ast.Mult: "·", ast.Div: "/", ast.Pow: "^"}
_PRECEDENCE = {ast.Add: 1, ast.Sub: 1, ast.Mult: 2, ast.Div: 2, ast.Pow: 3}


def _number(value: float) -> str:
    return f"{value:.4g}"


def _formula(node, parameters: dict, parent: int = 0, right: bool = False) -> str:
    """A formula's AST written as mathematics: symbols for inputs and Greek parameters."""
    if isinstance(node, ast.Expression):
        return _formula(node.body, parameters)
    if isinstance(node, ast.Name):
        if node.id in SYMBOLS:
            return SYMBOLS[node.id][0]
        return GREEK.get(node.id, node.id)
    if isinstance(node, ast.Constant):
        return _number(float(node.value))
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return "−" + _formula(node.operand, parameters, 3)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        args = [_formula(a, parameters) for a in node.args]
        if node.func.id == "abs" and len(args) == 1:
            return f"|{args[0]}|"
        return f"{node.func.id}({', '.join(args)})"
    if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        level = _PRECEDENCE[type(node.op)]
        left = _formula(node.left, parameters, level)
        rhs = _formula(node.right, parameters, level, right=True)
        text = f"{left}{_OPS[type(node.op)]}{rhs}"
        # Brackets where the order needs them (a − (b + c), a/(b·c)), not around every product.
        needed = level < parent or (
            right and level == parent and type(node.op) in (ast.Add, ast.Sub, ast.Mult, ast.Div)
        )
        return f"({text})" if needed else text
    return ast.unparse(node)


def _parameter_units(tree, parameters) -> dict[str, str]:
    """Each parameter's unit from the input it meets in the formula: one that sits with an
    input (``t / tau``, ``temp − m``) takes its unit, one that is an exponent none."""
    units: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
            for n in ast.walk(node.right):
                if isinstance(n, ast.Name) and n.id in parameters:
                    units[n.id] = ""
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("lag", "play", "duhem")
            and len(node.args) == 2
        ):
            # A lag's time constant is in seconds; a play's or a duhem's width in its input's unit.
            inner = [n.id for n in ast.walk(node.args[0]) if isinstance(n, ast.Name) and n.id in SYMBOLS]
            unit = "s" if node.func.id == "lag" else (SYMBOLS[inner[0]][1] if inner else "")
            for n in ast.walk(node.args[1]):
                if isinstance(n, ast.Name) and n.id in parameters:
                    units[n.id] = unit
    inputs = [n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and n.id in SYMBOLS]
    unit = SYMBOLS[inputs[0]][1] if inputs and len({SYMBOLS[i][1] for i in inputs}) == 1 else ""
    return {p: units.get(p, unit) for p in parameters}


def _values(term, profiled) -> str:
    """``τ = 907 ± 10 s`` for each parameter (its profiled value and standard error)."""
    found = {p["parameter"]: p for p in profiled or () if p.get("identified", True)}
    parameters = getattr(term, "parameters", {}) or {}
    if not parameters:
        return ""
    units = _parameter_units(ast.parse(term.formula, mode="eval"), parameters)
    parts = []
    for name, value in parameters.items():
        entry = found.get(name)
        v = entry["value"] if entry else value
        se = entry.get("stderr") if entry else None
        unit = f" {units[name]}" if units.get(name) else ""
        bound = ""
        if entry and entry.get("at_bound"):
            lo, hi = entry["bounds"]
            bound = f" (at the {'upper' if v >= (lo * hi) ** 0.5 else 'lower'} bound of its search)"
        rival = ""
        if entry and entry.get("rival") is not None:
            rival = f" (or {_number(entry['rival'])}{unit}: the data fit either as well)"
        parts.append(
            f"{GREEK.get(name, name)} = {_number(v)}" + (f" ± {se:.2g}" if se else "") + unit + bound + rival
        )
    return ", ".join(parts)


def _span(values, unit: str) -> str:
    return f"{_number(values[0])} to {_number(values[-1])} {unit}".strip()


def readable(spec, profiled=()) -> str:
    """The term as mathematics, with its parameters (profiled values and their standard
    errors where fitted): what a verdict and a table print; the spec stays beside it."""
    term = make_term(spec)
    inner = getattr(term, "term", term)
    drop = getattr(term, "drop", ())
    tail = f" (without {', '.join(drop)})" if drop else ""
    if inner.name == "expression":
        tree = ast.parse(inner.formula, mode="eval")
        text = "A·" + _formula(tree.body, inner.parameters, 2)  # A times the whole formula
        values = _values(inner, profiled)
        return text + (f", {values}" if values else "") + tail
    if inner.name == "smooth":
        symbol, unit = SYMBOLS.get(inner.input, (inner.input, ""))
        by = "ω × " if inner.by else ""
        return f"{by}a cubic spline of {symbol} on knots {_span(inner.knots, unit)}" + tail
    if inner.name == "levels":
        by = "ω × " if inner.by else ""
        return (
            f"{by}a table of ω over its {len(inner.values)} levels "
            f"{_span(inner.values, 'deg/s')}, straight between them" + tail
        )
    if inner.name == "cross_rate":
        text = {
            "square": "q_ab ω_b²",
            "abs": "q_ab |ω_b|",
            "signed_square": "q_ab ω_b |ω_b|",
            "levels": f"a table of ω_b over its {len(inner.values)} levels "
            f"{_span(inner.values or (0,), 'deg/s')}",
        }[inner.shape]
        return f"{text} on each other output a" + tail
    if inner.name in ("die_temperature", "temp_lag", "temp_rate"):
        found = {p["parameter"]: p for p in profiled or () if p.get("identified", True)}
        base = {
            "die_temperature": "every temperature dependence at the die, T_τ",
            "temp_lag": LIBRARY["temp_lag"],
            "temp_rate": LIBRARY["temp_rate"],
        }[inner.name]
        name = "tau" if inner.name != "temp_rate" else "window_s"
        entry = found.get(name)
        if entry:
            se = f" ± {entry['stderr']:.2g}" if entry.get("stderr") else ""
            label = "τ" if name == "tau" else "window"
            return f"{base}, {label} = {_number(entry['value'])}{se} s" + tail
        return base + tail
    formula = LIBRARY.get(inner.name)
    if formula is None:
        return term.spec_string()
    degree = getattr(inner, "degree", None)
    return formula + (f", degree {degree}" if degree else "") + tail
