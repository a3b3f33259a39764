"""The honest noise floor: each observation's noise from the sensor's own static stretches.

A real MEMS gyro is not a white-noise source: bias instability (flicker) and rate random walk
move a hold's mean by more than (within-hold std)/sqrt(n), and they move the bias between
temperature points that hours separate. A floor that ignores them makes every real unit look as
if an effect were missing. So, for every session:

1. the log's static stretches are found from its segmentation (:func:`static_stretches`);
2. their overlapping Allan deviation is pooled over the session (the model the floors use) and
   per temperature point (the terms' temperature dependence), and the IEEE Std 952 terms are
   fitted (:mod:`gyrocal.fit.noise`); bias instability and rate random walk enter the floors only
   where detected (:func:`floor_terms`);
3. every observation gets two standard deviations per axis (columns of the observation table):

   * ``floor_*``: its mean about the mean of its temperature point's holds, T = n / rate long:
     ``NoiseTerms.mean_variance(T, M)`` with M = (span of the point's holds) / T, i.e. each
     term's Allan variance at T times Barnes' B1(M); plus the hold's own white scatter beyond the
     static one, (s^2 - s0^2) / n, which table wobble or vibration adds while rotating;
   * ``wander_*``: its point's mean about a smooth curve across temperature: the flicker and
     random-walk Allan variance at the time between neighbouring points.

   A fit inside one temperature point sees ``floor``; a fit or comparison across points sees
   ``floor`` and ``wander`` in quadrature (:func:`gyrocal.fit.model.observation_floor`). The fits
   themselves use the full covariance of the hold means (``white_*``, ``flicker_*``, ``rrw_*``
   columns and :mod:`gyrocal.fit.wander`): holds close in time share the wander.

With white noise alone, ``floor`` is the noise density over sqrt(T), what std/sqrt(n) gives,
and ``wander`` vanishes. When nothing static can be characterised, the columns are left out and
every consumer falls back to std/sqrt(n); the summary (``Segmentation.info["noise"]``) says so.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NamedTuple, NotRequired, TypedDict

import numpy as np

from ..io import AXES
from ..io.errors import InputError
from .noise import MIN_SAMPLES, NoiseTerms, fit_noise_terms, pooled_from_sums, stretch_sums

if TYPE_CHECKING:
    import pandas as pd

MIN_STATIC_S = 1.0  # a stretch this long adds its short taus to the pooled estimate
MIN_STATIC_SAMPLES = 64
MIN_TOTAL_S = 10.0  # less static time in all reaches too few octaves to tell terms apart
MERGE_GAP_S = 1.0  # stretches closer than this are one stretch (a hold that ends a soak)
QUIET_BLOCK_S = 1.0  # servo pauses: blocks judged quiet by their scatter
QUIET_FACTOR = 2.0  # a block scattering more than this × the median block is moving
FALLBACK = "within-hold scatter"
STATIC = "noise model of the static stretches"


def merge_intervals(start: np.ndarray, end: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Union of intervals, joining those less than ``gap`` apart."""
    if start.size == 0:
        return start, end
    order = np.argsort(start)
    start, end = start[order], np.maximum.accumulate(end[order])
    new = np.r_[True, start[1:] - end[:-1] > gap]
    group = np.cumsum(new) - 1
    return start[new], np.maximum.reduceat(end, np.flatnonzero(new))[: group[-1] + 1]


def intersect_intervals(a0, a1, b0, b1) -> tuple[np.ndarray, np.ndarray]:
    """Pairwise intersection of two sorted sets of disjoint intervals."""
    lo = np.maximum(a0[:, None], b0[None, :])
    hi = np.minimum(a1[:, None], b1[None, :])
    keep = hi > lo
    return lo[keep], hi[keep]


