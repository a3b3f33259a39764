"""Servo calibrations: seed 001's six parameters (Algorithm 1 and a Levenberg-Marquardt
reference) and two with cross-axis terms, the symmetric model (Eq 3 with the cross products,
solved by Algorithm 1) and the fixture model (all twelve from every output); see the
section "Cross-axis terms" below and docs/method.md.

Convention. Eq 1 as printed reads ``g = k m + b``, but Eq 3 expands ``ω² = |g|²`` as
``Σ k_j² m_j² + 2 k_j² b_j m_j + k_j² b_j²``, i.e. ``ω² = Σ (k_j (m_j + b_j))²``, and
Algorithm 1 returns ``k_j = sqrt(β_j)``, ``b_j = β_{j+3} / (2 β_j)``, which only inverts that
expansion. So the model the paper actually fits (and this module fits) is, per axis,

    g_j = k_j (m_j + b_j)          (true rate g, raw output m; b in the unit of m)

gyrocal's calibration file means ``w = K w_true + B`` with raw output ``w``. With ``w = m``
and ``w_true = g``: ``m = g / k - b``, so

    K = diag(1 / k),   B = -b  (converted to deg/s),   compensation w_true = diag(k) (w - B).

:class:`ServoFit` holds both forms: ``k`` and ``b`` in the unit of the input (``unit``;
the paper's rad/s by default), ``K`` (1) and ``B`` (deg/s, the file's unit).

Regression (Eq 4 and 6): ``y = ω² = β0 + Σ β_j x_j`` with ``x = (m_x², m_y², m_z², m_x, m_y,
m_z)`` (columns in β's order; Eq 7 prints the same columns with linear terms first),
``β1..3 = k²``, ``β4..6 = 2 k² b``, and the constraint ``β0 = Σ β_{j+3}² / (4 β_j)``.
Algorithm 1 freezes β0, solves the linear least squares, updates β0 from the new β and
repeats until ``Σ |Δβ_j| <= tol`` (j = 1..6; the paper's 1e-6 is meant in rad/s). Since only
the constant ``β0`` changes between iterations, ``β(n+1) = A (Y - β0 1) = A Y - β0 A 1``
with ``A = (XᵀX)⁻¹Xᵀ``: the two products are computed once and every iteration is the
paper's update exactly, without a new solve.

Convergence: each iteration shrinks the error by a factor of about ``β0 / ω²`` (β0 = Σ k² b²,
ω the servo speed). The paper's condition ``0 <= β0 < 0.5`` leaves out the speed: a unit with
k = 2 and b = 0.2 rad/s (β0 = 0.48) does not converge in 50 iterations at 1 rad/s, while at
3 rad/s it needs six updates. The paper's "less than three iterations" (Table I) counts estimates
until the printed four decimals settle (:meth:`ServoFit.settled_at`); the 1e-6 stopping rule
takes two to five updates for Section III's normal units at 60 deg/s (``iterations``).

With exactly six observations both methods solve the six equations exactly (zero
residuals) and agree up to Algorithm 1's stopping rule (a few 1e-9 relative at tol=1e-6,
rounding at tol=1e-12). With more observations (one row per revolution) the
methods differ: LM minimises the squared ω² residuals with β0 tied to the other
parameters, while Algorithm 1's fixed point is the least-squares solution with β0 held at
its final value, so they agree only to within the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares

from ...io.errors import InputError

DEG = 180.0 / math.pi
UNIT_TO_DEG = {"rad/s": DEG, "deg/s": 1.0}
PARAMETERS = ("kx", "ky", "kz", "bx", "by", "bz")
MAX_CONDITION = 1e8  # column-scaled condition number above which the design is refused


class ServoFitError(InputError):
    """The servo observations cannot be calibrated: too few, degenerate, or no convergence."""


@dataclass(frozen=True)
class ServoFit:
    """Result of a servo calibration; nothing in it is ever NaN.

    ``k`` (1) and ``b`` (``unit``) are seed 001's parameters (g = k (m + b)); ``K`` (3x3, 1)
    and ``B`` (deg/s) the calibration file's (w = K w_true + B). ``beta`` is β0..β6 of
    Eq 4 in ``unit`` powers; ``residuals`` the ω² residual per observation (model minus
    servo, ``unit``²); ``trace`` one record per estimate: β, β0 used, change Σ|Δβ|.
    """

    k: np.ndarray
    b: np.ndarray
    K: np.ndarray
    B: np.ndarray
    beta: np.ndarray
    iterations: int
    trace: tuple[dict, ...]
    method: str
    converged: bool
    residuals: np.ndarray
    unit: str = "rad/s"
    k_se: np.ndarray | None = None  # linearised from the observations' standard errors
    b_se: np.ndarray | None = None
    n_observations: int = 6
    notes: tuple[str, ...] = field(default_factory=tuple)

    def compensate(self, gyro) -> np.ndarray:
        """True rates from raw outputs in deg/s (n, 3): ``K⁻¹ (w - B)`` = ``diag(k) (w - B)``."""
        return (np.asarray(gyro, dtype=float) - self.B) * self.k

    def coefficients(self) -> dict[str, float]:
        """The fit in gyrocal's term names (docs/method.md): ``bias.a`` = B_a (deg/s),
        ``scale.a`` = K_aa - 1 = 1/k_a - 1; seed 001's model has no cross-axis terms
        (:class:`CrossAxisFit` has them)."""
        out = {f"bias.{a}": float(self.B[i]) for i, a in enumerate("xyz")}
        out.update({f"scale.{a}": float(1.0 / self.k[i] - 1.0) for i, a in enumerate("xyz")})
        return out

    def coefficient_errors(self) -> dict[str, float] | None:
        """Standard errors of :meth:`coefficients` (linearised), when the fit had them."""
        if self.k_se is None:
            return None
        out = {f"bias.{a}": float(self.b_se[i] * UNIT_TO_DEG[self.unit]) for i, a in enumerate("xyz")}
        out.update({f"scale.{a}": float(self.k_se[i] / self.k[i] ** 2) for i, a in enumerate("xyz")})
        return out

    def settled_at(self, atol: float = 5e-5) -> int:
        """Index (1-based) of the first estimate whose k and b all lie within ``atol`` of the
        final ones: how seed 001's Table I counts iterations (values agreeing to the four
        printed decimals), as opposed to ``iterations``, the β0 updates the stopping rule took."""
        final = np.concatenate([self.k, self.b])
        for i, rec in enumerate(self.trace, start=1):
            if np.all(np.abs(np.asarray(rec["k"] + rec["b"]) - final) <= atol):
                return i
        return len(self.trace)

    def summary(self) -> dict[str, Any]:
        """JSON-plain record of the fit."""
        out = {
            "method": self.method,
            "unit": self.unit,
            "convention": "g = k (m + b)",
            "k": self.k.tolist(),
            "b": self.b.tolist(),
            "K": self.K.tolist(),
            "B_deg_s": self.B.tolist(),
            "beta": self.beta.tolist(),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "n_observations": int(self.n_observations),
            "residuals": self.residuals.tolist(),
            "trace": [dict(rec) for rec in self.trace],
            "notes": list(self.notes),
        }
        if self.k_se is not None:
            out["k_se"] = self.k_se.tolist()
            out["b_se"] = self.b_se.tolist()
        return out


# ---------------------------------------------------------------------------------------
# Algorithm 1, batched: shared by fit_iterative (one run) and the Monte-Carlo study.


def design(m: np.ndarray) -> np.ndarray:
    """Regressors x1..x6 of Eq 4 for observations m (..., n, 3): (..., n, 6)."""
    m = np.asarray(m, dtype=float)
    return np.concatenate([m * m, m], axis=-1)


def _products(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A Y`` and ``A 1`` with ``A = (XᵀX)⁻¹Xᵀ`` for stacked X (R, n, 6), Y (R, n)."""
    rhs = np.stack([Y, np.ones_like(Y)], axis=-1)
    if X.shape[-2] == X.shape[-1]:
        sol = np.linalg.solve(X, rhs)
    else:
        Q, R = np.linalg.qr(X)
        sol = np.linalg.solve(R, np.swapaxes(Q, -1, -2) @ rhs)
    return sol[..., 0], sol[..., 1]


