"""What every protocol's segmentation produces: observations in the turntable's hold
schema (``hold, t_start, t_end, duration, n, mount, …, point, point_temp``), the session's
timeline and the :class:`Segmentation` that carries them. From this table on one code path
fits, validates, diagnoses and reports every protocol."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from . import AXES
from .log import GYRO, MOUNTS, RigLog

TIMELINE_BUCKETS = 2000


def timeline(log: RigLog, buckets: int = TIMELINE_BUCKETS) -> pd.DataFrame:
    """The log in at most ``buckets`` consecutive buckets (the turntable timeline's columns)."""
    t = log.column("t")
    n = len(t)
    starts = np.arange(0, n, max(1, -(-n // buckets)))
    ends = np.r_[starts[1:], n] - 1
    ref = log.column("ref_rate")
    out = {
        "t_start": t[starts],
        "t_end": t[ends],
        "temp": np.add.reduceat(log.column("temp"), starts) / (ends - starts + 1),
        "ref_min": np.minimum.reduceat(ref, starts),
        "ref_max": np.maximum.reduceat(ref, starts),
    }
    for name in GYRO:
        g = log.column(name)
        out[f"{name}_min"] = np.minimum.reduceat(g, starts)
        out[f"{name}_max"] = np.maximum.reduceat(g, starts)
    return pd.DataFrame(out)


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop (exclusive) indices of the True runs of a boolean array: how the
    segmenters cut a flag per sample or block into stretches."""
    d = np.diff(np.r_[0, np.asarray(mask).astype(np.int8), 0])
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def temperature_points(temp: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    """Group observations into temperature points ``span`` °C wide (bins aligned to 0 °C),
    numbered in order of temperature; returns (point, the point's mean temperature)."""
    bins = np.floor(np.asarray(temp, float) / span).astype(np.int64)
    _, point = np.unique(bins, return_inverse=True)
    sums = np.bincount(point, weights=temp)
    counts = np.bincount(point)
    return point.astype(np.int64), (sums / counts)[point]


def hold_table(
    *,
    t_start,
    t_end,
    n,
    mount: np.ndarray,
    mount_source: str,
    ref_rate,
    gyro,
    std,
    temp,
    temp_rate,
    point,
    point_temp,
) -> pd.DataFrame:
    """Observations in the turntable's hold schema; ``gyro``/``std`` are (k, 3)."""
    mount = np.asarray(mount, dtype=object)
    axis = np.array([m[1] for m in mount], dtype=object)
    sign = np.where(np.array([m[0] for m in mount]) == "+", 1.0, -1.0)
    ref_rate = np.asarray(ref_rate, float)
    k = len(ref_rate)
    out = pd.DataFrame(
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
            "point": point,
            "point_temp": point_temp,
        }
    )
    return out


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment`: one row per accepted hold, plus what else was found."""

    observations: pd.DataFrame
    segments: pd.DataFrame  # every phase: hold, soak, ramp, gap, transient, rejected
    stable_periods: pd.DataFrame  # t_start, t_end, temp of stable-temperature stretches
    timeline: pd.DataFrame  # the session in at most 2000 buckets, for plots
    info: dict = field(default_factory=dict)

    def rejected(self) -> pd.DataFrame:
        return self.segments[self.segments["kind"] == "rejected"].reset_index(drop=True)

    def counts(self) -> pd.DataFrame:
        """Accepted holds per temperature point (rows) and mount (columns)."""
        obs = self.observations
        table = pd.crosstab(obs["point_temp"].round(2), obs["mount"].astype(str))
        return table.reindex(columns=[m for m in MOUNTS if m in table.columns])