def quiet_runs(t: np.ndarray, gyro: np.ndarray, still: np.ndarray, rate: float):
    """Runs of whole blocks where the reference is still and the gyro scatters no more than
    QUIET_FACTOR × the median still block (a hand moving the unit scatters far more); one block
    either side of such a block is dropped as settling."""
    size = max(int(round(QUIET_BLOCK_S * rate)), 2)
    nb = len(t) // size
    if nb < 3:
        return np.array([]), np.array([])
    g = gyro[: nb * size].reshape(nb, size, 3)
    block_still = still[: nb * size].reshape(nb, size).all(axis=1)
    spread = g.std(axis=1).max(axis=1)
    if not block_still.any():
        return np.array([]), np.array([])
    moving = block_still & (spread > QUIET_FACTOR * np.median(spread[block_still]))
    quiet = block_still & ~moving & ~np.r_[moving[1:], False] & ~np.r_[False, moving[:-1]]
    edges = np.diff(np.r_[0, quiet.astype(np.int8), 0])
    first, stop = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return t[first * size], t[stop * size - 1]


def static_stretches(log, seg, static, *, max_temp_rate: float = 0.1) -> pd.DataFrame:
    """Time spans (t_start, t_end, s) where the sensor sits still at a steady temperature,
    as the protocol finds them (``static``: its
    :attr:`gyrocal.protocols.registry.Protocol.static`), at least ``MIN_STATIC_S`` long."""
    import pandas as pd  # here, not with the module: a report reads the noise terms without it

    t0, t1 = static(log, seg, max_temp_rate)
    out = pd.DataFrame({"t_start": np.asarray(t0, float), "t_end": np.asarray(t1, float)})
    out = out[out["t_end"] - out["t_start"] >= MIN_STATIC_S].sort_values("t_start")
    return out.reset_index(drop=True)


SETTLING_SIGMAS = 8.0  # a stretch's start this far off its second half's line is settling
SETTLING_TRIMS = (0, 32, 16, 8, 4)  # starts tried: 0, then n/32, n/16, n/8, n/4


