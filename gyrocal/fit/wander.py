"""The covariance of hold means under slow wander, and the fit's whitening with it, in time
linear in the holds.

A MEMS gyro's bias wanders (flicker, rate random walk: :mod:`gyrocal.fit.floor`), so hold means
close in time err alike, and the fit is generalised least squares with their covariance
(:func:`gyrocal.fit.model.fit`): design and observations multiplied by L^-1, C = L L^T. Written
out, C costs O(n^2) memory and its factor O(n^3) time in the holds. But the wander is a
state-space process, a random walk plus flicker as a sum of first-order Gauss-Markov
processes, and in time order the covariance of its interval means is a diagonal plus a
semiseparable matrix of rank poles + 1 (:class:`HoldWander`), whose Cholesky factor and
L^-1 cost O(n J^2) and O(n J p) (:func:`gyrocal.fit.kernels.semiseparable_cholesky`): the same
estimator, exactly, in time linear in the holds.

Validation and the diagnosis refit the same holds many times (every candidate model leaves
each temperature point out in turn): the factors are kept, keyed by the holds' times and
noise levels, so a refit of holds already seen only applies L^-1 to its columns.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import kernels

POLES_PER_DECADE = 2  # flicker as a sum of Gauss-Markov processes: ripple well under 1 %


@dataclass(frozen=True)
class HoldWander:
    """The covariance of hold means under unit flicker (B = 1 deg/s) and unit random walk
    (K = 1 deg/s/sqrt(s)), as generators, the holds in time order (``order``: the rows
    given, sorted by start).

    Random walk: the means of K W(t) over [a_i, b_i] and [a_j, b_j] (i first) covary by K^2
    times the earlier one's mid-time and vary by K^2 (a + T/3), times from the first hold's
    start (a shift adds a constant to every entry, which the bias term absorbs). Flicker
    (two-sided PSD B^2 / (2 pi f), IEEE Std 952) is a sum of Gauss-Markov processes with
    correlation times c spaced 10^(1/POLES_PER_DECADE) apart, each of variance
    q^2 = B^2 ln(ratio) / pi, from a hundredth of the shortest hold (faster ones add 2 c / T
    to a mean's variance alone) to ten times the whole span; the means of one over two holds
    covary by q^2 c^2 / (T_i T_j) (1 - e^(-T_i/c)) (1 - e^(-T_j/c)) e^(-gap/c), and one mean
    varies by q^2 2 c^2 / T^2 (T/c - 1 + e^(-T/c)).

    For hold j after hold i both are rank one per term: ``edge_i edge_j e^(-(a_j - b_i)/c)``
    per pole, ``mid_i`` for the walk. The exponential is kept as decays between consecutive
    times, each at most 1 (celerite's preconditioning): ``gap_decay`` from the previous
    hold's end to this one's start, ``hold_decay`` across the hold. Their products give
    every pair's factor, and no exponential overflows however long the log."""

    order: np.ndarray  # (n,) rows in time order
    edge: np.ndarray  # (n, poles) q (1 - e^(-T/c)) c / T, q^2 = ln(ratio) / pi
    gap_decay: np.ndarray  # (n, poles) e^(-(a_n - b_{n-1}) / c); 1 on the first row
    hold_decay: np.ndarray  # (n, poles) e^(-(b_n - a_n) / c)
    flicker_var: np.ndarray  # (n,) the flicker covariance's diagonal
    mid: np.ndarray  # (n,) mid-times from the first start
    walk_var: np.ndarray  # (n,) the walk's diagonal, a + T/3


def hold_wander(t_start, t_end) -> HoldWander | None:
    """:class:`HoldWander` of observations over [t_start, t_end] (s); None when two of them
    overlap in time (the model is that of disjoint holds; no segmenter makes others)."""
    start = np.asarray(t_start, float)
    order = np.argsort(start, kind="stable")
    a, b = start[order], np.asarray(t_end, float)[order]
    if np.any(a[1:] < b[:-1]) or np.any(b < a):
        return None
    a, b = a - a[0], b - a[0]
    T = np.maximum(b - a, 1e-9)
    ratio = 10.0 ** (1.0 / POLES_PER_DECADE)
    lo, hi = 0.01 * T.min(), 10.0 * max(b.max(), T.max())
    poles = lo * ratio ** np.arange(int(np.ceil(np.log(hi / lo) / np.log(ratio))) + 1)
    q2 = np.log(ratio) / np.pi
    x = T[:, None] / poles[None, :]
    edge = np.sqrt(q2) * (-np.expm1(-x) / x)  # (1 - e^-x) / x
    variance = 2 * np.where(x < 1e-4, 0.5 - x / 6, (x + np.expm1(-x)) / x**2).sum(axis=1)
    # poles faster than the first average out within an observation: 2 c / T each, summed
    variance += 2 * poles[0] / T / (ratio - 1.0)
    gap = np.r_[0.0, a[1:] - b[:-1]]
    return HoldWander(
        order,
        edge,
        np.exp(-gap[:, None] / poles),
        np.exp(-(b - a)[:, None] / poles),
        q2 * variance,
        (a + b) / 2,
        a + T / 3,
    )


@dataclass(frozen=True)
class _Generators:
    """A time layout's generators at unit levels, the poles' columns then the walk's: an
    axis' covariance scales them by its levels (B on the poles, K on the walk)."""

    order: np.ndarray
    U: np.ndarray
    V: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    flicker_var: np.ndarray
    walk_var: np.ndarray

    @classmethod
    def of(cls, w: HoldWander) -> _Generators:
        ones = np.ones((len(w.mid), 1))
        return cls(
            w.order,
            np.hstack([w.edge, ones]),
            np.hstack([w.edge, w.mid[:, None]]),
            np.hstack([w.gap_decay, ones]),
            np.hstack([w.hold_decay, ones]),
            w.flicker_var,
            w.walk_var,
        )


@dataclass(frozen=True)
class Whitener:
    """One output axis' L^-1 (C = L L^T, the covariance of its hold means). Rows come out in
    time order: a permutation, which least squares does not see."""

    gen: _Generators
    level: np.ndarray  # per generator column: B on the poles, K on the walk
    W: np.ndarray
    D: np.ndarray

    def __call__(self, m) -> np.ndarray:
        g = self.gen
        return kernels.semiseparable_whiten(
            g.U, self.W, self.D, g.alpha, g.beta, np.asarray(m, float)[g.order], self.level
        )


def stacked(parts: list[Whitener]):
    """Independent records' whiteners as one map over their rows concatenated, each record's
    rows coming out in its own time order (as :class:`Whitener` gives them): the recursion is
    cut at each record's first row (its decays zero), so one pass whitens them all alike. A
    record with fewer poles has zero columns for the others (they stay zero throughout). None
    where the records' levels differ."""
    flicker, walk = parts[0].level[0], parts[0].level[-1]
    if any(not (np.all(w.level[:-1] == flicker) and w.level[-1] == walk) for w in parts):
        return None
    J = max(w.gen.U.shape[1] for w in parts)

    def widened(m: np.ndarray) -> np.ndarray:  # the poles' columns padded, the walk's last
        out = np.zeros((len(m), J))
        out[:, : m.shape[1] - 1], out[:, -1] = m[:, :-1], m[:, -1]
        return out

    U = np.vstack([widened(w.gen.U) for w in parts])
    W = np.vstack([widened(w.W) for w in parts])
    alpha = np.vstack([widened(w.gen.alpha) for w in parts])
    beta = np.vstack([widened(w.gen.beta) for w in parts])
    alpha[np.cumsum([0] + [len(w.D) for w in parts[:-1]])] = 0.0
    D = np.concatenate([w.D for w in parts])
    level = np.r_[np.full(J - 1, flicker), walk]

    def whiten(Y: np.ndarray) -> np.ndarray:
        return kernels.semiseparable_whiten(U, W, D, alpha, beta, Y, level)

    return whiten


def _factor(gen: _Generators, white: np.ndarray, flicker: float, rrw: float) -> Whitener | None:
    # A level of zero leaves its columns out exactly (their W stays zero).
    level = np.r_[np.full(gen.U.shape[1] - 1, flicker), rrw]
    diag = gen.flicker_var * flicker**2 + gen.walk_var * rrw**2 + white[gen.order] ** 2
    found = kernels.semiseparable_cholesky(diag, gen.U, gen.V, gen.alpha, gen.beta, level)
    return None if found is None else Whitener(gen, level, *found)


# Factors kept for refits: a 64-hour sweep at 10 Hz (11,500 holds, 17 generator columns)
# takes 1.6 MiB per array of generators; a diagnosis cycles through about 16 layouts.
CACHE_BYTES = 256 << 20
_cache: OrderedDict[bytes, tuple[object, int]] = OrderedDict()


def _nbytes(value) -> int:
    return (
        sum(v.nbytes for v in vars(value).values() if isinstance(v, np.ndarray)) if value is not None else 0
    )


def _cached(key: bytes, make: Callable):
    """``make()``, remembered by ``key``; the least recently used are dropped past
    CACHE_BYTES."""
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key][0]
    value = make()
    _cache[key] = (value, _nbytes(value))
    total = sum(size for _, size in _cache.values())
    while total > CACHE_BYTES and len(_cache) > 1:
        total -= _cache.popitem(last=False)[1][1]
    return value


def _digest(*arrays) -> bytes:
    h = hashlib.blake2b(digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(np.int64(a.size).tobytes())
        h.update(a.data)
    return h.digest()


def whiteners(t_start, t_end, white, flicker, rrw) -> list[Whitener | None] | None:
    """Per output axis i, the map that makes hold means unit white under white noise
    ``white[i]`` (n,) per hold, flicker of level ``flicker[i]`` (deg/s) and random walk
    ``rrw[i]`` (deg/s/sqrt(s)). None when the holds overlap in time; an axis' entry is
    None when its covariance is not positive definite to rounding."""
    times = _digest(t_start, t_end)
    gen = _cached(b"t" + times, lambda: _layout(t_start, t_end))
    if gen is None:
        return None
    out = []
    for w, f, k in zip(white, flicker, rrw, strict=False):
        w, f, k = np.asarray(w, float), float(f), float(k)
        out.append(_cached(b"f" + times + _digest(w, [f, k]), lambda w=w, f=f, k=k: _factor(gen, w, f, k)))
    return out


def _layout(t_start, t_end) -> _Generators | None:
    w = hold_wander(t_start, t_end)
    return None if w is None else _Generators.of(w)
