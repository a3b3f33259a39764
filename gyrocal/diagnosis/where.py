"""Where the model fails: how far its residuals exceed their noise floor, and which
covariates carry the excess."""

from __future__ import annotations

from typing import Any, NamedTuple, TypedDict

import numpy as np
import pandas as pd

from ..fit.thermal import in_sample
from ..terms import AXES
from .stats import chi2_sf

COVARIATES = {
    "temperature": "temp",
    "temperature rate": "temp_rate",
    "reference rate": "ref_rate",
    "|rate|": "abs_rate",
    "direction": "direction",
    "mount": "mount",
    "accel_x": "accel_x",
    "accel_y": "accel_y",
    "accel_z": "accel_z",
    "time": "time",
    "hold duration": "duration",
    # histories: what came before the hold
    "step into the hold": "step",
    "previous hold's rate": "previous_rate",
    "temperature's direction": "temp_direction",
    "mounting": "mounting",
}
TIME_LIKE = ("time", "time within a temperature point", "hold duration")
HISTORY_ROWS = ("step into the hold", "previous hold's rate", "temperature's direction", "mounting")

# The grouping each covariate is measured against: rate effects show on the axis that
# turns, so they are judged within the rotating axis; drift within a temperature point is
# judged within the point (what changes there is time, not the temperature); the
# temperature's direction within the point (one direction per point is the point's own
# bias), each mounting within its mount (one offset per mount is an effect of orientation).
BASELINE = {
    "|rate|": "rotating axis",
    "direction": "rotating axis",
    "reference rate": "rotating axis",
    "time within a temperature point": "point",
    "step into the hold": "rotating axis",
    "previous hold's rate": "rotating axis",
    "temperature's direction": "point",
    "mounting": "mount",
}
# The width (°C) of the play operator that tells the temperature's direction of travel: a
# few times a sensor's noise, well below a protocol's steps.
DIRECTION_WIDTH_C = 1.0


class FitQuality(NamedTuple):
    """The in-sample residuals of a fit against their floor."""

    chi2_red: dict[str, float]  # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float  # of χ² against its degrees of freedom
    resid: np.ndarray  # (n, 3) deg/s, NaN on rows not fitted
    floor: np.ndarray  # (n, 3)
    fitted_rows: np.ndarray  # (n,) bool

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
    rms = {
        "all": float(np.sqrt(np.nanmean(z**2))),
        **{a: float(np.sqrt(np.nanmean(z[:, i] ** 2))) for i, a in enumerate(AXES)},
    }
    return FitQuality(chi2_red, rms, float(chi2_sf(evaluation.chi2, evaluation.dof)), resid, floor, rows)


def _partition(values: np.ndarray) -> np.ndarray:
    return np.unique(values.astype(str), return_inverse=True)[1]


def _between(z: np.ndarray, labels: np.ndarray) -> tuple[float, int]:
    """Σ over groups and axes of n · mean(z)², and the number of groups."""
    counts = np.bincount(labels)
    sums = np.stack([np.bincount(labels, weights=z[:, i]) for i in range(z.shape[1])], axis=1)
    used = counts > 0
    return float(np.sum(sums[used] ** 2 / counts[used, None])), int(used.sum())


class _Layout(NamedTuple):
    """How a session's holds group by each covariate: what :func:`covariate_table` needs
    besides the residuals, the same for every fit of the same holds."""

    labels: dict  # covariate label -> group of each fitted hold
    groups: list  # covariates that group the holds identically, each a list
    joints: list  # per group: (joint labels with its baseline, baseline labels)
    product_bins: dict  # input -> bins for the rate-product rows
    rates: np.ndarray  # (fitted holds, 3) true rates
    heat: dict  # map name -> [(cell key, rows)]
    own: np.ndarray  # (fitted holds, 3): the output is the hold's turning axis


# The diagnosis shares out the residuals of many fits of the same holds (every candidate's
# leftover): their grouping is made once. Entries keep their frames alive, so an id is not
# reused while cached.
_LAYOUTS: list = []


