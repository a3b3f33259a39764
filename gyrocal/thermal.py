"""Calibration across temperature: one fit per temperature point, interpolated between.

Every interpolation method here is linear in the grid values, so it is expressed as a
weight matrix ``W`` (evaluation temperatures x grid points): coefficients at any temperature
are ``W @ values`` for all coefficients at once, and their uncertainty is
``sqrt(W² @ stderr²)`` (grid points are fitted independently).

Methods:

* ``lagrange3`` — seed 000 Eq 21-22: for ``T_{i-1} < T <= T_i`` the three-point Lagrange
  polynomial through ``T_{i-2}, T_{i-1}, T_i``; the first interval, lacking ``T_{i-2}``,
  uses ``T_0, T_1, T_2``. With two points it is linear, with one constant.
* ``linear`` — piecewise linear between neighbours.
* ``spline`` — natural cubic spline through all points.
* ``poly`` — one least-squares polynomial of the given degree over all points.

Outside the calibrated range every method clamps to the end value: no extrapolation.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from .errors import ConfigError, GyrocalError, IdentifiabilityError
from .model import FitResult, Model, columns_of, fit

METHODS = ("lagrange3", "linear", "spline", "poly")


class OutOfRangeWarning(UserWarning):
    """Temperatures outside the calibrated range were clamped to its ends."""


def lagrange3_weights(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Weights of seed 000's three-point Lagrange interpolation (Eq 21-22)."""
    nodes = np.asarray(nodes, dtype=float)
    P = len(nodes)
    W = np.zeros((len(x), P))
    if P < 3:
        return linear_weights(nodes, x)
    i = np.clip(np.searchsorted(nodes, x, side="left"), 1, P - 1)  # T_{i-1} < x <= T_i
    lo = np.maximum(i - 2, 0)
    idx = lo[:, None] + np.arange(3)
    t = nodes[idx]                                                  # (n, 3) stencil
    rows = np.arange(len(x))
    for j in range(3):
        others = [k for k in range(3) if k != j]
        num = (x - t[:, others[0]]) * (x - t[:, others[1]])
        den = (t[:, j] - t[:, others[0]]) * (t[:, j] - t[:, others[1]])
        W[rows, idx[:, j]] = num / den
    return W


