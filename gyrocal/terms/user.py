"""A user's own effects: terms from a Python file, and one-line expressions of columns.

A term file is an ordinary Python file that defines and registers terms exactly as the
library does (``@register_term("name")`` on a frozen dataclass subclass of ``Term``). It is
loaded by path; its SHA-256 is recorded in every calibration that uses one of its terms, and
loading such a calibration checks it, so a calibration is never applied with a term whose
code has changed.

An expression term is a formula over observation columns (``accel_x * rate_y``,
``temp_rate ** 2``, ``abs(rate_z)``), one coefficient per output axis. Formulas are read by
a small interpreter that knows numbers, the columns of ``FORMULA_COLUMNS``, + - * / **,
unary minus and a few one-argument functions: nothing else in the formula can run.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from . import AXES, TERMS, Term, register_term

_LOADED: dict[str, str] = {}   # resolved path -> sha256


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
    before = set(TERMS)
    module_name = f"gyrocal_user_terms_{digest[:12]}"
    spec = importlib.util.spec_from_file_location(module_name, path)
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


_FUNCTIONS = {"abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log, "sign": np.sign,
              "sin": np.sin, "cos": np.cos}
_OPERATORS = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
              ast.Div: np.divide, ast.Pow: np.power}


# Columns a formula may read: those every observation table has, which apply can also
# give for every sample (temp_rate derived from the log's t and temp).
FORMULA_COLUMNS = ("temp", "temp_rate", "rate_x", "rate_y", "rate_z", "accel_x", "accel_y", "accel_z")


def formula_names(formula: str) -> frozenset[str]:
    tree = _parse(formula)
    return frozenset(n.id for n in ast.walk(tree) if isinstance(n, ast.Name)
                     and n.id not in _FUNCTIONS)


def _parse(formula: str) -> ast.AST:
    if not isinstance(formula, str) or len(formula) > 500:
        raise ConfigError(f"a formula must be text of at most 500 characters, got {formula!r:.60}")
    try:
        tree = ast.parse(formula, mode="eval").body
    except (SyntaxError, ValueError, MemoryError, RecursionError):
        raise ConfigError(f"cannot read the formula {formula!r}") from None
    for node in ast.walk(tree):
        allowed = (ast.BinOp, ast.UnaryOp, ast.USub, ast.UAdd, ast.Name, ast.Constant,
                   ast.Call, ast.Load, *_OPERATORS)
        if not isinstance(node, allowed):
            raise ConfigError(f"formula {formula!r}: {type(node).__name__} is not allowed "
                              "(numbers, columns, + - * / **, abs sqrt exp log sign sin cos)")
        if isinstance(node, ast.Call) and (not isinstance(node.func, ast.Name)
                                           or node.func.id not in _FUNCTIONS or node.keywords
                                           or len(node.args) != 1):
            raise ConfigError(f"formula {formula!r}: only {', '.join(_FUNCTIONS)} may be called, "
                              "each with one argument")
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)) \
                    or not _finite_number(node.value):
                raise ConfigError(f"formula {formula!r}: only finite numbers may appear as constants")
        if isinstance(node, ast.Name) and node.id not in _FUNCTIONS and node.id not in FORMULA_COLUMNS:
            raise ConfigError(f"formula {formula!r}: {node.id} is not a column a formula can read "
                              f"({', '.join(FORMULA_COLUMNS)})")
    return tree


def _finite_number(value) -> bool:
    try:
        return bool(np.isfinite(float(value)))
    except OverflowError:
        return False


def evaluate(formula: str, data) -> np.ndarray:
    def value(node):
        if isinstance(node, ast.Constant):
            return float(node.value)
        if isinstance(node, ast.Name):
            return np.asarray(data[node.id], dtype=float)
        if isinstance(node, ast.UnaryOp):
            v = value(node.operand)
            return -v if isinstance(node.op, ast.USub) else v
        if isinstance(node, ast.BinOp):
            return _OPERATORS[type(node.op)](value(node.left), value(node.right))
        return _FUNCTIONS[node.func.id](*[value(a) for a in node.args])
    with np.errstate(all="ignore"):
        return value(_parse(formula))


@register_term("expression")
@dataclass(frozen=True)
class Expression(Term):
    """``e_a += c_a · f(columns)`` for a formula ``f`` of observation columns, under the
    coefficient prefix ``label``. [deg/s per unit of the formula]"""

    label: str = "expression"
    formula: str = "0"
    unit = "deg/s/formula"

    def __post_init__(self):
        if not self.label.isidentifier():
            raise ConfigError(f"expression label {self.label!r} must be a plain name")
        object.__setattr__(self, "needs", formula_names(self.formula))

    @property
    def identity(self) -> tuple:
        return (self.name, self.label)

    def coefficients(self):
        return [f"{self.label}.{a}" for a in AXES]

    def columns(self, data):
        v = np.broadcast_to(evaluate(self.formula, data), (len(data["rate_x"]),))
        return {f"{self.label}.{a}": v for a in AXES}