def _layout(obs: pd.DataFrame, data: dict, fitted_rows: np.ndarray) -> _Layout:
    for o, d, r, layout in _LAYOUTS:
        if o is obs and d is data and np.array_equal(r, fitted_rows):
            return layout
    frame = pd.DataFrame({k: v for k, v in data.items() if np.ndim(v) == 1})
    frame["mount"] = obs["mount"].astype(str).to_numpy()
    frame["rotating axis"] = obs["axis"].astype(str).to_numpy()
    frame["abs_rate"] = np.abs(data["ref_rate"])
    frame["direction"] = np.sign(data["ref_rate"])
    frame["time"] = (data["t_start"] - data["t_start"].min()) / 3600.0
    frame = frame.assign(**history_columns(obs, data))
    frame = frame[fitted_rows].reset_index(drop=True)
    labels: dict[str, np.ndarray] = {}
    for label, column in {**COVARIATES, "rotating axis": "rotating axis"}.items():
        if column not in frame:
            continue
        values = frame[column]
        if (
            column not in ("mount", "rotating axis", "mounting")
            and not np.isfinite(values.to_numpy(dtype=float)).all()
        ):
            continue
        if column in ("mount", "rotating axis", "mounting") or values.nunique() <= 8:
            labels[label] = _partition(values.to_numpy())
        else:
            labels[label] = pd.qcut(values.rank(method="first"), 8, labels=False).to_numpy()
    if "point" in frame and frame["point"].nunique() > 1:
        point = _partition(frame["point"].to_numpy())
        within = np.zeros(len(frame), dtype=np.int64)
        for p in np.unique(point):  # time quartiles inside each point
            rows = np.flatnonzero(point == p)
            within[rows] = pd.qcut(
                frame["time"].iloc[rows].rank(method="first"), min(4, len(rows)), labels=False
            ).to_numpy()
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
    joints = []
    for names in groups:
        base_name = BASELINE.get(names[0])
        base = labels.get(base_name) if base_name else None
        base = np.zeros(len(frame), dtype=np.int64) if base is None else base
        joint = _partition(np.char.add(np.char.add(base.astype(str), "|"), labels[names[0]].astype(str)))
        joints.append((joint, base))
    product_bins = {name: _partition(labels[name]) for name in PRODUCT_INPUTS if name in labels}
    rates = np.column_stack([np.asarray(data[f"rate_{a}"], dtype=float)[fitted_rows] for a in AXES])
    idx = pd.Series(np.arange(len(frame)))
    rate_bins = frame["ref_rate"].round(3).to_numpy()
    temp_bins = frame["temp"].round(0).to_numpy()
    heat = {
        "mount_by_rate": [
            (f"{m}|{r}", g.to_numpy()) for (m, r), g in idx.groupby([frame["mount"].to_numpy(), rate_bins])
        ],
        "temperature_by_rate": [
            (f"{t}|{r}", g.to_numpy()) for (t, r), g in idx.groupby([temp_bins, rate_bins])
        ],
    }
    own = frame["rotating axis"].to_numpy()[:, None] == np.array(AXES)[None, :]
    layout = _Layout(labels, groups, joints, product_bins, rates, heat, own)
    _LAYOUTS.insert(0, (obs, data, fitted_rows.copy(), layout))
    del _LAYOUTS[2:]
    return layout


def history_columns(obs: pd.DataFrame, data: dict) -> dict[str, np.ndarray]:
    """What came before each hold: the step of the reference rate into it and the rate it
    came from (0 after a remount: the table stood still while the unit was handled), the
    temperature's direction of travel (a play operator of :data:`DIRECTION_WIDTH_C` over the
    session's record, +1 rising, −1 falling), and its mounting (the stretch of consecutive
    holds on one mount)."""
    t = np.asarray(data["t_start"], dtype=float)
    ref = np.asarray(data["ref_rate"], dtype=float)
    before, stretch = _before_each_hold(obs, data, ref[:, None])
    previous = before[:, 0]
    out = {"step": ref - previous, "previous_rate": previous, "mounting": stretch}
    series = data.get("series")
    if series is not None and hasattr(series, "temp") and len(series.t) > 1:
        from ..terms.signals import temperature_play

        mid = 0.5 * (t + np.asarray(data["t_end"], dtype=float)) - series.t0
        temp = np.asarray(series.temp, dtype=float)
        # from a unit brought from the room, as the fit's play of the temperature starts
        state = 2.0 * (temp - temperature_play(temp, DIRECTION_WIDTH_C)) / DIRECTION_WIDTH_C
        out["temp_direction"] = np.round(np.interp(mid, series.t, state))
    return out


