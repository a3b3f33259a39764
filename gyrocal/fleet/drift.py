"""Drift audit: how a unit's calibration changes from session to session, and whether an
old calibration still holds on new data.

* :func:`parameter_changes` — each parameter at one temperature, per session in date order:
  its change since the previous session and since the first, the change's standard error,
  its significance, and a flag when it is both larger than a tolerance and significant.
* :func:`revalidate` — the previous session's calibration applied to the new session's hold
  means, scored as the validation stage scores a calibration (Mean/RMS per rotating ×
  output axis, against the noise floor).
* :func:`plot_drift` — parameters versus session date with error bars.

Parameters and their units are those of :func:`gyrocal.calibration.parameters.parameters_at` (scale in ppm,
misalignment in mrad, bias in deg/s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple, TypedDict

import numpy as np
import pandas as pd
from scipy.stats import chi2

from ..calibration.file import Calibration, load_calibration
from ..calibration.parameters import parameters_at
from ..fit.model import columns_of, observation_floor
from ..fit.validate import METHODS, _compensate, _Plan, _pooled_rms, _table, reference_point
from ..io.errors import ConfigError, InputError
from ..terms import AXES
from .limits import check_patterns, finite_number, match_pattern

Z_LIMIT = 3.0  # |z| above this is significant: two-sided p = 0.0027 per parameter and step


def _load(cal) -> Calibration:
    return cal if isinstance(cal, Calibration) else load_calibration(cal)


def parameter_changes(
    calibrations,
    *,
    temperature: float | None = None,
    tolerance: Mapping | None = None,
    z_limit: float = Z_LIMIT,
) -> pd.DataFrame:
    """Session-to-session changes of one device's parameters.

    ``calibrations`` (objects or file paths) are put in session-date order. Parameters are
    taken at ``temperature``, by default the first session's reference temperature, the same
    for every session (clamped to a session's calibrated span if outside it: column
    ``clamped``). A change's standard error is the root-sum-square of both sessions' errors
    (independent sessions), ``z = change / se``. A change is flagged when
    ``|change| > tolerance`` AND ``|z| > z_limit``: larger than what matters and larger than
    what the calibrations' own uncertainty explains (|z| > 3: a stable parameter is flagged
    0.27 % of the time per comparison). ``tolerance`` maps parameter patterns (wildcards,
    display units) to the change that matters; a parameter without one has tolerance 0
    (any significant change flags).

    Returns one row per session and parameter: device, batch, session, parameter, unit,
    temperature, clamped, value, stderr, change_prev, se_prev, z_prev, change_first,
    se_first, z_first, tolerance, flagged_prev, flagged_first, flagged, baseline. The first
    session (``baseline``) has changes, errors and z of 0 and is never flagged. z is ±inf
    only for a non-zero change between two calibrations that both report zero error.
    Parameters not in every session are left out (``attrs["left_out"]``).
    """
    sessions = _drift_sessions(calibrations, tolerance, z_limit)
    cals = sessions.calibrations
    T = float(cals[0].reference_temperature if temperature is None else temperature)
    values = _parameter_values(cals, T)
    out = _changes_frame(sessions, T, values)
    out.attrs["left_out"] = values.left_out
    return out


class _DriftSessions(NamedTuple):
    """One device's calibrations in session-date order, with the checked z limit and the
    tolerance of each parameter pattern."""

    calibrations: list[Calibration]
    device: str
    z_limit: float
    tolerance: dict[str, float]


def _drift_sessions(calibrations, tolerance: Mapping | None, z_limit: float) -> _DriftSessions:
    """The calibrations to compare, refused unless they are of one device and each names its
    session, and the z limit and tolerances refused unless they are numbers that make sense."""
    cals = [_load(c) for c in calibrations]
    if not cals:
        raise InputError("drift audit: no calibrations to compare")
    devices = sorted({str(c.meta.get("device")) for c in cals})
    if len(devices) > 1:
        raise InputError(f"drift audit compares one device's sessions, got devices {', '.join(devices)}")
    missing = [i for i, c in enumerate(cals) if not c.meta.get("session")]
    if missing:
        raise InputError(
            f"drift audit: calibration {missing[0] + 1} of device {devices[0]} has no session date"
        )
    z_limit = finite_number(z_limit, "z_limit", positive=True)
    tolerance = dict(tolerance or {})
    check_patterns(tolerance, "drift tolerance")
    tol_of = {p: finite_number(v, f"drift tolerance {p}") for p, v in tolerance.items()}
    if any(v < 0 for v in tol_of.values()):
        bad = next(p for p, v in tol_of.items() if v < 0)
        raise ConfigError(f"drift tolerance {bad} must be at least 0, got {tol_of[bad]!r}")
    order = sorted(range(len(cals)), key=lambda i: str(cals[i].meta["session"]))
    return _DriftSessions([cals[i] for i in order], devices[0], z_limit, tol_of)


class _ParameterValues(NamedTuple):
    """The parameters every session has, at one temperature: values and standard errors
    (sessions × parameters), whether each session's value was clamped to its calibrated
    span, and the parameters left out because some session lacks them."""

    names: list[str]
    units: list[str]
    values: np.ndarray
    stderr: np.ndarray
    clamped: np.ndarray
    left_out: list[str]


def _parameter_values(cals: list[Calibration], T: float) -> _ParameterValues:
    tables = [parameters_at(c, T).set_index("parameter") for c in cals]
    names = [n for n in tables[0].index if all(n in t.index for t in tables[1:])]
    left_out = sorted(set().union(*(set(t.index) for t in tables)) - set(names))
    V = np.array([t.loc[names, "value"].to_numpy(dtype=float) for t in tables])  # (S, P)
    E = np.array([t.loc[names, "stderr"].to_numpy(dtype=float) for t in tables])
    clamped = np.array([np.full(len(names), bool(t["clamped"].iloc[0])) for t in tables])
    units = tables[0].loc[names, "unit"].tolist()
    return _ParameterValues(names, units, V, E, clamped, left_out)


def _z_score(change: np.ndarray, se: np.ndarray) -> np.ndarray:
    """change / se; where se is 0, 0 for no change and ±inf for a change."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(
            se > 0,
            change / np.where(se > 0, se, 1.0),
            np.where(change == 0, 0.0, np.sign(change) * np.inf),
        )


