"""Physical effects as terms of the gyro error model, their registry, the signals they read.
May import: io.

The model describes the error of the gyro output, ``e = w - w_true`` (deg/s), as a sum of
terms, each linear in its coefficients. A term defines its regressor columns per sample,
one per coefficient, from the inputs of :mod:`gyrocal.terms.signals` (the true rate in the sensor
frame ``rate_x/y/z``, ``ref_rate``, ``accel_x/y/z``, ``temp``, and the series signals ``t``,
``temp_rate`` and ``data.lag(...)``); the library takes hold means for the fit and samples
for apply, so both see the same effect. Names are ``<term>.<output axis>[.<detail>]``: the
output axis is always the second part, so a fit can take each output axis's columns by name.

A term's coefficients are per temperature point (``scope = "point"``: a grid model fits
them at every point and interpolates) or one set for the session (``scope = "global"``:
fitted jointly over all points); by default (``auto``) a term that reads a series signal is
global and any other per point. Settings named in ``profile`` (a time constant, a lag) are
nonlinear parameters: the fit searches them within their bounds (:mod:`gyrocal.fit.profile`).

With the base terms the seed-000 model (Eq 12) reads ``w = K w_true + B``, where
``K = I + scale + misalignment`` and ``B = bias``; see :mod:`gyrocal.terms.base`.

The registry is the one place an effect is added: ``@register_term("name")`` on a frozen
dataclass subclass of :class:`Term`. Calibration files name their terms and are rebuilt
from here.
"""

from __future__ import annotations

import ast
import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..io import AXES as AXES
from ..io.errors import ConfigError, MissingInputError

TERMS: dict[str, type[Term]] = {}