def gamma(beta6: np.ndarray) -> np.ndarray:
    """β0 implied by β1..β6 (..., 6): Σ β_{j+3}² / (4 β_j)."""
    return np.sum(beta6[..., 3:] ** 2 / (4.0 * beta6[..., :3]), axis=-1)


class Algorithm1Runs(NamedTuple):
    """Algorithm 1 on R stacked runs, at exit."""

    beta: np.ndarray  # (R, p): β1..β6 (seed 001's model) or β1..β9 (the symmetric one)
    iterations: np.ndarray  # (R,) β0 updates made
    converged: np.ndarray  # (R,)
    positive: np.ndarray  # (R,) β kept the square root the parameters need
    trace: list | None  # per estimate (β (R, p), β0 used (R,), change (R,)); None unless kept


def algorithm1(
    m: np.ndarray, omega: np.ndarray, *, tol: float = 1e-6, max_iter: int = 50, keep_trace: bool = False
) -> Algorithm1Runs:
    """Algorithm 1 on R stacked runs: m (R, n, 3), omega (R, n) or broadcastable; with
    ``keep_trace`` every estimate is kept (``positive``: β1..β3 stayed > 0). A run stops
    updating once it meets the stopping rule, so each run's result is what a one-run call
    gives.
    """
    m = np.asarray(m, dtype=float)
    X = design(m)
    Y = np.broadcast_to(np.asarray(omega, dtype=float) ** 2, m.shape[:-1])
    u, v = _products(X, Y)
    return _iterate(
        u,
        v,
        admissible=lambda beta: np.all(beta[:, :3] > 0, axis=1),
        beta0=gamma,
        placeholder=1.0,
        tol=tol,
        max_iter=max_iter,
        keep_trace=keep_trace,
    )


