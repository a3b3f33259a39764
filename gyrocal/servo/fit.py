"""Six-parameter servo calibration of seed 001: Algorithm 1 and a Levenberg-Marquardt reference.

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

import numpy as np
from scipy.optimize import least_squares

from ..errors import InputError

DEG = 180.0 / math.pi
UNIT_TO_DEG = {"rad/s": DEG, "deg/s": 1.0}
PARAMETERS = ("kx", "ky", "kz", "bx", "by", "bz")
MAX_CONDITION = 1e8   # column-scaled condition number above which the design is refused


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
    k_se: np.ndarray | None = None     # linearised from the observations' standard errors
    b_se: np.ndarray | None = None
    n_observations: int = 6
    notes: tuple[str, ...] = field(default_factory=tuple)

    def compensate(self, gyro) -> np.ndarray:
        """True rates from raw outputs in deg/s (n, 3): ``K⁻¹ (w - B)`` = ``diag(k) (w - B)``."""
        return (np.asarray(gyro, dtype=float) - self.B) * self.k

    def coefficients(self) -> dict[str, float]:
        """The fit in gyrocal's term names (docs/method.md): ``bias.a`` = B_a (deg/s),
        ``scale.a`` = K_aa - 1 = 1/k_a - 1; the servo model has no cross-axis terms."""
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

    def summary(self) -> dict:
        """JSON-plain record of the fit."""
        out = {
            "method": self.method, "unit": self.unit, "convention": "g = k (m + b)",
            "k": self.k.tolist(), "b": self.b.tolist(),
            "K": self.K.tolist(), "B_deg_s": self.B.tolist(),
            "beta": self.beta.tolist(), "iterations": int(self.iterations),
            "converged": bool(self.converged), "n_observations": int(self.n_observations),
            "residuals": self.residuals.tolist(),
            "trace": [dict(rec) for rec in self.trace], "notes": list(self.notes),
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


def algorithm1(m: np.ndarray, omega: np.ndarray, *, tol: float = 1e-6, max_iter: int = 50,
               keep_trace: bool = False) -> dict:
    """Algorithm 1 on R stacked runs: m (R, n, 3), omega (R, n) or broadcastable.

    Returns arrays: ``beta`` (R, 6) = β1..β6 at exit, ``iterations`` (R,) β0 updates made,
    ``converged`` (R,), ``positive`` (R,) whether β1..β3 stayed > 0, and with
    ``keep_trace`` the list of (β (R, 6), β0 used (R,), change (R,)) per estimate.
    A run stops updating once it meets the stopping rule, so each run's result is what a
    one-run call gives.
    """
    m = np.asarray(m, dtype=float)
    X = design(m)
    Y = np.broadcast_to(np.asarray(omega, dtype=float) ** 2, m.shape[:-1])
    u, v = _products(X, Y)
    beta = u.copy()                                  # β(1), with β0(0) = 0
    R = beta.shape[0]
    positive = np.all(beta[:, :3] > 0, axis=1)
    active = positive.copy()
    converged = np.zeros(R, dtype=bool)
    iterations = np.zeros(R, dtype=int)
    trace = [(beta.copy(), np.zeros(R), np.full(R, np.inf))] if keep_trace else None
    for it in range(1, max_iter + 1):
        if not active.any():
            break
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            g0 = np.where(active, gamma(np.where(active[:, None], beta, 1.0)), 0.0)
            new = u - g0[:, None] * v
            change = np.sum(np.abs(new - beta), axis=1)
        ok = np.isfinite(new).all(axis=1) & np.all(new[:, :3] > 0, axis=1)
        step = active & ok
        beta = np.where(step[:, None], new, beta)
        iterations = np.where(step, it, iterations)
        positive &= ~(active & ~ok)
        done = step & (change <= tol)
        converged |= done
        active &= ok & ~done
        if keep_trace:
            trace.append((beta.copy(), g0, np.where(step, change, np.nan)))
    return dict(beta=beta, iterations=iterations, converged=converged, positive=positive,
                trace=trace)


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
        raise ServoFitError("a servo speed of 0 gives no scale information; every observation "
                            "needs a non-zero speed")
    X = design(m)
    scale = np.linalg.norm(X, axis=0)
    if np.any(scale == 0) or np.linalg.cond(X / scale) > MAX_CONDITION:
        raise ServoFitError("the observations do not determine all six parameters (the design "
                            "lacks rotations about some axis or in both directions)")
    if m_sem is not None:
        m_sem = np.asarray(m_sem, dtype=float)
        if m_sem.shape != m.shape or not np.isfinite(m_sem).all() or np.any(m_sem < 0):
            raise ServoFitError(f"m_sem must be finite, >= 0, shape {m.shape}")
    return m, np.abs(omega), m_sem


def residuals_of(k, b, m, omega) -> np.ndarray:
    """ω² residuals (model minus servo) of Eq 3 for parameters k, b."""
    return np.sum((k * (m + b)) ** 2, axis=-1) - omega ** 2


def _standard_errors(k, b, m, m_sem):
    """Linearised standard errors of (k, b) from the observations' standard errors."""
    if m_sem is None:
        return None, None
    mb = m + b
    J = np.hstack([2 * k * mb ** 2, 2 * k ** 2 * mb])           # ∂r/∂(k, b)
    var_r = np.sum((2 * k ** 2 * mb * m_sem) ** 2, axis=1)      # r's variance from m's
    try:
        A = np.linalg.solve(J.T @ J, J.T)
    except np.linalg.LinAlgError:
        raise ServoFitError("the standard errors cannot be propagated: singular Jacobian") from None
    se = np.sqrt(np.einsum("ij,j,ij->i", A, var_r, A))
    return se[:3], se[3:]


