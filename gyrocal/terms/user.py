"""A user's own effects: terms from a Python file, and one-line expressions of columns.

A term file is an ordinary Python file that defines and registers terms exactly as the
library does (``@register_term("name")`` on a frozen dataclass subclass of ``Term``). It is
loaded by path; its SHA-256 is recorded in every calibration that uses one of its terms, and
loading such a calibration checks it, so a calibration is never applied with a term whose
code has changed.

An expression term is a formula of the inputs every term has (``accel_x * rate_y``,
``temp_rate ** 2``, ``exp(-t / tau)``, ``lag(temp, 900) - temp``), one coefficient per
output axis. ``rate_own`` and ``accel_own`` are the output axis's own rate and
acceleration, so an effect that acts on each axis through its own rate is one formula
(``rate_own * exp(-t / tau)``: a scale that relaxes after power-on) rather than three. Formulas are read by a small interpreter that knows numbers, the inputs of
``FORMULA_COLUMNS``, the expression's named parameters, + - * / **, unary minus, a few
one-argument functions and ``lag``: nothing else in the formula can run.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib.util
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from ..io.errors import ConfigError
from . import AXES, TERMS, Term, register_term

_LOADED: dict[str, str] = {}  # resolved path -> sha256


def file_hash(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_term_file(path) -> tuple[str, list[str]]:
    """Import a term file (once per path); return its SHA-256 and the terms it added."""
    path = Path(path).resolve()
    if not path.is_file():
        raise ConfigError(f"term file {path} does not exist")
    digest = file_hash(path)
    key = str(path)
    if key in _LOADED:
        if _LOADED[key] != digest:
            raise ConfigError(f"term file {path} changed since it was loaded in this process")
        return digest, [n for n, c in TERMS.items() if getattr(c, "source_file", None) == key]
    same = next((other for other, d in _LOADED.items() if d == digest), None)
    if same is not None:  # the same code under another path: its terms are registered
        _LOADED[key] = digest
        return digest, [n for n, c in TERMS.items() if getattr(c, "source_file", None) == same]
    before = set(TERMS)
    module_name = f"gyrocal_user_terms_{digest[:12]}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:  # a path importlib cannot load as a module
        raise ConfigError(f"term file {path} cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except ConfigError:
        raise
    except Exception as exc:  # the user's code: report it, in one line
        raise ConfigError(f"term file {path} failed to load: {type(exc).__name__}: {exc}") from None
    added = sorted(set(TERMS) - before)
    for name in added:
        TERMS[name].source_file = key
        TERMS[name].source_sha256 = digest
    _LOADED[key] = digest
    return digest, added


_FUNCTIONS = {
    "abs": np.abs,
    "sqrt": np.sqrt,
    "exp": np.exp,
    "log": np.log,
    "sign": np.sign,
    "tanh": np.tanh,
    "sin": np.sin,
    "cos": np.cos,
}
_OPERATORS = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.divide,
    ast.Pow: np.power,
}
# lag(x, tau): x through a first-order lag of tau seconds; play(x, w): x through the play
# operator of width w; duhem(x, w): x's direction of travel relaxing over w of travel. x is an input of the session's record or a formula of them, taken at
# the record's points (the temperature, its rate, the rates as the gyro output them, the
# specific force), so fit and apply see the same history.
HISTORIES = ("lag", "play", "duhem")
RECORD_INPUTS = (
    "t",
    "temp",
    "temp_rate",
    "rate_x",
    "rate_y",
    "rate_z",
    "rate_own",
    "accel_x",
    "accel_y",
    "accel_z",
    "accel_own",
)
LAGGABLE = ("temp", "temp_rate")  # lags of these alone keep their own, older path

# What a formula may read: the inputs every term has (gyrocal.terms.signals), per sample in apply
# and as hold means in the fit. ``t`` is seconds since the log's first sample; ``t_mount``
# seconds since the unit was last mounted (infinite in apply: a stream long since mounted).
FORMULA_COLUMNS = (
    "t",
    "t_mount",
    "temp",
    "temp_rate",
    "rate_x",
    "rate_y",
    "rate_z",
    "ref_rate",
    "accel_x",
    "accel_y",
    "accel_z",
    "rate_own",
    "accel_own",
)
# The output axis's own input: rate_own is rate_x in the x output's column, and so on.
OWN_AXIS = {"rate_own": "rate", "accel_own": "accel"}
SERIES_NAMES = frozenset({"t", "t_mount", "temp_rate"})


def formula_names(formula: str, parameters=()) -> frozenset[str]:
    """Inputs a formula reads (``temp_lag`` for a lag), its parameters excluded."""
    if isinstance(formula, str) and isinstance(parameters, tuple):
        return _formula_names_cached(formula, parameters)
    return _formula_names(formula, tuple(parameters))


@functools.lru_cache(maxsize=4096)
def _formula_names_cached(formula: str, parameters: tuple) -> frozenset[str]:
    return _formula_names(formula, parameters)


def _formula_names(formula: str, parameters: tuple) -> frozenset[str]:
    tree = _parse(formula, parameters)
    names = {
        n.id
        for n in ast.walk(tree)
        if isinstance(n, ast.Name)
        and n.id not in _FUNCTIONS
        and n.id not in HISTORIES
        and n.id not in parameters
    }
    for own, kind in OWN_AXIS.items():
        if own in names:
            names = (names - {own}) | {f"{kind}_{a}" for a in AXES}
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call) and _called(n) in HISTORIES):
        names.add("temp_lag")  # the session's record
        inside = {n.id for n in ast.walk(call.args[0]) if isinstance(n, ast.Name)}
        if inside & {"rate_x", "rate_y", "rate_z", "rate_own"}:
            names.add("rate_history")
        if inside & {"accel_x", "accel_y", "accel_z", "accel_own"}:
            names.add("accel_history")
    return frozenset(names)


@functools.lru_cache(maxsize=4096)
def reads_own_axis(formula: str, parameters=()) -> bool:
    """Whether a formula reads an output axis's own input (``rate_own``, ``accel_own``)."""
    return any(isinstance(n, ast.Name) and n.id in OWN_AXIS for n in ast.walk(_parse(formula, parameters)))


