"""Validation of the interpolated calibration on data it never saw (seed 000, Tables 3-4).

Each temperature point is held out in turn: its holds are compensated by

* ``uncompensated`` — the raw output;
* ``single`` — one calibration at the reference temperature point (the point nearest
  ``reference_temperature``, or the next nearest when that point is the one held out): the
  "traditional" method of seed 000 Section 4;
* ``interpolated`` — the grid without the held-out point, interpolated to each hold's
  temperature.

Because every grid point is fitted on its own holds only, dropping a point from the grid is
the same as re-calibrating without it. With a single usable temperature point there is
nothing to interpolate from: each of its holds is then compensated by the fit of the other
holds (leave one hold out), and ``single`` equals ``interpolated``.

Errors are compensated rate minus true rate, per output axis, on hold means (systematic
error) and on samples (total error: the hold-mean error plus the within-hold scatter mapped
through the compensation). Beside them stand the noise floor — what a perfect calibration
would leave: within-hold std / sqrt(n) for hold means, the within-hold std for samples —
and the expected RMS: the floor plus the calibration's own uncertainty carried to each hold
(coefficient covariance through the interpolation weights and the model's columns), i.e.
what an adequate model should reach. Per-sample variances neglect correlation between the
axes' noise, which the compensation mixes by only the cross-axis terms (about 2 %).

Held-out end points lie outside the remaining grid, where calibrations are clamped rather
than extrapolated; their holds are reported but the headline figures use interior points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .errors import IdentifiabilityError
from .model import Model, columns_of, fit, observation_floor
from .terms import AXES
from .thermal import GridFit

METHODS = ("uncompensated", "single", "interpolated")


@dataclass(frozen=True)
class Validation:
    holds: pd.DataFrame              # one row per hold and method
    table_holds: pd.DataFrame        # Mean/RMS per rotating axis x output axis, hold means
    table_samples: pd.DataFrame      # the same on samples
    by_temperature: pd.DataFrame     # RMS per held-out temperature and method
    summary: dict = field(default_factory=dict)


def compensate_holds(model: Model, coefs, w: np.ndarray, rate: np.ndarray, data: dict
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Errors (n, 3) of compensated hold means, and the compensation matrices A (n, 3, 3)
    that map output errors to compensated errors."""
    w_true, J = model.compensate(coefs, w, data)
    return w_true - rate, np.linalg.inv(J)


def reference_point(temps: np.ndarray, reference_temperature: float, exclude: int | None = None) -> int:
    order = np.argsort(np.abs(temps - reference_temperature), kind="stable")
    return int(next((i for i in order if i != exclude), order[0]))