def one_way_points(obs: pd.DataFrame, data: dict, before: dict | None = None) -> dict[float, str] | None:
    """The temperature's direction of travel at each temperature point (+1 rising, −1
    falling, the first from the room; the session as one point where it has none), where
    every point saw one direction only; None where some point saw both, or the record
    cannot tell.

    A bias that depends on the direction the temperature came from (thermal hysteresis) is
    then constant within each point: each point's bias holds it, and no row or term of this
    session can see it. ``before``: :func:`history_columns`, when already computed."""
    way = (before if before is not None else history_columns(obs, data)).get("temp_direction")
    if way is None or not len(way):
        return None
    temps = np.asarray(data["temp"], dtype=float)
    points = np.asarray(obs["point"]) if "point" in obs else np.zeros(len(way), dtype=int)
    out = {}
    for p in np.unique(points):
        seen = set(np.unique(way[(points == p) & (way != 0)]).tolist())
        if len(seen) > 1:
            return None
        if seen:
            out[float(np.round(np.median(temps[points == p]), 1))] = int(seen.pop())
    return out or None


SETTLING_ROW = "settling within the hold"


def axis_steps(obs: pd.DataFrame, data: dict) -> np.ndarray:
    """(n, 3) the step of each axis's rate into each hold (deg/s): the hold's rate less the
    previous hold's on the same mounting, the whole rate after a remount (the table stood
    still while the unit was handled)."""
    rates = np.column_stack([np.asarray(data[f"rate_{a}"], dtype=float) for a in AXES])
    return rates - _before_each_hold(obs, data, rates)[0]


def mountings(obs: pd.DataFrame) -> np.ndarray:
    """Each hold's mounting: the stretch of consecutive holds on one mount, numbered in time."""
    return _in_time(obs, obs["t_start"].to_numpy(float))[2]


def _in_time(obs: pd.DataFrame, t_start) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The holds' order in time, whether each (in that order) starts a mounting, and each
    hold's mounting (in the holds' own order)."""
    n = len(obs)
    order = np.argsort(np.asarray(t_start, dtype=float), kind="stable")
    mount = obs["mount"].astype(str).to_numpy()[order] if "mount" in obs else np.zeros(n)
    stretch_start = np.r_[True, mount[1:] != mount[:-1]]
    stretch = np.empty(n, dtype=np.int64)
    stretch[order] = np.cumsum(stretch_start) - 1
    return order, stretch_start, stretch


def _before_each_hold(obs: pd.DataFrame, data: dict, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` (n, k) of the hold before each one in time on the same mounting (0 for the
    first after a remount: the table stood still while the unit was handled), and each
    hold's mounting (the stretch of consecutive holds on one mount, numbered in time)."""
    order, stretch_start, stretch = _in_time(obs, data["t_start"])
    ordered = values[order]
    before = np.empty_like(values)
    before[order] = np.where(stretch_start[:, None], 0.0, np.r_[np.zeros((1, values.shape[1])), ordered[:-1]])
    return before, stretch