def _parse(formula: str, parameters=()) -> ast.AST:
    """The formula's tree, checked; parsed once per formula and names (a profile evaluates
    the same formula hundreds of times). The tree is only read, never changed."""
    if isinstance(formula, str) and isinstance(parameters, tuple):
        return _parse_cached(formula, parameters)
    return _parse_checked(formula, parameters)


@functools.lru_cache(maxsize=4096)
def _parse_cached(formula: str, parameters: tuple) -> ast.AST:
    return _parse_checked(formula, parameters)


def _parse_checked(formula, parameters=()) -> ast.AST:
    if not isinstance(formula, str) or len(formula) > 500:
        raise ConfigError(f"a formula must be text of at most 500 characters, got {formula!r:.60}")
    try:
        tree = ast.parse(formula, mode="eval").body
    except (SyntaxError, ValueError, MemoryError, RecursionError):
        raise ConfigError(f"cannot read the formula {formula!r}") from None
    known = (*FORMULA_COLUMNS, *parameters)
    for node in ast.walk(tree):
        allowed = (
            ast.BinOp,
            ast.UnaryOp,
            ast.USub,
            ast.UAdd,
            ast.Name,
            ast.Constant,
            ast.Call,
            ast.Load,
            *_OPERATORS,
        )
        if not isinstance(node, allowed):
            raise ConfigError(
                f"formula {formula!r}: {type(node).__name__} is not allowed "
                "(numbers, inputs, parameters, + - * / **, abs sqrt exp log sign tanh "
                "sin cos, lag, play, duhem)"
            )
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.keywords:
                raise ConfigError(
                    f"formula {formula!r}: only {', '.join(_FUNCTIONS)}, lag, play and duhem may be called"
                )
            if node.func.id in HISTORIES:
                _check_history(formula, node, parameters)
            elif node.func.id not in _FUNCTIONS or len(node.args) != 1:
                raise ConfigError(
                    f"formula {formula!r}: only {', '.join(_FUNCTIONS)} (one argument "
                    "each), lag(x, tau), play(x, w) and duhem(x, w) may be called"
                )
        if isinstance(node, ast.Constant) and (
            isinstance(node.value, bool)
            or not isinstance(node.value, (int, float))
            or not _finite_number(node.value)
        ):
            raise ConfigError(f"formula {formula!r}: only finite numbers may appear as constants")
        if (
            isinstance(node, ast.Name)
            and node.id not in _FUNCTIONS
            and node.id not in HISTORIES
            and node.id not in known
        ):
            raise ConfigError(
                f"formula {formula!r}: {node.id} is neither an input a formula can "
                f"read ({', '.join(FORMULA_COLUMNS)}) nor one of its parameters"
            )
    return tree


def _called(call: ast.Call) -> str:
    """The function a call of a parsed formula names (:func:`_parse` admits only names)."""
    return call.func.id if isinstance(call.func, ast.Name) else ""


