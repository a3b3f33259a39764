"""Calibration across temperature: coefficients at temperature points, interpolated between.

Every interpolation method here is linear in the grid values, so it is expressed as a
weight matrix ``W`` (evaluation temperatures x grid points): coefficients at any temperature
are ``W @ values`` for all coefficients at once, and their uncertainty is
``sqrt(W² @ stderr²)`` (each point's covariance, the points taken as independent).

The grid is fitted in one least-squares problem with each hold at its own temperature (its
columns times ``W`` at the hold's temperature, :func:`_fit_joint`); which points are nodes is
decided by fitting each point's holds alone (:func:`fit_grid`).

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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from ..io.errors import ConfigError, GyrocalError, IdentifiabilityError
from ..terms import AXES, Term
from .model import FitResult, Model, columns_of, fit, observation_weights, shares_wander, subset_design
from .wander import Whitener, stacked

if TYPE_CHECKING:
    import pandas as pd

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
    t = nodes[idx]  # (n, 3) stencil
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
    from scipy.interpolate import CubicSpline  # half a second to import: only when a spline is used

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
        raise ConfigError(f"{where} method {method!r} is not known; choose one of {', '.join(METHODS)}")
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

    temperatures: np.ndarray  # (P,) increasing, °C
    names: tuple[str, ...]
    values: np.ndarray  # (P, C)
    stderr: np.ndarray  # (P, C)
    method: str = "lagrange3"
    degree: int = 3
    covariance: np.ndarray | None = None  # (P, C, C): each point's coefficients

    def __post_init__(self):
        check_method(self.method, self.degree)
        if self.covariance is not None:
            object.__setattr__(self, "covariance", canonical_covariance(self.covariance, self.stderr))
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
            warn_outside(self, temp)
        V = self.weights(temp) @ self.values
        return {n: V[:, j] for j, n in enumerate(self.names)}

    def stderr_at(self, temp) -> dict[str, np.ndarray]:
        S = np.sqrt(self.weights(temp) ** 2 @ self.stderr**2)
        return {n: S[:, j] for j, n in enumerate(self.names)}

    def covariance_at(self, temp) -> np.ndarray:
        """(n, C, C): the interpolated coefficients' covariance, the points' taken as
        independent (a joint fit's points share their global coefficients, whose own
        variance each point's matrix holds); from the standard errors alone, as
        uncorrelated, when the grid has no covariances."""
        temp = np.atleast_1d(np.asarray(temp, dtype=float))
        cov = self.covariance if self.covariance is not None else diagonal(self.stderr**2)
        return np.einsum("np,pcd->ncd", self.weights(temp) ** 2, cov)

    def without(self, index: int) -> TemperatureGrid:
        keep = np.arange(len(self.temperatures)) != index
        return TemperatureGrid(
            self.temperatures[keep],
            self.names,
            self.values[keep],
            self.stderr[keep],
            self.method,
            self.degree,
            None if self.covariance is None else self.covariance[keep],
        )


DIAGONAL_RTOL = 1e-6  # a covariance's diagonal against the squared standard errors


def canonical_covariance(cov, stderr) -> np.ndarray:
    """A grid's covariance as it is kept and written: exactly symmetric, its diagonal the
    squares of the standard errors beside it, the rows of a coefficient without uncertainty
    zero. A fit's matrix products leave the two triangles a few ulps apart, which is
    rounding; a diagonal that disagrees with the standard errors beyond rounding is a bug
    upstream, refused rather than hidden."""
    C = np.array(cov, dtype=float)
    s = np.asarray(stderr, dtype=float)
    C = 0.5 * (C + np.swapaxes(C, -1, -2))  # a + b == b + a: exactly symmetric
    with np.errstate(invalid="ignore"):  # an infinite variance is the writer's to refuse
        mismatch = np.abs(np.diagonal(C, axis1=-2, axis2=-1) - s**2)
    if np.any(mismatch > DIAGONAL_RTOL * s**2):
        raise GyrocalError(
            "a covariance's diagonal is not the squared standard errors (off "
            f"by up to {float(mismatch.max()):.3g})"
        )
    C *= (s[..., :, None] != 0) & (s[..., None, :] != 0)
    idx = np.arange(s.shape[-1])
    C[..., idx, idx] = s**2
    return C


def diagonal(variances: np.ndarray) -> np.ndarray:
    """(..., C) variances as (..., C, C) diagonal covariances."""
    out = np.zeros(variances.shape + (variances.shape[-1],))
    idx = np.arange(variances.shape[-1])
    out[..., idx, idx] = variances
    return out


@dataclass(frozen=True)
class ConstantCoefficients:
    """Coefficients of a temperature-continuous model: one value each, the temperature
    dependence being in the model's own terms. ``temperatures`` are the calibration's
    points (where K and B are tabulated for the file); ``span`` is where it was fitted."""

    temperatures: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray  # (C,)
    stderr: np.ndarray  # (C,)
    method: str = "continuous"
    degree: int = 0
    fitted_span: tuple[float, float] | None = None  # the fitted holds' temperatures
    covariance: np.ndarray | None = None  # (C, C)

    def __post_init__(self):
        if self.covariance is not None:
            object.__setattr__(self, "covariance", canonical_covariance(self.covariance, self.stderr))

    def covariance_at(self, temp) -> np.ndarray:
        """(n, C, C): the coefficients' covariance at each temperature (the same for all)."""
        n = len(np.atleast_1d(temp))
        cov = self.covariance if self.covariance is not None else diagonal(self.stderr**2)
        return np.broadcast_to(cov, (n,) + cov.shape)

    @property
    def span(self) -> tuple[float, float]:
        """Where the model was fitted: its holds' lowest to highest temperature (a
        point's mean lies inside its holds' range, so the points' extremes would clamp
        the ends of a sweep the terms were fitted on); the points' without that record."""
        if self.fitted_span is not None:
            return float(self.fitted_span[0]), float(self.fitted_span[1])
        return float(self.temperatures[0]), float(self.temperatures[-1])

    def outside(self, temp) -> np.ndarray:
        temp = np.asarray(temp, dtype=float)
        lo, hi = self.span
        return (temp < lo) | (temp > hi)

    def at(self, temp, *, warn: bool = True) -> dict[str, np.ndarray]:
        temp = np.atleast_1d(np.asarray(temp, dtype=float))
        if warn:
            warn_outside(self, temp)
        return {n: np.full(len(temp), v) for n, v in zip(self.names, self.values, strict=False)}


def warn_outside(coefs, temp: np.ndarray) -> None:
    """Warn that temperatures outside the calibrated range use the nearest end's."""
    out = coefs.outside(temp)
    if out.any():
        lo, hi = coefs.span
        warnings.warn(
            OutOfRangeWarning(
                f"{int(out.sum())} of {len(temp)} samples at {temp[out].min():.2f} to "
                f"{temp[out].max():.2f} °C lie outside the calibrated {lo:g} to {hi:g} °C and use "
                "the calibration at the nearest end"
            ),
            stacklevel=3,
        )


class _OnAGrid:
    """What a temperature-grid fit reads from its grid and points table."""

    grid: TemperatureGrid
    point_rows: tuple  # (point, temp, holds, used, reason) per temperature point

    @cached_property
    def points(self) -> pd.DataFrame:
        """The points as a table (point, temp, holds, used, reason), made when read: a
        profile makes hundreds of fits and reads none of their tables."""
        return _points_table(list(self.point_rows))

    @property
    def names(self) -> tuple[str, ...]:
        return self.grid.names

    @property
    def coefficients(self) -> TemperatureGrid:
        return self.grid

    def used_points(self) -> list[int]:
        return [int(row[0]) for row in self.point_rows if row[3]]

    def outside(self, temp) -> np.ndarray:
        return self.grid.outside(temp)

    def coefficients_at(self, temp) -> np.ndarray:
        return self.grid.weights(temp) @ self.grid.values


@dataclass(frozen=True)
class GridFit(_OnAGrid):
    """Per-temperature fits and the grid built from those that succeeded."""

    grid: TemperatureGrid
    fits: tuple[FitResult, ...]
    point_rows: tuple  # (point, temp, holds, used, reason) per point: the points table's
    excluded: dict[int, str] = field(default_factory=dict)
    rows: tuple[np.ndarray, ...] = ()  # the observation rows each fit used
    profiled: tuple = ()  # nonlinear settings found by profiling
    kind: ClassVar[str] = "grid"

    @property
    def model(self) -> Model:
        return self.fits[0].model

    def covariance_at(self, temp) -> np.ndarray:
        cov = np.array([f.covariance for f in self.fits])
        return np.einsum("np,pcd->ncd", self.grid.weights(temp) ** 2, cov)

    def point_fit(self, point: int) -> FitResult:
        """The calibration at one point: that point's own fit."""
        return self.fits[self.used_points().index(int(point))]

    def leave_out(self, point: int) -> GridFit | None:
        """The calibration without ``point``: the other points' fits (each used its own
        holds only, so this is what calibrating without the point gives)."""
        used = self.used_points()
        if point not in used:
            return self
        if len(used) < 2:
            return None
        k = used.index(point)
        return GridFit(
            self.grid.without(k),
            self.fits[:k] + self.fits[k + 1 :],
            tuple(row for row in self.point_rows if row[0] != point),
            self.excluded,
            self.rows[:k] + self.rows[k + 1 :],
        )


@dataclass(frozen=True)
class ContinuousFit:
    """One fit of a temperature-continuous model over every point's holds."""

    model: Model
    fit: FitResult
    data: dict  # the numeric observation columns fitted
    points: pd.DataFrame
    excluded: dict[int, str] = field(default_factory=dict)
    profiled: tuple = ()
    design: dict | None = field(default=None, repr=False, compare=False)  # the fit's columns
    kind: ClassVar[str] = "continuous"

    @property
    def rows(self) -> tuple[np.ndarray, ...]:
        return (np.arange(len(self.data["temp"])),)

    @property
    def names(self) -> tuple[str, ...]:
        return self.fit.names

    @property
    def fits(self) -> tuple[FitResult, ...]:
        return (self.fit,)

    @property
    def coefficients(self) -> ConstantCoefficients:
        temps = np.sort(self.points.loc[self.points["used"], "temp"].to_numpy(dtype=float))
        held = np.asarray(self.data["temp"], dtype=float)
        span = (min(float(held.min()), temps[0]), max(float(held.max()), temps[-1]))
        return ConstantCoefficients(
            temps,
            self.names,
            self.fit.values,
            self.fit.stderr,
            fitted_span=span,
            covariance=self.fit.covariance,
        )

    def used_points(self) -> list[int]:
        return [int(p) for p in self.points.loc[self.points["used"], "point"]]

    def outside(self, temp) -> np.ndarray:
        return self.coefficients.outside(temp)

    def coefficients_at(self, temp) -> np.ndarray:
        return np.broadcast_to(self.fit.values, (len(np.atleast_1d(temp)), len(self.names)))

    def covariance_at(self, temp) -> np.ndarray:
        n = len(np.atleast_1d(temp))
        return np.broadcast_to(self.fit.covariance, (n,) + self.fit.covariance.shape)

    def leave_out(self, point: int) -> ContinuousFit | None:
        """Refitted without ``point``'s holds (None when nothing would be left to fit)."""
        keep = self.data["point"].astype(int) != point
        if keep.all():
            return self
        if len(np.unique(self.data["point"][keep])) < 1:
            return None
        try:  # the holds that stay keep their columns: only the whitening is new
            return fit_continuous(
                self.model,
                {k: v[keep] for k, v in self.data.items()},
                design=None if self.design is None else subset_design(self.design, keep),
            )
        except IdentifiabilityError:
            return None


def in_sample(fitted, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (n, 3) and floors (n, 3) of a fit's own observations in observation
    order, and which rows were fitted (rows of points left out are NaN)."""
    resid, floor = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    for result, rows in zip(fitted.fits, fitted.rows, strict=False):
        resid[rows], floor[rows] = result.residuals, result.floor
    return resid, floor, ~np.isnan(resid[:, 0])


def fit_continuous(model: Model, obs, *, source=None, design: dict | None = None) -> ContinuousFit:
    """Fit a temperature-continuous model jointly over every point (seed 003 Eq 16 style:
    the temperature dependence is in terms such as ``bias_temp_poly``); ``design``: the
    model's columns on ``obs`` when already made."""
    data = columns_of(obs)
    if design is None:
        model.check_inputs(data, source)
        design = model.design(data)
    result = fit(model, data, source=source, label="all temperature points", design=design)
    point = data["point"].astype(int)
    rows = [
        (int(p), point_temperature(data["temp"][point == p]), int((point == p).sum()), True, "")
        for p in np.unique(point)
    ]
    points = _points_table(rows)
    return ContinuousFit(model, result, data, points, design=design)


def _points_table(rows: list) -> pd.DataFrame:
    """The fit's table of temperature points. pandas is imported here, by the fits, and not
    with the module: a report reads a calibration's grid without it."""
    import pandas as pd

    return pd.DataFrame(rows, columns=["point", "temp", "holds", "used", "reason"])


def fit_grid(
    model: Model,
    obs: pd.DataFrame,
    *,
    method: str = "lagrange3",
    degree: int = 3,
    source=None,
    fitter: Callable = fit,
    design: dict | None = None,
    prepared: dict | None = None,
) -> GridFit:
    """Fit ``model`` at every temperature point of ``obs`` (column ``point``).

    A point whose holds cannot determine the model (a mount missing there, too few holds)
    is left out and reported; if no point can be fitted the first refusal is raised.
    ``design``: the model's columns on every hold of ``obs``, where already made.
    ``prepared``: each point's holds and weighting, kept across fits of the same ``obs``
    (a profile's).
    """
    check_method(method, degree)
    fits, temps, rows, excluded, first_error, fitted_rows = [], [], [], {}, None, []
    data = columns_of(obs)
    point_of = data["point"].astype(int)
    # A hold's columns are its own: made once for every point rather than point by point
    # (a profile fits the same holds hundreds of times).
    whole = None
    if fitter is fit:
        model.check_inputs(data, source)
        whole = model.design(data) if design is None else design
    for point in np.unique(point_of):
        if prepared is not None and point in prepared:
            idx, group, weights = prepared[point]
        else:
            idx = np.flatnonzero(point_of == point)
            group = {k: v[idx] for k, v in data.items()}
            weights = observation_weights(group) if fitter is fit else None
            if prepared is not None:
                prepared[point] = idx, group, weights
        temp = point_temperature(group["temp"])
        own = {} if whole is None else {"design": subset_design(whole, idx), "weights": weights}
        try:
            result = fitter(model, group, source=source, label=f"{temp:.1f} °C", **own)
        except IdentifiabilityError as exc:
            first_error = first_error or exc
            excluded[int(point)] = str(exc).removeprefix(f"{source}: " if source else "")
            rows.append((int(point), temp, len(idx), False, excluded[int(point)]))
            continue
        fits.append(result)
        temps.append(temp)
        fitted_rows.append(idx)
        rows.append((int(point), temp, len(idx), True, ""))
    if not fits:
        raise first_error if first_error else GyrocalError("no observations to fit", source=source)
    names = fits[0].names
    grid = TemperatureGrid(
        np.array(temps),
        names,
        np.array([f.values for f in fits]),
        np.array([f.stderr for f in fits]),
        method,
        degree,
        np.array([f.covariance for f in fits]),
    )
    return GridFit(grid, tuple(fits), tuple(rows), excluded, tuple(fitted_rows))


class _AtPoint(Term):
    """A point-scope term's coefficients at one temperature point of a joint grid fit:
    its columns on that point's holds, zero elsewhere (names ``<coefficient>.@<point>``)."""

    def __init__(self, term: Term, point: int):
        self.term, self.point = term, int(point)
        self.name = term.name
        self.needs = term.needs

    def spec_string(self) -> str:
        return self.term.spec_string()

    def coefficients(self) -> list[str]:
        return [f"{c}.@{self.point}" for c in self.term.coefficients()]

    def columns(self, data):
        here = np.asarray(data["point"]) == self.point
        return {
            f"{k}.@{self.point}": np.where(here, np.asarray(v, float), 0.0)
            for k, v in self.term.columns(data).items()
        }


def global_terms(model: Model) -> list[Term]:
    """Terms with session-wide coefficients (one that adds none, a die temperature, is not
    fitted jointly for that)."""
    return [t for t in model.terms if t.coefficient_scope == "global" and t.coefficients()]


@dataclass(frozen=True)
class JointGridFit(_OnAGrid):
    """A grid model fitted in one least-squares problem over the points' holds, each hold at
    its own temperature: every point's own coefficients and the session-wide (scope global)
    ones where the model has them. The grid holds each global coefficient at every point
    (interpolating a constant gives it back), so files and apply read it as any grid."""

    model: Model
    fit: FitResult  # of the joint model (names with ``.@<point>``)
    data: dict  # the observation columns of the points fitted
    grid: TemperatureGrid
    point_rows: tuple  # (point, temp, holds, used, reason) per point, in point order
    excluded: dict[int, str] = field(default_factory=dict)
    rows: tuple[np.ndarray, ...] = ()  # the observation rows the fit used
    point_ids: tuple[int, ...] = ()  # grid order
    profiled: tuple = ()
    design: dict | None = field(default=None, repr=False, compare=False)  # the model's own columns
    point_weights: _PointWeights | None = field(default=None, repr=False, compare=False)
    kind: ClassVar[str] = "grid"

    @property
    def fits(self) -> tuple[FitResult, ...]:
        return (self.fit,)

    @cached_property
    def _layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where each coefficient sits among the joint parameters: the point-scope ones
        (their index in ``names``, and (C_l, P) joint indices, one per node) and the global
        ones (index in ``names``, joint index)."""
        joint = {name: j for j, name in enumerate(self.fit.names)}
        local = [c for c, name in enumerate(self.names) if name not in joint]
        index = [[joint[f"{self.names[c]}.@{p}"] for p in self.point_ids] for c in local]
        shared = [c for c, name in enumerate(self.names) if name in joint]
        return (
            np.array(local, dtype=int),
            np.array(index, dtype=int).reshape(len(local), len(self.point_ids)),
            np.array(shared, dtype=int),
            np.array([joint[self.names[c]] for c in shared], dtype=int),
        )

    def covariance_at(self, temp) -> np.ndarray:
        """(n, C, C): the coefficients' covariance at each temperature, ``A Σ A'`` with ``A``
        the mapping, contracted over the nodes rather than built: A has P·C columns of which
        each coefficient reads P (n·C·J·P operations, not n·C·J²)."""
        weights = self.grid.weights(np.atleast_1d(np.asarray(temp, float)))
        local, index, shared, at = self._layout
        cov = self.fit.covariance
        n, C = len(weights), len(self.names)
        B = np.empty((n, C, cov.shape[1]))  # A Σ
        B[:, local] = np.tensordot(weights, cov[index], axes=([1], [1]))
        B[:, shared] = cov[at][None]
        out = np.empty((n, C, C))
        out[:, :, local] = (B[:, :, index] @ weights[:, None, :, None])[..., 0]
        out[:, :, shared] = B[:, :, at]
        return out

    def point_fit(self, point: int):
        """The calibration at one point: its own coefficients and the global ones."""
        k = self.point_ids.index(int(point))
        local, index, shared, at = self._layout
        pick = np.empty(len(self.names), dtype=int)  # the joint parameter each coefficient is there
        pick[local], pick[shared] = index[:, k], at
        return _PointCalibration(self.grid.values[k], self.fit.covariance[np.ix_(pick, pick)])

    def leave_out(self, point: int) -> JointGridFit | None:
        """Refitted without ``point``'s holds (the global coefficients change with it)."""
        if point not in self.used_points():
            return self
        if len(self.used_points()) < 2:
            return None
        keep = self.data["point"].astype(int) != point
        try:  # the holds that stay keep their columns (those of the point left out drop)
            return _fit_joint(
                self.model,
                {k: v[keep] for k, v in self.data.items()},
                method=self.grid.method,
                degree=self.grid.degree,
                used=[p for p in self.point_ids if p != point],
                rows=self.rows[0][keep],
                excluded=self.excluded,
                design=None if self.design is None else subset_design(self.design, keep),
                known_weights=self.point_weights,
            )
        except IdentifiabilityError:
            return None


@dataclass(frozen=True)
class _PointCalibration:
    values: np.ndarray
    covariance: np.ndarray


WANDER_COLUMNS = frozenset(f"wander_{a}" for a in AXES)


@dataclass(frozen=True)
class _PointWeights:
    """The weighting of a joint grid's holds, point by point (:func:`_weights_by_point`):
    each point's observation rows (``rows``, the fit's own numbering) and their floors and
    whiteners, kept so that a refit without one point reuses the others'."""

    rows: dict[int, np.ndarray]
    found: dict[int, tuple[np.ndarray, list]]


def _weights_by_point(
    data: dict, blocks: dict[int, np.ndarray], rows: np.ndarray, known: _PointWeights | None = None
) -> tuple[tuple[np.ndarray, list], _PointWeights]:
    """The weighting of a grid's holds where they share slow wander: each point's holds
    whitened among themselves, as a fit of that point alone whitens them. Each node's bias
    takes the wander between the points; whitened as one record, the wander of hours would
    make the early points' biases as uncertain as a random walk from power-on. ``blocks``:
    each point's positions among the holds. A point whose holds (``rows``) are those
    ``known`` weighed keeps their weights."""
    weighed = []
    floor = np.empty((len(rows), 3))
    table = _PointWeights({}, {})
    for p, idx in blocks.items():
        if known is not None and p in known.rows and np.array_equal(known.rows[p], rows[idx]):
            floor[idx], found = known.found[p]
        else:
            floor[idx], found = observation_weights({k: v[idx] for k, v in data.items()})
        table.rows[p], table.found[p] = rows[idx], (floor[idx], found)
        weighed.append((idx, found))

    def axis(i):
        parts = [found[i] for _, found in weighed]
        # one pass over every point's holds where each point's map is a wander whitener
        together = stacked(parts) if all(isinstance(w, Whitener) for w in parts) else None
        if together is not None:
            into = np.concatenate([idx for idx, _ in weighed])
            taken = np.concatenate([idx[w.gen.order] for (idx, _), w in zip(weighed, parts, strict=True)])

        def whiten(m):
            m = np.asarray(m, dtype=float)
            out = np.empty(m.shape)
            if together is not None:
                out[into] = together(m[taken])
                return out
            for idx, found in weighed:
                out[idx] = found[i](m[idx])
            return out

        return whiten

    return (floor, [axis(i) for i in range(3)]), table


def point_temperature(temps) -> float:
    """A temperature point's place on the grid: the median of its holds' temperatures, where
    most of them settled (a hold warmed by an open door after a remount does not move it)."""
    return float(np.median(np.asarray(temps, dtype=float)))


def _temperatures_by_point(temp: np.ndarray, point: np.ndarray, ids) -> dict[int, np.ndarray]:
    """Each point's hold temperatures, sorted: one sort for every point of a fit (a profile
    makes hundreds)."""
    order = np.lexsort((temp, point))
    sorted_point, sorted_temp = point[order], temp[order]
    starts = np.searchsorted(sorted_point, ids, side="left")
    ends = np.searchsorted(sorted_point, ids, side="right")
    return {int(p): sorted_temp[a:b] for p, a, b in zip(ids, starts, ends, strict=True)}


END_SHARE = 5.0  # percent: the end nodes leave out this share of their point's holds beyond them


def _settled_ends(temps: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """The end nodes moved out to where their point's holds settled: past all but
    :data:`END_SHARE` % of them. At the coldest point the door warms the holds after each
    remount, at the hottest it cools them: the median lies inward, and the next session's
    settled holds, beyond the calibrated span, would be read at its end (apply clamps). A hold
    is fitted at its own temperature: where a node sits changes little but which holds lie beyond
    the span."""
    out = temps.copy()
    low = np.percentile(first, END_SHARE)  # ``first``, ``last``: the end points' holds
    high = np.percentile(last, 100.0 - END_SHARE)
    out[0] = min(out[0], low) if low < out[1] else out[0]
    out[-1] = max(out[-1], high) if high > out[-2] else out[-1]
    return out


def _fit_joint(
    model: Model,
    data: dict,
    *,
    method: str,
    degree: int,
    used: list[int],
    source=None,
    rows: np.ndarray | None = None,
    excluded=None,
    extra_points=(),
    design: dict | None = None,
    known_weights: _PointWeights | None = None,
) -> JointGridFit:
    """The grid fitted in one least-squares problem, each hold at its own temperature: a
    point-scope coefficient's column at node ``k`` is the hold's column times the weight
    the interpolation gives node ``k`` at the hold's temperature, so a hold is fitted with
    the coefficients apply will give it (seed 000 Eq 21-22). A hold settled at its point
    weighs that node alone; one still off it (the door opened at a remount) informs the
    nodes its temperature lies between. ``used``: the points that are nodes (their own
    holds determine them); holds of other points take part where they lie inside the nodes'
    span. ``design``: the model's own columns on ``data``."""
    point = data["point"].astype(int)
    ids = [int(p) for p in used]
    temp = np.asarray(data["temp"], dtype=float)
    held = _temperatures_by_point(temp, point, ids)
    temps = np.array([point_temperature(held[p]) for p in ids])
    order = np.argsort(temps, kind="stable")
    ids, temps = [ids[i] for i in order], temps[order]
    if len(ids) > 1:
        temps = _settled_ends(temps, held[ids[0]], held[ids[-1]])
    inside = np.isin(point, ids) | ((temp >= temps[0]) & (temp <= temps[-1]))
    rows = np.arange(len(point)) if rows is None else np.asarray(rows)
    if not inside.all():
        data = {k: v[inside] for k, v in data.items()}
        rows, point, temp = rows[inside], point[inside], temp[inside]
        design = None if design is None else subset_design(design, inside)
    if design is None:
        model.check_inputs(data, source)
        design = model.design(data)
    local = [t for t in model.terms if t.coefficient_scope != "global"]
    joint = Model(tuple(_AtPoint(t, p) for t in local for p in ids) + tuple(global_terms(model)))
    weights = interpolation_weights(method, temps, temp, degree=degree)
    n = len(point)
    joint_design = {}
    for term in local:
        for name in term.coefficients():
            column = np.broadcast_to(np.asarray(design[name], dtype=float), (n,))
            for k, p in enumerate(ids):
                joint_design[f"{name}.@{p}"] = weights[:, k] * column
    for term in global_terms(model):
        joint_design.update({name: design[name] for name in term.coefficients()})
    # Each node's bias takes the wander between the points, as a fit point by point does:
    # the floor it weights by is a hold's own, without that wander (fit.model.observation_floor).
    own_floor = {k: v for k, v in data.items() if k not in WANDER_COLUMNS}
    blocks = {int(p): np.flatnonzero(point == p) for p in np.unique(point)}
    weighting, point_weights = None, None
    if shares_wander(own_floor):
        weighting, point_weights = _weights_by_point(own_floor, blocks, rows, known_weights)
    result = fit(
        joint,
        own_floor,
        source=source,
        label="all temperature points",
        design=joint_design,
        weights=weighting,
        blocks=list(blocks.values()),
    )
    index = {name: j for j, name in enumerate(result.names)}
    values = np.empty((len(ids), len(model.names)))
    stderr = np.empty_like(values)
    for c, name in enumerate(model.names):
        if name in index:
            values[:, c], stderr[:, c] = result.values[index[name]], result.stderr[index[name]]
        else:
            for k, p in enumerate(ids):
                j = index[f"{name}.@{p}"]
                values[k, c], stderr[k, c] = result.values[j], result.stderr[j]
    grid = TemperatureGrid(temps, tuple(model.names), values, stderr, method, degree)
    joint_fit = JointGridFit(model, result, data, grid, (), {}, (), tuple(ids))
    grid = replace(grid, covariance=np.array([joint_fit.point_fit(p).covariance for p in ids]))
    table = [(p, float(t), int((point == p).sum()), True, "") for p, t in zip(ids, temps, strict=False)]
    table += list(extra_points)
    points = tuple(sorted(table, key=lambda row: row[0]))  # stable: as the table lists them
    return JointGridFit(
        model,
        result,
        data,
        grid,
        points,
        dict(excluded or {}),
        (rows,),
        tuple(ids),
        design=design,
        point_weights=point_weights,
    )


# A per-point regressor whose within-point scatter is below this fraction of its whole
# scatter is, to a per-point fit, a copy of the bias (temperature alone, say).
MIN_WITHIN_POINT = 0.01


def _check_point_terms(model: Model, data: Mapping[str, np.ndarray], source=None) -> dict[str, np.ndarray]:
    """Refuse a point-scope term that does not vary within the temperature points: its
    per-point coefficients cannot be told from each point's bias. Returns the point-scope
    terms' columns (the whole design of a model without global terms)."""
    point = data["point"].astype(int)
    _, index = np.unique(point, return_inverse=True)
    counts = np.bincount(index)
    local = Model(tuple(t for t in model.terms if t.coefficient_scope != "global"))
    design = local.design(data)
    names = [(term, name) for term in local.terms for name in term.coefficients()]
    if not names:
        return design
    # every column at once: (holds, columns)
    cols = np.column_stack([np.broadcast_to(np.asarray(design[n], float), point.shape) for _, n in names])
    finite = np.isfinite(cols).all(axis=0)  # the fit refuses the others, naming the holds
    safe = np.where(finite, cols, 0.0)
    total = np.sqrt(np.mean((safe - safe.mean(axis=0)) ** 2, axis=0))
    means = np.stack([np.bincount(index, weights=c) for c in safe.T], axis=1) / counts[:, None]
    within = np.sqrt(np.mean((safe - means[index]) ** 2, axis=0))
    varies = total > 1e-12 * np.maximum(np.max(np.abs(safe), axis=0), 1e-300)  # not the bias
    for (term, _), ok, inside, overall in zip(names, finite & varies, within, total, strict=True):
        if ok and inside < MIN_WITHIN_POINT * overall:
            # Each point's own bias takes any function of what is constant within the
            # point, per point or global: only a model without per-point biases fits it.
            raise ConfigError(
                f"term {term.spec_string()} does not vary within a temperature point (its "
                f"scatter there is {inside / overall:.1%} of its scatter overall), so a grid "
                "model's per-point biases absorb it: use model kind continuous, with the "
                "bias's own temperature dependence as terms (bias_temp_poly, scale_temp_poly, "
                "misalignment_temp)",
                source=source,
            )
    return design


def fit_model(
    model: Model,
    obs,
    *,
    kind: str = "grid",
    method: str = "lagrange3",
    degree: int = 3,
    source=None,
    profile: bool = True,
) -> GridFit | ContinuousFit | JointGridFit:
    """A model fitted as a temperature grid (per point, interpolated, with global terms
    fitted jointly) or continuously. Nonlinear settings of its terms (``profile``) are
    found by profiling (:mod:`gyrocal.fit.profile`); with ``profile=False`` they keep the
    model's values (a fitted model's, refitted on other holds)."""
    if kind not in ("grid", "continuous"):
        raise ConfigError(f"model kind {kind!r} is not known; choose grid or continuous")
    if profile and any(t.nonlinear() for t in model.terms):
        from .profile import profiled_fit

        data = columns_of(obs)  # once, not at each of the profile's few dozen fits
        # A joint grid's per-point fit of its point-scope terms decides which points take
        # part; the profiled term is global, so it is the same at every value: made once.
        point_fits: dict = {}
        prepared: dict = {}  # each point's holds and weighting: the same at every value
        return profiled_fit(
            model,
            lambda m: _fit_linear(
                m,
                data,
                kind=kind,
                method=method,
                degree=degree,
                source=source,
                point_fits=point_fits,
                prepared=prepared,
            ),
        )
    return _fit_linear(model, obs, kind=kind, method=method, degree=degree, source=source)


def _fit_linear(
    model: Model,
    obs,
    *,
    kind: str,
    method: str,
    degree: int,
    source=None,
    point_fits: dict | None = None,
    prepared: dict | None = None,
):
    data = model.transform_inputs(columns_of(obs))
    if kind == "continuous":
        return fit_continuous(model, data, source=source)
    temperature_only = [
        t.spec_string() for t in model.terms if t.varies_with_temperature and t.coefficient_scope != "global"
    ]
    if temperature_only:
        raise ConfigError(
            f"{', '.join(temperature_only)} depend{'s' if len(temperature_only) == 1 else ''} "
            "on temperature alone and cannot be fitted point by point: use model "
            "kind continuous"
        )
    point_design = _check_point_terms(model, data, source)
    check_method(method, degree)
    # Which points are nodes: those whose own holds determine their coefficients, as a fit
    # point by point finds; every hold is then fitted at its own temperature (_fit_joint).
    local = Model(tuple(t for t in model.terms if t.coefficient_scope != "global"))
    per_point = None
    if local.terms:
        # Cached only on the inputs as given: a term that moves them (the die's temperature)
        # changes every point's fit. Within a profile the points are those of its start
        # (profile.profiled_fit judges every value on them): keyed on the terms' coefficients,
        # not their settings, a profiled point-scope term is fitted point by point once.
        cached = point_fits if point_fits is not None and data is obs else {}
        key = tuple((t.name, tuple(t.coefficients())) for t in local.terms)
        if key not in cached:
            cached[key] = fit_grid(
                local,
                data,
                method=method,
                degree=degree,
                source=source,
                design=point_design,
                prepared=prepared if data is obs else None,
            )
        per_point = cached[key]
    used = per_point.used_points() if per_point is not None else [int(p) for p in np.unique(data["point"])]
    dropped = [] if per_point is None else [tuple(r) for r in per_point.point_rows if not r[3]]
    globals_ = global_terms(model)
    if globals_:
        model.check_inputs(data, source)
    design = {**point_design, **(Model(tuple(globals_)).design(data) if globals_ else {})}
    return _fit_joint(
        model,
        dict(data),
        method=method,
        degree=degree,
        used=used,
        design=design,
        source=source,
        excluded=per_point.excluded if per_point else {},
        extra_points=dropped,
    )