def _changes_frame(sessions: _DriftSessions, T: float, values: _ParameterValues) -> pd.DataFrame:
    """Each parameter's change since the previous and since the first session, its standard
    error and z, and the flags: one row per session and parameter."""
    cals, names, V, E = sessions.calibrations, values.names, values.values, values.stderr
    prev = np.r_[0, np.arange(len(cals) - 1)]
    change_prev, se_prev = V - V[prev], np.hypot(E, E[prev])
    change_first, se_first = V - V[0], np.hypot(E, E[0])
    se_prev[0] = se_first[0] = 0.0
    tol_of = sessions.tolerance
    tol = np.array([tol_of[p] if (p := match_pattern(tol_of, n)) else 0.0 for n in names])
    z_prev, z_first = _z_score(change_prev, se_prev), _z_score(change_first, se_first)
    flag = lambda c, z: (np.abs(c) > tol) & (np.abs(z) > sessions.z_limit)  # noqa: E731
    flagged_prev, flagged_first = flag(change_prev, z_prev), flag(change_first, z_first)
    S, P = V.shape
    return pd.DataFrame(
        {
            "device": sessions.device,
            "batch": np.repeat([c.meta.get("batch") for c in cals], P),
            "session": np.repeat([str(c.meta["session"]) for c in cals], P),
            "parameter": np.tile(names, S),
            "unit": np.tile(values.units, S),
            "temperature": T,
            "clamped": values.clamped.ravel(),
            "value": V.ravel(),
            "stderr": E.ravel(),
            "change_prev": change_prev.ravel(),
            "se_prev": se_prev.ravel(),
            "z_prev": z_prev.ravel(),
            "change_first": change_first.ravel(),
            "se_first": se_first.ravel(),
            "z_first": z_first.ravel(),
            "tolerance": np.tile(tol, S),
            "flagged_prev": flagged_prev.ravel(),
            "flagged_first": flagged_first.ravel(),
            "flagged": (flagged_prev | flagged_first).ravel(),
            "baseline": np.repeat(np.arange(S) == 0, P),
        }
    )


