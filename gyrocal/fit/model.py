"""A model is a sum of terms; fitting it is weighted linear least squares per output axis.

The fit follows seed 000 Eq 13-19 (``K_g = w Ω^T (Ω Ω^T)^-1``) generalised to any terms and
weighted by each observation's noise floor: hold ``i`` on output axis ``a`` has variance
``σ_ia² = std_ia² / n_i`` (the within-hold scatter over the sample count). Each output axis
is its own regression, since every coefficient belongs to one output axis. Parameter
covariance comes from the residual scatter: ``(Xᵀ W X)^-1`` scaled by the reduced
chi-square.

Compensation inverts ``w = w_true + e(w_true, covariates)``: the model is affine in
``w_true`` for the seed-000 terms, and Newton steps handle terms that are not.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..io.errors import ConfigError, IdentifiabilityError, MissingInputError
from ..terms import AXES, Term, make_term
from ..terms.signals import SERIES_INPUTS, Inputs, Quadrature, hold_inputs, node_means, quadrature_inputs

DEFAULT_TERMS = ("bias", "scale", "misalignment")
# Largest condition number of the column-scaled, weighted design a fit accepts. Sound
# designs stay far below (seed-000 model: about 1; a degree-5 temperature polynomial: about
# 200); columns kept apart only by noise exceed it (about 1e4 for an accelerometer on three
# mounts).
MAX_CONDITION = 1e3
RATE_COLUMNS = ("rate_x", "rate_y", "rate_z")


def axis_of(name: str) -> str:
    """Output axis of a coefficient name ``<term>.<axis>[...]``."""
    return name.split(".")[1]


@dataclass(frozen=True)
class Model:
    """An error model: an ordered tuple of terms with distinct coefficient names."""

    terms: tuple[Term, ...]

    def __post_init__(self):
        seen: dict[str, str] = {}
        for term in self.terms:
            for name in term.coefficients():
                if name in seen:
                    raise ConfigError(f"terms {seen[name]} and {term.name} both define {name}")
                if axis_of(name) not in AXES:
                    raise ConfigError(
                        f"coefficient {name} of term {term.name} does not name an output axis second"
                    )
                seen[name] = term.name

    @classmethod
    def from_spec(cls, specs: Sequence = DEFAULT_TERMS) -> Model:
        return cls(tuple(make_term(s) for s in specs))

    def spec(self) -> list[dict[str, Any]]:
        return [t.spec() for t in self.terms]

    @property
    def names(self) -> list[str]:
        return [n for t in self.terms for n in t.coefficients()]

    def axis_names(self, axis: str) -> list[str]:
        return [n for n in self.names if axis_of(n) == axis]

    @property
    def needs(self) -> frozenset[str]:
        return frozenset().union(*(t.needs for t in self.terms)) if self.terms else frozenset()

    @property
    def inputs(self) -> frozenset[str]:
        """Every input the terms read, declared or found by probing them."""
        return frozenset().union(*(t.inputs() for t in self.terms)) if self.terms else frozenset()

    def check_inputs(self, data: Mapping, source=None) -> None:
        for term in self.terms:
            term.check_inputs(data, source)

    def transform_inputs(self, data: Mapping) -> Mapping:
        """Observation columns as the terms read them: a term may redefine an input for all
        of them (``die_temperature``: the temperature every dependence is evaluated at).
        Always computed from the logged inputs, so applying it twice changes nothing."""
        for term in self.terms:
            data = term.transform_inputs(data)
        return data

    def sample_transforms(self) -> list:
        """The terms' stateful transforms of samples in time order (:meth:`Term.sample_transform`)."""
        return [f for f in (t.sample_transform() for t in self.terms) if f is not None]

    def design(self, data: Mapping[str, Any]) -> dict[str, np.ndarray]:
        """Regressor columns by coefficient name, one value per row of ``data``.

        ``data`` holds observation columns (one row per hold) or samples, and the session's
        record (``series``) where there is one. For holds, a term
        that reads a series signal (``t``, ``temp_rate``, a lag) is evaluated at quadrature
        nodes inside every hold and averaged (:mod:`gyrocal.terms.signals`); other terms read
        only what is constant within a hold and are evaluated on the hold's values."""
        holds = "t_start" in data
        if holds:
            base, context = hold_inputs(data)
        else:
            base = Inputs({k: v for k, v in data.items() if k != "series"}, data.get("series"), data.get("t"))
            context = Quadrature(None, None)
        nodes = None
        out: dict[str, np.ndarray] = {}
        for term in self.terms:
            inputs = Inputs(base, base.series, base.times)
            try:
                columns = term.columns(inputs)
                if (
                    context.series is not None
                    and context.span is not None
                    and len(context.span[0])
                    and inputs.read & SERIES_INPUTS
                ):
                    if nodes is None:
                        nodes = quadrature_inputs(base, context.series, context.span)
                    at_nodes = term.columns(Inputs(nodes, nodes.series, nodes.times))
                    columns = {k: node_means(v, nodes.plan) for k, v in at_nodes.items()}
            except MissingInputError as exc:
                raise MissingInputError(
                    f"term {term.spec_string()} reads an input it cannot have: {exc}"
                ) from None
            missing = [c for c in term.coefficients() if c not in columns]
            if missing:
                raise ConfigError(f"term {term.spec_string()} gives no column for {', '.join(missing)}")
            out.update(columns)
        return out

    def error(self, coefs: Mapping[str, np.ndarray | float], data: Mapping) -> np.ndarray:
        """Modelled error e (n, 3) for coefficients (scalars or per-row arrays)."""
        n = len(data[RATE_COLUMNS[0]])
        sums = [np.zeros(n) for _ in AXES]  # per axis, contiguous: faster than a column
        cols = self.design(data)
        for name, column in cols.items():
            sums[AXES.index(axis_of(name))] += np.asarray(coefs[name]) * column
        return np.column_stack(sums)

    def linearise(self, coefs, covariates: Mapping, w_true: np.ndarray):
        """Output ``f(w_true) = w_true + e`` near ``w_true`` (n, 3) as ``f ≈ J w_true + c``.

        Returns J (n, 3, 3) and c (n, 3); exact for models affine in the true rate.
        """
        f0 = self._output(coefs, covariates, w_true)
        J = np.empty(w_true.shape + (3,))
        for j in range(3):
            probe = w_true.copy()
            # 1 deg/s, or a step the rounding of a huge rate does not swallow (J singular)
            step = np.maximum(1.0, np.abs(w_true[:, j]) * 2.0**-26)
            probe[:, j] += step
            J[:, :, j] = (self._output(coefs, covariates, probe) - f0) / step[:, None]
        return J, f0 - np.einsum("nij,nj->ni", J, w_true)

    def _output(self, coefs, covariates, w_true):
        data = {**covariates, **{c: w_true[:, i] for i, c in enumerate(RATE_COLUMNS)}}
        return w_true + self.error(coefs, data)

    def compensate(
        self, coefs, w: np.ndarray, covariates: Mapping, *, tol: float = 1e-9, max_iter: int = 20, start=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """True rate for outputs ``w`` (n, 3): solve ``w_true + e(w_true) = w``.

        Returns (w_true, J) where J is the output's Jacobian at the solution (so the
        compensation maps output noise through J^-1). ``start``: (w_true, J), the first
        step made elsewhere from the linearisation at zero rate (as
        :meth:`gyrocal.calibration.file.Calibration.compensate` does once per distinct row);
        J may be None, and is returned so when no further step was needed.
        """
        if start is None:
            J, c = self.linearise(coefs, covariates, np.zeros_like(w, dtype=float))
            w_true = np.linalg.solve(J, (w - c)[..., None])[..., 0]
        else:
            w_true, J = start
        # The solve mixes a row's axes: none converges below the rounding of the row's
        # largest output (a huge output on one axis would otherwise keep the loop going, to
        # linearise where a step of 1 deg/s is lost in rounding and J is singular).
        size = np.abs(w)
        largest = size[..., :1].copy()  # the row's largest output (column by column: a
        for k in range(1, size.shape[-1]):  # reduction along a short axis is slow)
            np.maximum(largest, size[..., k : k + 1], out=largest)
        bound = np.maximum(tol * (1.0 + size), 64 * np.finfo(float).eps * largest)
        for _ in range(max_iter):
            resid = w - self._output(coefs, covariates, w_true)
            if not np.any(np.abs(resid) > bound):
                break
            J, _ = self.linearise(coefs, covariates, w_true)
            w_true = w_true + np.linalg.solve(J, resid[..., None])[..., 0]
        return w_true, J


@dataclass(frozen=True)
class FitResult:
    """Coefficients by name with standard errors, covariance and residual diagnostics."""

    model: Model
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray  # in ``names`` order; zero between output axes
    residuals: np.ndarray  # (n_obs, 3) observed minus modelled error, deg/s
    floor: np.ndarray  # (n_obs, 3) noise floor of each observation, deg/s
    chi2: dict[str, float]  # per output axis
    dof: dict[str, int]
    condition: dict[str, float]  # of the column-scaled weighted design, per axis
    n_obs: int
    info: dict = field(default_factory=dict)

    def coef(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def coefs(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.values, strict=False)}

    def chi2_red(self, axis: str) -> float:
        return self.chi2[axis] / self.dof[axis]

    def summary(self) -> dict[str, Any]:
        """The fit, JSON-plain: terms, coefficients and their errors, the residuals' figures
        per axis, and what :attr:`info` holds."""
        return {
            "terms": self.model.spec(),
            "coefficients": self.coefs(),
            "stderr": {n: float(s) for n, s in zip(self.names, self.stderr, strict=False)},
            "chi2_red": {a: self.chi2_red(a) for a in AXES},
            "dof": dict(self.dof),
            "condition": dict(self.condition),
            "n_obs": self.n_obs,
            **self.info,
        }


NON_NUMERIC = ("mount", "axis", "mount_source")


def columns_of(obs) -> dict[str, np.ndarray]:
    """Numeric observation columns as float arrays (what terms read), with the session's
    record (``series``, :mod:`gyrocal.terms.signals`) when the table carries one in its attrs; a
    mapping passes through."""
    pd = sys.modules.get("pandas")  # not imported here: a report reads a calibration without it
    if pd is None or not isinstance(obs, pd.DataFrame):
        return obs
    data = {
        c: obs[c].to_numpy(dtype=float)
        for c in obs.columns
        if c not in NON_NUMERIC and pd.api.types.is_numeric_dtype(obs[c])
    }
    series = obs.attrs.get("series")
    if series is not None:  # the session's record, for terms that read series signals
        data["series"] = series
    return data


def observation_floor(obs) -> np.ndarray:
    """Noise floor of each observation's mean (n, 3), deg/s.

    From the session's noise model when segmentation characterised it (``floor_*``, and across
    temperature points ``wander_*`` in quadrature: :mod:`gyrocal.fit.floor`); otherwise the
    white-noise floor, within-hold std / sqrt(n)."""
    data = columns_of(obs)
    if "floor_x" in data:
        floor = np.column_stack([data[f"floor_{a}"] for a in "xyz"])
        if "wander_x" in data and np.unique(data["point"]).size > 1:
            floor = np.hypot(floor, np.column_stack([data[f"wander_{a}"] for a in "xyz"]))
        return floor
    std = np.column_stack([data["std_x"], data["std_y"], data["std_z"]])
    return std / np.sqrt(data["n"])[:, None]


def _check_finite(model: Model, design: dict, n_obs: int, source, label: str) -> None:
    """A regressor that is NaN or infinite for some holds (an accelerometer that dropped
    out, a formula outside its domain) is refused, naming its term and how many holds."""
    for term in model.terms:
        for name in term.coefficients():
            bad = ~np.isfinite(design[name])  # a constant column is a scalar
            if bad.any():
                count = int(bad.sum()) if np.ndim(bad) else n_obs
                raise MissingInputError(
                    f"term {term.spec_string()} is not finite for {count} of {n_obs} "
                    f"holds{f' at {label}' if label else ''} (inputs: {', '.join(sorted(term.needs))})",
                    source=source,
                )


def subset_design(design: Mapping[str, np.ndarray], rows) -> dict[str, np.ndarray]:
    """A design's columns at some of its rows (a constant column stays a scalar)."""
    return {k: v[rows] if np.ndim(v) else v for k, v in design.items()}


def shares_wander(data) -> bool:
    """Whether the holds share slow wander (bias instability or rate random walk in the
    session's noise model), so that the fit whitens them jointly rather than one by one."""
    return (
        "white_x" in data
        and len(data["white_x"]) > 1
        and any(
            f"{k}_{a}" in data and bool(np.any(np.asarray(data[f"{k}_{a}"]) > 0))
            for k in ("flicker", "rrw")
            for a in AXES
        )
    )


def _whiteners(data: dict, floor: np.ndarray) -> list:
    """Per output axis, the map that makes the observations' noise unit white.

    Independent noise (white, or no noise model): divide by the floor. With bias instability or
    rate random walk in the session's noise model (``white_*``, ``flicker_*``, ``rrw_*`` columns,
    :mod:`gyrocal.fit.floor`), the hold means share slow wander, and holds close in time err alike;
    the fit is then generalised least squares with that covariance, C = L L^T and L^-1 applied
    (:mod:`gyrocal.fit.wander`, in time linear in the holds), so that the chi-square and the
    F-tests of the diagnosis count the evidence honestly (a wander that follows the
    protocol's order of rates would otherwise pass for a rate effect)."""

    def divide(i):
        w = 1.0 / floor[:, i]
        return lambda m: m * (w[:, None] if np.ndim(m) == 2 else w)

    if not shares_wander(data):
        return [divide(i) for i in range(3)]
    from .wander import whiteners

    white = [
        np.maximum(np.asarray(data[f"white_{a}"], float), 1e-3 * np.median(floor[:, i]))
        for i, a in enumerate(AXES)
    ]
    found = whiteners(
        data["t_start"],
        data["t_end"],
        white,
        [float(np.max(data[f"flicker_{a}"])) for a in AXES],
        [float(np.max(data[f"rrw_{a}"])) for a in AXES],
    )
    if found is None:  # observations overlapping in time (no segmenter makes them)
        return [divide(i) for i in range(3)]
    return [divide(i) if w is None else w for i, w in enumerate(found)]


# A term with a roughness penalty (an empirical spline) is penalised this much relative to
# what the data tell of its coefficients: negligible where holds determine them, enough to
# carry the smoothest curve across a stretch of its input without holds (a temperature
# point left out to validate). Whether the penalised model is determined at all is judged
# with the penalty at full weight: a direction only the penalty fixes is not a collinearity.
PENALTY_WEIGHT = 1e-4
DEAD_COLUMN = 1e-12  # a column norm below this share of the largest counts as zero


def _penalty_rows(
    model: Model, cols: list[str], scale: np.ndarray, weight: float = PENALTY_WEIGHT
) -> np.ndarray | None:
    """Rows appended to the column-scaled, whitened design of one output axis: for each
    term with a penalty ``c' Ω c`` (:meth:`gyrocal.terms.Term.penalty`), ``sqrt(λ e) V'``
    on its columns, ``Ω / (scale scale') = V diag(e) V'``, ``λ`` the penalty weight times the
    number of its columns over ``trace(Ω)`` (each scaled column has unit norm)."""
    blocks = []
    index = {c: j for j, c in enumerate(cols)}
    for term in model.terms:
        mine = [c for c in term.coefficients() if c in index]
        omega = term.penalty(mine) if mine else None
        if omega is None:
            continue
        J = np.array([index[c] for c in mine])
        scaled = omega / np.outer(scale[J], scale[J])
        e, V = np.linalg.eigh(scaled)
        keep = e > 1e-12 * max(e.max(), 1e-300)
        if not keep.any():
            continue
        lam = weight * len(J) / float(np.trace(scaled))
        block = np.zeros((int(keep.sum()), len(cols)))
        block[:, J] = np.sqrt(lam * e[keep])[:, None] * V[:, keep].T
        blocks.append(block)
    return np.vstack(blocks) if blocks else None


def fit(
    model: Model,
    obs,
    *,
    source=None,
    label: str = "",
    design: dict | None = None,
    weights: tuple[np.ndarray, list] | None = None,
    blocks: list[np.ndarray] | None = None,
) -> FitResult:
    """Weighted least squares of the gyro error on the model's columns, per output axis.

    ``obs`` is an observation table or a mapping of its numeric columns. Refuses
    (:class:`IdentifiabilityError`, naming the coefficients) when the observations do not
    excite some coefficient, or leave no degree of freedom for the covariance. ``design``,
    the model's columns on these observations when already made (:func:`subset_design`
    of a fit of more holds: a hold's columns are its own, as apply evaluates them sample by
    sample), saves making them again. ``blocks``: row sets the weighting keeps apart (a
    joint grid's points) and each of which touches a few of many columns: a wide design is
    then solved from their normal equations (:func:`_block_normal`).
    """
    data = columns_of(obs)
    model.check_inputs(data, source)
    n_obs = len(data["gyro_x"])
    design = model.design(data) if design is None else design
    _check_finite(model, design, n_obs, source, label)
    floor, whiteners = observation_weights(data) if weights is None else weights
    where = f" at {label}" if label else ""
    axes: dict[str, _AxisFit] = {}
    resid = np.zeros((n_obs, 3))
    unexcited: list[str] = []
    worst = 0.0
    for i, axis in enumerate(AXES):
        cols = model.axis_names(axis)
        if not cols:
            continue
        y = data[f"gyro_{axis}"] - data[f"rate_{axis}"]
        found = _fit_axis(model, cols, design, y, whiteners[i], where=where, source=source, blocks=blocks)
        if isinstance(found, _Unexcited):
            unexcited += found.names
            worst = max(worst, found.condition)
            continue
        axes[axis] = found
        resid[:, i] = found.residuals
    if unexcited:
        _refuse_unexcited(model, unexcited, worst, n_obs, where, source)
    return _joined(model, axes, resid, floor, n_obs)


def observation_weights(data) -> tuple[np.ndarray, list]:
    """The floors the observations are weighted by, and per output axis the map that
    whitens their noise: what a fit of these observations weights by, whatever its model."""
    floor = _weighting_floor(observation_floor(data))
    return floor, _whiteners(data, floor)


def _weighting_floor(floor: np.ndarray) -> np.ndarray:
    """The floors the observations are weighted by. A hold whose scatter is zero (a constant,
    quantised output) would get infinite weight: no observation is trusted more than a
    thousandth of the typical floor (the largest when most holds of an axis have none;
    equal weights when none has any, as from an axis stuck for part of the log)."""
    typical = np.median(floor, axis=0)
    typical = np.where(typical > 0, typical, floor.max(axis=0, initial=0.0))
    return np.maximum(floor, 1e-3 * np.where(typical > 0, typical, 1e3))


@dataclass(frozen=True)
class _AxisFit:
    """One output axis's regression: its coefficients (in the axis's column order), their
    standard errors and covariance, the residuals, chi-square, degrees of freedom and the
    condition number of the column-scaled weighted design."""

    names: list[str]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    chi2: float
    dof: int
    condition: float


@dataclass(frozen=True)
class _Unexcited:
    """Coefficients of one output axis the observations do not excite, and the condition
    number that says how badly."""

    names: list[str]
    condition: float


# From this many columns of one axis a design whose rows fall in blocks touching few of them
# (a joint grid of many points) is solved from its normal equations block by block: the SVD
# of the whole design grows with its columns squared times its rows. Below it the SVD keeps
# every narrower fit's figures to the last bit.
BLOCK_SOLVE_COLUMNS = 64


def _block_normal(A: np.ndarray, b: np.ndarray, blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``A'A`` and ``A'b`` summed over row ``blocks``, each on the columns it touches: a
    joint grid's point reads only the nodes its holds' temperatures lie between."""
    C = A.shape[1]
    N, Ab = np.zeros((C, C)), np.zeros(C)
    for idx in blocks:
        part = A[idx]
        live = np.flatnonzero(np.any(part != 0.0, axis=0))
        part = part[:, live]
        N[np.ix_(live, live)] += part.T @ part
        Ab[live] += part.T @ b[idx]
    return N, Ab


def _spectrum(
    A: np.ndarray, yw: np.ndarray, blocks: list[np.ndarray] | None
) -> tuple[np.ndarray, np.ndarray, Callable[[], np.ndarray]]:
    """The column-scaled design's singular values (descending), right singular vectors, and
    the scaled solution ``V diag(1/s) U'y`` to make once the spectrum is accepted: by SVD, or,
    given row ``blocks``, from the eigenvalues of its normal equations (sound for what the fit
    accepts: a condition number within MAX_CONDITION, squared, is far from rounding)."""
    if blocks is None:
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        return s, Vt, lambda: Vt.T @ ((U.T @ yw) / s)
    N, Ab = _block_normal(A, yw, blocks)
    e, V = np.linalg.eigh(N)
    e, V = np.maximum(e[::-1], 0.0), V[:, ::-1]
    return np.sqrt(e), V.T, lambda: V @ ((V.T @ Ab) / e)


def _fit_axis(
    model: Model,
    cols: list[str],
    design: Mapping,
    y: np.ndarray,
    whiten,
    *,
    where: str,
    source,
    blocks: list[np.ndarray] | None = None,
) -> _AxisFit | _Unexcited:
    """The weighted least squares of one output axis's error ``y`` on its columns ``cols``,
    solved by the SVD of the whitened, column-scaled design (with the penalty rows of
    :func:`_penalty_rows` beneath it), or from its normal equations (:func:`_spectrum`)."""
    n_obs = len(y)
    X = np.empty((n_obs, len(cols)))
    for j, c in enumerate(cols):
        X[:, j] = design[c]  # a constant column is a scalar
    XY = whiten(np.column_stack([X, y]))  # one pass; each column is whitened alone
    # contiguous, as whitened apart: a strided vector takes another BLAS path, whose
    # last bits steer a profiled fit of a jagged chi-square to another local minimum
    Xw, yw = np.ascontiguousarray(XY[:, :-1]), np.ascontiguousarray(XY[:, -1])
    scale = np.linalg.norm(Xw, axis=0)
    # A column 1e-12 of the largest (a profiled bump whose width misses every hold)
    # is no more excited than a zero one: its coefficient's variance would overflow.
    dead = scale <= DEAD_COLUMN * scale.max(initial=0.0)
    scale[dead] = 1.0
    rows = _penalty_rows(model, cols, scale)
    A = np.vstack([Xw / scale, rows]) if rows is not None else Xw / scale
    if rows is not None:
        yw = np.concatenate([yw, np.zeros(len(rows))])
        dead &= ~np.any(rows != 0, axis=0)  # the penalty carries a column without holds
    # penalty rows span every column: no block structure then
    by_blocks = blocks is not None and rows is None and A.shape[1] >= BLOCK_SOLVE_COLUMNS
    s, Vt, solve = _spectrum(A, yw, blocks if by_blocks else None)
    check, check_Vt = s, Vt
    # judged with the penalty at full weight (PENALTY_WEIGHT), whose rows come from the same terms
    if rows is not None and (full := _penalty_rows(model, cols, scale, 1.0)) is not None:
        _, check, check_Vt = np.linalg.svd(np.vstack([Xw / scale, full]), full_matrices=False)
    # Columns that only noise keeps apart (an accelerometer that reads the same on
    # every mount but for its noise) fit noise, not physics: refuse them too.
    weak = check <= check[0] / MAX_CONDITION if check.size else np.array([], bool)
    if weak.any() and by_blocks:
        # a refusal is judged and named as the SVD finds it: the normal equations' square puts
        # an exact collinearity at rounding of either sign (1e8 or 1e300, not 1e16)
        _, check, check_Vt = np.linalg.svd(A, full_matrices=False)
        weak = check <= check[0] / MAX_CONDITION
    if dead.any() or weak.any():
        involved = set(np.flatnonzero(dead))
        for k in np.flatnonzero(weak):
            involved |= set(np.flatnonzero(np.abs(check_Vt[k]) > 0.1))
        return _Unexcited([cols[j] for j in sorted(involved)], float(check[0] / max(check[-1], 1e-300)))
    n_dof = n_obs - len(cols)
    if n_dof < 1:
        raise IdentifiabilityError(
            f"{n_obs} holds{where} cannot fit {len(cols)} coefficients per axis with "
            f"a residual left to estimate their uncertainty",
            parameters=tuple(cols),
            source=source,
        )
    theta = solve() / scale
    r = y - X @ theta
    c2 = float(np.sum(whiten(r) ** 2))
    cov = (Vt.T / s**2) @ Vt / np.outer(scale, scale) * (c2 / n_dof)
    cov = 0.5 * (cov + cov.T)  # the product's triangles differ in their last bits
    se = np.sqrt(np.diag(cov))
    cov[np.diag_indices_from(cov)] = se**2  # as a calibration file holds it
    return _AxisFit(cols, theta, se, cov, r, c2, n_dof, float(s[0] / s[-1]))


def _refuse_unexcited(model: Model, unexcited: list[str], worst: float, n_obs: int, where: str, source):
    bad = tuple(n for n in model.names if n in unexcited)
    how = (
        "no rotation or holds that separate them"
        if worst > 1e9
        else f"they are nearly collinear (condition number {worst:.3g})"
    )
    raise IdentifiabilityError(
        f"the observations{where} do not excite {', '.join(bad)}: {how} ({n_obs} holds)",
        parameters=bad,
        source=source,
    )


def _joined(
    model: Model, axes: dict[str, _AxisFit], resid: np.ndarray, floor: np.ndarray, n_obs: int
) -> FitResult:
    """The output axes' regressions as one fit, in the model's order of coefficients (the
    covariance zero between axes)."""
    names = [n for found in axes.values() for n in found.names]
    covariance = np.zeros((len(names), len(names)))
    at = 0
    for found in axes.values():
        k = len(found.covariance)
        covariance[at : at + k, at : at + k] = found.covariance
        at += k
    order = [names.index(n) for n in model.names]  # report in the model's own order
    covariance = covariance[np.ix_(order, order)]
    values = np.concatenate([found.values for found in axes.values()])[order]
    stderr = np.concatenate([found.stderr for found in axes.values()])[order]
    return FitResult(
        model,
        tuple(model.names),
        values,
        stderr,
        covariance,
        resid,
        floor,
        {a: found.chi2 for a, found in axes.items()},
        {a: found.dof for a, found in axes.items()},
        {a: found.condition for a, found in axes.items()},
        n_obs,
    )