def linear_weights(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    nodes = np.asarray(nodes, dtype=float)
    W = np.zeros((len(x), len(nodes)))
    if len(nodes) == 1:
        W[:, 0] = 1.0
        return W
    i = np.clip(np.searchsorted(nodes, x, side="right"), 1, len(nodes) - 1)
    frac = (x - nodes[i - 1]) / (nodes[i] - nodes[i - 1])
    rows = np.arange(len(x))
    W[rows, i - 1] = 1.0 - frac
    W[rows, i] = frac
    return W


def spline_weights(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    if len(nodes) < 3:
        return linear_weights(nodes, x)
    return CubicSpline(nodes, np.eye(len(nodes)), bc_type="natural")(x)


def poly_weights(nodes: np.ndarray, x: np.ndarray, degree: int) -> np.ndarray:
    degree = min(degree, len(nodes) - 1)
    centre, half = (nodes[0] + nodes[-1]) / 2, max((nodes[-1] - nodes[0]) / 2, 1e-12)
    V = np.polynomial.legendre.legvander((nodes - centre) / half, degree)
    Vx = np.polynomial.legendre.legvander((x - centre) / half, degree)
    return Vx @ np.linalg.pinv(V)


def check_method(method, degree=3, *, where: str = "interpolation") -> None:
    """The one check of an interpolation setting, wherever it comes from."""
    if method not in METHODS:
        raise ConfigError(f"{where} method {method!r} is not known; choose one of "
                          f"{', '.join(METHODS)}")
    if isinstance(degree, bool) or not isinstance(degree, int) or degree < 0:
        raise ConfigError(f"{where} degree must be a non-negative integer, got {degree!r}")


def interpolation_weights(method: str, nodes, x, *, degree: int = 3) -> np.ndarray:
    """Weights (len(x), len(nodes)) of ``method``; ``x`` is clamped to the node range."""
    nodes = np.asarray(nodes, dtype=float)
    x = np.clip(np.atleast_1d(np.asarray(x, dtype=float)), nodes[0], nodes[-1])
    if method == "lagrange3":
        return lagrange3_weights(nodes, x)
    if method == "linear":
        return linear_weights(nodes, x)
    if method == "spline":
        return spline_weights(nodes, x)
    check_method(method, degree)
    return poly_weights(nodes, x, degree)


@dataclass(frozen=True)
class TemperatureGrid:
    """Coefficients fitted at temperature points, interpolated between them."""

    temperatures: np.ndarray          # (P,) increasing, °C
    names: tuple[str, ...]
    values: np.ndarray                # (P, C)
    stderr: np.ndarray                # (P, C)
    method: str = "lagrange3"
    degree: int = 3

    def __post_init__(self):
        check_method(self.method, self.degree)
        if len(self.temperatures) == 0:
            raise ConfigError("a temperature grid needs at least one point")
        if np.any(np.diff(self.temperatures) <= 0):
            raise ConfigError("grid temperatures must increase strictly")

    @property
    def span(self) -> tuple[float, float]:
        return float(self.temperatures[0]), float(self.temperatures[-1])

    def weights(self, temp) -> np.ndarray:
        return interpolation_weights(self.method, self.temperatures, temp, degree=self.degree)

    def outside(self, temp) -> np.ndarray:
        temp = np.asarray(temp, dtype=float)
        lo, hi = self.span
        return (temp < lo) | (temp > hi)

    def at(self, temp, *, warn: bool = True) -> dict[str, np.ndarray]:
        """Coefficient arrays at ``temp`` (clamped to the grid, with a warning if so)."""
        temp = np.atleast_1d(np.asarray(temp, dtype=float))
        if warn:
            out = self.outside(temp)
            if out.any():
                lo, hi = self.span
                warnings.warn(OutOfRangeWarning(
                    f"{int(out.sum())} of {len(temp)} samples at {temp[out].min():.2f} to "
                    f"{temp[out].max():.2f} °C lie outside the calibrated {lo:g} to {hi:g} °C "
                    "and use the nearest end's calibration"), stacklevel=2)
        V = self.weights(temp) @ self.values
        return {n: V[:, j] for j, n in enumerate(self.names)}

    def stderr_at(self, temp) -> dict[str, np.ndarray]:
        S = np.sqrt(self.weights(temp) ** 2 @ self.stderr ** 2)
        return {n: S[:, j] for j, n in enumerate(self.names)}

    def without(self, index: int) -> TemperatureGrid:
        keep = np.arange(len(self.temperatures)) != index
        return TemperatureGrid(self.temperatures[keep], self.names, self.values[keep],
                               self.stderr[keep], self.method, self.degree)

@dataclass(frozen=True)
class GridFit:
    """Per-temperature fits and the grid built from those that succeeded."""

    grid: TemperatureGrid
    fits: tuple[FitResult, ...]
    points: pd.DataFrame              # point, temp, holds, used, reason
    excluded: dict[int, str] = field(default_factory=dict)


def fit_grid(model: Model, obs: pd.DataFrame, *, method: str = "lagrange3", degree: int = 3,
             source=None, fitter: Callable = fit) -> GridFit:
    """Fit ``model`` at every temperature point of ``obs`` (column ``point``).

    A point whose holds cannot determine the model (a mount missing there, too few holds)
    is left out and reported; if no point can be fitted the first refusal is raised.
    """
    check_method(method, degree)
    fits, temps, rows, excluded, first_error = [], [], [], {}, None
    data = columns_of(obs)
    point_of = data["point"].astype(int)
    for point in np.unique(point_of):
        idx = np.flatnonzero(point_of == point)
        group = {k: v[idx] for k, v in data.items()}
        temp = float(group["temp"].mean())
        try:
            result = fitter(model, group, source=source, label=f"{temp:.1f} °C")
        except IdentifiabilityError as exc:
            first_error = first_error or exc
            excluded[int(point)] = str(exc).removeprefix(f"{source}: " if source else "")
            rows.append((int(point), temp, len(idx), False, excluded[int(point)]))
            continue
        fits.append(result)
        temps.append(temp)
        rows.append((int(point), temp, len(idx), True, ""))
    if not fits:
        raise first_error if first_error else GyrocalError("no observations to fit", source=source)
    names = fits[0].names
    grid = TemperatureGrid(np.array(temps), names, np.array([f.values for f in fits]),
                           np.array([f.stderr for f in fits]), method, degree)
    points = pd.DataFrame(rows, columns=["point", "temp", "holds", "used", "reason"])
    return GridFit(grid, tuple(fits), points, excluded)