def _plans(cal: Calibration, temp: np.ndarray):
    """The calibration as validation's per-hold plans: at each hold's temperature
    (``interpolated``, clamped to the calibrated span) and at its reference point only
    (``single``, seed 000's one-temperature method), with the coefficients' covariance the
    file holds (standard errors alone, as uncorrelated, in files without it)."""
    n, names = len(temp), tuple(cal.grid.names)
    at = cal.clamp(temp)
    g = cal.grid
    if cal.kind == "continuous":
        values = np.tile(np.asarray(g.values, dtype=float), (n, 1))
        cov = np.array(g.covariance_at(at))
        ref_temp = float(cal.clamp(cal.reference_temperature))
        single = _Plan(cal.model, names, values, cov.copy(), np.full(n, ref_temp))
    else:
        coefs = cal.coefficients(at, warn=False)
        values = np.column_stack([coefs[k] for k in names])
        cov = g.covariance_at(at)
        k = reference_point(g.temperatures, cal.reference_temperature)
        ref_temp = float(g.temperatures[k])
        single = _Plan(
            cal.model,
            names,
            np.tile(g.values[k], (n, 1)),
            g.covariance_at(np.full(n, ref_temp)),
            np.full(n, ref_temp),
        )
    return _Plan(cal.model, names, values, cov, at), single, ref_temp


class HoldErrors(NamedTuple):
    """Each hold's error (n, 3) after a calibration's interpolated compensation, its noise
    floor (n, 3) and true rates (n, 3), deg/s, and the holds :func:`revalidate` scores."""

    errors: np.ndarray
    floor: np.ndarray
    rates: np.ndarray
    scored: np.ndarray


def scored_hold_errors(cal: Calibration, obs: pd.DataFrame, span_margin: float = 1.0) -> HoldErrors:
    """Each hold's error after ``cal``'s interpolated compensation, as :func:`revalidate`
    scores it, with what a reader of them needs beside (:class:`HoldErrors`), from one pass
    over the holds' inputs."""
    data = cal.model.transform_inputs(columns_of(obs))
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    interp, _, _ = _plans(cal, data["temp"])
    rates = stack("rate")
    errors, _, _ = _compensate(interp, stack("gyro"), rates, stack("std"), data)
    scored = _scored_holds(cal, data["temp"], span_margin).use
    return HoldErrors(errors, observation_floor(data), rates, scored)