def settled_start(gyro: np.ndarray) -> int:
    """Where a static stretch's output has settled: the first of the starts 0, n/32, n/16,
    n/8 and n/4 whose next sixteenth has a mean within :data:`SETTLING_SIGMAS` of the
    straight line through the stretch's second half, where those before it stood off that
    line by more, on the same side and shrinking (an output that settles after the table
    stops: a slow pole, a relaxation); n/2 where none is; 0 where the offsets do not fall
    one way (a wander, kept whole). A drift through the whole stretch (a ramp) is on the
    line. σ is the white noise's, from second differences, which a settling does not move.
    A floor made of a settling would be made of the effect."""
    n = len(gyro)
    if n < 64:
        return 0
    x = np.asarray(gyro, dtype=np.float64)
    d2 = np.diff(x, 2, axis=0)
    sigma = np.sqrt(_nanmean_of_squares(d2) / 6.0)
    half = np.arange(n // 2, n, dtype=np.float64)
    tail = x[n // 2 :]
    h_mean, y_mean, slope = _line(half, tail)
    if not np.all(np.isfinite(y_mean)):  # the line through the rows finite on every axis
        keep = np.all(np.isfinite(tail), axis=1)
        if keep.sum() < 8:
            return 0
        h_mean, y_mean, slope = _line(half[keep], tail[keep])
    h_bar = half.mean()
    h_ss = (half - h_bar) @ (half - h_bar)
    window = n // 16
    previous = None
    for trim in SETTLING_TRIMS:
        start = n // trim if trim else 0
        lead = x[start : start + window]
        centre = start + (window - 1) / 2.0
        line = y_mean + slope * (centre - h_mean)
        # the lead's mean and the line's value there, each with its white-noise variance
        spread = 1.0 / window + 1.0 / len(half) + (centre - h_bar) ** 2 / h_ss
        off = (np.nanmean(lead, axis=0) - line) / (sigma * np.sqrt(spread))
        worst = int(np.argmax(np.abs(off)))
        if abs(off[worst]) < SETTLING_SIGMAS:
            return start
        shrinking = previous is None or (
            np.sign(off[worst]) == np.sign(previous) and abs(off[worst]) < abs(previous)
        )
        if not shrinking:
            return 0
        previous = off[worst]
    return n // 2


def _nanmean_of_squares(d: np.ndarray) -> np.ndarray:
    """``np.nanmean(d**2, axis=0)``, in one pass where nothing is NaN (a finite sum says so)."""
    sumsq = np.einsum("ij,ij->j", d, d)
    return sumsq / len(d) if np.all(np.isfinite(sumsq)) else np.nanmean(d**2, axis=0)


def _line(h: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The least-squares line through each column of ``y`` against ``h``: the mean of h,
    the column means (the line's value there) and slopes, from centred sums (matrix-vector
    products: numpy's sum down the rows of a narrow array is slow)."""
    h_mean = float(h.mean())
    hc = h - h_mean
    return h_mean, np.ones(len(y)) @ y / len(y), (hc @ y) / (hc @ hc)


class StretchSampler:
    """The samples of the static stretches, gathered from a log given batch by batch
    (``push``: dicts with t, temp and the gyro axes), each stretch trimmed of its settling and
    reduced to its :func:`gyrocal.fit.noise.stretch_sums` on two threads as soon as it is
    complete, so that only the stretches being reduced are held. A stretch is the rows with t_start <= t <= t_end; one
    shorter than the noise model needs is left out. ``result()``: per stretch kept, its
    sums, its sample count and its mean temperature."""

    NAMES = ("t", "temp", *(f"gyro_{a}" for a in AXES))

    def __init__(self, stretches: pd.DataFrame, rate: float, *, trim_settling: bool = False):
        self.trim_settling = trim_settling  # each stretch from where its output settled
        self.start = stretches["t_start"].to_numpy(float)
        self.end = stretches["t_end"].to_numpy(float)
        self.rate = rate
        self._pieces: dict[int, list[dict[str, np.ndarray]]] = {}
        self._done: dict[int, Future[Stretch | None]] = {}
        self._pool = ThreadPoolExecutor(2)  # numpy releases the GIL: a stretch's work beside the read

    def push(self, batch: dict[str, np.ndarray]) -> None:
        t = batch["t"]
        lo = np.searchsorted(t, self.start, side="left")
        hi = np.searchsorted(t, self.end, side="right")
        for i in np.flatnonzero(hi > lo):
            self._pieces.setdefault(int(i), []).append({c: batch[c][lo[i] : hi[i]] for c in self.NAMES[1:]})
        for k in [k for k in self._pieces if self.end[k] < t[-1]]:
            self._close(k)

    def _close(self, k: int) -> None:
        pieces = self._pieces.pop(k)
        cols = {
            c: (pieces[0][c] if len(pieces) == 1 else np.concatenate([p[c] for p in pieces]))
            for c in self.NAMES[1:]
        }
        gyro = np.column_stack([cols[c] for c in self.NAMES[2:]])  # a copy: the batches can go
        # the rest on the pool: the main thread goes on with the next batch
        self._done[k] = self._pool.submit(self._reduce, gyro, cols["temp"], float(self.start[k]))

    def _reduce(self, gyro: np.ndarray, temp: np.ndarray, start: float) -> Stretch | None:
        if self.trim_settling:
            gyro = gyro[settled_start(gyro) :]
        n = len(gyro)
        if n < max(MIN_STATIC_SAMPLES, MIN_SAMPLES):
            return None
        half = n // 2
        # in float64: a float32 column's own accumulator overflows near its largest value
        drift = gyro[half:].mean(axis=0, dtype=np.float64) - gyro[:half].mean(axis=0, dtype=np.float64)
        return Stretch(stretch_sums(gyro, self.rate), n, float(np.mean(temp, dtype=np.float64)), start, drift)

    def result(self) -> list[Stretch]:
        for k in list(self._pieces):
            self._close(k)
        self._pool.shutdown()
        return [s for _, f in sorted(self._done.items()) if (s := f.result()) is not None]


class Stretch(NamedTuple):
    """A static stretch as the noise model reads it: its sums (:func:`gyrocal.fit.noise.stretch_sums`),
    its samples, its mean temperature, its start (s) and its drift (the second half's mean
    less the first's, per axis, deg/s)."""

    sums: Any
    n: int
    temp: float
    start: float
    drift: np.ndarray


MOTION_DRIFT_P = 1e-3  # the session's: the stretches' drifts follow the motion (the axes' tests combined)
MOTION_DRIFT_AXIS_P = 0.05  # then each axis whose own test passes at this level


def motion_drift(obs: pd.DataFrame, stretches: list[Stretch]) -> dict[str, Any] | None:
    """Whether the static stretches' drifts follow the motion before them, per axis: each
    stretch's drift regressed on 1, the previous hold's rate on that axis and its rate's
    magnitude, F-tested against no drift (p per axis). A session's drifts follow the motion
    where the axes' tests combined (Fisher's: -2 Σ ln p is χ² with six degrees of freedom when
    no axis follows) give p below MOTION_DRIFT_P; then ``follows`` every
    axis whose own p is below MOTION_DRIFT_AXIS_P (an effect of the motion shows on the axes
    its direction reaches, some more faintly than others).
    Rate random walk and bias instability drift each stretch its own random way; an output
    that relaxes after turning (a slow pole, a charge that decays) drifts the way the turn
    before it says, and its Allan deviation at long τ would pass for random walk: a floor made
    of the effect. None where fewer than eight stretches follow a hold or the holds have no
    rates."""
    if not stretches or any(f"rate_{a}" not in obs for a in AXES) or obs.empty:
        return None
    holds = obs.sort_values("t_end")
    ends = holds["t_end"].to_numpy(float)
    rates = holds[[f"rate_{a}" for a in AXES]].to_numpy(float)
    starts = np.array([s.start for s in stretches])
    previous = np.searchsorted(ends, starts, side="right") - 1
    keep = previous >= 0
    if keep.sum() < 8:
        return None
    prev = rates[previous[keep]]
    drifts = np.array([s.drift for s in stretches])[keep]
    magnitude = np.linalg.norm(prev, axis=1)
    from scipy.special import chdtrc, fdtrc  # tails, without scipy.stats' import

    p_values = []
    for i in range(3):
        design = np.column_stack([np.ones(len(prev)), prev[:, i], magnitude])
        y = drifts[:, i]
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        rank = int(np.linalg.matrix_rank(design))
        left = float(np.sum((y - design @ coef) ** 2))
        dof = len(y) - rank
        total = float(np.sum(y**2))
        if dof < 1 or left <= 0 or not np.isfinite(total):
            p_values.append(1.0)
            continue
        p_values.append(float(fdtrc(rank, dof, ((total - left) / rank) / (left / dof))))
    combined = float(chdtrc(2 * len(p_values), -2.0 * np.sum(np.log(np.maximum(p_values, 1e-300)))))
    follows = [combined < MOTION_DRIFT_P and p < MOTION_DRIFT_AXIS_P for p in p_values]
    return {"p": p_values, "p_session": combined, "follows": follows}


class NoiseModel(TypedDict):
    """A noise model of static stretches, JSON-plain (:func:`_model`)."""

    sample_variance: list[float]  # within the stretches, per axis, (deg/s)²
    allan: dict[str, Any]  # the pooled Allan deviation: tau_s, adev, lo, hi, edf, level
    terms: dict[str, Any]  # the fitted IEEE Std 952 terms (NoiseTerms.to_dict)
    motion_drift: NotRequired[dict[str, Any]]  # :func:`motion_drift`, where it could be judged


class Resolution(TypedDict):
    """What the static stretches can and cannot tell (:func:`resolution`)."""

    tau_max_s: float
    longest_static_s: float
    text: str


class NoiseSummary(TypedDict):
    """The session's noise characterisation (:func:`characterise`), JSON-plain: segmentation
    writes it in its info (``noise``)."""

    source: str  # STATIC (the static stretches' model) or FALLBACK (std / sqrt(n))
    points: list[dict[str, Any]]  # per temperature point: point, temp, stretches, seconds, its model
    static_seconds: float
    reason: NotRequired[str]  # why the fallback
    stretches: NotRequired[int]
    longest_static_s: NotRequired[float]
    session: NotRequired[NoiseModel]
    resolves: NotRequired[Resolution]
    between_points_s: NotRequired[float]  # set by add_floor_columns


class NoiseRecord(TypedDict):
    """What a calibration file keeps of the noise characterisation (:func:`noise_record`)."""

    floor: str
    reason: NotRequired[str]
    resolves: NotRequired[Resolution]
    static_seconds: NotRequired[float]
    stretches: NotRequired[int]
    session: NotRequired[dict[str, Any]]
    floor_terms: NotRequired[dict[str, Any]]
    points: NotRequired[list[dict[str, Any]]]


def _model(parts: list, rate: float) -> NoiseModel | None:
    """Pooled Allan deviation, fitted terms and within-stretch sample variance of stretches
    given by their :func:`gyrocal.fit.noise.stretch_sums`, JSON-plain; None when they reach too few
    octaves for a fit."""
    try:
        allan = pooled_from_sums(parts, rate)
        terms = fit_noise_terms(allan)
    except InputError:
        return None
    variance = sum(p.centred_sumsq for p in parts) / (sum(p.n for p in parts) - len(parts))
    return {
        "sample_variance": variance.tolist(),
        "allan": {
            "tau_s": allan.tau.tolist(),
            "adev": allan.adev.tolist(),
            "lo": allan.lo.tolist(),
            "hi": allan.hi.tolist(),
            "edf": allan.edf.tolist(),
            "level": allan.level,
        },
        "terms": terms.to_dict(),
    }


def characterise(log, seg, static, *, max_temp_rate: float = 0.1, sampled=None) -> NoiseSummary:
    """Noise of the session, JSON-plain: ``session`` pools every static stretch (the model the
    floors use: a few short soaks per temperature cannot pin down flicker and random walk, all
    of them together can), ``points`` the same per temperature point (the terms' temperature
    dependence; a point without static stretches is listed without them); ``source`` says
    which floor applies and ``reason`` why the fallback did. Each stretch is read once: the
    pooled estimates are sums over stretches (:class:`StretchSampler`; ``sampled``, its
    result when the caller read the log for it, with other consumers; ``static``, the
    protocol's finder of static stretches, otherwise)."""
    obs = seg.observations
    rate = float(seg.info.get("sample_rate") or 0.0)
    summary: NoiseSummary = {
        "source": FALLBACK,
        "points": [],
        "static_seconds": 0.0,
        "reason": f"less than {MIN_TOTAL_S:g} s of static data with a steady temperature in the log",
    }
    if obs.empty or rate <= 0:
        return summary
    after_turning = bool(getattr(getattr(static, "__self__", None), "static_after_turning", False))
    if sampled is None:
        sampler = StretchSampler(
            static_stretches(log, seg, static, max_temp_rate=max_temp_rate), rate, trim_settling=after_turning
        )
        for batch in log.scan(StretchSampler.NAMES):
            sampler.push(batch)
        sampled = sampler.result()
    seconds = sum(s.n for s in sampled) / rate
    if seconds < MIN_TOTAL_S:
        return summary
    parts = [s.sums for s in sampled]
    session = _model(parts, rate)
    if session is None:
        summary["reason"] = "the static stretches are too short for a noise model"
        return summary
    drift = motion_drift(obs, sampled) if after_turning else None
    if drift is not None:
        session["motion_drift"] = drift
    points = obs.groupby("point")["point_temp"].first()
    temps = np.array([s.temp for s in sampled])
    # each stretch belongs to the temperature point nearest its mean temperature
    nearest = np.abs(temps[:, None] - points.to_numpy()[None, :]).argmin(axis=1)
    rows = []
    for k, (point, point_temp) in enumerate(points.items()):
        mine = [p for p, j in zip(parts, nearest, strict=False) if j == k]
        row: dict[str, Any] = {
            "point": int(point),
            "temp": float(point_temp),
            "stretches": len(mine),
            "seconds": float(sum(p.n for p in mine) / rate),
        }
        row.update((_model(mine, rate) or {}) if mine else {})
        rows.append(row)
    longest = max(p.n for p in parts) / rate
    return {
        "source": STATIC,
        "static_seconds": float(seconds),
        "stretches": len(parts),
        "longest_static_s": float(longest),
        "session": session,
        "points": rows,
        "resolves": resolution(longest, float(session["allan"]["tau_s"][-1])),
    }


def resolution(longest_s: float, tau_max_s: float) -> Resolution:
    """What the static stretches can and cannot tell, JSON-plain: they measure the Allan
    deviation up to ``tau_max_s``; wander over longer times (a chamber's bursts are seconds
    long, its temperature points minutes apart) is beyond them."""
    return {
        "tau_max_s": tau_max_s,
        "longest_static_s": longest_s,
        "text": (
            f"the static stretches, {longest_s:.3g} s at the longest, measure the noise up to "
            f"τ = {tau_max_s:.3g} s; bias instability and rate random walk over longer times "
            "are not measured by them: the floors count them only where detected, and the "
            "diagnosis weighs an excess against the most of them the data cannot rule out"
        ),
    }


def terms_of(entry: Mapping[str, Any]) -> NoiseTerms:
    """The :class:`NoiseTerms` of one point of a :func:`characterise` summary."""
    d = entry["terms"]
    keys = ("arw", "bias_instability", "rrw", "quantisation")
    kw = {k: np.asarray(d[k], float) for k in keys}
    kw.update({f"{k}_stderr": np.asarray(d[f"{k}_stderr"], float) for k in keys})
    if "ramp" in d:  # files written before the ramp was fitted have none
        kw.update(ramp=np.asarray(d["ramp"], float), ramp_stderr=np.asarray(d["ramp_stderr"], float))
    return NoiseTerms(
        **kw,
        bias_instability_min=np.asarray(d["bias_instability_min"], float),
        tau_min=np.asarray(d["tau_min"], float),
        chi2_reduced=np.asarray(d["chi2_reduced"], float),
        tau_range=tuple(d["tau_range_s"]),
    )


DETECTION_Z = 3.0  # a coloured term counts when its variance coefficient is this many s.e. above 0


def detected(value, error, z: float = DETECTION_Z) -> np.ndarray:
    """Whether a fitted term (``value``, with the ``error`` :class:`NoiseTerms` reports for it)
    is detected: its variance coefficient c = value^2 at least ``z`` standard errors s above
    zero. The reported error is sqrt(c + s) - sqrt(c) (in the term's unit), so
    s = (value + error)^2 - value^2."""
    value, error = np.asarray(value, float), np.asarray(error, float)
    return value**2 >= z * ((value + error) ** 2 - value**2)


def floor_terms(model: Mapping[str, Any]) -> NoiseTerms:
    """The session's terms as the floors use them: bias instability and rate random walk only
    where the static data detect them (:func:`detected`). A few minutes of white noise fit a
    flicker level of a few deg/h; counted, it would raise the floor of a white-noise unit by a
    third and hide real effects. The ramp, a drift, counts in no floor; nor do they on an
    axis whose static stretches drift the way the turn before them says (:func:`motion_drift`):
    there the slow part of the static data is an effect of the motion, which the fit is
    asked to find, and a floor made of it would hide it."""
    terms = terms_of(model)
    follows = np.asarray(model.get("motion_drift", {}).get("follows", [False] * 3), bool)

    def counted(name: str) -> np.ndarray:
        value = np.asarray(getattr(terms, name), float)
        return np.where(detected(value, getattr(terms, f"{name}_stderr")) & ~follows, value, 0.0)

    return replace(terms, bias_instability=counted("bias_instability"), rrw=counted("rrw"))


UPPER_Z = 2.0  # the slow terms' upper bound: their variance coefficient 2 s.e. up


def upper_terms(model: Mapping[str, Any], z: float = UPPER_Z) -> NoiseTerms:
    """The session's terms with bias instability and rate random walk at their upper bound
    (variance coefficient ``z`` standard errors above its estimate, detected or not): the
    most slow wander the static data cannot rule out. A few minutes of static data leave
    wander of correlation times beyond them nearly unconstrained."""
    terms = terms_of(model)
    kw = {}
    for name in ("bias_instability", "rrw"):
        value = np.asarray(getattr(terms, name), float)
        s = (value + np.asarray(getattr(terms, f"{name}_stderr"), float)) ** 2 - value**2
        kw[name] = np.sqrt(value**2 + z * np.clip(s, 0.0, None))
    return replace(terms, **kw)


FLOOR_COLUMNS = ("floor", "wander", "white", "flicker", "rrw")


def add_floor_columns(obs: pd.DataFrame, summary: NoiseSummary, rate: float) -> pd.DataFrame:
    """``obs`` with ``floor_*`` and ``wander_*`` (deg/s) from the session's noise model, and
    the same columns with the slow terms at their upper bound (``upper_floor_*``, ...:
    :func:`upper_terms`); unchanged when the summary has none (the std/sqrt(n) fallback)."""
    if "session" not in summary or obs.empty or rate <= 0:
        return obs
    obs = _floor_columns(obs.copy(), summary, rate, floor_terms(summary["session"]), "")
    return _floor_columns(obs, summary, rate, upper_terms(summary["session"]), "upper_")


def with_upper_floor(obs: pd.DataFrame) -> pd.DataFrame | None:
    """``obs`` whose floor columns are the upper-bound ones (None when it has none)."""
    if "upper_floor_x" not in obs:
        return None
    out = obs.copy()
    for k in FLOOR_COLUMNS:
        for a in AXES:
            out[f"{k}_{a}"] = obs[f"upper_{k}_{a}"]
    return out


def _floor_columns(
    obs: pd.DataFrame, summary: NoiseSummary, rate: float, terms: NoiseTerms, prefix: str
) -> pd.DataFrame:
    model = summary["session"]
    duration = obs["n"].to_numpy(float) / rate
    span = obs.groupby("point").agg(t0=("t_start", "min"), t1=("t_end", "max"))
    # A hold scatters about its visit's mean: a sweep passes each temperature going up and
    # coming down hours later, and the wander of those hours is no hold's noise.
    visit = _visits(obs)
    visit_span = (
        obs.groupby(visit)["t_end"].transform("max") - obs.groupby(visit)["t_start"].transform("min")
    ).to_numpy(float)
    count = np.maximum(visit_span / duration, 1.0)
    mids = ((span["t0"] + span["t1"]) / 2).sort_values().to_numpy()
    between = float(np.median(np.diff(mids))) if mids.size > 1 else 0.0
    std = obs[[f"std_{a}" for a in AXES]].to_numpy(float)
    extra = np.clip(std**2 - np.asarray(model["sample_variance"])[None, :], 0.0, None)
    extra /= obs["n"].to_numpy(float)[:, None]
    white = replace(terms, bias_instability=np.zeros(3), rrw=np.zeros(3))
    floor2 = terms.mean_variance(duration, count) + extra
    wander = np.sqrt(terms.coloured_variance(between)) if between > 0 else np.zeros(3)
    white2 = white.mean_variance(duration) + extra
    flicker = np.asarray(terms.bias_instability, float) / 3600.0  # deg/h -> deg/s
    walk = np.asarray(terms.rrw, float) / 3600.0**1.5  # -> deg/s/sqrt(s)
    for i, a in enumerate(AXES):
        obs[f"{prefix}floor_{a}"] = np.sqrt(floor2[:, i])
        obs[f"{prefix}wander_{a}"] = wander[i]
        obs[f"{prefix}white_{a}"] = np.sqrt(white2[:, i])
        obs[f"{prefix}flicker_{a}"] = flicker[i]
        obs[f"{prefix}rrw_{a}"] = walk[i]
    summary["between_points_s"] = between
    return obs


def _visits(obs: pd.DataFrame) -> np.ndarray:
    """Per observation, a label of its point's visit: a run of the point's holds in time
    order that no other point's hold interrupts."""
    order = np.argsort(obs["t_start"].to_numpy(float), kind="stable")
    point = obs["point"].to_numpy()[order]
    run = np.cumsum(np.r_[True, point[1:] != point[:-1]])
    out = np.empty(len(order), np.int64)
    out[order] = run
    return out


def noise_record(summary: NoiseSummary) -> NoiseRecord:
    """What a calibration file keeps of the noise characterisation: the terms (IEEE Std 952
    units), the session's and per temperature point, and which floor the fit used."""
    out: NoiseRecord = {"floor": summary["source"]}
    if "reason" in summary:
        out["reason"] = summary["reason"]
    if "session" not in summary:
        return out
    used = floor_terms(summary["session"])
    if "resolves" in summary:
        out["resolves"] = summary["resolves"]
    out["static_seconds"] = summary["static_seconds"]
    out["stretches"] = summary["stretches"]
    out["session"] = summary["session"]["terms"]
    out["floor_terms"] = {
        "bias_instability": np.asarray(used.bias_instability).tolist(),
        "rrw": np.asarray(used.rrw).tolist(),
        "detection_z": DETECTION_Z,
    }
    out["points"] = [
        {
            "temperature": p["temp"],
            "stretches": p["stretches"],
            "seconds": p["seconds"],
            **({"terms": p["terms"]} if "terms" in p else {}),
        }
        for p in summary["points"]
    ]
    return out