def settling_row(obs: pd.DataFrame, data: dict) -> CovariateRow | None:
    """Inside each hold, the output's change from its first half to its second (``settle_*``,
    from segmentation) against the step of that axis's rate into the hold: a slow pole, a
    part of the output that follows the rate through a lag, leaves a change in proportion to
    the step. Per output axis a line with an intercept (a drift common to every hold, a
    warm-up's, is not the step's) by least squares; the slope's F-test uses the scatter about
    the line, so no noise model is assumed; the axes' p-values combined (Fisher). The slope
    is in parts of the step. None where segmentation kept no halves or nothing steps."""
    if not all(f"settle_{a}" in data for a in AXES) or "rate_x" not in data or "t_start" not in data:
        return None
    from .stats import f_sf, fisher_combined

    settle = np.column_stack([np.asarray(data[f"settle_{a}"], dtype=float) for a in AXES])
    steps = axis_steps(obs, data)
    slopes, p_values, used = {}, [], 0
    for i, a in enumerate(AXES):
        x, y = steps[:, i], settle[:, i]
        good = np.isfinite(x) & np.isfinite(y)
        x, y = x[good], y[good]
        if np.count_nonzero(x) < 3 or len(x) < 5:
            continue
        design = np.column_stack([np.ones_like(x), x])
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        ss1 = float(np.sum((y - design @ coef) ** 2))
        ss0 = float(np.sum((y - y.mean()) ** 2))
        dof = len(x) - 2
        if ss1 <= 0 or dof <= 0:
            continue
        p_values.append(float(f_sf((ss0 - ss1) / (ss1 / dof), 1, dof)))
        slopes[a] = float(coef[1])
        used = max(used, len(x))
    if not p_values:
        return None
    return {
        "covariate": SETTLING_ROW,
        "bins": used,
        "share_of_excess": None,
        "p_value": float(fisher_combined(*p_values)),
        "within": "the step into the hold",
        "chi2_beyond_chance": 0.0,
        "slope": slopes,
        "reason": "the output's change within each hold against the step of its rate into "
        "it (a separate test: no share of the hold means' excess)",
    }


def covariate_table(
    obs: pd.DataFrame, data: dict, z: np.ndarray, fitted_rows: np.ndarray, dof: int, excess_significant: bool
) -> tuple[list[CovariateRow], dict[str, Any]]:
    """Share of the excess χ² each covariate accounts for, ranked; heat maps.

    A covariate's share is what grouping the holds by it adds to the grouping it is judged
    against (:data:`BASELINE`; none for most), beyond chance: for unit-normal residuals the
    gain is χ² with 3 degrees of freedom per extra group, whose expectation is subtracted
    and whose p-value is reported. Covariates that group the holds identically (on three
    mounts: the mount, the rotating axis and the accelerometer) are one row, since the
    protocol cannot tell them apart. Without a significant excess there is nothing to share
    out: the shares are None."""
    layout = _layout(obs, data, fitted_rows)
    zz = z[fitted_rows]
    total = float(np.sum(zz**2))
    excess = max(total - dof, 1e-9)
    rows = []
    for names, (joint, base) in zip(layout.groups, layout.joints, strict=False):
        lead = names[0]
        ss_joint, k_joint = _between(zz, joint)
        ss_base, k_base = _between(zz, base)
        df = 3 * (k_joint - k_base)
        gain = ss_joint - ss_base
        p = float(chi2_sf(gain, df)) if df > 0 else 1.0
        share = min(max(gain - df, 0.0) / excess, 1.0) if excess_significant else None
        row = {
            "covariate": " = ".join(names) if len(names) > 1 else lead,
            "bins": int(k_joint),
            "share_of_excess": share,
            "p_value": p,
            "within": BASELINE.get(lead),
            "chi2_beyond_chance": max(gain - df, 0.0),
        }
        if len(names) > 1:
            row["confounded"] = names
            row["reason"] = "these group the holds identically in this protocol: it cannot tell them apart"
        rows.append(row)
    rows += _split_rows(layout, zz, excess, excess_significant)
    rows += _product_rows(layout.product_bins, zz, layout.rates, excess, excess_significant)
    rows.sort(key=lambda r: -(r["share_of_excess"] or 0.0))
    settling = settling_row(obs, data)
    if settling is not None:
        rows.append(settling)
    heat = {
        name: {key: float(np.sqrt(np.mean(zz[cell] ** 2))) for key, cell in cells}
        for name, cells in layout.heat.items()
    }
    return rows, heat


# Rate covariates whose rows are also split by output: the turning axis's own output and the
# two others (a rate's shape on its own axis, or the turning axis's rate seen on the others).
SPLIT = ("|rate|", "reference rate")
SPLIT_AXES = {"own axis": 1, "cross axes": 2}


