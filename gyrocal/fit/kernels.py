"""The fit's compiled kernels (``_kernels.c``: the overlapping Allan variance's sums, the
semiseparable Cholesky of the wander-aware fit), with the numpy fallback beside them.

The extension is optional: where it cannot be built the numpy functions here do the same
work, more slowly (the Allan sums in blocks of numpy temporaries, the semiseparable
recursion one Python step per hold). ``GYROCAL_PURE_NUMPY=1`` forces the fallback; the
tests run both and compare.
"""

from __future__ import annotations

import ctypes
import importlib
import os

import numpy as np


def _load() -> ctypes.CDLL | None:
    if os.environ.get("GYROCAL_PURE_NUMPY"):
        return None
    try:
        lib = ctypes.CDLL(importlib.import_module("gyrocal.fit._kernels").__file__)
    except (ImportError, OSError):
        return None
    i64, p = ctypes.c_int64, ctypes.c_void_p
    lib.second_diff_sumsq.argtypes = [p, i64, p, i64, p]
    lib.second_diff_sumsq.restype = None
    lib.semisep_factor.argtypes = [i64, i64] + [p] * 9
    lib.semisep_factor.restype = i64
    lib.semisep_solve.argtypes = [i64, i64, i64] + [p] * 9
    lib.semisep_solve.restype = None
    return lib


LIB = _load()


_BLOCK = 1 << 14  # numpy path: (block,) temporaries of 128 KB stay in cache


def second_diff_sumsq(theta: np.ndarray, m: np.ndarray) -> np.ndarray:
    """For each averaging factor m_j: sum_i (theta[i+2m] - 2 theta[i+m] + theta[i])^2 over a
    1-D float64 angle sequence (the overlapping Allan variance's sums, gyrocal/fit/noise.py)."""
    theta = np.ascontiguousarray(theta, dtype=np.float64)
    m = np.ascontiguousarray(m, dtype=np.int64)
    out = np.zeros(m.size)
    if LIB is not None:  # ctypes releases the GIL: stretches on two threads run in parallel
        LIB.second_diff_sumsq(theta.ctypes.data, theta.size, m.ctypes.data, m.size, out.ctypes.data)
        return out
    for j, step in enumerate(m):
        count = theta.size - 2 * int(step)
        for i0 in range(0, count, _BLOCK):
            i1 = min(i0 + _BLOCK, count)
            d = theta[i0 + 2 * step : i1 + 2 * step] - theta[i0 + step : i1 + step]
            d -= theta[i0 + step : i1 + step]
            d += theta[i0:i1]
            out[j] += d @ d
    return out


# ---- Diagonal plus semiseparable matrices: the covariance of hold means under wander ----


def _doubles(*arrays):
    return [np.ascontiguousarray(a, dtype=np.float64) for a in arrays]


def semiseparable_cholesky(diag, U, V, alpha, beta, scale=None):
    """Cholesky factor of C = diag(``diag``) + the semiseparable matrix whose entry for
    row n after row m is ``sum_k s_k^2 U[n, k] V[m, k] P_k(m, n)``, with ``s`` the
    column scales (ones by default) and ``P_k(m, n) = alpha[n, k] beta[n-1, k]
    alpha[n-1, k] ... beta[m+1, k] alpha[m+1, k]`` (decays of at most 1: no product of
    exponentials overflows). C = L diag(D) L^T with L unit lower triangular,
    ``L[n, m] = sum_k s_k U[n, k] W[m, k] P_k(m, n)``: returns (W, D), or None when C is
    not positive definite to rounding. celerite's recursion (Foreman-Mackey et al. 2017),
    O(n J^2) for n rows and J generator columns; arrays (n, J), (n,) and (J,)."""
    diag, U, V, alpha, beta = _doubles(diag, U, V, alpha, beta)
    n, J = U.shape
    s = np.ones(J) if scale is None else _doubles(scale)[0]
    W, D = np.empty((n, J)), np.empty(n)
    if LIB is not None:
        work = np.empty(J * J + 3 * J)
        bad = LIB.semisep_factor(n, J, *(a.ctypes.data for a in (diag, U, V, s, alpha, beta, W, D, work)))
        return None if bad else (W, D)
    S = np.zeros((J, J))
    for i in range(n):
        if i:
            decay = alpha[i] * beta[i - 1]
            w = alpha[i] * W[i - 1]
            S = np.outer(decay, decay) * S + D[i - 1] * np.outer(w, w)
        u = U[i] * s
        t = S @ u
        d = diag[i] - u @ t
        if not d > 0.0:
            return None
        D[i] = d
        W[i] = (V[i] * s - beta[i] * t) / d
    return W, D


def semiseparable_whiten(U, W, D, alpha, beta, Y, scale=None):
    """``L^-1 Y`` for the Cholesky factor L = L_unit diag(D)^(1/2) of
    :func:`semiseparable_cholesky` (the same ``U``, decays and ``scale``): the rows of
    ``Y`` (n,) or (n, p) made unit white, O(n J p)."""
    Y = np.asarray(Y, dtype=np.float64)
    flat = Y.ndim == 1
    Y = np.ascontiguousarray(Y.reshape(len(Y), -1))
    U, W, D, alpha, beta = _doubles(U, W, D, alpha, beta)
    n, p = Y.shape
    J = U.shape[1]
    s = np.ones(J) if scale is None else _doubles(scale)[0]
    Z = np.empty((n, p))
    if LIB is not None:
        work = np.empty(J * p + p)
        LIB.semisep_solve(n, J, p, *(a.ctypes.data for a in (U, s, W, D, alpha, beta, Y, Z, work)))
        return Z[:, 0] if flat else Z
    f = np.zeros((J, p))
    z = np.zeros(p)
    for i in range(n):
        if i:
            f = (alpha[i] * beta[i - 1])[:, None] * f + (alpha[i] * W[i - 1])[:, None] * z[None, :]
        z = Y[i] - (U[i] * s) @ f
        Z[i] = z
    Z /= np.sqrt(D)[:, None]
    return Z[:, 0] if flat else Z