def literal(value) -> str:
    """A setting as a Python literal whose strings are in double quotes: a spec string is then
    one shell word inside single quotes and one YAML scalar inside single quotes, pasted as
    printed."""
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{literal(k)}: {literal(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(map(literal, value)) + "]"
    if isinstance(value, tuple):
        return "(" + ", ".join(map(literal, value)) + ("," if len(value) == 1 else "") + ")"
    return repr(value)


class Term:
    """A physical effect: regressor columns for the gyro error, one per coefficient."""

    # A class sets these; a term whose settings decide them sets its own when it is made.
    name: str = ""
    needs: frozenset[str] = frozenset()  # observation columns required
    profile: Mapping[str, tuple[float, float]] = {}  # nonlinear setting -> bounds
    scope: ClassVar[str] = "auto"  # "point" or "global" in a grid model; auto: global
    # when the term reads a series signal (t, temp_rate, lag)
    # The file a user term comes from and its SHA-256 (gyrocal.terms.user.load_terms)
    source_file: ClassVar[str | None] = None
    source_sha256: ClassVar[str | None] = None

    # A class sets these as constants, or computes them from the term's settings.
    @property
    def unit(self) -> str:
        """The unit of the coefficients."""
        return ""

    @property
    def varies_with_temperature(self) -> bool:
        """Whether the term depends on the temperature alone."""
        return False

    @property
    def moving_temperature(self) -> bool:
        """Whether the term is seen only where the temperature moves within a point."""
        return False

    def coefficients(self) -> list[str]:
        """Full coefficient names, in a fixed order."""
        raise NotImplementedError

    def columns(self, data: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Regressor column per coefficient name, each of the length of ``data``."""
        raise NotImplementedError

    def params(self) -> dict[str, Any]:
        """The term's settings, JSON-plain (what a calibration file stores to rebuild it)."""
        return (
            {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
            if dataclasses.is_dataclass(self)
            else {}
        )

    def spec(self) -> dict[str, Any]:
        """What a calibration file stores to rebuild the term; a user term also records the
        file it came from and that file's SHA-256."""
        spec = {"name": self.name, **self.params()}
        if self.coefficient_scope != self.default_scope():
            spec["scope"] = self.coefficient_scope
        source = type(self).source_file
        if source:
            spec["source"] = {"file": Path(source).name, "sha256": type(self).source_sha256}
        return spec

    def spec_string(self) -> str:
        """The term as ``--add-term`` and config files take it: ``name`` or
        ``name(key=value, ...)`` for settings that differ from the defaults."""
        defaults: dict[str, Any] = (
            {
                f.name: f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
                for f in dataclasses.fields(self)
            }
            if dataclasses.is_dataclass(self)
            else {}
        )
        changed = {k: v for k, v in self.params().items() if defaults.get(k, dataclasses.MISSING) != v}
        if self.coefficient_scope != self.default_scope():
            changed["scope"] = self.coefficient_scope
        return self.name + (
            "(" + ", ".join(f"{k}={literal(v)}" for k, v in changed.items()) + ")" if changed else ""
        )

    @property
    def identity(self) -> tuple:
        """What makes two terms the same effect: a model holds one term per identity, and
        adding one replaces the other (``bias_temp_poly(degree=3)`` replaces degree 2)."""
        return (self.name,)

    @property
    def coefficient_scope(self) -> str:
        """``point`` or ``global``: where a grid model fits this term's coefficients (the
        class's ``scope``, unless the term was made with ``scope=...``)."""
        return getattr(self, "_scope", None) or self.default_scope()

    def default_scope(self) -> str:
        if self.scope != "auto":
            return self.scope
        if "_auto_scope" not in self.__dict__:  # the probe runs once per term
            object.__setattr__(self, "_auto_scope", "global" if self.reads_series() else "point")
        return self.__dict__["_auto_scope"]

    def reads_series(self) -> bool:
        """Whether the term reads ``t``, ``temp_rate`` or a lag: an effect of time or of
        the temperature's history, one per session (each temperature point covers only
        its own block of time)."""
        from .signals import SERIES_INPUTS

        return bool(self.inputs() & SERIES_INPUTS)

    def inputs(self) -> frozenset[str]:
        """The inputs the term reads: its ``needs`` and what it reads when evaluated on a
        probe of every input (so a term that forgot to declare one still gets it in
        ``apply``)."""
        if "_inputs" not in self.__dict__:
            from .signals import HOLD_INPUTS, Inputs, Series

            probe_t = np.array([0.0, 600.0])
            probe = Inputs(
                {
                    **{c: np.array([1.0, 2.0]) for c in HOLD_INPUTS},
                    "t": probe_t,
                    "temp_rate": np.array([0.1, 0.2]),
                },
                Series(probe_t, np.array([20.0, 21.0])),
                probe_t,
            )
            try:
                with np.errstate(all="ignore"):
                    self.columns(probe)
            except Exception:  # noqa: BLE001 - a term that fails on the probe: its needs
                pass
            object.__setattr__(self, "_inputs", frozenset(self.needs | probe.read))
        return self.__dict__["_inputs"]

    def nonlinear(self) -> dict[str, tuple[float, float]]:
        """Settings fitted by profiling, with their search bounds (both > 0)."""
        return dict(self.profile)

    def with_settings(self, **values) -> Term:
        """The same term, scope kept, with some settings changed (a profiled parameter)."""
        if not dataclasses.is_dataclass(self):
            raise TypeError(f"term {self.name} is no dataclass: its settings cannot be changed")
        term = dataclasses.replace(self, **values)
        scope = getattr(self, "_scope", None)
        if scope:
            object.__setattr__(term, "_scope", scope)
        return term

    def transform_inputs(self, data):
        """Hold-level inputs every term of the model reads, as this term redefines them (a
        die temperature for the logged one); most terms leave them as they are."""
        return data

    def sample_transform(self):
        """For samples in time order, given in consecutive pieces: a callable taking and
        returning the inputs as :meth:`transform_inputs` redefines them, with the state it
        carries between pieces; None for a term that redefines nothing."""
        return None

    def penalty(self, names: list[str]) -> np.ndarray | None:
        """A roughness penalty ``c' Ω c`` on the coefficients ``names`` (of one output axis):
        Ω (symmetric, positive semi-definite), or None for an unpenalised term."""
        return None

    def check_inputs(self, data: Mapping[str, np.ndarray], source=None) -> None:
        from .signals import SERIES_INPUTS

        series = "series" in data or "t" in data
        missing = sorted(c for c in self.needs if c not in data and not (series and c in SERIES_INPUTS))
        if missing:
            raise MissingInputError(
                f"term {self.spec_string()} needs {', '.join(missing)}, which the data lack", source=source
            )


class Restricted(Term):
    """A term with some of its coefficients held at zero (``drop``, names without the
    term's own): the part of an effect a protocol can tell apart from the rest of the
    model. On three mounts with gravity along one axis each, a g-sensitivity's column of
    the third axis is the bias less the other two; without it, the other two coefficients
    fit each output's sensitivity differences, which is all those mounts show and all a
    session of the same protocol needs. The same effect as the full term: it replaces it
    in a model, and the full term replaces it."""

    def __init__(self, term: Term, drop):
        if isinstance(drop, str) or not isinstance(drop, (list, tuple)):
            raise ConfigError(f"term {term.name}: drop must be a list of coefficient names, got {drop!r}")
        prefix = term.name + "."
        own = [c.removeprefix(prefix) for c in term.coefficients()]
        unknown = [d for d in drop if d not in own]
        if unknown:
            raise ConfigError(
                f"term {term.name} has no coefficient {', '.join(map(str, unknown))} "
                f"to drop (it has {', '.join(own)})"
            )
        self.term = term
        self.drop = tuple(d for d in own if d in set(drop))
        self.name = term.name
        self.needs = term.needs
        self.profile = term.profile

    def __eq__(self, other):
        return isinstance(other, Restricted) and (self.term, self.drop) == (other.term, other.drop)

    def __hash__(self):
        return hash((self.term, self.drop))

    def __getattr__(self, attribute):  # unit, needs, profile, ... are the term's
        if attribute.startswith("__") or attribute in ("term", "drop"):
            raise AttributeError(attribute)
        return getattr(self.term, attribute)

    @property
    def unit(self) -> str:
        return self.term.unit

    @property
    def varies_with_temperature(self) -> bool:
        return self.term.varies_with_temperature

    @property
    def moving_temperature(self) -> bool:
        return self.term.moving_temperature

    def coefficients(self) -> list[str]:
        dropped = {f"{self.term.name}.{d}" for d in self.drop}
        return [c for c in self.term.coefficients() if c not in dropped]

    def columns(self, data):
        kept = set(self.coefficients())
        return {k: v for k, v in self.term.columns(data).items() if k in kept}

    def params(self) -> dict[str, Any]:
        return {**self.term.params(), "drop": list(self.drop)}

    def spec(self) -> dict[str, Any]:
        return {**self.term.spec(), "drop": list(self.drop)}

    def spec_string(self) -> str:
        inner = self.term.spec_string()
        setting = "drop=[" + ", ".join(f'"{d}"' for d in self.drop) + "]"  # shell-quotable
        return inner[:-1] + f", {setting})" if inner.endswith(")") else f"{inner}({setting})"

    @property
    def identity(self) -> tuple:
        return self.term.identity

    @property
    def coefficient_scope(self) -> str:
        return self.term.coefficient_scope

    def default_scope(self) -> str:
        return self.term.default_scope()

    def inputs(self) -> frozenset[str]:
        return self.term.inputs()

    def nonlinear(self):
        return self.term.nonlinear()

    def with_settings(self, **values) -> Term:
        return Restricted(self.term.with_settings(**values), self.drop)

    def check_inputs(self, data, source=None) -> None:
        self.term.check_inputs(data, source)

    def transform_inputs(self, data):
        return self.term.transform_inputs(data)

    def sample_transform(self):
        return self.term.sample_transform()

    def penalty(self, names):
        return self.term.penalty(names)


def register_term(name: str):
    """Class decorator adding a term to the registry under ``name``."""

    def add(cls):
        if name in TERMS and TERMS[name] is not cls:
            raise ConfigError(
                f"term name {name!r} is already registered by "
                f"{TERMS[name].__module__}.{TERMS[name].__qualname__}"
            )
        cls.name = name
        TERMS[name] = cls
        return cls

    return add


def parse_spec(text: str) -> dict[str, Any]:
    """``"name"`` or ``"name(key=value, ...)"`` (values are Python literals) as a term's spec:
    ``name`` and the term's own settings, which differ from term to term."""
    text = text.strip()
    try:
        node = ast.parse(text, mode="eval").body
    except SyntaxError:
        raise ConfigError(f"cannot read model term {text!r}; write name or name(key=value)") from None
    if isinstance(node, ast.Name):
        return {"name": node.id}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.args:
        try:
            # a None key (a **mapping) is passed on for the term to refuse
            params: dict[Any, Any] = {kw.arg: ast.literal_eval(kw.value) for kw in node.keywords}
        except ValueError:
            raise ConfigError(f"model term {text!r}: settings must be plain values") from None
        return {"name": node.func.id, **params}
    raise ConfigError(f"cannot read model term {text!r}; write name or name(key=value)")


def make_term(spec) -> Term:
    """A term from a name (``"bias"``), a spec string (``"bias_temp_poly(degree=3)"``) or
    a mapping (``{"name": "...", <params>}``)."""
    if isinstance(spec, Term):
        return spec
    if isinstance(spec, str):
        spec = parse_spec(spec)
    if not isinstance(spec, Mapping) or "name" not in spec:
        raise ConfigError(f"a model term must be a name or a mapping with 'name', got {spec!r}")
    params = dict(spec)
    name = params.pop("name")
    source = params.pop("source", None)
    cls = TERMS.get(name)
    if cls is None:
        hint = (
            f" (it comes from the term file {source.get('file')}: load that file)"
            if isinstance(source, Mapping)
            else ""
        )
        raise ConfigError(f"unknown model term {name!r}{hint}; known terms: {', '.join(sorted(TERMS))}")
    if isinstance(source, Mapping) and source.get("sha256") != getattr(cls, "source_sha256", None):
        raise ConfigError(
            f"term {name} was fitted with {source.get('file')} of SHA-256 "
            f"{str(source.get('sha256'))[:12]}…, but the loaded definition differs"
        )
    scope = params.pop("scope", None)
    if scope not in (None, "point", "global"):
        raise ConfigError(f"term {name}: scope must be 'point' or 'global', got {scope!r}")
    drop = params.pop("drop", None)
    try:
        term = cls(**params)
    except TypeError as exc:
        raise ConfigError(f"term {name}: {exc}") from None
    if scope is not None:
        object.__setattr__(term, "_scope", scope)
    return term if not drop else Restricted(term, drop)


from . import base, effects, empirical, user  # noqa: E402,F401  (register the library's terms)