def _check_history(formula: str, node: ast.Call, parameters) -> None:
    """``lag(x, tau)`` / ``play(x, w)`` / ``duhem(x, w)``: two arguments, ``x`` a formula of the record's inputs
    (no history inside a history), the size a number or a parameter."""
    what = "tau in seconds" if _called(node) == "lag" else "w its width in the input's unit"
    usage = (
        f"formula {formula!r}: write {_called(node)}(x, {what.split()[0]}), x an input of the "
        f"session's record ({', '.join(RECORD_INPUTS)}) or a formula of them, {what} "
        "(a number or a parameter)"
    )
    if len(node.args) != 2:
        raise ConfigError(usage)
    inner = list(ast.walk(node.args[0]))
    if any(isinstance(n, ast.Call) and _called(n) in HISTORIES for n in inner):
        raise ConfigError(
            f"formula {formula!r}: a history cannot hold another ({_called(node)} of a lag, a play or a duhem)"
        )
    for n in inner:
        if (
            isinstance(n, ast.Name)
            and n.id not in _FUNCTIONS
            and n.id not in RECORD_INPUTS
            and n.id not in parameters
        ):
            raise ConfigError(usage + f"; {n.id} is not in the record")
    if _called(node) == "duhem" and ast.unparse(node.args[0]) != "temp":
        # Its state before the record is the room's, which only the temperature has.
        raise ConfigError(
            f"formula {formula!r}: duhem(temp, w) is the temperature's direction "
            "of travel; it reads the temperature alone"
        )
    if not all(
        isinstance(n, (ast.Constant, ast.UnaryOp, ast.USub, ast.UAdd, ast.Load))
        or (isinstance(n, ast.Name) and n.id in parameters)
        for n in ast.walk(node.args[1])
    ):
        raise ConfigError(usage)


def _finite_number(value) -> bool:
    try:
        return bool(np.isfinite(float(value)))
    except OverflowError:
        return False


def evaluate(formula: str, data, parameters: Mapping[str, float] | None = None) -> np.ndarray:
    """The formula over ``data`` (a mapping of inputs; ``data.lag`` for lags) with the
    parameters' values."""
    parameters = dict(parameters or {})
    with np.errstate(all="ignore"):
        return _value(_parse(formula, tuple(parameters)), data, parameters, formula)


def _value(node, data, parameters, formula):
    """One node of a parsed formula over ``data``."""
    if isinstance(node, ast.Constant):
        return float(cast(float, node.value))  # _parse admits finite numbers only
    if isinstance(node, ast.Name):
        if node.id in parameters:
            return float(parameters[node.id])
        return np.asarray(data[node.id], dtype=float)
    if isinstance(node, ast.UnaryOp):
        v = _value(node.operand, data, parameters, formula)
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.BinOp):
        return _OPERATORS[type(node.op)](
            _value(node.left, data, parameters, formula), _value(node.right, data, parameters, formula)
        )
    if _called(node) in HISTORIES:
        return _history(node, data, parameters, formula)
    return _FUNCTIONS[_called(node)](*[_value(a, data, parameters, formula) for a in node.args])


def _history(node: ast.Call, data, parameters, formula):
    """``lag(x, tau)``, ``play(x, w)`` or ``duhem(x, w)``: ``x`` over the session's record, through the
    operator, at ``data``'s times (:meth:`gyrocal.terms.signals.Inputs.history`)."""
    size = _value(node.args[1], data, parameters, formula)
    arg = node.args[0]
    if _called(node) == "lag":
        if np.ndim(size) or not lag_time_constant_ok(size):
            raise ConfigError(
                f"formula {formula!r}: a lag's time constant must be a number of seconds >= 0, got {size!r}"
            )
        if isinstance(arg, ast.Name) and arg.id in LAGGABLE:
            return data.lag(arg.id, float(size))
        if float(size) == 0:  # no lag: the input itself
            return _value(arg, data, parameters, formula)
    elif np.ndim(size) or not (np.isfinite(size) and size > 0):
        raise ConfigError(
            f"formula {formula!r}: a {_called(node)} operator's width must be a positive number, got {size!r}"
        )
    axis = getattr(data, "axis", None)
    names = {n.id for n in ast.walk(arg) if isinstance(n, ast.Name)}
    reads = {
        k
        for k, group in (("rate_history", "rate"), ("accel_history", "accel"))
        if any(n.startswith(group) for n in names)
    }
    used = {k: float(v) for k, v in parameters.items() if k in names}
    key = (ast.unparse(arg), axis if names & set(OWN_AXIS) else None, tuple(sorted(used.items())))
    # The temperature's play starts from the room, as its Duhem state does; both read it
    # through a short lag (on the samples' noise an operator narrower than it would chatter).
    temperature = _called(node) in ("play", "duhem") and key[0] == "temp"
    operator = "temperature_play" if temperature and _called(node) == "play" else _called(node)
    return data.history(
        key,
        lambda series: _value(arg, _Record(series, axis), used, formula),
        operator,
        float(size),
        reads,
        smooth=temperature,
    )


class _Record:
    """The session's record as a formula inside a history reads it (the own axis's input
    for ``rate_own``, ``accel_own``)."""

    def __init__(self, series, axis):
        self.series, self.axis = series, axis

    def __getitem__(self, name):
        kind = OWN_AXIS.get(name)
        if kind:
            if self.axis is None:
                raise ConfigError(f"{name} is read per output axis")
            name = f"{kind}_{self.axis}"
        return self.series.column(name)


