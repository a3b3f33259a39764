"""The compiled kernels (``_blockstats.c``: block statistics, Allan sums, the semiseparable
Cholesky of the wander-aware fit), with the numpy fallback beside them.

The extension is optional: where it cannot be built the numpy functions here do the same
work, more slowly (block statistics in five passes over each sample instead of one, the
semiseparable recursion one Python step per hold). ``GYROCAL_PURE_NUMPY=1`` forces the
fallback; the tests run both and compare.
"""

from __future__ import annotations

import ctypes
import importlib
import os

import numpy as np


def _load():
    if os.environ.get("GYROCAL_PURE_NUMPY"):
        return None
    try:
        lib = ctypes.CDLL(importlib.import_module("gyrocal.io._blockstats").__file__)
        lib.second_diff_sumsq  # noqa: B018 - an extension built from older sources lacks it
    except (ImportError, OSError, AttributeError):
        return None
    i64, p = ctypes.c_int64, ctypes.c_void_p
    for name in ("block_moments_f32", "block_moments_f64"):
        getattr(lib, name).argtypes = [p, i64, i64, p, i64, p, i64]
        getattr(lib, name).restype = None
    for name in ("block_mean_f32", "block_mean_f64", "block_finite_mean_f32", "block_finite_mean_f64"):
        getattr(lib, name).argtypes = [p, i64, i64, p, i64]
        getattr(lib, name).restype = None
    lib.second_diff_sumsq.argtypes = [p, i64, p, i64, p]
    lib.second_diff_sumsq.restype = None
    return lib


LIB = _load()
_SUFFIX = {np.dtype(np.float32): "f32", np.dtype(np.float64): "f64"}


def _compiled(x: np.ndarray) -> bool:
    return LIB is not None and x.dtype in _SUFFIX and x.flags.c_contiguous


def _address(a: np.ndarray) -> tuple[int, int]:
    return a.ctypes.data, a.strides[0] // a.itemsize


def block_moments(v: np.ndarray, mean_out: np.ndarray, var_out: np.ndarray, work: list) -> None:
    """Row means (float64) and sample variances (float32) of a (k, size) view into the
    given (possibly strided) 1-D outputs. ``work`` holds a reusable float32 buffer."""
    k, size = v.shape
    if _compiled(v) and mean_out.dtype == np.float64 and var_out.dtype == np.float32:
        m, ms = _address(mean_out)
        q, qs = _address(var_out)
        getattr(LIB, "block_moments_" + _SUFFIX[v.dtype])(v.ctypes.data, k, size, m, ms, q, qs)
        return
    # numpy: centre on each block's first value (float32 stays exact at large offsets)
    if work[0].size < v.size:
        work[0] = np.empty(v.size, dtype=np.float32)
    d = work[0][: v.size].reshape(v.shape)
    first = v[:, :1]
    np.subtract(v, first, out=d, casting="same_kind")
    ones = np.ones(size, dtype=np.float32)
    s = d @ ones
    np.square(d, out=d)
    q = d @ ones
    var_out[:] = np.maximum(q - s * s / size, 0.0) / (size - 1)
    mean_out[:] = first[:, 0] + s.astype(np.float64) / size


def block_mean(v: np.ndarray, out: np.ndarray, *, finite_only: bool = False) -> None:
    """Row means of a (k, size) view into ``out``; with ``finite_only`` NaN and inf are
    skipped (a row with none finite gives NaN)."""
    k, size = v.shape
    if _compiled(v) and out.dtype == np.float64:
        m, ms = _address(out)
        kind = "block_finite_mean_" if finite_only else "block_mean_"
        getattr(LIB, kind + _SUFFIX[v.dtype])(v.ctypes.data, k, size, m, ms)
        return
    if finite_only:
        finite = np.isfinite(v)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:] = np.where(finite, v, 0.0).sum(axis=1, dtype=np.float64) / finite.sum(axis=1)
        out[~np.isfinite(out)] = np.nan
    else:
        out[:] = v.sum(axis=1, dtype=np.float64) / size


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


def _semiseparable_lib():
    if LIB is None:
        return None
    try:
        factor, solve = LIB.semisep_factor, LIB.semisep_solve
    except AttributeError:  # an extension built from older sources
        return None
    i64, p = ctypes.c_int64, ctypes.c_void_p
    factor.argtypes = [i64, i64] + [p] * 9
    factor.restype = i64
    solve.argtypes = [i64, i64, i64] + [p] * 9
    solve.restype = None
    return LIB


SEMISEPARABLE = _semiseparable_lib()


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
    if SEMISEPARABLE is not None:
        work = np.empty(J * J + 3 * J)
        bad = SEMISEPARABLE.semisep_factor(
            n, J, *(a.ctypes.data for a in (diag, U, V, s, alpha, beta, W, D, work))
        )
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
    if SEMISEPARABLE is not None:
        work = np.empty(J * p + p)
        SEMISEPARABLE.semisep_solve(n, J, p, *(a.ctypes.data for a in (U, s, W, D, alpha, beta, Y, Z, work)))
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