def validate(model: Model, obs: pd.DataFrame, grid_fit: GridFit, *,
             reference_temperature: float = 25.0) -> Validation:
    """Compare the three methods on every hold with a calibration that never saw it.

    With two or more temperature points each point is held out in turn; with one (or one
    that could be fitted) each hold of that point is left out of its own fit instead.
    """
    grid = grid_fit.grid
    P = len(grid.temperatures)
    n = len(obs)
    data = columns_of(obs)
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    w, rate, sd = stack("gyro"), stack("rate"), stack("std")
    if P >= 2:
        plan = _leave_temperature_out(grid_fit, data, reference_temperature)
        basis = "temperature"
    else:
        plan = _leave_hold_out(model, grid_fit, data)
        basis = "hold"
    interp, interp_cov, single, single_cov, clamped, ref_temp = plan

    # Design rows in the grid's coefficient order, split by output axis, to carry the
    # calibration's own uncertainty to each hold: var_a = x_a' V x_a.
    design = model.design(data)
    x = np.column_stack([np.broadcast_to(design[c], (n,)) for c in grid.names])
    masks = [np.array([name.split(".")[1] == a for name in grid.names]) for a in AXES]

    def calibration_var(V):
        return np.column_stack([np.einsum("nc,ncd,nd->n", x * m, V, x * m) for m in masks])

    as_coefs = lambda V: {name: V[:, j] for j, name in enumerate(grid.names)}  # noqa: E731
    err_s, A_s = compensate_holds(model, as_coefs(single), w, rate, data)
    err_i, A_i = compensate_holds(model, as_coefs(interp), w, rate, data)
    mapped = lambda A, v: np.einsum("nij,nj->ni", A ** 2, v)  # noqa: E731
    errors = {"uncompensated": (w - rate, sd ** 2, np.zeros((n, 3))),
              "single": (err_s, mapped(A_s, sd ** 2), mapped(A_s, calibration_var(single_cov))),
              "interpolated": (err_i, mapped(A_i, sd ** 2), mapped(A_i, calibration_var(interp_cov)))}

    floor = observation_floor(data)
    base = obs[["hold", "point", "point_temp", "temp", "mount", "axis", "ref_rate", "n",
                "std_x", "std_y", "std_z"]].reset_index(drop=True)
    base = base.assign(clamped=clamped, reference_temp=ref_temp,
                       **{f"floor_{a}": floor[:, i] for i, a in enumerate(AXES)})
    holds = pd.concat([base] * len(METHODS), ignore_index=True)
    holds["method"] = pd.Categorical(np.repeat(METHODS, n), categories=METHODS)
    for k, kind in enumerate(("err", "var", "cal")):
        stacked = np.concatenate([errors[m][k] for m in METHODS])
        for i, a in enumerate(AXES):
            holds[f"{kind}_{a}"] = stacked[:, i]

    interior = ~clamped
    use = interior if interior.any() else np.ones(n, dtype=bool)
    scored = holds[np.tile(use, len(METHODS))]
    overall = {m: _pooled_rms(errors[m][0][use]) for m in METHODS}
    floor_all = _pooled_rms(floor[use])
    expected = float(np.sqrt(np.mean(floor[use] ** 2 + errors["interpolated"][2][use])))
    summary = {
        "validation_rms": overall["interpolated"],
        "noise_floor": floor_all,
        "excess": overall["interpolated"] / floor_all if floor_all > 0 else float("inf"),
        "expected_rms": expected,
        "excess_over_expected": overall["interpolated"] / expected if expected > 0 else float("inf"),
        "uncompensated_rms": overall["uncompensated"],
        "single_rms": overall["single"],
        "reference_temperature": float(grid.temperatures[
            reference_point(grid.temperatures, reference_temperature)]),
        "held_out": basis,
        "scored": "interior" if interior.any() else "all",
        "holds_scored": int(use.sum()),
        "temperature_points": int(P),
    }
    return Validation(holds, _table(scored, samples=False), _table(scored, samples=True),
                      _by_temperature(holds), summary)


def _leave_temperature_out(grid_fit: GridFit, data: dict, reference_temperature: float):
    """Per hold: coefficients and their covariance from the grid without its own point
    (interpolated) and from the reference point (single; the next nearest when the
    reference is the point held out)."""
    grid = grid_fit.grid
    cov = np.array([f.covariance for f in grid_fit.fits])          # (P, C, C)
    n, P = len(data["temp"]), len(grid.temperatures)
    C = len(grid.names)
    temp, point = data["temp"], data["point"].astype(int)
    grid_index = {int(p): k for k, p in enumerate(
        grid_fit.points.loc[grid_fit.points["used"], "point"])}
    interp, single = np.empty((n, C)), np.empty((n, C))
    interp_cov, single_cov = np.empty((n, C, C)), np.empty((n, C, C))
    clamped, ref_temp = np.empty(n, dtype=bool), np.empty(n)
    for p in np.unique(point):
        rows = np.flatnonzero(point == p)
        k = grid_index.get(int(p))
        keep = np.arange(P) != k
        loo = grid.without(k) if k is not None else grid
        W = loo.weights(temp[rows])
        interp[rows] = W @ loo.values
        interp_cov[rows] = np.einsum("np,pcd->ncd", W ** 2, cov[keep])
        ref = reference_point(grid.temperatures, reference_temperature, exclude=k)
        single[rows], single_cov[rows] = grid.values[ref], cov[ref]
        clamped[rows] = loo.outside(temp[rows])
        ref_temp[rows] = grid.temperatures[ref]
    return interp, interp_cov, single, single_cov, clamped, ref_temp


def _leave_hold_out(model: Model, grid_fit: GridFit, data: dict):
    """One usable temperature point: each of its holds is compensated by the fit of the
    point's other holds (holds of points that could not be fitted use the whole fit)."""
    grid = grid_fit.grid
    n = len(data["temp"])
    point = data["point"].astype(int)
    fitted = int(grid_fit.points.loc[grid_fit.points["used"], "point"].iloc[0])
    coefs = np.tile(grid.values[0], (n, 1))
    cov = np.tile(grid_fit.fits[0].covariance, (n, 1, 1))
    mine = np.flatnonzero(point == fitted)
    for i in mine:
        others = mine[mine != i]
        try:
            result = fit(model, {k: v[others] for k, v in data.items()})
        except IdentifiabilityError:
            coefs[i], cov[i] = np.nan, np.nan  # only this hold excites something
            continue
        coefs[i], cov[i] = result.values, result.covariance
    clamped = point != fitted
    bad = ~np.isfinite(coefs).all(axis=1)
    clamped |= bad
    coefs[bad], cov[bad] = grid.values[0], grid_fit.fits[0].covariance
    return coefs, cov, coefs.copy(), cov.copy(), clamped, np.full(n, grid.temperatures[0])