def _split_rows(
    layout: _Layout, z: np.ndarray, excess: float, excess_significant: bool
) -> list[CovariateRow]:
    """The rate rows again, each output's residuals taken apart: on the axis that turns
    (``own axis``, one residual per hold) and on the two others (``cross axes``, two), each
    judged within the rotating axis beyond chance as the whole row is."""
    out = []
    for names, (joint, base) in zip(layout.groups, layout.joints, strict=False):
        covariate = next((n for n in names if n in SPLIT), None)
        if covariate is None:
            continue
        for axes, per_hold in SPLIT_AXES.items():
            mask = layout.own if axes == "own axis" else ~layout.own
            zm = np.where(mask, z, 0.0)
            ss_joint, k_joint = _between(zm, joint)
            ss_base, k_base = _between(zm, base)
            df = per_hold * (k_joint - k_base)
            gain = ss_joint - ss_base
            p = float(chi2_sf(gain, df)) if df > 0 else 1.0
            share = min(max(gain - df, 0.0) / excess, 1.0) if excess_significant else None
            out.append(
                {
                    "covariate": f"{covariate} ({axes})",
                    "bins": int(k_joint),
                    "share_of_excess": share,
                    "p_value": p,
                    "within": "rotating axis",
                    "chi2_beyond_chance": max(gain - df, 0.0),
                    "split": {"input": covariate, "axes": axes},
                }
            )
    return out


# Inputs whose product with the output axis's own rate (a scale changing with them) or the
# other axes' rates (cross-axis terms changing with them) the table also tries.
PRODUCT_INPUTS = ("time", "time within a temperature point", "temperature", "temperature rate")


def _product_rows(
    product_bins: dict, z: np.ndarray, rates: np.ndarray, excess: float, excess_significant: bool
) -> list[CovariateRow]:
    """Rows for products of the rates with an input: within each bin of the input, the
    residuals of each output axis regressed on its own rate (``own axis``: 1 degree of
    freedom per bin and axis) or on the two other rates (``cross axes``: 2). What the
    per-bin slopes explain is the gain, judged beyond chance as the other rows are. The fit
    has taken out one slope per temperature point already (its scale and cross-axis
    terms): what is left is a slope that changes with the input."""
    if not np.any(rates):
        return []
    out = []
    for name, bins in product_bins.items():
        for kind in ("own axis", "cross axes"):
            gain, df = _binned_slopes(bins, z, rates, own=kind == "own axis")
            if df == 0:
                continue
            p = float(chi2_sf(gain, df))
            share = min(max(gain - df, 0.0) / excess, 1.0) if excess_significant else None
            out.append(
                {
                    "covariate": f"rate × {name} ({kind})",
                    "bins": int(bins.max()) + 1,
                    "share_of_excess": share,
                    "p_value": p,
                    "within": None,
                    "chi2_beyond_chance": max(gain - df, 0.0),
                    "product": {"input": name, "axes": kind},
                }
            )
    return out