def _iterate(u, v, *, admissible, beta0, placeholder, tol, max_iter, keep_trace=False) -> Algorithm1Runs:
    """Algorithm 1's loop on R stacked runs, given ``u = A Y`` and ``v = A 1`` (R, p):
    β(n+1) = u − β0(β(n)) v until Σ|Δβ| <= tol. ``admissible(β)`` (R,): whether β has the
    square root the parameters need; ``beta0(β)``: the constant the model ties to β,
    evaluated on ``placeholder`` rows for runs that have stopped."""
    beta = u.copy()  # β(1), with β0(0) = 0
    R = beta.shape[0]
    positive = admissible(beta)
    active = positive.copy()
    converged = np.zeros(R, dtype=bool)
    iterations = np.zeros(R, dtype=int)
    trace = [(beta.copy(), np.zeros(R), np.full(R, np.inf))] if keep_trace else None
    for it in range(1, max_iter + 1):
        if not active.any():
            break
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            g0 = np.where(active, beta0(np.where(active[:, None], beta, placeholder)), 0.0)
            new = u - g0[:, None] * v
            change = np.sum(np.abs(new - beta), axis=1)
        ok = np.isfinite(new).all(axis=1) & admissible(new)
        step = active & ok
        beta = np.where(step[:, None], new, beta)
        iterations = np.where(step, it, iterations)
        positive &= ~(active & ~ok)
        done = step & (change <= tol)
        converged |= done
        active &= ok & ~done
        if trace is not None:
            trace.append((beta.copy(), g0, np.where(step, change, np.nan)))
    return Algorithm1Runs(beta, iterations, converged, positive, trace)