def _pooled_rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def _table(holds: pd.DataFrame, *, samples: bool) -> pd.DataFrame:
    """Mean and RMS of the error per rotating axis x output axis for each method."""
    rotating = np.array([AXES.index(a) for a in holds["axis"]])
    method = holds["method"].cat.codes.to_numpy()
    group = rotating * len(METHODS) + method
    n = holds["n"].to_numpy(dtype=float)
    size = 3 * len(METHODS)
    total = lambda v: np.bincount(group, weights=v, minlength=size).reshape(3, len(METHODS))  # noqa: E731
    weight = total(n if samples else np.ones_like(n))
    count = total(np.ones_like(n))
    rows = []
    for r, rot in enumerate(AXES):
        if count[r].sum() == 0:
            continue
        for a in AXES:
            e = holds[f"err_{a}"].to_numpy()
            cal = holds[f"cal_{a}"].to_numpy()
            if samples:
                mean = total(n * e)[r] / weight[r]
                rms = np.sqrt(total(n * (e ** 2 + holds[f"var_{a}"].to_numpy()))[r] / weight[r])
                noise = holds[f"std_{a}"].to_numpy() ** 2
                floor = np.sqrt(total(n * noise)[r] / weight[r])
                expected = np.sqrt(total(n * (noise + cal))[r] / weight[r])
            else:
                mean = total(e)[r] / weight[r]
                rms = np.sqrt(total(e ** 2)[r] / weight[r])
                noise = holds[f"floor_{a}"].to_numpy() ** 2
                floor = np.sqrt(total(noise)[r] / weight[r])
                expected = np.sqrt(total(noise + cal)[r] / weight[r])
            row = {"rotating": rot, "output": a}
            for m, name in enumerate(METHODS):
                row[f"{name}_mean"], row[f"{name}_rms"] = mean[m], rms[m]
            row["noise_floor"] = floor[METHODS.index("interpolated")]
            row["expected_rms"] = expected[METHODS.index("interpolated")]
            row["holds"] = int(count[r, METHODS.index("interpolated")])
            rows.append(row)
    table = pd.DataFrame(rows)
    with np.errstate(divide="ignore", invalid="ignore"):
        table["gain_vs_uncompensated_pct"] = 100.0 * (1 - table["interpolated_rms"] / table["uncompensated_rms"])
        table["gain_vs_single_pct"] = 100.0 * (1 - table["interpolated_rms"] / table["single_rms"])
    order = ["rotating", "output"] + [f"{m}_{s}" for m in METHODS for s in ("mean", "rms")] + \
        ["noise_floor", "expected_rms", "gain_vs_uncompensated_pct", "gain_vs_single_pct", "holds"]
    return table[order]


def _by_temperature(holds: pd.DataFrame) -> pd.DataFrame:
    """RMS (pooled over output axes) per temperature point and method."""
    points, index = np.unique(holds["point"].to_numpy(), return_inverse=True)
    method = holds["method"].cat.codes.to_numpy()
    group = index * len(METHODS) + method
    size = len(points) * len(METHODS)
    mean = lambda v: (np.bincount(group, weights=v, minlength=size)  # noqa: E731
                      / np.maximum(np.bincount(group, minlength=size), 1)).reshape(len(points), -1)
    e2 = mean(sum(holds[f"err_{a}"].to_numpy() ** 2 for a in AXES) / 3)
    f2 = mean(sum(holds[f"floor_{a}"].to_numpy() ** 2 for a in AXES) / 3)
    first = np.unique(index, return_index=True)[1]
    counts = np.bincount(index) // len(METHODS)
    clamped = np.bincount(index, weights=holds["clamped"].to_numpy(dtype=float)) \
        == np.bincount(index)
    out = pd.DataFrame({"point": points, "temp": holds["point_temp"].to_numpy()[first],
                        "holds": counts, "clamped": clamped})
    for m, name in enumerate(METHODS):
        out[f"{name}_rms"] = np.sqrt(e2[:, m])
    out["noise_floor"] = np.sqrt(f2[:, METHODS.index("interpolated")])
    return out
