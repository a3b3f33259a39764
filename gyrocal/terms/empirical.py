"""Empirical terms: an effect of a shape no formula of the library gives, as a smooth
function of one input, its degrees of freedom counted.

``smooth(input=..., knots=[...])`` adds to each output axis ``a`` a cubic spline of the
input on the given breakpoints (twice continuously differentiable, a B-spline basis),
``e_a += Σ_k c_ak B_k(x)``, one coefficient per basis function and axis (its degrees of
freedom); ``by="rate_own"`` multiplies it by the axis's own rate (a scale factor that
changes with the input). The spline's constant is left out (the bias, or the scale, holds
it) and, with ``linear=False``, its slope at the lowest knot too (for a model that already
has the linear part). A light penalty on the coefficients' second differences (Eilers and
Marx's P-spline) carries the smoothest curve across a stretch of the input without holds,
as when a temperature point is left out to validate. The input is clamped to the end knots,
where the fit saw data: nothing is extrapolated, as the temperature grid does not.

Inputs: ``t`` (time since the log's first sample), ``temp``, ``temp_rate``, ``ref_rate`` and
``rate_own`` (the output axis's own rate: a rate nonlinearity of any shape).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..io.errors import ConfigError
from . import AXES, Term, register_term

INPUTS = {"t": "s", "temp": "degC", "temp_rate": "degC/min", "ref_rate": "deg/s", "rate_own": "deg/s"}
BY = (None, "rate_own")
MAX_KNOTS = 12


def spline_basis(x: np.ndarray, knots, *, linear: bool = True) -> np.ndarray:
    """(n, K + 1 or K) cubic B-spline basis at ``x`` (clamped to the end knots) on the
    interior breakpoints ``knots``, its end knots repeated, without the first basis
    function (the spline is 0 at the lowest knot: the bias, or the scale, holds the
    constant) and, with ``linear=False``, the second too (nor its slope there: a model that
    has the linear part already holds it). Local support keeps the basis well conditioned."""
    from scipy.interpolate import BSpline

    knots = np.asarray(knots, dtype=float)
    t = np.r_[[knots[0]] * 3, knots, [knots[-1]] * 3]
    u = np.clip(np.asarray(x, dtype=float), knots[0], knots[-1])
    full = BSpline.design_matrix(u, t, 3).toarray()
    return full[:, 1 if linear else 2 :]


@register_term("smooth")
@dataclass(frozen=True)
class Smooth(Term):
    """An effect of one input of any smooth shape: a natural cubic spline of ``input`` with
    the given ``knots`` (2 to 12, increasing, in the input's unit), optionally times the
    axis's own rate (``by="rate_own"``). [deg/s, or 1 with ``by``]"""

    input: str = "t"
    knots: tuple = (0.0, 1.0)
    by: str | None = None
    linear: bool = True
    label: str = ""

    def __post_init__(self):
        if self.input not in INPUTS:
            raise ConfigError(f"term smooth: input must be one of {', '.join(INPUTS)}, got {self.input!r}")
        if self.by not in BY:
            raise ConfigError(f"term smooth: by must be rate_own or absent, got {self.by!r}")
        try:
            knots = tuple(float(k) for k in self.knots)
        except (TypeError, ValueError):
            raise ConfigError(f"term smooth: knots must be a list of numbers, got {self.knots!r}") from None
        if (
            not 2 <= len(knots) <= MAX_KNOTS
            or not all(map(math.isfinite, knots))
            or any(b <= a for a, b in zip(knots, knots[1:], strict=False))
        ):
            raise ConfigError(
                f"term smooth: knots must be 2 to {MAX_KNOTS} increasing finite numbers, got {self.knots!r}"
            )
        if not self.linear and len(knots) < 3:
            raise ConfigError("term smooth: without its linear part a spline needs 3 knots or more")
        label = self.label or f"smooth_{self.input}" + ("_by_rate" if self.by else "")
        if not label.isidentifier():
            raise ConfigError(f"term smooth: label {label!r} must be a plain name")
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "label", label)
        needs = {"rate_x", "rate_y", "rate_z"} if "rate_own" in (self.input, self.by) else set()
        needs |= {self.input} if self.input != "rate_own" else set()
        object.__setattr__(self, "needs", frozenset(needs))

    @property
    def unit(self) -> str:
        return "1" if self.by else "deg/s"

    @property
    def varies_with_temperature(self) -> bool:
        return self.input == "temp"

    @property
    def identity(self) -> tuple:
        return (self.name, self.label)

    @property
    def size(self) -> int:
        return len(self.knots) + int(self.linear)

    def params(self) -> dict[str, Any]:
        return {
            "input": self.input,
            "knots": list(self.knots),
            "by": self.by,
            "linear": self.linear,
            "label": self.label,
        }

    def spec_string(self) -> str:
        # Double quotes, so that the option is one shell word in single quotes.
        parts = [f'input="{self.input}"', f"knots=[{', '.join(map(_number, self.knots))}]"]
        if self.by:
            parts.append(f'by="{self.by}"')
        if not self.linear:
            parts.append("linear=False")
        if self.label != f"smooth_{self.input}" + ("_by_rate" if self.by else ""):
            parts.append(f'label="{self.label}"')
        return f"smooth({', '.join(parts)})"

    def coefficients(self) -> list[str]:
        return [f"{self.label}.{a}.k{j + 1}" for a in AXES for j in range(self.size)]

    def columns(self, data):
        out = {}
        for a in AXES:
            x = data[f"rate_{a}"] if self.input == "rate_own" else data[self.input]
            basis = spline_basis(x, self.knots, linear=self.linear)
            if self.by:
                basis = basis * np.asarray(data[f"rate_{a}"], dtype=float)[:, None]
            out.update({f"{self.label}.{a}.k{j + 1}": basis[:, j] for j in range(self.size)})
        return out

    def penalty(self, names: list[str]) -> np.ndarray:
        """Second differences of the coefficients (the basis functions dropped counted as 0),
        ``Σ (c_k − 2 c_{k+1} + c_{k+2})²``: light (:data:`gyrocal.fit.model.PENALTY_WEIGHT`),
        it draws the smoothest curve across a stretch of the input without holds."""
        dropped = 2 - int(self.linear)
        n = self.size + dropped
        D = np.diff(np.eye(n), 2, axis=0)[:, dropped:]
        omega = D.T @ D
        index = [int(n.rsplit(".k", 1)[1]) - 1 for n in names]
        return omega[np.ix_(index, index)]

    def shape(self, coefficients: dict, x: np.ndarray, axis: str) -> np.ndarray:
        """The fitted function of the input on one output axis (deg/s, or 1 with ``by``)."""
        basis = spline_basis(x, self.knots, linear=self.linear)
        c = np.array([coefficients[f"{self.label}.{axis}.k{j + 1}"] for j in range(self.size)])
        return basis @ c