def lag_time_constant_ok(tau) -> bool:
    return bool(np.isfinite(tau) and tau >= 0)


def _plain_parameters(values, formula: str, what: str) -> dict:
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise ConfigError(f"expression {formula!r}: {what} must be a mapping of names")
    out = {}
    for name, value in values.items():
        if (
            not isinstance(name, str)
            or not name.isidentifier()
            or name in FORMULA_COLUMNS
            or name in _FUNCTIONS
            or name == "lag"
        ):
            raise ConfigError(
                f"expression {formula!r}: {name!r} cannot name a parameter "
                "(a plain name that is not an input or a function)"
            )
        out[name] = value
    return out


@register_term("expression")
@dataclass(frozen=True, eq=False)
class Expression(Term):
    """``e_a += c_a · f(inputs)`` for a formula ``f`` under the coefficient prefix ``label``.

    ``parameters`` gives the formula's named constants their values; ``profile`` gives a
    nonlinear parameter (a time constant, in seconds) its search bounds ``[low, high]``,
    and the fit finds its value (:mod:`gyrocal.fit.profile`), which the calibration then holds
    under ``parameters``. A formula reading ``t``, ``temp_rate`` or a lag describes a
    session-wide effect: its coefficients default to ``scope: global``. [deg/s per unit of
    the formula]"""

    label: str = "expression"
    formula: str = "0"
    parameters: dict = field(default_factory=dict)
    profile: dict = field(default_factory=dict)
    unit = "deg/s/formula"

    def __post_init__(self):
        if not self.label.isidentifier():
            raise ConfigError(f"expression label {self.label!r} must be a plain name")
        parameters = _plain_parameters(self.parameters, self.formula, "parameters")
        profile = _plain_parameters(self.profile, self.formula, "profile")
        for name, value in parameters.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not _finite_number(value):
                raise ConfigError(
                    f"expression {self.label}: parameter {name} must be a finite number, got {value!r}"
                )
        for name, bounds in profile.items():
            ok = (
                isinstance(bounds, (list, tuple))
                and len(bounds) == 2
                and all(
                    isinstance(b, (int, float)) and not isinstance(b, bool) and _finite_number(b)
                    for b in bounds
                )
            )
            if not ok or not 0 < bounds[0] < bounds[1]:
                raise ConfigError(
                    f"expression {self.label}: profile {name} must be [low, high] "
                    f"with 0 < low < high, got {bounds!r}"
                )
            profile[name] = [float(bounds[0]), float(bounds[1])]
            parameters.setdefault(name, float(np.sqrt(bounds[0] * bounds[1])))
        object.__setattr__(self, "parameters", {k: parameters[k] for k in sorted(parameters)})
        object.__setattr__(self, "profile", {k: profile[k] for k in sorted(profile)})
        object.__setattr__(self, "needs", formula_names(self.formula, tuple(self.parameters)))

    def __eq__(self, other):  # by its settings, which hold dicts: unhashable (__hash__ is None)
        return isinstance(other, Expression) and self.params() == other.params()

    @property
    def identity(self) -> tuple:
        return (self.name, self.label)

    def nonlinear(self) -> dict[str, tuple[float, float]]:
        return {k: tuple(v) for k, v in self.profile.items()}

    def with_settings(self, **values) -> Term:
        term = dataclasses.replace(self, parameters={**self.parameters, **values})
        scope = getattr(self, "_scope", None)
        if scope:
            object.__setattr__(term, "_scope", scope)
        return term

    def coefficients(self):
        return [f"{self.label}.{a}" for a in AXES]

    def columns(self, data):
        n = (len(data["rate_x"]),)
        if not reads_own_axis(self.formula, tuple(self.parameters)):
            v = np.broadcast_to(evaluate(self.formula, data, self.parameters), n)
            return {f"{self.label}.{a}": v for a in AXES}
        return {
            f"{self.label}.{a}": np.broadcast_to(
                evaluate(self.formula, _own_axis(data, a), self.parameters), n
            )
            for a in AXES
        }


class _OwnAxis:
    """``data`` as one output axis's formula reads it: ``rate_own`` is that axis's rate."""

    def __init__(self, data, axis: str):
        self.data, self.axis = data, axis

    def __getitem__(self, name):
        kind = OWN_AXIS.get(name)
        return self.data[f"{kind}_{self.axis}" if kind else name]

    def lag(self, name, tau):
        return self.data.lag(name, tau)

    def history(self, *args, **kwargs):
        return self.data.history(*args, **kwargs)


def _own_axis(data, axis: str) -> _OwnAxis:
    return _OwnAxis(data, axis)
