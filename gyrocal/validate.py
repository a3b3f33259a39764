"""Leave-one-temperature-out validation of the interpolated calibration (seed 000, Tables 3-4).

Each temperature point is held out in turn: its holds are compensated by

* ``uncompensated`` — the raw output;
* ``single`` — one calibration at the reference temperature point (the point nearest
  ``reference_temperature``, or the next nearest when that point is the one held out): the
  "traditional" method of seed 000 Section 4;
* ``interpolated`` — the grid without the held-out point, interpolated to each hold's
  temperature.

Because every grid point is fitted on its own holds only, dropping a point from the grid is
the same as re-calibrating without it. Errors are compensated rate minus true rate, per
output axis, on hold means (systematic error) and on samples (total error: the hold-mean
error plus the within-hold scatter mapped through the compensation). The noise floor is
what a perfect calibration would leave: within-hold std / sqrt(n) for hold means, the
within-hold std for samples. Per-sample variances neglect correlation between the axes'
noise, which the compensation mixes by only the cross-axis terms (about 2 %).

Held-out end points lie outside the remaining grid, where calibrations are clamped rather
than extrapolated; their holds are reported but the headline figures use interior points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .model import Model, columns_of, observation_floor
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


def compensate_holds(model: Model, coefs, w: np.ndarray, rate: np.ndarray, sd: np.ndarray,
                     data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Errors (n, 3) of compensated hold means and the per-sample error variances (n, 3)."""
    w_true, J = model.compensate(coefs, w, data)
    A = np.linalg.inv(J)
    return w_true - rate, np.einsum("nij,nj->ni", A ** 2, sd ** 2)


def reference_point(temps: np.ndarray, reference_temperature: float, exclude: int | None = None) -> int:
    order = np.argsort(np.abs(temps - reference_temperature), kind="stable")
    return int(next((i for i in order if i != exclude), order[0]))


def validate(model: Model, obs: pd.DataFrame, grid_fit: GridFit, *,
             reference_temperature: float = 25.0) -> Validation:
    grid = grid_fit.grid
    P = len(grid.temperatures)
    n = len(obs)
    data = columns_of(obs)
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    w, rate, sd = stack("gyro"), stack("rate"), stack("std")
    temp = data["temp"]
    point = data["point"].astype(int)
    grid_index = {int(p): k for k, p in enumerate(
        grid_fit.points.loc[grid_fit.points["used"], "point"])}

    # Coefficients each hold is compensated with, held-out point by held-out point.
    interp = np.empty((n, len(grid.names)))
    single = np.empty((n, len(grid.names)))
    clamped = np.ones(n, dtype=bool)
    held_out = np.zeros(n, dtype=bool)
    ref_temp = np.empty(n)
    for p in np.unique(point):
        rows = np.flatnonzero(point == p)
        k = grid_index.get(int(p))
        loo = grid.without(k) if k is not None and P > 1 else grid
        ref = reference_point(grid.temperatures, reference_temperature,
                              exclude=k if P > 1 else None)
        interp[rows] = loo.weights(temp[rows]) @ loo.values
        single[rows] = grid.values[ref]
        if P > 1:
            clamped[rows] = loo.outside(temp[rows])
            held_out[rows] = k is not None
        ref_temp[rows] = grid.temperatures[ref]
    as_coefs = lambda V: {name: V[:, j] for j, name in enumerate(grid.names)}  # noqa: E731
    errors = {"uncompensated": (w - rate, sd ** 2),
              "single": compensate_holds(model, as_coefs(single), w, rate, sd, data),
              "interpolated": compensate_holds(model, as_coefs(interp), w, rate, sd, data)}

    floor = observation_floor(data)
    base = obs[["hold", "point", "point_temp", "temp", "mount", "axis", "ref_rate", "n",
                "std_x", "std_y", "std_z"]].reset_index(drop=True)
    base = base.assign(clamped=clamped, held_out=held_out, reference_temp=ref_temp,
                       **{f"floor_{a}": floor[:, i] for i, a in enumerate(AXES)})
    holds = pd.concat([base] * len(METHODS), ignore_index=True)
    holds["method"] = pd.Categorical(np.repeat(METHODS, n), categories=METHODS)
    err = np.concatenate([errors[m][0] for m in METHODS])
    var = np.concatenate([errors[m][1] for m in METHODS])
    for i, a in enumerate(AXES):
        holds[f"err_{a}"] = err[:, i]
        holds[f"var_{a}"] = var[:, i]

    interior = ~clamped
    basis = "interior" if interior.any() else "all"
    scored = holds[np.tile(interior, len(METHODS))] if interior.any() else holds
    overall = {m: _pooled_rms(errors[m][0][interior if interior.any() else slice(None)])
               for m in METHODS}
    floor_all = _pooled_rms(floor[interior] if interior.any() else floor)
    summary = {
        "validation_rms": overall["interpolated"],
        "noise_floor": floor_all,
        "excess": overall["interpolated"] / floor_all if floor_all > 0 else float("inf"),
        "uncompensated_rms": overall["uncompensated"],
        "single_rms": overall["single"],
        "reference_temperature": float(grid.temperatures[
            reference_point(grid.temperatures, reference_temperature)]),
        "basis": basis,
        "holds_scored": int(interior.sum()) if interior.any() else n,
        "temperature_points": int(P),
    }
    return Validation(holds, _table(scored, samples=False), _table(scored, samples=True),
                      _by_temperature(holds), summary)


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
            if samples:
                mean = total(n * e)[r] / weight[r]
                rms = np.sqrt(total(n * (e ** 2 + holds[f"var_{a}"].to_numpy()))[r] / weight[r])
                floor = np.sqrt(total(n * holds[f"std_{a}"].to_numpy() ** 2)[r] / weight[r])
            else:
                mean = total(e)[r] / weight[r]
                rms = np.sqrt(total(e ** 2)[r] / weight[r])
                floor = np.sqrt(total(holds[f"floor_{a}"].to_numpy() ** 2)[r] / weight[r])
            row = {"rotating": rot, "output": a}
            for m, name in enumerate(METHODS):
                row[f"{name}_mean"], row[f"{name}_rms"] = mean[m], rms[m]
            row["noise_floor"] = floor[METHODS.index("interpolated")]
            row["holds"] = int(count[r, METHODS.index("interpolated")])
            rows.append(row)
    table = pd.DataFrame(rows)
    with np.errstate(divide="ignore", invalid="ignore"):
        table["gain_vs_uncompensated_pct"] = 100.0 * (1 - table["interpolated_rms"] / table["uncompensated_rms"])
        table["gain_vs_single_pct"] = 100.0 * (1 - table["interpolated_rms"] / table["single_rms"])
    order = ["rotating", "output"] + [f"{m}_{s}" for m in METHODS for s in ("mean", "rms")] + \
        ["noise_floor", "gain_vs_uncompensated_pct", "gain_vs_single_pct", "holds"]
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