def parameters_from_beta(beta6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """k and b from β1..β6 (..., 6): k = sqrt(β1..3), b = β4..6 / (2 β1..3)."""
    return np.sqrt(beta6[..., :3]), beta6[..., 3:] / (2.0 * beta6[..., :3])


# ---------------------------------------------------------------------------------------


def _check(m, omega, m_sem, unit: str):
    if unit not in UNIT_TO_DEG:
        raise ServoFitError(f"unit must be one of {', '.join(UNIT_TO_DEG)}; got {unit!r}")
    try:
        m = np.asarray(m, dtype=float)
        omega = np.asarray(omega, dtype=float)
    except (TypeError, ValueError):
        raise ServoFitError("observations must be numeric arrays: m (n, 3) and omega (n,)") from None
    if m.ndim != 2 or m.shape[1] != 3:
        raise ServoFitError(f"observations m must have shape (n, 3); got {m.shape}")
    n = m.shape[0]
    omega = np.broadcast_to(omega, (n,)) if omega.ndim == 0 else omega
    if omega.shape != (n,):
        raise ServoFitError(f"omega must have one value per observation ({n}); got shape {omega.shape}")
    if n < 6:
        raise ServoFitError(f"the six-parameter model needs at least 6 observations; got {n}")
    if not (np.isfinite(m).all() and np.isfinite(omega).all()):
        raise ServoFitError("observations hold non-finite values")
    if np.any(omega == 0):
        raise ServoFitError(
            "a servo speed of 0 gives no scale information; every observation needs a non-zero speed"
        )
    X = design(m)
    scale = np.linalg.norm(X, axis=0)
    if np.any(scale == 0) or np.linalg.cond(X / scale) > MAX_CONDITION:
        raise ServoFitError(
            "the observations do not determine all six parameters (the design "
            "lacks rotations about some axis or in both directions)"
        )
    if m_sem is not None:
        m_sem = np.asarray(m_sem, dtype=float)
        if m_sem.shape != m.shape or not np.isfinite(m_sem).all() or np.any(m_sem < 0):
            raise ServoFitError(f"m_sem must be finite, >= 0, shape {m.shape}")
    return m, np.abs(omega), m_sem


def residuals_of(k, b, m, omega) -> np.ndarray:
    """ω² residuals (model minus servo) of Eq 3 for parameters k, b."""
    return np.sum((k * (m + b)) ** 2, axis=-1) - omega**2


def _standard_errors(k, b, m, m_sem):
    """Linearised standard errors of (k, b) from the observations' standard errors."""
    if m_sem is None:
        return None, None
    mb = m + b
    J = np.hstack([2 * k * mb**2, 2 * k**2 * mb])  # ∂r/∂(k, b)
    var_r = np.sum((2 * k**2 * mb * m_sem) ** 2, axis=1)  # r's variance from m's
    try:
        A = np.linalg.solve(J.T @ J, J.T)
    except np.linalg.LinAlgError:
        raise ServoFitError("the standard errors cannot be propagated: singular Jacobian") from None
    se = np.sqrt(np.einsum("ij,j,ij->i", A, var_r, A))
    return se[:3], se[3:]


def _result(k, b, *, m, omega, unit, method, iterations, trace, converged, m_sem, notes=()):
    k = np.abs(np.asarray(k, dtype=float))
    b = np.asarray(b, dtype=float)
    beta = np.concatenate([[np.sum(k**2 * b**2)], k**2, 2 * k**2 * b])
    res = residuals_of(k, b, m, omega)
    k_se, b_se = _standard_errors(k, b, m, m_sem)
    values = [k, b, beta, res] + ([k_se, b_se] if k_se is not None else [])
    if not all(np.isfinite(x).all() for x in values):
        raise ServoFitError(f"{method} fit produced non-finite parameters")
    return ServoFit(
        k=k,
        b=b,
        K=np.diag(1.0 / k),
        B=-b * UNIT_TO_DEG[unit],
        beta=beta,
        iterations=int(iterations),
        trace=tuple(trace),
        method=method,
        converged=bool(converged),
        residuals=res,
        unit=unit,
        k_se=k_se,
        b_se=b_se,
        n_observations=len(m),
        notes=tuple(notes),
    )


def fit_iterative(
    m, omega, *, tol: float = 1e-6, max_iter: int = 50, unit: str = "rad/s", m_sem=None, strict: bool = True
) -> ServoFit:
    """Algorithm 1 of seed 001 on n >= 6 observations.

    ``m`` (n, 3): mean raw output per observation (a rotation or a revolution, Eq 8);
    ``omega`` (n,): servo speed (sign ignored), both in ``unit``. ``tol`` is the stopping
    rule on Σ|Δβ| in that unit. ``m_sem`` (n, 3), optional: standard errors of ``m``, for
    the parameters' standard errors. Raises :class:`ServoFitError` when β1..β3 turn
    non-positive (no square root) or, with ``strict``, when ``max_iter`` updates do not
    converge; a non-strict call returns the last estimate with ``converged=False``.
    """
    m, omega, m_sem = _check(m, omega, m_sem, unit)
    out = algorithm1(m[None], omega[None], tol=tol, max_iter=max_iter, keep_trace=True)
    if not out.positive[0]:
        raise ServoFitError(
            "Algorithm 1 gave β1..β3 <= 0 (no square root for k); the β0 "
            "iteration diverges when Σ k² b² is not small against ω²: rotate "
            "faster or use fit_lm"
        )
    converged = bool(out.converged[0])
    if not converged and strict:
        raise ServoFitError(
            f"Algorithm 1 did not converge to Σ|Δβ| <= {tol:g} in {max_iter} "
            f"iterations (speed too low for the biases: β0/ω² must stay well below 1)"
        )
    trace = []
    for i, (beta6, g0, change) in enumerate(out.trace or []):
        if i > 0 and not np.isfinite(change[0]):
            break
        kk, bb = parameters_from_beta(beta6[0])
        trace.append(
            {
                "estimate": i + 1,
                "beta0_used": float(g0[0]),
                "beta": [float(x) for x in beta6[0]],
                "k": [float(x) for x in kk],
                "b": [float(x) for x in bb],
                "change": None if i == 0 else float(change[0]),
            }
        )
    k, b = parameters_from_beta(out.beta[0])
    return _result(
        k,
        b,
        m=m,
        omega=omega,
        unit=unit,
        method="iterative",
        iterations=out.iterations[0],
        trace=trace,
        converged=converged,
        m_sem=m_sem,
    )


def lm_solve(m: np.ndarray, omega: np.ndarray, x0: np.ndarray):
    """scipy's Levenberg-Marquardt on Eq 3's ω² residuals with (k, b) as unknowns."""

    def fun(p):
        return residuals_of(p[:3], p[3:], m, omega)

    def jac(p):
        k, mb = p[:3], m + p[3:]
        return np.hstack([2 * k * mb**2, 2 * k**2 * mb])

    return least_squares(fun, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)


def initial_guess(m: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Algorithm 1's first estimate β(1) (β0 = 0) as (k, b): the start of the LM fit."""
    u, _ = _products(design(m)[None], (omega**2)[None])
    if not np.all(u[0, :3] > 0):
        raise ServoFitError("the first linear estimate has β1..β3 <= 0; no starting point")
    k, b = parameters_from_beta(u[0])
    return np.concatenate([k, b])


def fit_lm(m, omega, *, unit: str = "rad/s", m_sem=None) -> ServoFit:
    """Levenberg-Marquardt reference (Eq 2-3, scipy ``least_squares(method="lm")``) with
    (k, b) as the unknowns, started from Algorithm 1's first step; tolerances 1e-15."""
    m, omega, m_sem = _check(m, omega, m_sem, unit)
    x0 = initial_guess(m, omega)
    res = lm_solve(m, omega, x0)
    if not res.success or not np.isfinite(res.x).all():
        raise ServoFitError(f"Levenberg-Marquardt did not converge ({res.message})")
    trace = [
        {"estimate": 1, "k": x0[:3].tolist(), "b": x0[3:].tolist(), "change": None},
        {
            "estimate": 2,
            "k": np.abs(res.x[:3]).tolist(),
            "b": res.x[3:].tolist(),
            "change": float(np.sum(np.abs(res.x - x0))),
        },
    ]
    return _result(
        res.x[:3],
        res.x[3:],
        m=m,
        omega=omega,
        unit=unit,
        method="lm",
        iterations=res.nfev,
        trace=trace,
        converged=True,
        m_sem=m_sem,
        notes=(f"scipy least_squares lm: {res.nfev} evaluations, status {res.status}",),
    )


def fit_observations(obs, *, method: str = "iterative", tol: float = 1e-6, max_iter: int = 50) -> ServoFit:
    """Calibrate from a rotations or revolutions table (:mod:`gyrocal.protocols.servo.rotations`):
    columns ``gyro_x/y/z`` and ``ref_rate`` in deg/s, optionally ``gyro_x/y/z_sem`` (or
    ``gyro_x/y/z_noise`` and ``n``) for standard errors. The fit
    runs in rad/s, so ``tol`` keeps the paper's meaning; ``k``, ``b`` come back in rad/s and
    ``B`` in deg/s."""
    m, omega, m_sem, _ = observation_arrays(obs, DEG)
    if method == "iterative":
        return fit_iterative(m, omega, tol=tol, max_iter=max_iter, m_sem=m_sem)
    if method == "lm":
        return fit_lm(m, omega, m_sem=m_sem)
    raise ServoFitError(f"method must be 'iterative' or 'lm'; got {method!r}")


# ---------------------------------------------------------------------------------------
# Cross-axis terms. What a servo log can tell about them depends on what is known of the
# rotation axes (docs/method.md, "Servo protocol"): each rotation reads K u ω + B, u the
# axis in the sensor frame. A hand mount leaves u unknown (a tilt of a few degrees, new each
# mount), so the off-axis outputs hold the tilt as well as K's cross terms; only the
# magnitude |K⁻¹(m − B)| = ω is free of it. A fixture makes u the commanded axis.

MODELS = ("auto", "seed001", "symmetric", "fixture")
COEFFICIENTS = (
    *(f"bias.{a}" for a in "xyz"),
    *(f"scale.{a}" for a in "xyz"),
    *(f"misalignment.{a}.{b}" for a in "xyz" for b in "xyz" if a != b),
)
# The symmetric cross terms are fitted when the rotations determine each to 1e-2 (1 %, the
# size of a large MEMS cross-axis sensitivity; a less determined term could not be told from
# zero in any unit), and ``auto`` applies them when they are also significant together
# (χ² of the three at p < CROSS_ALPHA): then they are larger than their uncertainty and
# correcting them beats assuming them zero (seed 001's model).
MAX_CROSS_STDERR = 1e-2
CROSS_ALPHA = 0.01
CROSS_PAIRS = ("misalignment.x.y", "misalignment.x.z", "misalignment.y.z")


@dataclass(frozen=True)
class CrossAxisFit:
    """A servo calibration with cross-axis terms, ``w = K w_true + B`` (K 3x3, B deg/s).

    ``model``: ``"symmetric"`` (K symmetric, fitted so that the compensated rate's magnitude
    is the servo speed: Eq 2 with a full K; the triad's rotation against the housing cannot
    be seen by magnitudes and is taken as none) or ``"fixture"`` (every term, the commanded
    axes taken as the true rate's direction). ``stderr``: standard error per coefficient
    (:data:`COEFFICIENTS`, linearised from the observations' noise); ``residuals``: per
    observation, the ω² residual (symmetric, rad²/s²) or the output residual vector (fixture,
    deg/s)."""

    model: str
    K: np.ndarray
    B: np.ndarray
    stderr: dict
    residuals: np.ndarray
    n_observations: int
    iterations: int = 0
    converged: bool = True
    notes: tuple[str, ...] = field(default_factory=tuple)
    covariance: np.ndarray | None = None  # of the coefficients, in COEFFICIENTS order

    def cross_significance(self) -> tuple[float, float]:
        """(χ², p) of the three symmetric cross terms together against zero, from their
        covariance: how surely the rotations show cross-axis sensitivity."""
        from scipy.special import chdtrc

        chi2 = float(cross_chi2(self.K, self.covariance))
        return chi2, float(chdtrc(len(CROSS_PAIRS), chi2))

    def compensate(self, gyro) -> np.ndarray:
        """True rates from raw outputs in deg/s (n, 3): ``K⁻¹ (w − B)``."""
        return np.linalg.solve(self.K, (np.asarray(gyro, dtype=float) - self.B).T).T

    def coefficients(self) -> dict[str, float]:
        return _coefficients(self.K, self.B)

    def coefficient_errors(self) -> dict[str, float]:
        return dict(self.stderr)

    def summary(self) -> dict[str, Any]:
        """JSON-plain record of the fit."""
        return {
            "model": self.model,
            "K": self.K.tolist(),
            "B_deg_s": self.B.tolist(),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "n_observations": int(self.n_observations),
            "residuals": self.residuals.tolist(),
            "stderr": dict(self.stderr),
            "notes": list(self.notes),
        }


def _coefficients(K, B) -> dict[str, float]:
    out = {f"bias.{a}": float(B[i]) for i, a in enumerate("xyz")}
    out.update({f"scale.{a}": float(K[i, i] - 1.0) for i, a in enumerate("xyz")})
    out.update(
        {
            f"misalignment.{a}.{b}": float(K[i, j])
            for i, a in enumerate("xyz")
            for j, b in enumerate("xyz")
            if i != j
        }
    )
    return out


def nominal_rates(directions, omega) -> np.ndarray:
    """The commanded rate vectors (n, 3): the servo speed along each rotation's direction
    label (``+x`` ... ``-z``)."""
    out = np.zeros((len(omega), 3))
    for i, (d, w) in enumerate(zip(directions, np.abs(np.asarray(omega, dtype=float)), strict=False)):
        d = str(d)
        if len(d) != 2 or d[0] not in "+-" or d[1] not in "xyz":
            raise ServoFitError(f"rotation {i}: direction {d!r} is not one of ±x, ±y, ±z")
        out[i, "xyz".index(d[1])] = w if d[0] == "+" else -w
    return out


def fit_fixture(m, rates, *, m_sem=None) -> CrossAxisFit:
    """All twelve parameters from every output of every observation, the commanded rate
    vectors ``rates`` (n, 3, deg/s) taken as the true ones (a fixture holds the axes): per
    output axis a, ``m_a = Σ_b K_ab r_b + B_a``, least squares weighted by ``m_sem`` (n, 3,
    deg/s; standard errors from it). Needs rotations about three independent axes, both
    ways or at two speeds, to separate B."""
    m = np.asarray(m, dtype=float)
    rates = np.asarray(rates, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or rates.shape != m.shape:
        raise ServoFitError(
            f"observations and rates must both have shape (n, 3); got {m.shape}, {rates.shape}"
        )
    X = np.column_stack([rates, np.ones(len(m))])
    scale = np.linalg.norm(X, axis=0)
    if len(m) < 4 or np.any(scale == 0) or np.linalg.cond(X / scale) > 1e3:
        raise ServoFitError(
            "the rotations do not determine the twelve parameters: a fixture "
            "calibration needs rotations about three independent axes, both ways"
        )
    sem = np.ones_like(m) if m_sem is None else np.asarray(m_sem, dtype=float)
    if sem.shape != m.shape or not np.all(np.isfinite(sem) & (sem > 0)):
        raise ServoFitError(f"m_sem must be finite and > 0, shape {m.shape}")
    K, B = np.zeros((3, 3)), np.zeros(3)
    stderr = {}
    for a, axis in enumerate("xyz"):
        w = 1.0 / sem[:, a]
        coef, *_ = np.linalg.lstsq(X * w[:, None], m[:, a] * w, rcond=None)
        K[a], B[a] = coef[:3], coef[3]
        if m_sem is not None:
            se = np.sqrt(np.diag(np.linalg.inv((X * w[:, None]).T @ (X * w[:, None]))))
            stderr[f"bias.{axis}"] = float(se[3])
            for b, other in enumerate("xyz"):
                stderr[f"scale.{axis}" if a == b else f"misalignment.{axis}.{other}"] = float(se[b])
    residuals = m - rates @ K.T - B
    if not (np.isfinite(K).all() and np.isfinite(B).all()):
        raise ServoFitError("the fixture fit produced non-finite parameters")
    return CrossAxisFit(
        "fixture", K, B, {k: stderr[k] for k in COEFFICIENTS if k in stderr}, residuals, len(m)
    )


# The symmetric model, solved as seed 001 solves its own: Eq 3 with the cross products,
# ω² = (m − B)ᵀ S (m − B), S = K⁻ᵀK⁻¹ = C² (C = K⁻¹ symmetric), is linear in
# x = (m_x², m_y², m_z², 2m_xm_y, 2m_xm_z, 2m_ym_z, m_x, m_y, m_z) with
# β = (S_xx, S_yy, S_zz, S_xy, S_xz, S_yz, c) and c = −2 S B, given the constant
# β0 = Bᵀ S B = cᵀ S⁻¹ c / 4; Algorithm 1 freezes β0, solves, updates β0 and repeats.


def symmetric_design(m: np.ndarray) -> np.ndarray:
    """Regressors of the symmetric model for observations m (..., n, 3): (..., n, 9)."""
    m = np.asarray(m, dtype=float)
    x, y, z = m[..., 0], m[..., 1], m[..., 2]
    return np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z], axis=-1)


def _matrix(s6: np.ndarray) -> np.ndarray:
    """Symmetric 3x3 matrices from (xx, yy, zz, xy, xz, yz) (..., 6)."""
    xx, yy, zz, xy, xz, yz = (s6[..., i] for i in range(6))
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def _positive(S: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.all(np.linalg.eigvalsh(np.where(np.isfinite(S), S, 0.0)) > 0, axis=-1) & np.isfinite(S).all(
            axis=(-2, -1)
        )


def algorithm1_symmetric(
    m: np.ndarray, omega: np.ndarray, *, tol: float = 1e-6, max_iter: int = 50
) -> Algorithm1Runs:
    """Algorithm 1 for the symmetric model on R stacked runs m (R, n, 3), n >= 9 (``beta``
    (R, 9); ``positive``: S positive definite)."""
    m = np.asarray(m, dtype=float)
    X = symmetric_design(m)
    Y = np.broadcast_to(np.asarray(omega, dtype=float) ** 2, m.shape[:-1])
    u, v = _products(X, Y)

    def beta0(beta):  # Bᵀ S B = cᵀ S⁻¹ c / 4
        c = beta[:, 6:]
        return 0.25 * np.einsum("ri,ri->r", c, np.linalg.solve(_matrix(beta[:, :6]), c[..., None])[..., 0])

    return _iterate(
        u,
        v,
        admissible=lambda beta: _positive(_matrix(beta[:, :6])),
        beta0=beta0,
        placeholder=np.r_[1.0, 1, 1, 0, 0, 0, 0, 0, 0],
        tol=tol,
        max_iter=max_iter,
    )


def symmetric_parameters(beta9: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C = K⁻¹ (the symmetric positive square root of S) and the bias B (unit of m) from
    β (..., 9)."""
    S = _matrix(beta9[..., :6])
    lam, V = np.linalg.eigh(S)
    C = (V * np.sqrt(lam)[..., None, :]) @ np.swapaxes(V, -1, -2)
    B = -0.5 * np.linalg.solve(S, beta9[..., 6:, None])[..., 0]
    return C, B


_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # C's entries, in β's order


def symmetric_covariance(C, B, m, m_sem, to_deg: float = 1.0) -> np.ndarray:
    """Covariance (..., 12, 12) of the coefficients (:data:`COEFFICIENTS`) of the symmetric
    model at C = K⁻¹ (..., 3, 3) and B (..., 3, unit of m) for observations m and their
    standard errors m_sem (..., n, 3), linearised: the Jacobian of the ω² residuals in (C's
    six entries, B), an unweighted least-squares sandwich, mapped through K = C⁻¹ (bias in
    deg/s by ``to_deg``). NaN where the rotations do not determine the nine parameters at all
    (a singular Jacobian)."""
    C, B, m, m_sem = (np.asarray(x, dtype=float) for x in (C, B, m, m_sem))
    d = m - B[..., None, :]
    v = d @ C  # rows C (m − B), C symmetric
    Cv = v @ C
    J = np.stack(
        [
            2 * v[..., a] * d[..., b] if a == b else 2 * (v[..., a] * d[..., b] + v[..., b] * d[..., a])
            for a, b in _PAIRS
        ]
        + [-2 * Cv[..., j] for j in range(3)],
        axis=-1,
    )
    var_r = np.sum((2 * Cv * m_sem) ** 2, axis=-1)
    JT = np.swapaxes(J, -1, -2)
    with np.errstate(all="ignore"):
        try:
            A = np.linalg.solve(JT @ J, JT)
        except np.linalg.LinAlgError:
            return np.full((*C.shape[:-2], 12, 12), np.nan)
        cov = (A * var_r[..., None, :]) @ np.swapaxes(A, -1, -2)  # of (C entries, B)
        K = np.linalg.inv(C)
    G = np.zeros((*C.shape[:-2], 12, 9))  # d(coefficients) / d(C entries, B)
    off = [(i, j) for i in range(3) for j in range(3) if i != j]
    for p, (a, b) in enumerate(_PAIRS):
        dK = -(
            K[..., :, a, None] * K[..., None, b, :]
            + (K[..., :, b, None] * K[..., None, a, :] if a != b else 0)
        )
        G[..., 3:6, p] = np.diagonal(dK, axis1=-2, axis2=-1)
        G[..., 6:, p] = np.stack([dK[..., i, j] for i, j in off], axis=-1)
    G[..., 0:3, 6:9] = np.eye(3) * to_deg  # bias.a = B_a in deg/s
    out = G @ cov @ np.swapaxes(G, -1, -2)
    return np.where(np.isfinite(out).all(axis=(-2, -1))[..., None, None], out, np.nan)


def cross_stderr(cov: np.ndarray) -> np.ndarray:
    """The largest standard error of the cross terms (misalignment) of covariances
    (..., 12, 12); inf where undetermined."""
    se = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1)[..., 6:], 0.0, None))
    return np.where(np.isfinite(se).all(axis=-1), se.max(axis=-1), np.inf)


def cross_chi2(K: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """χ² of the three symmetric cross terms (K_xy, K_xz, K_yz) together against zero, from
    their covariance: (...,)."""
    idx = [COEFFICIENTS.index(n) for n in CROSS_PAIRS]
    est = np.stack([K[..., 0, 1], K[..., 0, 2], K[..., 1, 2]], axis=-1)
    sub = cov[..., idx, :][..., :, idx]
    with np.errstate(all="ignore"):
        ok = np.isfinite(sub).all(axis=(-2, -1))
        sol = np.linalg.solve(np.where(ok[..., None, None], sub, np.eye(3)), est[..., None])[..., 0]
    return np.where(ok, np.sum(est * sol, axis=-1), np.nan)


def _stderr(cov: np.ndarray) -> dict:
    return dict(
        zip(COEFFICIENTS, (float(x) for x in np.sqrt(np.clip(np.diag(cov), 0.0, None))), strict=False)
    )


def symmetric_identified(m, omega, m_sem, start: ServoFit) -> tuple[bool, float]:
    """Whether the observations determine the symmetric cross terms, judged at seed 001's
    solution ``start`` (rad/s): (each cross term's standard error <= MAX_CROSS_STDERR, the
    largest of them; inf where the Jacobian is singular). Three rotation axes never do: their
    magnitudes give three equations, all taken by the scale factors."""
    m = np.asarray(m, dtype=float)
    if m_sem is None or len(m) < 9:
        return False, math.inf
    worst = float(cross_stderr(symmetric_covariance(np.diag(start.k), -start.b, m, m_sem)))
    return bool(worst <= MAX_CROSS_STDERR), worst


def fit_symmetric(
    m, omega, *, tol: float = 1e-6, max_iter: int = 50, unit: str = "rad/s", m_sem=None
) -> CrossAxisFit:
    """The symmetric model by Algorithm 1 on n >= 9 observations ``m`` (n, 3) and speeds
    ``omega`` (n,) in ``unit``; K and B of the result in the file's units (1, deg/s)."""
    if unit not in UNIT_TO_DEG:
        raise ServoFitError(f"unit must be one of {', '.join(UNIT_TO_DEG)}; got {unit!r}")
    m = np.asarray(m, dtype=float)
    omega = np.abs(np.asarray(omega, dtype=float))
    if m.ndim != 2 or m.shape[1] != 3 or omega.shape != (len(m),):
        raise ServoFitError(f"observations m (n, 3) and omega (n,) expected; got {m.shape}, {omega.shape}")
    if len(m) < 9:
        raise ServoFitError(f"the symmetric model needs at least 9 observations; got {len(m)}")
    out = algorithm1_symmetric(m[None], omega[None], tol=tol, max_iter=max_iter)
    if not (out.positive[0] and out.converged[0]):
        raise ServoFitError(
            "Algorithm 1 for the symmetric model did not converge to a positive "
            "definite K⁻ᵀK⁻¹: the rotations do not determine its cross terms"
        )
    C, b = symmetric_parameters(out.beta[0])
    to_deg = UNIT_TO_DEG[unit]
    cov = None if m_sem is None else symmetric_covariance(C, b, m, m_sem, to_deg)
    if cov is not None and not np.isfinite(cov).all():
        raise ServoFitError("the rotations do not determine the symmetric model (singular Jacobian)")
    K = np.linalg.inv(C)
    residuals = np.sum(((m - b) @ C) ** 2, axis=1) - omega**2
    if not (np.isfinite(K).all() and np.isfinite(b).all()):
        raise ServoFitError("the symmetric fit produced non-finite parameters")
    return CrossAxisFit(
        "symmetric",
        K,
        b * to_deg,
        {} if cov is None else _stderr(cov),
        residuals,
        len(m),
        iterations=int(out.iterations[0]),
        covariance=cov,
    )


def observation_arrays(obs, scale: float = 1.0):
    """m (n, 3), the servo speed (n,), m's standard errors (n, 3; None without a noise
    column) and the direction labels (None without them) of a rotations or revolutions
    table (:mod:`gyrocal.protocols.servo.rotations`), in deg/s ÷ ``scale``. Standard errors come from
    ``gyro_x/y/z_sem``, or from ``gyro_x/y/z_noise`` and ``n`` (a revolutions table)."""
    if hasattr(obs, "observations"):
        obs = obs.observations()
    missing = [c for c in ("gyro_x", "gyro_y", "gyro_z", "ref_rate") if c not in obs]
    if missing:
        raise ServoFitError(f"observation table lacks column(s) {', '.join(missing)}")
    m = obs[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(dtype=float) / scale
    omega = obs["ref_rate"].to_numpy(dtype=float) / scale
    sem_cols = ["gyro_x_sem", "gyro_y_sem", "gyro_z_sem"]
    noise_cols = ["gyro_x_noise", "gyro_y_noise", "gyro_z_noise"]
    m_sem = None
    if all(c in obs for c in sem_cols):
        m_sem = obs[sem_cols].to_numpy(dtype=float) / scale
    elif all(c in obs for c in noise_cols) and "n" in obs:  # a revolutions table
        m_sem = (
            obs[noise_cols].to_numpy(dtype=float) / scale / np.sqrt(obs["n"].to_numpy(dtype=float))[:, None]
        )
    label = "direction" if "direction" in obs else "mount" if "mount" in obs else None
    directions = None if label is None else obs[label].astype(str).to_numpy()
    return m, omega, m_sem, directions


def fit_model(obs, model: str = "auto", *, seed001: ServoFit | None = None):
    """The servo calibration of ``model`` (:data:`MODELS`) from a rotations or revolutions
    table: (fit, the model used, why). ``seed001``: bias and scale by Algorithm 1 (given, or
    fitted here); ``fixture``: all twelve parameters, the commanded axes taken as exact;
    ``symmetric``: bias, scale and the symmetric cross terms from the speed's magnitude,
    refused where the rotations do not determine them (:func:`symmetric_identified`);
    ``auto``: the symmetric model where it is determined and its cross terms are significant
    (p < CROSS_ALPHA), seed 001's otherwise."""
    if model not in MODELS:
        raise ServoFitError(f"servo model must be one of {', '.join(MODELS)}; got {model!r}")
    m, omega, m_sem, directions = observation_arrays(obs)
    omega = np.abs(omega)
    if model == "fixture":
        if directions is None:
            raise ServoFitError("the fixture model needs each rotation's direction (+x ... -z)")
        return (
            fit_fixture(m, nominal_rates(directions, omega), m_sem=m_sem),
            "fixture",
            "all twelve parameters from every output, the commanded axes taken as exact (a fixture)",
        )
    start = seed001 or fit_observations(obs)
    if model == "seed001":
        return start, "seed001", "seed 001's bias and scale, as configured"
    identified, worst = symmetric_identified(
        m / DEG, omega / DEG, None if m_sem is None else m_sem / DEG, start
    )
    if not identified:
        why = (
            "the rotations do not determine the symmetric cross terms (standard error "
            + ("unbounded" if not math.isfinite(worst) else f"{worst:.2g}")
            + f", limit {MAX_CROSS_STDERR:g}): rotations about three axes give three "
            "magnitudes, all taken by the scale factors; turn the unit about six or more axes"
        )
        if model == "symmetric":
            raise ServoFitError(why)
        return start, "seed001", why
    fit = fit_symmetric(m / DEG, omega / DEG, m_sem=m_sem / DEG)
    chi2, p = fit.cross_significance()
    worst = max(fit.stderr[n] for n in CROSS_PAIRS)
    told = (
        f"χ² {chi2:.3g} of the three cross terms against zero, p {p:.2g}; standard errors up to {worst:.2g}"
    )
    if model == "auto" and not p < CROSS_ALPHA:
        return (
            start,
            "seed001",
            (
                f"the rotations determine the symmetric cross terms but do not show them "
                f"({told}): assuming them zero is as good"
            ),
        )
    return fit, "symmetric", f"the rotations determine the symmetric cross terms ({told})"
