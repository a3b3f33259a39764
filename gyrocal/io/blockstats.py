"""Statistics of blocks of samples (means, variances) for the read, compiled
(``_blockstats.c``) with the numpy fallback beside them.

The extension is optional: where it cannot be built the numpy functions here do the same
work, more slowly (five passes over each sample instead of one). ``GYROCAL_PURE_NUMPY=1``
forces the fallback; the tests run both and compare.
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
        lib = ctypes.CDLL(importlib.import_module("gyrocal.io._blockstats").__file__)
    except (ImportError, OSError):
        return None
    i64, p = ctypes.c_int64, ctypes.c_void_p
    for name in ("block_moments_f32", "block_moments_f64"):
        getattr(lib, name).argtypes = [p, i64, i64, p, i64, p, i64]
        getattr(lib, name).restype = None
    for name in ("block_mean_f32", "block_mean_f64", "block_finite_mean_f32", "block_finite_mean_f64"):
        getattr(lib, name).argtypes = [p, i64, i64, p, i64]
        getattr(lib, name).restype = None
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
