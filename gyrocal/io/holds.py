"""What every protocol's segmentation produces, and the parts they build it from:
observations in the hold schema (``hold, t_start, t_end, duration, n, mount, …, point,
point_temp``: :func:`hold_table`), their temperature points (:func:`temperature_points`)
and temperature rates (:func:`regression_rate`, :func:`thirds_rate`), the session's
timeline (:func:`timeline`) and the :class:`Segmentation` that carries them. From this table
on one code path fits, validates, diagnoses and reports every protocol."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pandas as pd

from . import AXES
from .log import GYRO, MOUNTS, RigLog

TIMELINE_BUCKETS = 2000


def timeline(log: RigLog, buckets: int = TIMELINE_BUCKETS) -> pd.DataFrame:
    """The log's samples in at most ``buckets`` consecutive buckets (:func:`bucketed`)."""
    t = log.column("t")
    return bucketed(t, t, log.column("temp"), log.column("ref_rate"), [log.column(c) for c in GYRO], buckets)


def bucketed(
    t_first: np.ndarray,
    t_last: np.ndarray,
    temp: np.ndarray,
    ref: np.ndarray,
    gyro: Sequence[np.ndarray],
    buckets: int = TIMELINE_BUCKETS,
) -> pd.DataFrame:
    """A session's timeline for plots: consecutive rows (samples, or blocks of them with
    their first and last time) in at most ``buckets`` buckets, each with its time span, mean
    temperature and the range of the reference and of each gyro axis (``gyro``: one array
    per axis), so that a second of handling motion still shows in a day-long plot."""
    n = len(t_first)
    starts = np.arange(0, n, max(1, -(-n // buckets)))
    ends = np.r_[starts[1:], n] - 1
    out = {
        "t_start": t_first[starts],
        "t_end": t_last[ends],
        "temp": np.add.reduceat(temp, starts) / (ends - starts + 1),
        "ref_min": np.minimum.reduceat(ref, starts),
        "ref_max": np.maximum.reduceat(ref, starts),
    }
    for name, g in zip(GYRO, gyro, strict=True):
        out[f"{name}_min"] = np.minimum.reduceat(g, starts)
        out[f"{name}_max"] = np.maximum.reduceat(g, starts)
    return pd.DataFrame(out)


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop (exclusive) indices of the True runs of a boolean array: how the
    segmenters cut a flag per sample or block into stretches."""
    d = np.diff(np.r_[0, np.asarray(mask).astype(np.int8), 0])
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


class TemperaturePoints(NamedTuple):
    """Each observation's temperature point (numbered in order of temperature) and the
    point's mean temperature."""

    point: np.ndarray
    point_temp: np.ndarray


def temperature_points(temp, *, span: float | None = None, gap: float | None = None) -> TemperaturePoints:
    """Group observations into temperature points, numbered in order of temperature: bins
    ``span`` °C wide aligned to 0 °C (a continuous sweep), or (``gap``) chains of
    observations each within ``gap`` °C of the next warmer one (a turntable's set points,
    however far apart).

    Chains average with pandas' compensated sum, bins with numpy's plain one: point
    temperatures go into calibration files to the last bit, so each keeps its own."""
    temp = np.asarray(temp, float)
    if (span is None) == (gap is None):
        raise ValueError("temperature_points takes span or gap")
    if gap is not None:
        order = np.argsort(temp, kind="stable")
        point = np.empty(len(temp), dtype=np.int64)
        point[order] = np.r_[0, np.cumsum(np.diff(temp[order]) > gap)]
        means = pd.Series(temp).groupby(point).transform("mean").to_numpy()
        return TemperaturePoints(point, means)
    bins = np.floor(temp / span).astype(np.int64)
    _, point = np.unique(bins, return_inverse=True)
    sums = np.bincount(point, weights=temp)
    counts = np.bincount(point)
    return TemperaturePoints(point.astype(np.int64), (sums / counts)[point])


class SlopeSums(NamedTuple):
    """Sums over each range of samples for the least-squares slope of temperature on time:
    the count, Σt, ΣT, Σt², ΣtT (times and temperatures from an origin the caller chooses;
    the slope does not depend on it, its rounding does, so each range's own first sample
    is the best)."""

    n: np.ndarray
    t: np.ndarray
    temp: np.ndarray
    tt: np.ndarray
    t_temp: np.ndarray


def range_sums(t: np.ndarray, temp: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> SlopeSums:
    """:class:`SlopeSums` over the sample ranges ``lo[i]:hi[i]`` (any, overlapping or
    apart), from prefix sums with the log's first time as the origin."""
    tc = t - t[0]
    csum = np.vstack([np.zeros(4), np.cumsum(np.c_[tc, temp, tc * tc, tc * temp], axis=0)])
    s = csum[hi] - csum[lo]
    return SlopeSums((hi - lo).astype(float), s[:, 0], s[:, 1], s[:, 2], s[:, 3])


def regression_rate(sums: SlopeSums) -> np.ndarray:
    """The temperature rate (°C/min) of each range: the least-squares slope of temperature
    on time; 0 where the range has no spread in time (a single sample)."""
    n = sums.n
    with np.errstate(divide="ignore", invalid="ignore"):
        var = sums.tt - sums.t**2 / n
        slope = (sums.t_temp - sums.t * sums.temp / n) / var
    return np.where(np.isfinite(slope) & (var > 0), 60.0 * slope, 0.0)


def thirds_rate(temp: np.ndarray, t_mid: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The temperature rate (°C/min) over the rows ``lo:hi`` of a series of block means at
    times ``t_mid``, from the means of its first and last thirds.

    89 % as efficient as a regression slope, and free of the cancellation a regression on
    absolute times suffers: the estimator for block statistics, where the samples of a log
    too large to keep are gone."""
    third = np.maximum((hi - lo) // 3, 1)
    p_T = np.r_[0.0, np.cumsum(temp, dtype=np.float64)]
    p_t = np.r_[0.0, np.cumsum(t_mid - t_mid[0])]
    T_a = (p_T[lo + third] - p_T[lo]) / third
    T_b = (p_T[hi] - p_T[hi - third]) / third
    t_a = (p_t[lo + third] - p_t[lo]) / third
    t_b = (p_t[hi] - p_t[hi - third]) / third
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = 60.0 * (T_b - T_a) / (t_b - t_a)
    return np.where(np.isfinite(rate), rate, 0.0)


def thirds_rate_error(noise: float, t_mid: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The standard error (°C/min) of :func:`thirds_rate` over ``lo:hi`` from the series'
    scatter ``noise`` (°C per row); infinite where the range spans no time."""
    third = np.maximum((hi - lo) // 3, 1)
    spacing = (t_mid[hi - 1] - t_mid[lo]) * 2.0 / 3.0
    with np.errstate(divide="ignore", invalid="ignore"):
        sd = 60.0 * noise * np.sqrt(2.0 / third) / spacing
    return np.where(np.isfinite(sd), sd, np.inf)


def hold_table(
    *,
    t_start,
    t_end,
    n,
    mount: np.ndarray,
    mount_source: str | np.ndarray,
    ref_rate,
    gyro,
    std,
    temp,
    temp_rate,
    point,
    point_temp,
    own: Mapping[str, np.ndarray] | None = None,
) -> pd.DataFrame:
    """Observations in the hold schema; ``gyro``/``std`` are (k, 3), ``mount_source`` one
    word for every hold or one per hold. ``own``: the protocol's own columns, placed before
    the temperature point."""
    mount = np.asarray(mount, dtype=object)
    axis = np.array([m[1] for m in mount], dtype=object)
    sign = np.where(np.array([m[0] for m in mount]) == "+", 1.0, -1.0)
    ref_rate = np.asarray(ref_rate, float)
    k = len(ref_rate)
    return pd.DataFrame(
        {
            "hold": np.arange(k, dtype=np.int64),
            "t_start": t_start,
            "t_end": t_end,
            "duration": np.asarray(t_end, float) - np.asarray(t_start, float),
            "n": np.asarray(n, np.int64),
            "mount": pd.Categorical(mount, categories=list(MOUNTS)),
            "axis": axis.astype(str),
            "sign": sign,
            "mount_source": mount_source,
            "ref_rate": ref_rate,
            **{f"rate_{a}": np.where(axis == a, sign * ref_rate, 0.0) for a in AXES},
            **{f"gyro_{a}": gyro[:, i] for i, a in enumerate(AXES)},
            **{f"std_{a}": std[:, i] for i, a in enumerate(AXES)},
            "temp": temp,
            "temp_rate": temp_rate,
            **(own or {}),
            "point": point,
            "point_temp": point_temp,
        }
    )


def segments_of_holds(obs: pd.DataFrame, detail) -> pd.DataFrame:
    """The segment table of a segmentation that keeps every hold it finds (it rejects
    nothing): one ``hold`` row per observation, ``detail`` saying what the hold is."""
    return pd.DataFrame(
        {
            "kind": "hold",
            "reason": "",
            "detail": detail,
            "t_start": obs["t_start"],
            "t_end": obs["t_end"],
            "ref_rate": obs["ref_rate"],
            "hold": obs["hold"],
        }
    ).astype({"kind": "string", "reason": "string", "detail": "string"})


def no_stable_periods() -> pd.DataFrame:
    """The stable-temperature periods of a segmentation that finds none of its own."""
    return pd.DataFrame({"t_start": [], "t_end": [], "temp": []}, dtype=float)


@dataclass(frozen=True)
class Segmentation:
    """Result of a protocol's segmentation: one row per accepted hold, plus what else was
    found."""

    observations: pd.DataFrame
    segments: pd.DataFrame  # every phase: hold, soak, ramp, gap, transient, rejected
    stable_periods: pd.DataFrame  # t_start, t_end, temp of stable-temperature stretches
    timeline: pd.DataFrame  # the session in at most TIMELINE_BUCKETS buckets, for plots
    info: dict = field(default_factory=dict)

    def rejected(self) -> pd.DataFrame:
        return self.segments[self.segments["kind"] == "rejected"].reset_index(drop=True)

    def counts(self) -> pd.DataFrame:
        """Accepted holds per temperature point (rows) and mount (columns)."""
        obs = self.observations
        table = pd.crosstab(obs["point_temp"].round(2), obs["mount"].astype(str))
        return table.reindex(columns=[m for m in MOUNTS if m in table.columns])