def _result(k, b, *, m, omega, unit, method, iterations, trace, converged, m_sem, notes=()):
    k = np.abs(np.asarray(k, dtype=float))
    b = np.asarray(b, dtype=float)
    beta = np.concatenate([[np.sum(k ** 2 * b ** 2)], k ** 2, 2 * k ** 2 * b])
    res = residuals_of(k, b, m, omega)
    k_se, b_se = _standard_errors(k, b, m, m_sem)
    values = [k, b, beta, res] + ([k_se, b_se] if k_se is not None else [])
    if not all(np.isfinite(x).all() for x in values):
        raise ServoFitError(f"{method} fit produced non-finite parameters")
    return ServoFit(k=k, b=b, K=np.diag(1.0 / k), B=-b * UNIT_TO_DEG[unit], beta=beta,
                    iterations=int(iterations), trace=tuple(trace), method=method,
                    converged=bool(converged), residuals=res, unit=unit, k_se=k_se, b_se=b_se,
                    n_observations=len(m), notes=tuple(notes))


def fit_iterative(m, omega, *, tol: float = 1e-6, max_iter: int = 50, unit: str = "rad/s",
                  m_sem=None, strict: bool = True) -> ServoFit:
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
    if not out["positive"][0]:
        raise ServoFitError("Algorithm 1 gave β1..β3 <= 0 (no square root for k); the β0 "
                            "iteration diverges when Σ k² b² is not small against ω²: rotate "
                            "faster or use fit_lm")
    converged = bool(out["converged"][0])
    if not converged and strict:
        raise ServoFitError(f"Algorithm 1 did not converge to Σ|Δβ| <= {tol:g} in {max_iter} "
                            f"iterations (speed too low for the biases: β0/ω² must stay well below 1)")
    trace = []
    for i, (beta6, g0, change) in enumerate(out["trace"]):
        if i > 0 and not np.isfinite(change[0]):
            break
        kk, bb = parameters_from_beta(beta6[0])
        trace.append({"estimate": i + 1, "beta0_used": float(g0[0]),
                      "beta": [float(x) for x in beta6[0]], "k": [float(x) for x in kk],
                      "b": [float(x) for x in bb], "change": None if i == 0 else float(change[0])})
    k, b = parameters_from_beta(out["beta"][0])
    return _result(k, b, m=m, omega=omega, unit=unit, method="iterative",
                   iterations=out["iterations"][0], trace=trace, converged=converged, m_sem=m_sem)


def lm_solve(m: np.ndarray, omega: np.ndarray, x0: np.ndarray):
    """scipy's Levenberg-Marquardt on Eq 3's ω² residuals with (k, b) as unknowns."""
    def fun(p):
        return residuals_of(p[:3], p[3:], m, omega)

    def jac(p):
        k, mb = p[:3], m + p[3:]
        return np.hstack([2 * k * mb ** 2, 2 * k ** 2 * mb])

    return least_squares(fun, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                         max_nfev=2000)


def initial_guess(m: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Algorithm 1's first estimate β(1) (β0 = 0) as (k, b): the start of the LM fit."""
    u, _ = _products(design(m)[None], (omega ** 2)[None])
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
    trace = [{"estimate": 1, "k": x0[:3].tolist(), "b": x0[3:].tolist(), "change": None},
             {"estimate": 2, "k": np.abs(res.x[:3]).tolist(), "b": res.x[3:].tolist(),
              "change": float(np.sum(np.abs(res.x - x0)))}]
    return _result(res.x[:3], res.x[3:], m=m, omega=omega, unit=unit, method="lm",
                   iterations=res.nfev, trace=trace, converged=True, m_sem=m_sem,
                   notes=(f"scipy least_squares lm: {res.nfev} evaluations, status {res.status}",))


def fit_observations(obs, *, method: str = "iterative", tol: float = 1e-6,
                     max_iter: int = 50) -> ServoFit:
    """Calibrate from a rotations or revolutions table (:mod:`gyrocal.servo.rotations`):
    columns ``gyro_x/y/z`` and ``ref_rate`` in deg/s, optionally ``gyro_x/y/z_sem`` (or
    ``gyro_x/y/z_noise`` and ``n``) for standard errors. The fit
    runs in rad/s, so ``tol`` keeps the paper's meaning; ``k``, ``b`` come back in rad/s and
    ``B`` in deg/s."""
    if hasattr(obs, "observations"):
        obs = obs.observations()
    missing = [c for c in ("gyro_x", "gyro_y", "gyro_z", "ref_rate") if c not in obs]
    if missing:
        raise ServoFitError(f"observation table lacks column(s) {', '.join(missing)}")
    m = obs[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(dtype=float) / DEG
    omega = obs["ref_rate"].to_numpy(dtype=float) / DEG
    sem_cols = ["gyro_x_sem", "gyro_y_sem", "gyro_z_sem"]
    noise_cols = ["gyro_x_noise", "gyro_y_noise", "gyro_z_noise"]
    m_sem = None
    if all(c in obs for c in sem_cols):
        m_sem = obs[sem_cols].to_numpy(dtype=float) / DEG
    elif all(c in obs for c in noise_cols) and "n" in obs:          # a revolutions table
        m_sem = obs[noise_cols].to_numpy(dtype=float) / DEG / np.sqrt(obs["n"].to_numpy(dtype=float))[:, None]
    if method == "iterative":
        return fit_iterative(m, omega, tol=tol, max_iter=max_iter, m_sem=m_sem)
    if method == "lm":
        return fit_lm(m, omega, m_sem=m_sem)
    raise ServoFitError(f"method must be 'iterative' or 'lm'; got {method!r}")
