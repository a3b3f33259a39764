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
would leave: the session's noise model at each hold's duration for hold means
(:func:`gyrocal.fit.model.observation_floor`; within-hold std / sqrt(n) without one), the
within-hold std for samples —
and the expected RMS: the floor plus the calibration's own uncertainty carried to each hold
(coefficient covariance through the interpolation weights and the model's columns), i.e.
what an adequate model should reach. Per-sample variances neglect correlation between the
axes' noise, which the compensation mixes by only the cross-axis terms (about 2 %).

Held-out end points lie outside the remaining grid, where calibrations are clamped rather
than extrapolated; their holds are reported but the headline figures use interior points.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict

import numpy as np
import pandas as pd

from ..io.errors import GyrocalError, IdentifiabilityError
from ..terms import AXES
from . import METHODS
from .model import Model, columns_of, fit, observation_floor, subset_design


class ValidationFigures(TypedDict):
    """The figures every summary of a model's error has, a fit's own residuals' too
    (:func:`gyrocal.diagnosis.evaluation.in_sample_summary`), deg/s where a rate."""

    validation_rms: float  # the interpolated calibration's error on the scored holds
    noise_floor: float
    excess: float  # validation_rms over noise_floor
    expected_rms: float  # the floor and the calibration's own uncertainty
    excess_over_expected: float
    held_out: str  # "temperature" or "hold"; "none" in sample
    holds_scored: int


class ValidationSummary(ValidationFigures):
    """A validation's headline figures (validation.json's ``summary``), deg/s where a rate."""

    uncompensated_rms: float
    single_rms: float
    reference_temperature: float  # °C, the one-point calibration's point
    scored: str  # "interior", "left-out" or "all"
    temperature_points: int
    model_kind: str
    points_not_left_out: NotRequired[int]
    # points logged on their own (a gap in the log before and after: each may hold a power-on
    # of the unit) scored with their holds' mean error per axis taken out (own_power_ons)
    rezeroed_rms: NotRequired[float]
    rezeroed_stretches: NotRequired[int]


@dataclass(frozen=True)
class Validation:
    holds: pd.DataFrame  # one row per hold and method
    table_holds: pd.DataFrame  # Mean/RMS per rotating axis x output axis, hold means
    table_samples: pd.DataFrame  # the same on samples
    by_temperature: pd.DataFrame  # RMS per held-out temperature and method
    # the common model's ValidationSummary; a protocol with a validation of its own adds keys
    summary: Mapping[str, Any]
    free_points: pd.DataFrame | None = None  # continuous models: free_point_fits()


@dataclass
class _Plan:
    """For every hold: the calibration that never saw it, as coefficient arrays of a model,
    with their covariance; and the temperature its terms are evaluated at (clamped to that
    calibration's range, never extrapolated)."""

    model: Model
    names: tuple[str, ...]
    values: np.ndarray  # (n, C)
    cov: np.ndarray  # (n, C, C)
    temp: np.ndarray  # (n,)


def _compensate(plan: _Plan, w, rate, sd, data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Errors (n, 3) of compensated hold means, the per-sample noise variances and the
    calibration-uncertainty variances carried through the compensation."""
    coefs = {name: plan.values[:, j] for j, name in enumerate(plan.names)}
    covariates = {**data, "temp": plan.temp}
    w_true, J = plan.model.compensate(coefs, w, covariates)
    A2 = np.linalg.inv(J) ** 2
    # Design rows at the compensated rates, split by output axis: var_a = x_a' V x_a.
    design = plan.model.design({**covariates, **{f"rate_{a}": w_true[:, i] for i, a in enumerate(AXES)}})
    x = np.column_stack([np.broadcast_to(design[c], (len(w),)) for c in plan.names])
    cal = np.column_stack(
        [
            np.einsum("nc,ncd,nd->n", x * m, plan.cov, x * m)
            for m in [np.array([n.split(".")[1] == a for n in plan.names]) for a in AXES]
        ]
    )
    return w_true - rate, np.einsum("nij,nj->ni", A2, sd**2), np.einsum("nij,nj->ni", A2, cal)


def reference_point(
    temps: np.ndarray,
    reference_temperature: float,
    exclude: int | None = None,
    eligible: np.ndarray | None = None,
) -> int:
    """The point nearest the reference temperature, other than ``exclude``, among the
    ``eligible`` ones (those with holds enough for a one-point calibration) where any is."""
    order = np.argsort(np.abs(temps - reference_temperature), kind="stable")
    ok = [i for i in order if i != exclude]
    if eligible is not None and any(eligible[i] for i in ok):
        ok = [i for i in ok if eligible[i]]
    return int(ok[0] if ok else order[0])


def single_point_model(model: Model, *, series: bool = True) -> Model:
    """The model's terms a single temperature point can determine: the traditional
    one-temperature calibration of the same model. ``series=False`` leaves out terms of
    time or the temperature's history too, which one point of a continuous model need not
    excite (a spline of time over the whole session)."""
    return Model(
        tuple(t for t in model.terms if not t.varies_with_temperature and (series or not t.reads_series()))
    )


def validate(
    model: Model, obs: pd.DataFrame, fitted, *, reference_temperature: float = 25.0, every_point: bool = True
) -> Validation:
    """Compare the three methods on every hold with a calibration that never saw it.

    ``fitted`` is a :class:`~gyrocal.fit.thermal.GridFit` or :class:`ContinuousFit`. With two
    or more temperature points each point is held out in turn; with one, each hold of that
    point is left out of its own fit instead.

    A session-wide term that only one point's holds excite (a step in time inside one
    soak) makes that point impossible to leave out. ``every_point`` then raises
    :class:`CannotLeaveOut` (the diagnosis compares models on the same holds); otherwise
    that point's holds are compensated by the whole fit and not scored, and the summary
    counts them (``points_not_left_out``), so that a calibration with such a term is still
    made and validated on the other points.
    """
    n = len(obs)
    data = model.transform_inputs(columns_of(obs))
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    w, rate, sd = stack("gyro"), stack("rate"), stack("std")
    held = _held_out(model, fitted, data, reference_temperature, every_point=every_point)
    zero = np.zeros((n, 3))
    errors = {
        "uncompensated": (w - rate, sd**2, zero),
        "single": _compensate(held.single, w, rate, sd, data),
        "interpolated": _compensate(held.interpolated, w, rate, sd, data),
    }
    floor = observation_floor(data)
    holds = _hold_table(obs, held, floor, errors)
    interior = ~held.clamped
    # Holds a point could not be left out for are never scored: with no interior hold, the
    # ones left out (outside the remaining range) are.
    in_sample = held.in_sample
    use = interior if interior.any() else (~in_sample if (~in_sample).any() else np.ones(n, dtype=bool))
    scored = holds[np.tile(use, len(METHODS))]
    summary = _summary(model, fitted, data, held, errors, floor, use, reference_temperature)
    if held.held_out == "temperature":
        rezeroed = own_power_ons(obs, errors["interpolated"][0], floor, use)
        if rezeroed is not None:
            summary["rezeroed_rms"], summary["rezeroed_stretches"] = rezeroed
    return Validation(
        holds, _table(scored, samples=False), _table(scored, samples=True), _by_temperature(holds), summary
    )


@dataclass(frozen=True)
class _HeldOut:
    """For every hold, the calibrations that never saw it: ``interpolated`` (the model without
    its point, or without the hold) and ``single`` (the one-point calibration at the reference
    point), whether its temperature lies outside the first's range (``clamped``), the
    reference point's temperature, which holds could not be left out (``in_sample``), and
    what was held out (``temperature`` or ``hold``)."""

    interpolated: _Plan
    single: _Plan
    clamped: np.ndarray
    reference_temp: np.ndarray
    in_sample: np.ndarray
    held_out: str


def _held_out(
    model: Model, fitted, data: Mapping[str, np.ndarray], reference_temperature: float, *, every_point: bool
) -> _HeldOut:
    """Each temperature point left out in turn where two or more were fitted (a continuous
    model whose temperature terms need every point: each hold instead); with one point, each
    of its holds."""
    n = len(data["temp"])
    used = fitted.used_points()
    if len(used) >= 2:
        try:
            interp, single, clamped, ref_temp, in_sample = _leave_temperature_out(
                model, fitted, data, reference_temperature, every_point=every_point
            )
            return _HeldOut(interp, single, clamped, ref_temp, in_sample, "temperature")
        except CannotLeaveOut:
            if fitted.kind == "grid":  # a joint grid too: its holds cannot be left out alone
                raise
            # A continuous model whose temperature terms need every point (a degree-2
            # polynomial on three points): only holds can be left out.
        interp, clamped = _leave_hold_out(model, fitted, data, every_point=True)
        ref_temp = data["temp"].copy()
    else:
        interp, clamped = _leave_hold_out(model, fitted, data)
        ref_temp = np.full(n, float(fitted.points.loc[fitted.points["used"], "temp"].iloc[0]))
    return _HeldOut(interp, interp, clamped, ref_temp, np.zeros(n, dtype=bool), "hold")


def _hold_table(obs: pd.DataFrame, held: _HeldOut, floor: np.ndarray, errors: dict) -> pd.DataFrame:
    """One row per hold and method: the hold, its floor, and each method's error, noise
    variance and calibration variance per output axis."""
    n = len(obs)
    base = obs[
        ["hold", "point", "point_temp", "temp", "mount", "axis", "ref_rate", "n", "std_x", "std_y", "std_z"]
    ].reset_index(drop=True)
    base = base.assign(
        clamped=held.clamped,
        reference_temp=held.reference_temp,
        **{f"floor_{a}": floor[:, i] for i, a in enumerate(AXES)},
    )
    holds = pd.concat([base] * len(METHODS), ignore_index=True)
    holds["method"] = pd.Categorical(np.repeat(METHODS, n), categories=METHODS)
    for k, kind in enumerate(("err", "var", "cal")):
        stacked = np.concatenate([errors[m][k] for m in METHODS])
        for i, a in enumerate(AXES):
            holds[f"{kind}_{a}"] = stacked[:, i]
    return holds


def _summary(
    model: Model,
    fitted,
    data: Mapping[str, np.ndarray],
    held: _HeldOut,
    errors: dict,
    floor: np.ndarray,
    use: np.ndarray,
    reference_temperature: float,
) -> ValidationSummary:
    """The headline figures over the scored holds ``use``."""
    interior = ~held.clamped
    used = fitted.used_points()
    overall = {m: _pooled_rms(errors[m][0][use]) for m in METHODS}
    floor_all = _pooled_rms(floor[use])
    expected = float(np.sqrt(np.mean(floor[use] ** 2 + errors["interpolated"][2][use])))
    point_temps = fitted.points.loc[fitted.points["used"], "temp"].to_numpy(dtype=float)
    one_point_fits = _one_point_fits(
        fitted, len(single_point_model(model, series=fitted.kind == "grid").names)
    )
    summary: ValidationSummary = {
        "validation_rms": overall["interpolated"],
        "noise_floor": floor_all,
        "excess": overall["interpolated"] / floor_all if floor_all > 0 else float("inf"),
        "expected_rms": expected,
        "excess_over_expected": overall["interpolated"] / expected if expected > 0 else float("inf"),
        "uncompensated_rms": overall["uncompensated"],
        "single_rms": overall["single"],
        "reference_temperature": float(
            point_temps[reference_point(point_temps, reference_temperature, eligible=one_point_fits)]
        ),
        "held_out": held.held_out,
        "scored": "interior" if interior.any() else ("left-out" if held.in_sample.any() else "all"),
        "holds_scored": int(use.sum()),
        "temperature_points": int(len(used)),
        "model_kind": fitted.kind,
    }
    if held.in_sample.any():
        summary["points_not_left_out"] = int(np.unique(data["point"][held.in_sample]).size)
    return summary


def _one_point_fits(fitted, coefficients: int) -> np.ndarray:
    """Per used point, whether its holds can fit a one-point calibration of ``coefficients``
    (over the three axes, each fitted on its own) with a residual left (a burst log's sparse
    end may hold one window)."""
    points = fitted.points.set_index("point").loc[fitted.used_points()]
    return points["holds"].to_numpy() > -(-coefficients // len(AXES))


def _leave_temperature_out(
    model: Model,
    fitted,
    data: Mapping[str, np.ndarray],
    reference_temperature: float,
    *,
    every_point: bool = True,
):
    """Per hold: the calibration without its own point (interpolated, or refitted for a
    continuous model) and the one-point calibration at the reference point (the next
    nearest when the reference is the point held out); with ``every_point`` false, a point
    that cannot be left out gets the whole fit, its holds marked as not scored."""
    n, C = len(data["temp"]), len(fitted.names)
    temp, point = data["temp"], data["point"].astype(int)
    used = fitted.used_points()
    point_temps = fitted.points.set_index("point").loc[used, "temp"].to_numpy(dtype=float)
    one_point = single_point_model(model, series=fitted.kind == "grid")
    Cs = len(one_point.names)
    single_fits: dict[int, object] = {}
    eligible = _one_point_fits(fitted, Cs)

    def single_fit(p):
        if p not in single_fits:
            if fitted.kind == "grid":
                single_fits[p] = fitted.point_fit(p)
            else:
                keep = point == p
                try:
                    single_fits[p] = fit(one_point, {k: v[keep] for k, v in data.items()})
                except IdentifiabilityError as exc:
                    # every point too thin for a one-point calibration (a sweep's narrow points)
                    raise IdentifiabilityError(
                        f"no temperature point holds observations enough for the one-point "
                        f"calibration the validation compares with (the one at "
                        f"{temp[keep].mean():.1f} °C: {exc}); wider points gather more "
                        "(point_span in the protocol's options: of the config)",
                        parameters=exc.parameters,
                    ) from None
        return single_fits[p]

    interp = _Plan(model, fitted.names, np.empty((n, C)), np.empty((n, C, C)), temp.copy())
    single = _Plan(one_point, tuple(one_point.names), np.empty((n, Cs)), np.empty((n, Cs, Cs)), temp.copy())
    clamped, ref_temp = np.empty(n, dtype=bool), np.empty(n)
    in_sample_rows = np.zeros(n, dtype=bool)
    not_left_out = 0
    for p in np.unique(point):
        rows = np.flatnonzero(point == p)
        loo = fitted.leave_out(int(p))
        if loo is None:
            if every_point or not_left_out + 1 >= len(used):
                raise CannotLeaveOut(
                    f"leaving out the point at {temp[rows].mean():.1f} °C leaves nothing to calibrate from"
                )
            not_left_out += 1
            in_sample_rows[rows] = True
        source = fitted if loo is None else loo
        interp.values[rows] = source.coefficients_at(temp[rows])
        interp.cov[rows] = source.covariance_at(temp[rows])
        lo, hi = source.coefficients.span
        interp.temp[rows] = np.clip(temp[rows], lo, hi)
        clamped[rows] = True if loo is None else loo.outside(temp[rows])
        k = reference_point(
            point_temps,
            reference_temperature,
            exclude=used.index(int(p)) if int(p) in used else None,
            eligible=eligible,
        )
        ref = single_fit(used[k])
        single.values[rows], single.cov[rows] = ref.values, ref.covariance
        ref_temp[rows] = point_temps[k]
    return interp, single, clamped, ref_temp, in_sample_rows


def _leave_hold_out(model: Model, fitted, data: Mapping[str, np.ndarray], *, every_point: bool = False):
    """One usable temperature point (or, ``every_point``, one continuous fit over all
    points): each of its holds is compensated by the fit of the other holds (holds of
    points that could not be fitted use the whole fit)."""
    n = len(data["temp"])
    point = data["point"].astype(int)
    whole = fitted.fits[0]
    plan = _Plan(
        model,
        fitted.names,
        np.tile(whole.values, (n, 1)),
        np.tile(whole.covariance, (n, 1, 1)),
        data["temp"].copy(),
    )
    fitted_rows = np.isin(point, fitted.used_points()) if every_point else point == fitted.used_points()[0]
    mine = np.flatnonzero(fitted_rows)
    clamped = ~fitted_rows
    own = {k: v[mine] for k, v in data.items()}
    model.check_inputs(own)
    design = model.design(own)  # each refit keeps the columns of its holds
    for j, i in enumerate(mine):
        others = np.arange(len(mine)) != j
        try:
            result = fit(model, {k: v[others] for k, v in own.items()}, design=subset_design(design, others))
        except IdentifiabilityError:
            clamped[i] = True  # only this hold excites something: scored with the whole fit
            continue
        plan.values[i], plan.cov[i] = result.values, result.covariance
    return plan, clamped


def held_out_errors(fitted, columns: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The errors (n, 3) of holds (``columns``: :func:`.model.columns_of`) that ``fitted``
    never saw, compensated by its model (nonlinear settings at their fitted values) at their
    temperatures, clamped to the fit's range as the validation clamps, and their floors."""
    model = fitted.model
    data = model.transform_inputs(columns)
    lo, hi = fitted.coefficients.span
    temp = np.clip(data["temp"], lo, hi)
    plan = _Plan(model, fitted.names, fitted.coefficients_at(temp), fitted.covariance_at(temp), temp)
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    errors, _, _ = _compensate(plan, stack("gyro"), stack("rate"), stack("std"), data)
    return errors, observation_floor(data)


class CannotLeaveOut(GyrocalError):
    """A temperature point cannot be left out: what remains does not determine the model."""


# A stretch between the log's gaps with fewer holds than this joins the one before it: a
# logger that pauses between holds would otherwise give each hold a power-on of its own and
# leave nothing to judge.
MIN_STRETCH_HOLDS = 6


def stretches_between_gaps(resumed: np.ndarray | None, n: int) -> np.ndarray:
    """Each hold's stretch between the log's gaps (codes 0, 1, ... in time; ``resumed``,
    the chain's ``resumed_at``), stretches of fewer than :data:`MIN_STRETCH_HOLDS` holds
    joined to the one before (the first to the one after). The unit may have been switched
    off in any gap, and the log cannot tell."""
    if resumed is None:
        return np.zeros(n, dtype=int)
    codes = np.unique(resumed, return_inverse=True)[1]
    kept = np.flatnonzero(np.bincount(codes) >= MIN_STRETCH_HOLDS)
    if kept.size == 0:
        return np.zeros(n, dtype=int)
    owner = np.maximum(np.searchsorted(kept, np.arange(codes.max() + 1), side="right") - 1, 0)
    return owner[codes]


def stretch_means(runs: np.ndarray, values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per stretch (``runs``, codes 0, 1, ... as :func:`stretches_between_gaps` gives), the
    weighted mean of each column of ``values`` (n, c): ``weights`` (n,) shared by the columns
    or (n, c) one per column. Shape (stretches, c)."""
    count = int(runs.max()) + 1
    weights = np.broadcast_to(weights.reshape(len(runs), -1), values.shape)
    columns = range(values.shape[1])
    totals = np.stack([np.bincount(runs, weights=weights[:, j], minlength=count) for j in columns], 1)
    sums = np.stack(
        [np.bincount(runs, weights=values[:, j] * weights[:, j], minlength=count) for j in columns], 1
    )
    return sums / totals


def own_power_ons(
    obs: pd.DataFrame, errors: np.ndarray, floor: np.ndarray, use: np.ndarray
) -> tuple[float, int] | None:
    """The held-out error (RMS over the scored holds ``use``) with each stretch between the
    log's gaps that holds one temperature point alone rezeroed: its mean error per axis
    (weighted by the holds' floors) taken out, and the RMS scaled by sqrt(N / (N − k)) for
    the k means over N holds, as a fit's residuals count its parameters. A unit switched off
    between set points (or a log that stops between them) takes a turn-on bias at each that
    no interpolation from the other points knows; the log cannot tell it from a bias that
    changes between the points in the same way, so neither is the calibration's failure to
    interpolate. None where no point is logged on its own."""
    if "resumed_at" not in obs or "point" not in obs or not use.any():
        return None
    runs = stretches_between_gaps(obs["resumed_at"].to_numpy(float), len(obs))
    points = obs["point"].to_numpy()
    alone = pd.Series(points).groupby(runs).nunique().to_numpy() == 1
    take = use & alone[runs]
    if not take.any():
        return None
    codes, run = np.unique(runs[take], return_inverse=True)
    rezeroed = errors.copy()
    rezeroed[take] -= stretch_means(run, errors[take], 1.0 / np.maximum(floor[take], 1e-300) ** 2)[run]
    count, scored = codes.size, int(use.sum())
    if scored <= count:
        return None
    return _pooled_rms(rezeroed[use]) * float(np.sqrt(scored / (scored - count))), count


def _pooled_rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def _table(holds: pd.DataFrame, *, samples: bool) -> pd.DataFrame:
    """Mean and RMS of the error per rotating axis x output axis for each method."""
    # the rotating axis' index, by column (a loop over an Arrow string column is slow)
    axis = holds["axis"].to_numpy(dtype=object)
    rotating = np.select([axis == a for a in AXES], range(len(AXES)), -1)
    if (rotating < 0).any():
        raise ValueError(f"rotating axis {axis[rotating < 0][0]!r} is none of {', '.join(AXES)}")
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
                rms = np.sqrt(total(n * (e**2 + holds[f"var_{a}"].to_numpy()))[r] / weight[r])
                noise = holds[f"std_{a}"].to_numpy() ** 2
                floor = np.sqrt(total(n * noise)[r] / weight[r])
                expected = np.sqrt(total(n * (noise + cal))[r] / weight[r])
            else:
                mean = total(e)[r] / weight[r]
                rms = np.sqrt(total(e**2)[r] / weight[r])
                noise = holds[f"floor_{a}"].to_numpy() ** 2
                floor = np.sqrt(total(noise)[r] / weight[r])
                expected = np.sqrt(total(noise + cal)[r] / weight[r])
            row: dict[str, Any] = {"rotating": rot, "output": a}
            for m, name in enumerate(METHODS):
                row[f"{name}_mean"], row[f"{name}_rms"] = mean[m], rms[m]
            row["noise_floor"] = floor[METHODS.index("interpolated")]
            row["expected_rms"] = expected[METHODS.index("interpolated")]
            row["holds"] = int(count[r, METHODS.index("interpolated")])
            rows.append(row)
    table = pd.DataFrame(rows)
    with np.errstate(divide="ignore", invalid="ignore"):
        table["gain_vs_uncompensated_pct"] = 100.0 * (
            1 - table["interpolated_rms"] / table["uncompensated_rms"]
        )
        table["gain_vs_single_pct"] = 100.0 * (1 - table["interpolated_rms"] / table["single_rms"])
    order = (
        ["rotating", "output"]
        + [f"{m}_{s}" for m in METHODS for s in ("mean", "rms")]
        + ["noise_floor", "expected_rms", "gain_vs_uncompensated_pct", "gain_vs_single_pct", "holds"]
    )
    return table[order]


def _by_temperature(holds: pd.DataFrame) -> pd.DataFrame:
    """RMS (pooled over output axes) per temperature point and method."""
    points, index = np.unique(holds["point"].to_numpy(), return_inverse=True)
    method = holds["method"].cat.codes.to_numpy()
    group = index * len(METHODS) + method
    size = len(points) * len(METHODS)

    def mean(v):
        return (
            np.bincount(group, weights=v, minlength=size) / np.maximum(np.bincount(group, minlength=size), 1)
        ).reshape(len(points), -1)

    e2 = mean(sum(holds[f"err_{a}"].to_numpy() ** 2 for a in AXES) / 3)
    f2 = mean(sum(holds[f"floor_{a}"].to_numpy() ** 2 for a in AXES) / 3)
    first = np.unique(index, return_index=True)[1]
    counts = np.bincount(index) // len(METHODS)
    clamped = np.bincount(index, weights=holds["clamped"].to_numpy(dtype=float)) == np.bincount(index)
    out = pd.DataFrame(
        {"point": points, "temp": holds["point_temp"].to_numpy()[first], "holds": counts, "clamped": clamped}
    )
    for m, name in enumerate(METHODS):
        out[f"{name}_rms"] = np.sqrt(e2[:, m])
    out["noise_floor"] = np.sqrt(f2[:, METHODS.index("interpolated")])
    return out


def free_point_fits(obs: pd.DataFrame) -> pd.DataFrame:
    """The seed-000 terms fitted freely at each temperature point (``temp``, each
    coefficient and its ``_stderr``): what a temperature-continuous model's K and B are
    checked against, since where the two disagree its temperature dependence is wrong. No
    rows when the points are too few to fit."""
    from .model import DEFAULT_TERMS
    from .thermal import fit_grid

    try:
        grid = fit_grid(Model.from_spec(DEFAULT_TERMS), obs).coefficients
    except GyrocalError:
        return pd.DataFrame({"temp": np.array([], dtype=float)})
    return pd.DataFrame(
        {
            "temp": grid.temperatures,
            **{n: grid.values[:, j] for j, n in enumerate(grid.names)},
            **{f"{n}_stderr": grid.stderr[:, j] for j, n in enumerate(grid.names)},
        }
    )
