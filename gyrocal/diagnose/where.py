"""Where the model fails: how far its residuals exceed their noise floor, and which
covariates carry the excess."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from ..terms import AXES
from ..thermal import in_sample
from .stats import chi2_sf

COVARIATES = {
    "temperature": "temp", "temperature rate": "temp_rate", "reference rate": "ref_rate",
    "|rate|": "abs_rate", "direction": "direction", "mount": "mount",
    "accel_x": "accel_x", "accel_y": "accel_y", "accel_z": "accel_z",
    "time": "time", "hold duration": "duration",
}
TIME_LIKE = ("time", "time within a temperature point", "hold duration")

# The grouping each covariate is measured against: rate effects show on the axis that
# turns, so they are judged within the rotating axis; drift within a temperature point is
# judged within the point (what changes there is time, not the temperature).
BASELINE = {"|rate|": "rotating axis", "direction": "rotating axis",
            "reference rate": "rotating axis", "time within a temperature point": "point"}


class FitQuality(NamedTuple):
    """The in-sample residuals of a fit against their floor."""

    chi2_red: dict[str, float]        # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float             # of χ² against its degrees of freedom
    resid: np.ndarray                 # (n, 3) deg/s, NaN on rows not fitted
    floor: np.ndarray                 # (n, 3)
    fitted_rows: np.ndarray           # (n,) bool

    @property
    def z(self) -> np.ndarray:
        return self.resid / self.floor


def fit_quality(evaluation, n: int) -> FitQuality:
    """χ²/dof and RMS ÷ floor overall and per output axis, and the χ² test's p-value."""
    fits = evaluation.fitted.fits
    resid, floor, rows = in_sample(evaluation.fitted, n)
    z = resid / floor
    dof = {a: sum(f.dof[a] for f in fits) for a in AXES}
    chi2 = {a: sum(f.chi2[a] for f in fits) for a in AXES}
    chi2_red = {"all": evaluation.chi2 / evaluation.dof, **{a: chi2[a] / dof[a] for a in AXES}}
    rms = {"all": float(np.sqrt(np.nanmean(z ** 2))),
           **{a: float(np.sqrt(np.nanmean(z[:, i] ** 2))) for i, a in enumerate(AXES)}}
    return FitQuality(chi2_red, rms, float(chi2_sf(evaluation.chi2, evaluation.dof)), resid, floor, rows)


def _partition(values: np.ndarray) -> np.ndarray:
    return np.unique(values.astype(str), return_inverse=True)[1]


def _between(z: np.ndarray, labels: np.ndarray) -> tuple[float, int]:
    """Σ over groups and axes of n · mean(z)², and the number of groups."""
    counts = np.bincount(labels)
    sums = np.stack([np.bincount(labels, weights=z[:, i]) for i in range(z.shape[1])], axis=1)
    used = counts > 0
    return float(np.sum(sums[used] ** 2 / counts[used, None])), int(used.sum())


