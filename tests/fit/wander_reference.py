"""The dense reference of the wander-aware fit: the covariance of hold means built entry by
entry (O(n^2) memory) and factored by LAPACK (O(n^3)), as gyrocal fitted before its
semiseparable factorisation (gyrocal.fit.wander); kept here only to check that one against."""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, solve_triangular

POLES_PER_DECADE = 2


def time_covariances(t_start, t_end) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (n, n) of observation means per unit flicker level B = 1 deg/s and per
    unit random walk K = 1 deg/s/sqrt(s), for disjoint observations over [t_start, t_end],
    in the order given (gyrocal.fit.wander.HoldWander states the model)."""
    a = np.asarray(t_start, float)
    b = np.asarray(t_end, float)
    a, b = a - a.min(), b - a.min()
    T = np.maximum(b - a, 1e-9)
    first = a[:, None] <= a[None, :]
    mid = (a + b) / 2
    walk = np.where(first, mid[:, None], mid[None, :])
    np.fill_diagonal(walk, a + T / 3)
    ratio = 10.0 ** (1.0 / POLES_PER_DECADE)
    lo, hi = 0.01 * T.min(), 10.0 * max(b.max(), T.max())
    poles = lo * ratio ** np.arange(int(np.ceil(np.log(hi / lo) / np.log(ratio))) + 1)
    q2 = np.log(ratio) / np.pi
    gap = np.abs(np.where(first, a[None, :] - b[:, None], a[:, None] - b[None, :]))
    np.fill_diagonal(gap, np.inf)
    flicker = np.zeros_like(walk)
    variance = np.zeros_like(T)
    for c in poles:
        x = T / c
        edge = -np.expm1(-x) / x
        flicker += np.outer(edge, edge) * np.exp(-gap / c)
        variance += 2 * np.where(x < 1e-4, 0.5 - x / 6, (x + np.expm1(-x)) / x**2)
    variance += 2 * poles[0] / T / (ratio - 1.0)
    np.fill_diagonal(flicker, variance)
    return q2 * flicker, walk


def dense_semiseparable(diag, U, V, alpha, beta) -> np.ndarray:
    """The matrix gyrocal.fit.kernels.semiseparable_cholesky factors, entry by entry."""
    n = len(diag)
    C = np.diag(np.asarray(diag, float))
    for m in range(n):
        p = np.ones(U.shape[1])
        for j in range(m + 1, n):
            p = p * alpha[j] * (beta[j - 1] if j - 1 > m else 1.0)
            C[j, m] = C[m, j] = U[j] @ (V[m] * p)
    return C


def held_covariances(t_start, t_end) -> tuple[np.ndarray, np.ndarray]:
    """The flicker and walk covariances gyrocal.fit.wander's generators stand for, written out
    in the rows' own order (what time_covariances gives, from the library's code)."""
    from gyrocal.fit.wander import hold_wander

    w = hold_wander(t_start, t_end)
    ones = np.ones((len(w.mid), 1))
    flicker = dense_semiseparable(w.flicker_var, w.edge, w.edge, w.gap_decay, w.hold_decay)
    walk = dense_semiseparable(w.walk_var, ones, w.mid[:, None], ones, ones)
    back = np.argsort(w.order)
    return flicker[np.ix_(back, back)], walk[np.ix_(back, back)]


def dense_whiteners(data: dict, floor: np.ndarray) -> list:
    """Per output axis, L^-1 of the dense covariance (gyrocal.fit.model's whitening before the
    semiseparable factorisation, without its 3000-hold cap)."""
    flicker, walk = time_covariances(data["t_start"], data["t_end"])
    n = len(floor)
    out = []
    for i, a in enumerate("xyz"):
        white = np.maximum(np.asarray(data[f"white_{a}"], float), 1e-3 * np.median(floor[:, i]))
        cov = flicker * float(np.max(data[f"flicker_{a}"])) ** 2 + walk * float(np.max(data[f"rrw_{a}"])) ** 2
        cov[np.diag_indices(n)] += white**2
        lower = cho_factor(cov, lower=True)[0]
        out.append(lambda m, L=lower: solve_triangular(L, m, lower=True, check_finite=False))
    return out


def dense_gls(X: np.ndarray, y: np.ndarray, whiten) -> tuple[np.ndarray, np.ndarray, float]:
    """Coefficients, their covariance scaled by the reduced chi-square, and the chi-square
    of generalised least squares through a dense whitener."""
    Xw, yw = whiten(X), whiten(y)
    Q, R = np.linalg.qr(Xw)
    theta = np.linalg.solve(R, Q.T @ yw)
    chi2 = float(np.sum(whiten(y - X @ theta) ** 2))
    Rinv = np.linalg.inv(R)
    return theta, Rinv @ Rinv.T * chi2 / (len(y) - X.shape[1]), chi2


def dense_model_whiteners(data: dict, floor: np.ndarray) -> list:
    """A stand-in for gyrocal.fit.model._whiteners with the dense factor, and no cap on the
    holds (benchmarks/scaling.py --dense times the fit with it)."""
    from scipy.linalg import LinAlgError

    def divide(i):
        w = 1.0 / floor[:, i]
        return lambda m: m * (w[:, None] if np.ndim(m) == 2 else w)

    coloured = (
        "white_x" in data
        and len(floor) > 1
        and any(np.any(np.asarray(data[f"{k}_{a}"]) > 0) for k in ("flicker", "rrw") for a in "xyz")
    )
    if not coloured:
        return [divide(i) for i in range(3)]
    try:
        return dense_whiteners(data, floor)
    except LinAlgError:
        return [divide(i) for i in range(3)]