def hold_errors(cal: Calibration, obs: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Each hold's error (n, 3) after ``cal``'s interpolated compensation, as
    :func:`revalidate` scores it, and the hold's noise floor (n, 3), deg/s."""
    held = scored_hold_errors(cal, obs)
    return held.errors, held.floor


class Revalidation(TypedDict):
    """The previous session's calibration on the new session's holds (:func:`revalidate`),
    deg/s where a rate: JSON-plain but for ``table``, which a fleet audit writes as records."""

    device: str | None
    calibration_session: str | None
    holds: bool  # the old calibration still holds
    verdict: str
    validation_rms: float  # the interpolated compensation's, on the scored holds
    noise_floor: float
    excess: float
    expected_rms: float  # the floor and the old calibration's uncertainty
    excess_over_expected: float
    limit_over_expected: float | None  # the chi-squared bound, where no max_excess is given
    max_excess: float | None
    uncompensated_rms: float
    single_rms: float
    reference_temperature: float  # °C, the one-point compensation's
    holds_scored: int
    holds_outside_span: int
    holds_left_out: int
    scored: str  # "within the old span" or "all"
    table: pd.DataFrame  # Mean/RMS per rotating x output axis and method


def revalidate(
    previous_cal,
    observations,
    *,
    max_excess: float | None = None,
    alpha: float = 1e-3,
    span_margin: float = 1.0,
) -> Revalidation:
    """Does the previous session's calibration still hold on the new session's holds?

    ``observations`` is the new session's observation table or its results folder (a
    failure record there raises ``UpstreamFailure``): hold
    means ``gyro_*``, true rates ``rate_*``, ``std_*``, ``n``, ``temp``, ``axis`` ...
    Each hold is compensated with the old calibration's model exactly as the validation
    stage compensates (:func:`gyrocal.fit.validate._compensate`): at the hold's temperature
    (``interpolated``) and with the old calibration's reference point alone (``single``),
    beside the raw output (``uncompensated``). Holds outside the old calibrated span are
    compensated at its nearest end; those more than ``span_margin`` °C outside (where the
    old calibration says nothing, rather than where the new session's end points fall a
    hair beyond the old ones) are left out of the headline figures when others remain.

    Verdict: with ``max_excess`` given, the old calibration holds when its RMS is at most
    ``max_excess`` × the noise floor. Otherwise it holds when its RMS is what noise plus the
    old calibration's own uncertainty explain: ``RMS ≤ expected · sqrt(χ²_N(1 − alpha)/N)``,
    N the number of hold-mean errors scored (3 per hold), expected the RMS of the floor and
    the calibration uncertainty carried to each hold. (Calibration errors are shared by
    holds, which widens the true scatter slightly; they are small beside the floor.)

    Returns a :class:`Revalidation` (its ``table``, the Mean/RMS per rotating × output axis,
    a DataFrame: ``table.to_dict("records")`` for files).
    """
    cal = _load(previous_cal)
    obs = _revalidation_holds(cal, observations)
    if max_excess is not None:
        max_excess = finite_number(max_excess, "max_excess", positive=True)
    alpha = finite_number(alpha, "alpha", positive=True)
    if alpha >= 1:
        raise ConfigError(f"alpha must be below 1, got {alpha!r}")
    data = cal.model.transform_inputs(columns_of(obs))
    errors, ref_temp = _method_errors(cal, data)
    span_margin = finite_number(span_margin, "span_margin")
    scored = _scored_holds(cal, data["temp"], span_margin)
    use = scored.use
    floor = observation_floor(data)
    table = _method_table(obs, errors, floor, use)
    score = _revalidation_score(errors, floor, use, max_excess, alpha)
    return {
        "device": cal.meta.get("device"),
        "calibration_session": cal.meta.get("session"),
        "holds": bool(score.holds),
        "verdict": score.verdict,
        "validation_rms": score.rms,
        "noise_floor": score.floor_rms,
        "excess": score.excess,
        "expected_rms": score.expected,
        "excess_over_expected": score.rms / score.expected,
        "limit_over_expected": score.bound if max_excess is None else None,
        "max_excess": max_excess,
        "uncompensated_rms": _pooled_rms(errors["uncompensated"][0][use]),
        "single_rms": _pooled_rms(errors["single"][0][use]),
        "reference_temperature": ref_temp,
        "holds_scored": int(use.sum()),
        "holds_outside_span": int((scored.beyond > 0).sum()),
        "holds_left_out": int((~use).sum()),
        "scored": "within the old span" if scored.within_span else "all",
        "table": table,
    }


def _revalidation_holds(cal: Calibration, observations) -> pd.DataFrame:
    """The new session's holds (a table, or read from a results folder), refused unless
    their true rates are known and there is at least one."""
    if not isinstance(observations, pd.DataFrame):
        from ..terms.signals import read_observations

        observations, _ = read_observations(observations)
    from ..protocols import registry

    if not registry.get(cal.meta.get("protocol")).known_rate or "revolution" in observations.columns:
        raise InputError(
            "revalidation needs holds with a known true rate (turntable or sweep "
            "sessions); a servo session's hand mount leaves the rate's direction unknown"
        )
    obs = observations.reset_index(drop=True)
    if obs.empty:
        raise InputError("revalidation: the new session has no holds")
    return obs


def _method_errors(cal: Calibration, data) -> tuple[dict, float]:
    """Each hold's (error, variance, calibration variance) by method (uncompensated, single,
    interpolated), as the validation stage compensates, and the reference temperature."""
    stack = lambda prefix: np.column_stack([data[f"{prefix}_{a}"] for a in AXES])  # noqa: E731
    w, rate, sd = stack("gyro"), stack("rate"), stack("std")
    interp, single, ref_temp = _plans(cal, data["temp"])
    zero = np.zeros((len(w), 3))
    errors = {
        "uncompensated": (w - rate, sd**2, zero),
        "single": _compensate(single, w, rate, sd, data),
        "interpolated": _compensate(interp, w, rate, sd, data),
    }
    return errors, ref_temp


class _ScoredHolds(NamedTuple):
    """How far each hold lies beyond the old calibrated span (°C, ≤ 0 within), which holds
    the headline figures score, and whether those are the ones within the span."""

    beyond: np.ndarray
    use: np.ndarray
    within_span: bool


def _scored_holds(cal: Calibration, temp, span_margin: float) -> _ScoredHolds:
    lo, hi = cal.grid.span
    beyond = np.maximum(lo - temp, temp - hi)
    clamped = beyond > max(span_margin, 0.0)
    within_span = bool((~clamped).any())
    use = ~clamped if within_span else np.ones(len(temp), dtype=bool)
    return _ScoredHolds(beyond, use, within_span)


def _method_table(obs: pd.DataFrame, errors: dict, floor: np.ndarray, use: np.ndarray) -> pd.DataFrame:
    """Mean/RMS per rotating × output axis and method, of the scored holds."""
    n = len(obs)
    holds = pd.concat([obs[["axis", "n", "std_x", "std_y", "std_z"]]] * len(METHODS), ignore_index=True)
    holds["method"] = pd.Categorical(np.repeat(METHODS, n), categories=METHODS)
    for i, a in enumerate(AXES):
        holds[f"floor_{a}"] = np.tile(floor[:, i], len(METHODS))
        for k, kind in enumerate(("err", "var", "cal")):
            holds[f"{kind}_{a}"] = np.concatenate([errors[m][k][:, i] for m in METHODS])
    return _table(holds[np.tile(use, len(METHODS))], samples=False)


class _RevalidationScore(NamedTuple):
    """The interpolated compensation's RMS against the noise floor and against what noise
    plus calibration uncertainty explain, and whether the old calibration holds."""

    rms: float
    floor_rms: float
    expected: float
    bound: float
    excess: float
    holds: bool
    verdict: str


def _revalidation_score(
    errors: dict, floor: np.ndarray, use: np.ndarray, max_excess: float | None, alpha: float
) -> _RevalidationScore:
    rms = _pooled_rms(errors["interpolated"][0][use])
    floor_rms = _pooled_rms(floor[use])
    expected = float(np.sqrt(np.mean(floor[use] ** 2 + errors["interpolated"][2][use])))
    N = 3 * int(use.sum())
    bound = float(math.sqrt(chi2.ppf(1.0 - alpha, N) / N))
    excess = rms / floor_rms
    if max_excess is not None:
        holds_up, limit_text = excess <= max_excess, f"limit {max_excess:g}× the floor"
    else:
        holds_up = rms <= expected * bound
        limit_text = (
            f"noise and calibration uncertainty explain up to {expected * bound / floor_rms:.3g}× "
            f"at α = {alpha:g}"
        )
    verdict = (
        f"the old calibration still holds ({excess:.3g}× the floor)"
        if holds_up
        else f"the old calibration no longer holds ({excess:.3g}× the floor; {limit_text})"
    )
    return _RevalidationScore(rms, floor_rms, expected, bound, excess, holds_up, verdict)


def plot_drift(changes: pd.DataFrame, path_or_none=None) -> str:
    """Each parameter of :func:`parameter_changes` against session date with 1-σ error
    bars; flagged sessions ringed in red, the first session's value ± tolerance shaded.
    Deterministic SVG; written to ``path_or_none`` when given."""
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter

    from ..report.plots import figure_style, panels, to_svg, write_svg

    if changes.empty:
        raise InputError("drift plot: no parameter changes to plot")
    params = list(dict.fromkeys(changes["parameter"]))
    dates = pd.to_datetime(changes["session"], errors="coerce")
    use_dates = not dates.isna().any()
    with figure_style():
        fig, grid = panels(params, 2.2)
        for axis, p in grid:
            part = changes[changes["parameter"] == p]
            x = dates[part.index] if use_dates else np.arange(len(part))
            axis.errorbar(
                x, part["value"], yerr=part["stderr"], fmt="o-", ms=3, lw=0.8, capsize=2, color="#1f77b4"
            )
            tol = float(part["tolerance"].iloc[0])
            if tol > 0:
                base = float(part["value"].iloc[0])
                axis.axhspan(base - tol, base + tol, color="#2ca02c", alpha=0.12, lw=0)
            hit = part["flagged"].to_numpy()
            if hit.any():
                axis.plot(
                    np.asarray(x)[hit],
                    part["value"].to_numpy()[hit],
                    "o",
                    ms=9,
                    mfc="none",
                    mec="#d62728",
                    mew=1.5,
                )
            axis.set_title(f"{p}, {part['unit'].iloc[0]}", fontsize=9, parse_math=False)
            if not use_dates:
                axis.set_xticks(np.arange(len(part)), part["session"].tolist(), parse_math=False)
            axis.ticklabel_format(axis="y", useOffset=False)
            if use_dates:
                locator = AutoDateLocator(minticks=2, maxticks=5)
                axis.xaxis.set_major_locator(locator)
                axis.xaxis.set_major_formatter(ConciseDateFormatter(locator))
                axis.tick_params(axis="x", labelsize=7)
        fig.supxlabel("session", fontsize=9)
        return write_svg(to_svg(fig), path_or_none)