def _binned_slopes(bins: np.ndarray, z: np.ndarray, rates: np.ndarray, *, own: bool) -> tuple[float, int]:
    """What per-bin least-squares slopes of each axis' residuals on its own rate (one
    regressor) or on the two other rates (two) explain, summed over bins and axes, and
    their number (degrees of freedom), from per-bin sums (normal equations)."""
    k = int(bins.max()) + 1
    sums = lambda v: np.bincount(bins, weights=v, minlength=k)  # noqa: E731
    gain, df = 0.0, 0
    for i in range(3):
        if own:
            zw, ww = sums(z[:, i] * rates[:, i]), sums(rates[:, i] ** 2)
            used = ww > 0
            gain += float(np.sum(zw[used] ** 2 / ww[used]))
            df += int(used.sum())
            continue
        j, k = [b for b in range(3) if b != i]
        a, b, c = sums(rates[:, j] ** 2), sums(rates[:, j] * rates[:, k]), sums(rates[:, k] ** 2)
        u, v = sums(z[:, i] * rates[:, j]), sums(z[:, i] * rates[:, k])
        det = a * c - b * b
        full = det > 1e-9 * np.maximum(a * c, 1e-300)
        # Two regressors where they are not collinear in the bin, else the one that is there.
        gain += float(np.sum((c * u * u - 2 * b * u * v + a * v * v)[full] / det[full]))
        single = ~full & ((a > 0) | (c > 0))
        gain += float(
            np.sum(np.where(a > 0, u * u / np.where(a > 0, a, 1.0), v * v / np.where(c > 0, c, 1.0))[single])
        )
        df += 2 * int(full.sum()) + int(single.sum())
    return gain, df


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two labellings split the holds into the same groups."""
    # Labels are small non-negative integers (_partition, qcut): count distinct pairs as
    # distinct integers, a hash rather than the sort of a row-wise unique.
    a, b = a.astype(np.int64), b.astype(np.int64)
    pairs = a * (int(b.max()) + 1) + b
    return len(np.unique(pairs)) == len(np.unique(a)) == len(np.unique(b))


class CovariateRow(TypedDict, total=False):
    """A row of the covariate table (:func:`covariate_table`): the share of the excess χ²
    that a covariate's bins account for beyond chance, and its test; a split row names the
    input and axes it splits, a product row the input the rate multiplies; the settling row
    (:func:`settling_row`) carries its ``slope`` per axis."""

    covariate: str
    bins: int
    share_of_excess: float | None
    p_value: float
    chi2_beyond_chance: float
    within: str | None
    split: dict[str, str]
    product: dict[str, str]
    slope: dict[str, float]
    confounded: list[str]
    reason: str


class ShapeEstimate(TypedDict):
    """The residuals against the leading covariate's input (:func:`shape_estimate`), binned
    and smoothed per axis, for the report's figure."""

    covariate: str
    input: str
    unit: str
    of: str
    value_unit: str
    x: list[float]
    knots: list[float] | None
    axes: dict[str, dict[str, list[float]]]


class Leftover(TypedDict):
    """The covariate a fit's residuals still follow most (:func:`leftover`)."""

    covariate: str
    p_value: float
    chi2_red_share: float


def leftover(obs: pd.DataFrame, data: dict, evaluation) -> Leftover:
    """The covariate a fit's residuals still follow most, with its Bonferroni p-value and
    the share of χ²/dof it carries beyond chance."""
    resid, floor, rows = in_sample(evaluation.fitted, len(obs))
    table, _ = covariate_table(obs, data, np.nan_to_num(resid / floor), rows, evaluation.dof, True)
    worst = min(table, key=lambda r: r["p_value"])
    return {
        "covariate": worst["covariate"],
        "p_value": min(1.0, worst["p_value"] * len(table)),  # Bonferroni
        "chi2_red_share": worst["chi2_beyond_chance"] / max(evaluation.dof, 1),
    }


# The input a covariate row stands for, as a term reads it (the shape's x axis).
INPUT_OF = {
    "time": "t",
    "time within a temperature point": "t_point",
    "temperature": "temp",
    "temperature rate": "temp_rate",
    "|rate|": "abs_rate",
    "reference rate": "rate_own",
    "direction": "rate_own",
    "hold duration": "duration",
    "|rate| (own axis)": "abs_rate",
    "reference rate (own axis)": "rate_own",
    "|rate| (cross axes)": "rate_cross",
    "reference rate (cross axes)": "rate_cross",
}
INPUT_UNIT = {
    "t": "s",
    "t_point": "s",
    "temp": "degC",
    "temp_rate": "degC/min",
    "abs_rate": "deg/s",
    "rate_own": "deg/s",
    "rate_cross": "deg/s",
    "duration": "s",
}
SHAPE_KNOTS = 5
SHAPE_POINTS = 61