MAX_LEVELS = 24


def level_basis(x: np.ndarray, levels, anchors) -> np.ndarray:
    """(n, L − len(anchors)) straight-line interpolation weights of ``x`` between the
    ``levels`` (each column the "hat" of one level: 1 there, 0 at the others, clamped
    outside), without the columns of the ``anchors`` (indices), where the table is 0."""
    x = np.asarray(x, dtype=float)
    levels = np.asarray(levels, dtype=float)
    keep = [k for k in range(levels.size) if k not in anchors]
    eye = np.eye(levels.size)
    return np.column_stack([np.interp(x, levels, eye[k]) for k in keep]) if keep else np.zeros((x.size, 0))


def _number(v: float) -> str:
    """A level as a person writes it, exactly: ``-400``, ``171.887338``."""
    return f"{v:g}" if float(f"{v:g}") == v else repr(v)


def _levels(values, what: str) -> tuple:
    try:
        levels = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(f"term {what}: values must be a list of numbers, got {values!r}") from None
    if (
        not 3 <= len(levels) <= MAX_LEVELS
        or not all(map(math.isfinite, levels))
        or any(b <= a for a, b in zip(levels, levels[1:], strict=False))
    ):
        raise ConfigError(
            f"term {what}: values must be 3 to {MAX_LEVELS} increasing finite numbers, got {values!r}"
        )
    return levels


@register_term("levels")
@dataclass(frozen=True)
class Levels(Term):
    """An effect of the axis's own rate known at the protocol's levels of it (a turntable's
    rates): a table of its value at each level, ``e_a += Σ_k c_ak h_k(ω_a)``, with ``h_k``
    the straight-line interpolation weight of level k (valid at the levels; between them a
    straight line, outside the end value). ``by="rate_own"`` multiplies it by the rate (a
    scale that changes with the rate: a range switch). The table is 0 at its anchors, where
    the model's bias and scale hold it: the two lowest levels, or with ``by`` the level
    nearest 0 (where the product is 0) and the lowest. One table per session: the shape of
    the rate is the same at every temperature. [deg/s, or 1 with ``by``]"""

    values: tuple = (0.0, 1.0, 2.0)
    by: str | None = None
    label: str = ""
    scope = "global"
    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    def __post_init__(self):
        if self.by not in BY:
            raise ConfigError(f"term levels: by must be rate_own or absent, got {self.by!r}")
        object.__setattr__(self, "values", _levels(self.values, "levels"))
        label = self.label or ("levels_by_rate" if self.by else "levels_rate")
        if not label.isidentifier():
            raise ConfigError(f"term levels: label {label!r} must be a plain name")
        object.__setattr__(self, "label", label)

    @property
    def unit(self) -> str:
        return "1" if self.by else "deg/s"

    @property
    def identity(self) -> tuple:
        return (self.name, self.label)

    @property
    def anchors(self) -> tuple[int, ...]:
        levels = np.asarray(self.values)
        if self.by:
            zero = int(np.argmin(np.abs(levels)))
            return tuple(sorted({zero, 0 if zero else 1}))
        return (0, 1)

    def params(self) -> dict[str, Any]:
        return {"values": list(self.values), "by": self.by, "label": self.label}

    def spec_string(self) -> str:
        parts = [f"values=[{', '.join(map(_number, self.values))}]"]
        if self.by:
            parts.append(f'by="{self.by}"')
        if self.label != ("levels_by_rate" if self.by else "levels_rate"):
            parts.append(f'label="{self.label}"')
        return f"levels({', '.join(parts)})"

    def coefficients(self) -> list[str]:
        kept = [k for k in range(len(self.values)) if k not in self.anchors]
        return [f"{self.label}.{a}.k{k + 1}" for a in AXES for k in kept]

    def columns(self, data):
        out = {}
        kept = [k for k in range(len(self.values)) if k not in self.anchors]
        for a in AXES:
            rate = np.asarray(data[f"rate_{a}"], dtype=float)
            basis = level_basis(rate, self.values, self.anchors)
            if self.by:
                basis = basis * rate[:, None]
            out.update({f"{self.label}.{a}.k{k + 1}": basis[:, j] for j, k in enumerate(kept)})
        return out

    def shape(self, coefficients: dict, x: np.ndarray, axis: str) -> np.ndarray:
        """The table's function of the rate on one output axis (deg/s, or 1 with ``by``)."""
        kept = [k for k in range(len(self.values)) if k not in self.anchors]
        c = np.array([coefficients[f"{self.label}.{axis}.k{k + 1}"] for k in kept])
        return level_basis(x, self.values, self.anchors) @ c


