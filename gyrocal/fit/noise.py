"""Noise characterisation of static gyro data: overlapping Allan deviation and IEEE Std 952 terms.

Conventions (IEEE Std 952-1997, annex C). For a rate signal Omega(t) in deg/s the Allan variance is
half the mean squared difference of consecutive tau-long means. Writing the integrated angle
theta_k = sum_{j<k} (Omega_j - mean) / rate (theta_0 = 0, N = n + 1 points), the overlapping
estimator at tau = m / rate is (NIST SP 1065, eq. 11)

    sigma^2(tau) = 1 / (2 tau^2 (N - 2m)) * sum_{i=0}^{N-2m-1} (theta_{i+2m} - 2 theta_{i+m} + theta_i)^2.

Removing the mean before the cumulative sum leaves every second difference unchanged and keeps the
angle small, so a long soak with a large bias loses no precision. The sum takes one read of the
angle per tau (``gyrocal/fit/_kernels.c``; cache-sized numpy blocks where it is not built).

Noise model fitted to sigma^2 (IEEE Std 952, eq. C.41)

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

Q quantisation (angle), N angle random walk, B bias instability (flicker; sqrt(2 ln 2/pi) = 0.664),
K rate random walk, R rate ramp. Reported in IEEE units: N deg/sqrt(h), B deg/h, K deg/h/sqrt(h),
Q arcsec, R deg/h/h. The ramp is fitted so that a drift in the static data (a die still settling
after a temperature ramp, a warm-up) rises as tau, not as the random walk's sqrt(tau): it is an
effect for the model to carry, not noise, and no floor counts it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..io.errors import InputError
from .kernels import second_diff_sumsq

__all__ = [
    "AllanResult",
    "NoiseTerms",
    "allan_deviation",
    "pooled_allan_deviation",
    "stretch_sums",
    "pooled_from_sums",
    "StretchSums",
    "barnes_b1",
    "fit_noise_terms",
    "MIN_SAMPLES",
    "FLICKER_FACTOR",
]

MIN_SAMPLES = 8  # fewer samples give a single-octave curve with one or two terms: nothing to fit
FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643: Allan plateau / B
_EDF_READING = 10.0  # min(adev) reading skips long taus whose scatter (~1/sqrt(2 edf)) > 22 %

# SI (deg, s) -> IEEE Std 952 reporting units
_TO_ARW = 60.0  # deg/sqrt(s) -> deg/sqrt(h)
_TO_BI = 3600.0  # deg/s -> deg/h
_TO_RRW = 3600.0**1.5  # deg/s/sqrt(s) -> deg/h/sqrt(h)
_TO_Q = 3600.0  # deg -> arcsec
_TO_R = 3600.0**2  # deg/s^2 -> deg/h/h


def _plain(a):
    a = np.asarray(a)
    return a.tolist() if a.ndim else a.item()


@dataclass(frozen=True)
class AllanResult:
    """Allan deviation at ``tau`` (s); ``adev``, ``lo``, ``hi`` in the unit of the input (deg/s).

    ``adev`` is (k,) for a 1-D input and (k, axes) for an (n, axes) input. ``lo``/``hi`` bound
    the ``level`` confidence interval from chi-square with ``edf`` degrees of freedom.
    """

    tau: np.ndarray
    m: np.ndarray
    adev: np.ndarray
    n_terms: np.ndarray
    edf: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    rate: float
    n_samples: int
    overlapping: bool = True
    level: float = 0.683

    def to_dict(self) -> dict[str, Any]:
        return {
            "rate_hz": float(self.rate),
            "n_samples": int(self.n_samples),
            "overlapping": bool(self.overlapping),
            "level": float(self.level),
            "tau_s": _plain(self.tau),
            "m": _plain(self.m),
            "adev": _plain(self.adev),
            "n_terms": _plain(self.n_terms),
            "edf": _plain(self.edf),
            "lo": _plain(self.lo),
            "hi": _plain(self.hi),
        }


def _averaging_factors(taus, n: int, rate: float, overlapping: bool) -> np.ndarray:
    m_max = n // 2 if overlapping else n // 3  # at least one second difference
    if isinstance(taus, str):
        if taus != "octave":
            raise InputError(f"taus: expected 'octave' or an array of seconds, found {taus!r}")
        return 2 ** np.arange(int(math.log2(m_max)) + 1)
    t = np.asarray(taus, dtype=float).ravel()
    if t.size == 0 or not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise InputError("taus: expected positive finite averaging times in seconds")
    m = np.unique(np.rint(t * rate).astype(np.int64))
    if m[0] < 1 or m[-1] > m_max:
        raise InputError(
            f"taus: averaging times must lie in [{1 / rate:g}, {m_max / rate:g}] s "
            f"for {n} samples at {rate:g} Hz"
        )
    return m


def edf_overlapping(n_phase, m) -> np.ndarray:
    """Effective degrees of freedom of the overlapping Allan variance, conservatively.

    Howe, Allan & Barnes (1981) approximations as tabulated in NIST SP 1065 (Riley 2008,
    table 5) for white, flicker and random-walk rate noise (the three a gyro shows beyond the
    shortest taus); the smallest of the three is used, so the interval never claims more
    confidence than the worst of those noise types allows. ``n_phase`` = samples + 1.
    """
    N = np.asarray(n_phase, dtype=float)
    m = np.asarray(m, dtype=float)
    white = (3 * (N - 1) / (2 * m) - 2 * (N - 2) / N) * (4 * m**2 / (4 * m**2 + 5))
    flicker = np.where(m == 1, 2 * (N - 2) ** 2 / (2.3 * N - 4.9), 5 * N**2 / (4 * m * (N + 3 * m)))
    walk = (N - 2) / m * ((N - 1) ** 2 - 3 * m * (N - 1) + 4 * m**2) / (N - 3) ** 2
    return np.maximum(np.minimum(np.minimum(white, flicker), walk), 1.0)


def _sumsq(cols: np.ndarray, rate: float, m: np.ndarray, overlapping: bool = True) -> np.ndarray:
    """(len(m), axes) sums of squared second differences of the integrated angle per tau."""
    n = cols.shape[0]
    sumsq = np.empty((m.size, cols.shape[1]))
    theta = np.zeros((1, n + 1))  # one axis at a time: contiguous, and peak memory of one axis
    for j in range(cols.shape[1]):
        col = cols[:, j]
        np.cumsum(col - col.mean(), out=theta[0, 1:])
        theta /= rate
        if overlapping:
            sumsq[:, j] = second_diff_sumsq(theta[0], m)
        else:
            for i, mj in enumerate(m):
                d = np.diff(theta[0, ::mj], 2)
                sumsq[i, j] = d @ d
    return sumsq


def _interval(adev, edf, level):
    """The two-sided interval at ``level`` from chi-squared quantiles with ``edf`` degrees
    of freedom, 2 P^-1(edf/2, q) (scipy.special: scipy.stats takes a second to import)."""
    from scipy.special import gammaincinv

    lo = adev * np.sqrt(edf / (2.0 * gammaincinv(edf / 2.0, 0.5 + level / 2)))[:, None]
    hi = adev * np.sqrt(edf / (2.0 * gammaincinv(edf / 2.0, 0.5 - level / 2)))[:, None]
    return lo, hi


def allan_deviation(
    x, rate: float, *, taus="octave", overlapping: bool = True, level: float = 0.683
) -> AllanResult:
    """Allan deviation of a rate signal ``x`` (1-D or (n, axes)) sampled at ``rate`` Hz.

    ``taus="octave"`` uses m = 1, 2, 4, ... up to n/2 (overlapping; n/3 otherwise); an array gives
    averaging times in seconds, rounded to whole samples. ``overlapping=False`` is the classic
    estimator with stride m and edf = number of terms (white-noise approximation).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2):
        raise InputError(f"allan_deviation: expected a 1-D or (n, axes) array, found shape {x.shape}")
    rate = float(rate)
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f"allan_deviation: rate must be a positive finite frequency, found {rate}")
    n = x.shape[0]
    if n < MIN_SAMPLES:
        raise InputError(f"allan_deviation: {n} samples, at least {MIN_SAMPLES} needed")
    if not np.all(np.isfinite(x)):
        raise InputError(f"allan_deviation: {int(np.sum(~np.isfinite(x)))} non-finite samples")
    if not (0 < level < 1):
        raise InputError(f"allan_deviation: level must lie in (0, 1), found {level}")
    m = _averaging_factors(taus, n, rate, overlapping)

    cols = x.reshape(n, -1)
    tau = m / rate
    sumsq = _sumsq(cols, rate, m, overlapping)
    if overlapping:
        n_terms = n + 1 - 2 * m
        edf = edf_overlapping(n + 1, m)
    else:
        n_terms = (n // m) - 1  # points theta_0, theta_m, ... minus two
        edf = n_terms.astype(float)
    avar = sumsq / (2.0 * tau[:, None] ** 2 * n_terms[:, None])
    adev = np.sqrt(avar)
    lo, hi = _interval(adev, edf, level)
    if x.ndim == 1:
        adev, lo, hi = adev[:, 0], lo[:, 0], hi[:, 0]
    return AllanResult(
        tau=tau,
        m=m,
        adev=adev,
        n_terms=np.asarray(n_terms),
        edf=edf,
        lo=lo,
        hi=hi,
        rate=rate,
        n_samples=n,
        overlapping=overlapping,
        level=level,
    )


@dataclass(frozen=True)
class StretchSums:
    """One static stretch's share of a pooled Allan deviation: per octave m = 1, 2, 4, ... its
    sums of squared second differences (k, axes), their count and equivalent degrees of
    freedom, and its within-stretch sum of squares about the mean (axes,)."""

    sumsq: np.ndarray
    n_terms: np.ndarray
    edf: np.ndarray
    n: int
    centred_sumsq: np.ndarray


def stretch_sums(x, rate: float) -> StretchSums:
    """The sums one stretch ((n, axes), n >= MIN_SAMPLES, finite) adds to a pooled estimate."""
    x = np.asarray(x, dtype=float)
    x = x.reshape(x.shape[0], -1)
    n = x.shape[0]
    if n < MIN_SAMPLES or not np.all(np.isfinite(x)):
        raise InputError(f"stretch_sums: need at least {MIN_SAMPLES} finite samples, found {n}")
    m = 2 ** np.arange(int(math.log2(n // 2)) + 1)
    centred = x - x.mean(axis=0)
    return StretchSums(
        sumsq=_sumsq(x, float(rate), m),
        n_terms=n + 1 - 2 * m,
        edf=edf_overlapping(n + 1, m),
        n=n,
        centred_sumsq=np.einsum("ij,ij->j", centred, centred),
    )


def pooled_from_sums(parts, rate: float, *, level: float = 0.683) -> AllanResult:
    """The pooled Allan deviation of stretches given by their :func:`stretch_sums`."""
    parts = list(parts)
    if not parts:
        raise InputError(f"pooled_allan_deviation: no stretch of at least {MIN_SAMPLES} samples")
    k = max(p.sumsq.shape[0] for p in parts)
    axes = parts[0].sumsq.shape[1]
    if any(p.sumsq.shape[1] != axes for p in parts):
        raise InputError("pooled_allan_deviation: stretches need the same axes")
    m = 2 ** np.arange(k)
    sumsq, n_terms, edf = np.zeros((k, axes)), np.zeros(k), np.zeros(k)
    for p in parts:
        j = p.sumsq.shape[0]
        sumsq[:j] += p.sumsq
        n_terms[:j] += p.n_terms
        edf[:j] += p.edf
    tau = m / float(rate)
    adev = np.sqrt(sumsq / (2.0 * tau[:, None] ** 2 * n_terms[:, None]))
    lo, hi = _interval(adev, edf, level)
    return AllanResult(
        tau=tau,
        m=m,
        adev=adev,
        n_terms=n_terms.astype(np.int64),
        edf=edf,
        lo=lo,
        hi=hi,
        rate=float(rate),
        n_samples=int(sum(p.n for p in parts)),
        level=level,
    )


def pooled_allan_deviation(stretches, rate: float, *, level: float = 0.683) -> AllanResult:
    """Overlapping Allan deviation of one sensor from several static stretches ((n_i, axes) each).

    A soak per mount or several pauses at one temperature are not one record; joining them would
    put a step at every seam. Instead, at each octave tau the squared second differences of every
    stretch at least 2m samples long are summed and divided by their total count (the estimator
    of the module docstring over the union), and their edf add up. One stretch gives
    :func:`allan_deviation`'s result exactly. Stretches under MIN_SAMPLES are skipped.
    """
    parts = [np.asarray(x, dtype=float) for x in stretches]
    return pooled_from_sums(
        [stretch_sums(x, rate) for x in parts if x.shape[0] >= MIN_SAMPLES], rate, level=level
    )


def barnes_b1(count, mu: int) -> np.ndarray:
    """Barnes' bias function B1: the expected sample variance (ddof 1) of ``count`` adjacent
    tau-means over the Allan variance at tau, for noise whose Allan variance grows as tau^mu
    (mu = -2 quantisation, -1 white rate, 0 flicker, 1 random walk; NIST SP 1065, section 5.15).
    It is 1 for white noise at any count and for every noise at count 2; counts under 2 are
    taken as 2."""
    M = np.maximum(np.asarray(count, dtype=float), 2.0)
    if mu == 0:
        return M * np.log(M) / (2.0 * (M - 1.0) * math.log(2.0))
    return M * (1.0 - M**mu) / (2.0 * (M - 1.0) * (1.0 - 2.0**mu))


_TERMS = ("quantisation", "arw", "bias_instability", "rrw", "ramp")
_NOISE = 4  # the first four are noise; the ramp is a drift


def _design(tau: np.ndarray) -> np.ndarray:
    """Columns multiplying (Q^2, N^2, B^2, K^2, R^2) in SI units (deg, s)."""
    tau = np.asarray(tau, dtype=float)
    return np.stack(
        [3.0 / tau**2, 1.0 / tau, np.full_like(tau, FLICKER_FACTOR**2), tau / 3.0, tau**2 / 2.0], axis=-1
    )


_SCALE = np.array([_TO_Q, _TO_ARW, _TO_BI, _TO_RRW, _TO_R])


@dataclass(frozen=True)
class NoiseTerms:
    """IEEE Std 952 noise terms: ``arw`` deg/sqrt(h), ``bias_instability`` deg/h,
    ``rrw`` deg/h/sqrt(h), ``quantisation`` arcsec; each a float (1-D input) or (axes,) array.

    ``*_stderr`` are 1-sigma uncertainties: the half-width sqrt(c + s_c) - sqrt(c) of the fitted
    variance coefficient c with standard error s_c mapped through the square root (equal to
    s_c / (2 sqrt c) when c is well determined, an upper bound sqrt(s_c) when c = 0).
    ``bias_instability_min`` is the datasheet reading min(adev) / 0.664 (deg/h) over the points
    with edf >= 10; it exceeds the fitted flicker coefficient wherever white or random-walk noise
    still adds at the minimum.
    ``tau_min`` (s) is where the fitted curve is lowest.
    """

    arw: np.ndarray | float
    bias_instability: np.ndarray | float
    rrw: np.ndarray | float
    quantisation: np.ndarray | float
    arw_stderr: np.ndarray | float
    bias_instability_stderr: np.ndarray | float
    rrw_stderr: np.ndarray | float
    quantisation_stderr: np.ndarray | float
    bias_instability_min: np.ndarray | float
    tau_min: np.ndarray | float
    chi2_reduced: np.ndarray | float
    tau_range: tuple[float, float] = field(default=(0.0, 0.0))
    ramp: np.ndarray | float = 0.0
    ramp_stderr: np.ndarray | float = 0.0

    def _coefficients(self) -> np.ndarray:
        """(axes, 5) variance coefficients (Q^2, N^2, B^2, K^2, R^2) in SI units."""
        # broadcast: terms read from a file written before the ramp was fitted have a zero ramp
        vals = np.stack(
            np.broadcast_arrays(*[np.atleast_1d(np.asarray(getattr(self, k), dtype=float)) for k in _TERMS]),
            -1,
        )
        return (vals / _SCALE) ** 2

    def avar(self, tau, *, drift: bool = True) -> np.ndarray:
        """Model Allan variance (deg/s)^2 at ``tau`` (s); shape tau.shape (+ (axes,));
        ``drift=False``: the noise alone, without the rate ramp."""
        tau = np.asarray(tau, dtype=float)
        coefficients = self._coefficients()
        if not drift:
            coefficients[:, _NOISE:] = 0.0
        out = _design(tau) @ coefficients.T
        return out[..., 0] if np.ndim(self.arw) == 0 else out

    def adev(self, tau) -> np.ndarray:
        """Model Allan deviation (deg/s) at ``tau`` (s)."""
        return np.sqrt(self.avar(tau))

    def floor(self, duration_s) -> np.ndarray:
        """Standard deviation (deg/s) of a ``duration_s``-long mean predicted by the noise model.

        Defined as the Allan deviation at tau = T: the rms difference of two adjacent T-long
        means divided by sqrt 2. For white noise this is exactly the standard deviation of a
        mean, N / sqrt(T). For flicker and random-walk rate noise the variance of a mean about
        the long-term mean grows without bound with the record length, so the adjacent-hold
        scatter is the meaningful finite quantity: holds far apart in time scatter more (for
        random walk by about sqrt(separation / T)); the floor is a lower bound for them.
        """
        t = np.asarray(duration_s, dtype=float)
        if not np.all(np.isfinite(t)) or np.any(t <= 0):
            raise InputError(f"NoiseTerms.floor: durations must be positive and finite, found {t}")
        return np.sqrt(self.avar(t, drift=False))

    def _parts(self, tau) -> np.ndarray:
        """(..., axes, 5) Allan variance of each term (Q, N, B, K, R) at ``tau``."""
        return _design(np.asarray(tau, dtype=float))[..., None, :] * self._coefficients()

    def _per_axis(self, out):
        return out[..., 0] if np.ndim(self.arw) == 0 else out

    def mean_variance(self, duration_s, count=2.0) -> np.ndarray:
        """Expected sample variance (ddof 1, (deg/s)^2) of ``count`` adjacent ``duration_s``-long
        means: each term's Allan variance at tau = T times its :func:`barnes_b1` (quantisation
        mu = -2, white -1, flicker 0, random walk 1). It is the scatter a fit with a free
        bias leaves in such means; with count 2 it is the Allan variance itself (:meth:`floor`
        squared). Flicker and random walk make holds scatter more the longer the stretch a fit
        pools them over. ``duration_s`` and ``count`` broadcast; per-axis terms append an axis
        dimension."""
        parts = self._parts(duration_s)
        count = np.asarray(count, dtype=float)[..., None]
        parts[..., 0] *= barnes_b1(count, -2)
        parts[..., 2] *= barnes_b1(count, 0)
        parts[..., 3] *= barnes_b1(count, 1)
        return self._per_axis(parts[..., :_NOISE].sum(axis=-1))

    def coloured_variance(self, tau) -> np.ndarray:
        """Flicker plus random-walk Allan variance ((deg/s)^2) at ``tau`` (s): how far apart the
        means of stretches ``tau`` apart wander beyond white noise."""
        parts = self._parts(tau)
        return self._per_axis(parts[..., 2] + parts[..., 3])

    def to_dict(self) -> dict[str, Any]:
        units = {
            "arw": "deg/sqrt(h)",
            "bias_instability": "deg/h",
            "rrw": "deg/h/sqrt(h)",
            "quantisation": "arcsec",
            "ramp": "deg/h/h",
            "bias_instability_min": "deg/h",
            "tau_min": "s",
        }
        out = {
            "units": units,
            "standard": "IEEE Std 952-1997",
            "tau_range_s": [float(self.tau_range[0]), float(self.tau_range[1])],
        }
        for k in (*_TERMS, "bias_instability_min", "tau_min", "chi2_reduced"):
            out[k] = _plain(getattr(self, k))
        for k in _TERMS:
            out[f"{k}_stderr"] = _plain(getattr(self, f"{k}_stderr"))
        return out


RAMP_P = 0.05  # the ramp stays only where the F-test for it passes at this level


def _fit_axis(tau, avar, edf, iterations: int = 6):
    """Non-negative weighted least squares of avar on the five-term model, or on the four
    noise terms where the ramp fails the F-test of the fall in χ² it brings (against the
    five-term fit's χ² per degree of freedom: the edf's errors are conservative, so their
    scale is the fit's to tell) at :data:`RAMP_P`. A ramp the data do not ask for would
    only blur the random walk it resembles over a few octaves (a turntable's 100-s soaks);
    the two are told apart by the fit, not by the ramp's own standard error, which their
    likeness inflates.

    Var(avar_hat) ~ 2 avar^2 / edf; weights use the model's avar (iteratively reweighted) so a
    point that happens to fall low does not pull the fit down with an inflated weight.
    """
    # scipy.special's tail, as scipy.stats' f.sf computes it (1 below the support), without
    # the half second scipy.stats takes to import
    from scipy.special import fdtrc

    A = _design(tau)
    coef, se, chi2r, chi2 = _fit_columns(tau, avar, edf, A, iterations)
    coef4, se4, chi2r4, chi24 = _fit_columns(tau, avar, edf, A[:, :_NOISE], iterations)
    dof = len(tau) - A.shape[1]
    if (
        coef[_NOISE] > 0
        and dof >= 1
        and chi2 > 0
        and fdtrc(1, dof, max((chi24 - chi2) / (chi2 / dof), 0.0)) < RAMP_P
    ):
        return coef, se, chi2r
    return np.r_[coef4, 0.0], np.r_[se4, 0.0], chi2r4


def _fit_columns(tau, avar, edf, A, iterations):
    from scipy.optimize import nnls  # on use: scipy.optimize takes half a second to import

    sigma2 = avar.copy()
    for _ in range(iterations):
        w = np.sqrt(edf / 2.0) / sigma2
        Aw = A * w[:, None]
        norm = np.linalg.norm(Aw, axis=0)  # columns span ~10 decades: solve in unit columns
        coef = nnls(Aw / norm, avar * w)[0] / norm
        model = A @ coef
        sigma2 = np.where(model > 0, model, avar)
    w = np.sqrt(edf / 2.0) / sigma2
    Aw = A * w[:, None]
    norm = np.linalg.norm(Aw, axis=0)
    resid = (avar - model) * w
    dof = max(len(tau) - int(np.sum(coef > 0)), 1)
    chi2r = float(resid @ resid / dof)
    cov = np.linalg.pinv((Aw / norm).T @ (Aw / norm)) / np.outer(norm, norm)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None) * max(chi2r, 1.0))  # inflate on a poor fit
    return coef, se, chi2r, float(resid @ resid)


def fit_noise_terms(result: AllanResult) -> NoiseTerms:
    """Fit IEEE Std 952 noise terms to an overlapping Allan deviation (see the module docstring).

    By construction the fitted N is the tau^-1/2 line read at tau = 1 s and K the tau^+1/2 line
    read at tau = 3 s. Points with edf < 1 or zero deviation carry no information and are skipped.
    """
    adev = np.asarray(result.adev, dtype=float)
    cols = adev.reshape(adev.shape[0], -1)
    tau, edf = np.asarray(result.tau, dtype=float), np.asarray(result.edf, dtype=float)
    coefs, ses, chi2s, bmins, tmins = [], [], [], [], []
    for j in range(cols.shape[1]):
        keep = (cols[:, j] > 0) & (edf >= 1.0)
        if keep.sum() < 4:
            raise InputError(f"fit_noise_terms: {int(keep.sum())} usable averaging times, 4 needed")
        coef, se, chi2r = _fit_axis(tau[keep], cols[keep, j] ** 2, edf[keep])
        coefs.append(coef)
        ses.append(se)
        chi2s.append(chi2r)
        solid = keep & (edf >= _EDF_READING)
        bmins.append(cols[solid if solid.any() else keep, j].min() / FLICKER_FACTOR * _TO_BI)
        grid = np.geomspace(tau[keep][0], tau[keep][-1], 512)
        tmins.append(float(grid[np.argmin(_design(grid) @ coef)]))
    coef_rows, se_rows = np.array(coefs), np.array(ses)
    values = np.sqrt(coef_rows) * _SCALE
    errors = (np.sqrt(coef_rows + se_rows) - np.sqrt(coef_rows)) * _SCALE

    def pick(a):
        a = np.asarray(a, dtype=float)
        return float(a[0]) if adev.ndim == 1 else a

    kw = {}
    for i, k in enumerate(_TERMS):
        kw[k] = pick(values[:, i])
        kw[f"{k}_stderr"] = pick(errors[:, i])
    return NoiseTerms(
        **kw,
        bias_instability_min=pick(bmins),
        tau_min=pick(tmins),
        chi2_reduced=pick(chi2s),
        tau_range=(float(tau[0]), float(tau[-1])),
    )