def input_values(obs: pd.DataFrame, data: dict, name: str) -> np.ndarray:
    """(n, 3) values of an input at the holds, per output axis (the same on the three but
    for the own-axis rate): time since the log's first sample or since its point's first
    hold (s), temperature, its rate, |reference rate|, the axis's own rate, hold length."""
    n = len(obs)
    if name in ("t", "t_point"):
        series = data.get("series")
        t0 = series.t0 if series is not None else float(np.min(data["t_start"]))
        x = 0.5 * (np.asarray(data["t_start"]) + np.asarray(data["t_end"])) - t0
        if name == "t_point" and "point" in data:
            start = pd.Series(x).groupby(np.asarray(data["point"])).transform("min").to_numpy()
            x = x - start
    elif name == "t_mount" and "mounted_at" in data:
        x = 0.5 * (np.asarray(data["t_start"]) + np.asarray(data["t_end"])) - np.asarray(data["mounted_at"])
    elif name == "abs_rate":
        x = np.abs(np.asarray(data["ref_rate"], dtype=float))
    elif name == "rate_own":
        return np.column_stack([np.asarray(data[f"rate_{a}"], dtype=float) for a in AXES])
    elif name == "rate_cross":  # the other axes' rate: on a turntable, the turning one's
        rates = np.column_stack([np.asarray(data[f"rate_{a}"], dtype=float) for a in AXES])
        return rates.sum(axis=1, keepdims=True) - rates
    else:
        x = np.asarray(data[name], dtype=float)
    return np.repeat(np.asarray(x, dtype=float)[:, None], 3, axis=1) if np.ndim(x) else np.full((n, 3), x)


def knots_for(values: np.ndarray, count: int = SHAPE_KNOTS) -> list[float] | None:
    """Knots at quantiles of an input's distinct values (None with fewer than three)."""
    distinct = np.unique(np.round(np.asarray(values, dtype=float)[np.isfinite(values)], 9))
    if distinct.size < 3:
        return None
    knots = np.quantile(distinct, np.linspace(0.0, 1.0, min(count, distinct.size)))
    knots = np.unique([float(f"{k:.4g}") for k in knots])  # as a person would write them
    return [float(k) for k in knots] if knots.size >= 3 else None


def shape_estimate(
    obs: pd.DataFrame, data: dict, quality: FitQuality, row: CovariateRow
) -> ShapeEstimate | None:
    """A smooth estimate of what the residuals of each output axis do against the input of a
    covariate row, with its ±2σ band: a natural cubic spline (knots at quantiles) fitted
    by weighted least squares to the residuals (deg/s), or for a product row to their
    slope against the own rate (a scale change, as a fraction). The band's σ comes from the
    fit's covariance scaled by its reduced χ² when that is above 1. None for a covariate
    without a numeric input (the mount) or with too few distinct values."""
    from ..terms.empirical import spline_basis

    product = row.get("product")
    label = product["input"] if product else row["covariate"].split(" = ")[0]
    name = INPUT_OF.get(label)
    if name is None or (product and product["axes"] != "own axis"):
        return None
    x_all = input_values(obs, data, name)
    rows = quality.fitted_rows
    rates = np.column_stack([np.asarray(data[f"rate_{a}"], dtype=float) for a in AXES])
    knots = knots_for(x_all[rows])
    if knots is None:
        return None
    grid = np.linspace(knots[0], knots[-1], SHAPE_POINTS)
    out = {
        "covariate": row["covariate"],
        "input": name,
        "unit": INPUT_UNIT[name],
        "of": "scale change" if product else "residual",
        "value_unit": "1" if product else "deg/s",
        "x": grid.tolist(),
        "knots": knots,
        "axes": {},
    }
    for i, a in enumerate(AXES):
        x, r, f = x_all[rows, i], quality.resid[rows, i], quality.floor[rows, i]
        design = np.column_stack([np.ones(len(x)), spline_basis(x, knots)])
        at = np.column_stack([np.ones(grid.size), spline_basis(grid, knots)])
        if product:
            design = design * rates[rows, i][:, None]
            if not np.any(design):
                continue
        w = 1.0 / f
        coef, _, rank, _ = np.linalg.lstsq(design * w[:, None], r * w, rcond=1e-9)
        if rank < design.shape[1]:
            continue
        chi2_red = float(np.sum(((r - design @ coef) * w) ** 2)) / max(len(r) - rank, 1)
        cov = np.linalg.inv((design * w[:, None]).T @ (design * w[:, None])) * max(chi2_red, 1.0)
        fit = at @ coef
        sigma = np.sqrt(np.einsum("ij,jk,ik->i", at, cov, at))
        out["axes"][a] = {
            "fit": fit.tolist(),
            "low": (fit - 2 * sigma).tolist(),
            "high": (fit + 2 * sigma).tolist(),
        }
    return out if out["axes"] else None