def covariate_table(obs: pd.DataFrame, data: dict, z: np.ndarray, fitted_rows: np.ndarray,
                    dof: int, excess_significant: bool) -> tuple[list[dict], dict]:
    """Share of the excess χ² each covariate accounts for, ranked; heat maps.

    A covariate's share is what grouping the holds by it adds to the grouping it is judged
    against (:data:`BASELINE`; none for most), beyond chance: for unit-normal residuals the
    gain is χ² with 3 degrees of freedom per extra group, whose expectation is subtracted
    and whose p-value is reported. Covariates that group the holds identically (on three
    mounts: the mount, the rotating axis and the accelerometer) are one row, since the
    protocol cannot tell them apart. Without a significant excess there is nothing to share
    out: the shares are None."""
    frame = pd.DataFrame({k: v for k, v in data.items() if np.ndim(v) == 1})
    frame["mount"] = obs["mount"].astype(str).to_numpy()
    frame["rotating axis"] = obs["axis"].astype(str).to_numpy()
    frame["abs_rate"] = np.abs(data["ref_rate"])
    frame["direction"] = np.sign(data["ref_rate"])
    frame["time"] = (data["t_start"] - data["t_start"].min()) / 3600.0
    frame = frame[fitted_rows].reset_index(drop=True)
    zz = z[fitted_rows]
    total = float(np.sum(zz ** 2))
    excess = max(total - dof, 1e-9)
    labels: dict[str, np.ndarray] = {}
    for label, column in {**COVARIATES, "rotating axis": "rotating axis"}.items():
        if column not in frame:
            continue
        values = frame[column]
        if column not in ("mount", "rotating axis") and not np.isfinite(values.to_numpy(dtype=float)).all():
            continue
        if column in ("mount", "rotating axis") or values.nunique() <= 8:
            labels[label] = _partition(values.to_numpy())
        else:
            labels[label] = pd.qcut(values.rank(method="first"), 8, labels=False).to_numpy()
    if "point" in frame and frame["point"].nunique() > 1:
        point = _partition(frame["point"].to_numpy())
        within = np.zeros(len(frame), dtype=np.int64)
        for p in np.unique(point):  # time quartiles inside each point
            rows = np.flatnonzero(point == p)
            within[rows] = pd.qcut(frame["time"].iloc[rows].rank(method="first"),
                                   min(4, len(rows)), labels=False).to_numpy()
        labels["time within a temperature point"] = point * 4 + within
        labels["point"] = point
    # Covariates that group the holds the same way are one: the protocol confounds them.
    groups: list[list[str]] = []
    for label in labels:
        if label == "point":
            continue
        for g in groups:
            if same_partition(labels[g[0]], labels[label]):
                g.append(label)
                break
        else:
            groups.append([label])
    rows = []
    for names in groups:
        lead = names[0]
        base_name = BASELINE.get(lead)
        base = labels.get(base_name) if base_name else None
        base = np.zeros(len(frame), dtype=np.int64) if base is None else base
        joint = _partition(np.char.add(np.char.add(base.astype(str), "|"), labels[lead].astype(str)))
        ss_joint, k_joint = _between(zz, joint)
        ss_base, k_base = _between(zz, base)
        df = 3 * (k_joint - k_base)
        gain = ss_joint - ss_base
        p = float(chi2_sf(gain, df)) if df > 0 else 1.0
        share = min(max(gain - df, 0.0) / excess, 1.0) if excess_significant else None
        row = {"covariate": " = ".join(names) if len(names) > 1 else lead, "bins": int(k_joint),
               "share_of_excess": share, "p_value": p, "within": base_name,
               "chi2_beyond_chance": max(gain - df, 0.0)}
        if len(names) > 1:
            row["confounded"] = names
            row["reason"] = "these group the holds identically in this protocol: it cannot tell them apart"
        rows.append(row)
    rows.sort(key=lambda r: -(r["share_of_excess"] or 0.0))
    rms = lambda g: float(np.sqrt(np.mean(zz[g.to_numpy()] ** 2)))  # noqa: E731
    idx = pd.Series(np.arange(len(frame)))
    rate_bins = frame["ref_rate"].round(3).to_numpy()
    temp_bins = frame["temp"].round(0).to_numpy()
    heat = {
        "mount_by_rate": {f"{m}|{r}": rms(g) for (m, r), g in idx.groupby([frame["mount"].to_numpy(), rate_bins])},
        "temperature_by_rate": {f"{t}|{r}": rms(g) for (t, r), g in idx.groupby([temp_bins, rate_bins])},
    }
    return rows, heat


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two labellings split the holds into the same groups."""
    # Labels are small non-negative integers (_partition, qcut): count distinct pairs as
    # distinct integers, a hash rather than the sort of a row-wise unique.
    a, b = a.astype(np.int64), b.astype(np.int64)
    pairs = a * (int(b.max()) + 1) + b
    return len(np.unique(pairs)) == len(np.unique(a)) == len(np.unique(b))


def leftover(obs: pd.DataFrame, data: dict, evaluation) -> dict:
    """The covariate a fit's residuals still follow most, with its Bonferroni p-value and
    the share of χ²/dof it carries beyond chance."""
    resid, floor, rows = in_sample(evaluation.fitted, len(obs))
    table, _ = covariate_table(obs, data, np.nan_to_num(resid / floor), rows, evaluation.dof, True)
    worst = min(table, key=lambda r: r["p_value"])
    return {"covariate": worst["covariate"],
            "p_value": min(1.0, worst["p_value"] * len(table)),  # Bonferroni
            "chi2_red_share": worst["chi2_beyond_chance"] / max(evaluation.dof, 1)}
