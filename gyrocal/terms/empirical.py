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
    return full[:, 1 if linear else 2:]


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
        if not 2 <= len(knots) <= MAX_KNOTS or not all(map(math.isfinite, knots)) \
                or any(b <= a for a, b in zip(knots, knots[1:])):
            raise ConfigError(f"term smooth: knots must be 2 to {MAX_KNOTS} increasing finite numbers, "
                              f"got {self.knots!r}")
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

    def params(self) -> dict:
        return {"input": self.input, "knots": list(self.knots), "by": self.by, "linear": self.linear,
                "label": self.label}

    def spec_string(self) -> str:
        # Double quotes, so that the option is one shell word in single quotes.
        parts = [f'input="{self.input}"', f"knots=[{', '.join(repr(k) for k in self.knots)}]"]
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