CROSS_SHAPES = ("square", "abs", "signed_square", "levels")


@register_term("cross_rate")
@dataclass(frozen=True)
class CrossRate(Term):
    """The rate of another axis on each output: ``e_a += Σ_{b≠a} f_ab(ω_b)``, one shape per
    pair of axes: ``square`` (``q_ab ω_b²``: the turning axis's rate squared, anisoinertia or
    rectified vibration on the other outputs), ``abs`` (``q_ab |ω_b|``), ``signed_square``
    (``q_ab ω_b |ω_b|``: a misalignment growing with the rate, keeping its sign) or ``levels`` (a
    table of ``ω_b`` at the protocol's levels, as :class:`Levels`, 0 at the two lowest: the
    bias and the misalignment hold a straight line). [deg/s per (deg/s)², per deg/s, or deg/s]"""

    shape: str = "square"
    values: tuple = ()
    label: str = ""
    scope = "global"
    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    def __post_init__(self):
        if self.shape not in CROSS_SHAPES:
            raise ConfigError(
                f"term cross_rate: shape must be one of {', '.join(CROSS_SHAPES)}, got {self.shape!r}"
            )
        if self.shape == "levels":
            object.__setattr__(self, "values", _levels(self.values, "cross_rate"))
        elif self.values:
            raise ConfigError("term cross_rate: values belong to shape='levels'")
        label = self.label or f"cross_rate_{self.shape}"
        if not label.isidentifier():
            raise ConfigError(f"term cross_rate: label {label!r} must be a plain name")
        object.__setattr__(self, "label", label)

    @property
    def unit(self) -> str:
        return {"square": "1/(deg/s)", "abs": "1", "signed_square": "1/(deg/s)", "levels": "deg/s"}[
            self.shape
        ]

    @property
    def identity(self) -> tuple:
        return (self.name, self.label)

    def params(self) -> dict[str, Any]:
        out: dict[str, Any] = {"shape": self.shape, "label": self.label}
        if self.values:
            out["values"] = list(self.values)
        return out

    def spec_string(self) -> str:
        parts = [f'shape="{self.shape}"']
        if self.values:
            parts.append(f"values=[{', '.join(map(_number, self.values))}]")
        if self.label != f"cross_rate_{self.shape}":
            parts.append(f'label="{self.label}"')
        return f"cross_rate({', '.join(parts)})"

    def _pairs(self):
        return [(a, b) for a in AXES for b in AXES if b != a]

    def coefficients(self) -> list[str]:
        if self.shape != "levels":
            return [f"{self.label}.{a}.{b}" for a, b in self._pairs()]
        kept = range(2, len(self.values))
        return [f"{self.label}.{a}.{b}.k{k + 1}" for a, b in self._pairs() for k in kept]

    def columns(self, data):
        out = {}
        for a, b in self._pairs():
            rate = np.asarray(data[f"rate_{b}"], dtype=float)
            if self.shape == "square":
                out[f"{self.label}.{a}.{b}"] = rate**2
            elif self.shape == "abs":
                out[f"{self.label}.{a}.{b}"] = np.abs(rate)
            elif self.shape == "signed_square":
                out[f"{self.label}.{a}.{b}"] = rate * np.abs(rate)
            else:
                basis = level_basis(rate, self.values, (0, 1))
                out.update(
                    {
                        f"{self.label}.{a}.{b}.k{k + 1}": basis[:, j]
                        for j, k in enumerate(range(2, len(self.values)))
                    }
                )
        return out
