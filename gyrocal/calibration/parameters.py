"""A calibration's parameters in engineering units: at one temperature with their standard
errors (:func:`parameters_at`), their largest temperature coefficients, and one row per unit
for a fleet (:func:`parameter_table`).

``scale.*`` (``K_aa − 1``) is in ppm, ``misalignment.*`` (``K_ab``, a small angle) in mrad,
``bias.*`` in deg/s, other dimensionless coefficients in ppm and the rest in their term's own
unit (``gyrocal/terms``). For continuous models ``bias``, ``scale`` and ``misalignment`` are
read from ``K(T)`` and ``B(T)``, so that temperature terms (``bias_temp_poly`` ...) are
included.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from ..fit.thermal import ConstantCoefficients, TemperatureGrid
from ..terms import AXES
from .file import Calibration, load_calibration, standard_coefficients

# term name -> (display unit, factor from the coefficient's own unit)
DISPLAY = {"scale": ("ppm", 1e6), "misalignment": ("mrad", 1e3), "bias": ("deg/s", 1.0)}
TC_SAMPLES = 401  # temperatures at which d/dT is evaluated across the calibrated span


def _display(cal: Calibration) -> dict[str, tuple[str, float]]:
    """Display unit and factor of every coefficient name of the calibration's model."""
    units = {t.name: t.unit for t in cal.model.terms}
    out = {}
    for name in cal.model.names:
        term = name.split(".")[0]
        unit = units.get(term, "")
        out[name] = DISPLAY.get(term) or (("ppm", 1e6) if unit == "1" else (unit, 1.0))
    return out


def _standard_from_KB(K: np.ndarray, B: np.ndarray, names) -> dict[str, np.ndarray]:
    """The seed-000 coefficients of K and B, for those of ``names`` the model has."""
    return {n: v for n, v in standard_coefficients(K, B).items() if n in names}


def _linearise(cal: Calibration, coefs: dict, temps: np.ndarray):
    n = len(temps)
    return cal.static_model.linearise(coefs, cal._neutral(n, temps), np.zeros((n, 3)))


def parameter_curves(cal: Calibration, temps) -> dict[str, np.ndarray]:
    """Every parameter at ``temps`` (clamped to the calibrated span), in display units; the
    bias as the session measured it where the file holds that form (``bias_in_session``:
    terms kept though the data cannot tell them from the bias make the fitted one an
    extrapolation)."""
    temps = np.atleast_1d(np.asarray(temps, dtype=float))
    values = cal.coefficients(temps, warn=False)
    if cal.kind == "continuous":
        K, B = cal.matrices_at(temps)
        values = {**values, **_standard_from_KB(K, B, values)}
    session = _in_session(cal, temps)
    if session is not None:
        values = {**values, **session[0]}
    return {n: np.asarray(values[n], dtype=float) * f for n, (_, f) in _display(cal).items()}


def _in_session(cal: Calibration, temps) -> tuple[dict, dict] | None:
    """The bias in the session's form at ``temps`` and its standard error, interpolated as
    the grid interpolates (points taken as independent); None where the file has no such form."""
    found = cal.extra.get("bias_in_session")
    if not found or not isinstance(cal.grid, TemperatureGrid):  # a continuous model's
        return None
    w = cal.grid.weights(np.clip(temps, *cal.grid.span))
    bias, se = np.asarray(found["bias"], dtype=float), np.asarray(found["stderr"], dtype=float)
    return (
        {f"bias.{a}": w @ bias[:, i] for i, a in enumerate(AXES)},
        {f"bias.{a}": np.sqrt((w**2) @ se[:, i] ** 2) for i, a in enumerate(AXES)},
    )


def parameters_at(cal: Calibration, temperature: float | None = None) -> pd.DataFrame:
    """The calibration's parameters at ``temperature`` (default: its reference temperature):
    columns parameter, value, stderr, unit, temperature, clamped.

    Standard errors come from the file's per-coefficient errors (``TemperatureGrid.stderr_at``
    for grids). For continuous models ``K(T)``/``B(T)`` combine several coefficients; their
    errors are added in quadrature through the model's own linearisation, neglecting the
    correlations the file does not store (exact at the temperature terms' ``t_ref``)."""
    T = float(cal.reference_temperature if temperature is None else temperature)
    lo, hi = cal.grid.span
    clamped = not (lo <= T <= hi)
    units = _display(cal)
    names = list(units)
    values = {n: v[0] for n, v in parameter_curves(cal, [T]).items()}
    if isinstance(cal.grid, ConstantCoefficients):  # a continuous model
        se = dict(zip(cal.grid.names, np.asarray(cal.grid.stderr, dtype=float), strict=False))
        # Row 0: the coefficients; row j + 1: coefficient j raised by its standard error.
        C = len(cal.grid.names)
        temps = np.full(C + 1, min(max(T, lo), hi))
        base = np.tile(np.asarray(cal.grid.values, dtype=float), (C + 1, 1))
        base[np.arange(1, C + 1), np.arange(C)] += cal.grid.stderr
        K, B = _linearise(cal, {n: base[:, j] for j, n in enumerate(cal.grid.names)}, temps)
        std = _standard_from_KB(K, B, names)
        for n, v in std.items():
            se[n] = float(np.sqrt(np.sum((v[1:] - v[0]) ** 2)))
    else:
        se = {n: float(v[0]) for n, v in cal.grid.stderr_at([T]).items()}
        session = _in_session(cal, np.array([T]))
        if session is not None:
            se.update({n: float(v[0]) for n, v in session[1].items()})
    return pd.DataFrame(
        {
            "parameter": names,
            "value": [float(values[n]) for n in names],
            "stderr": [float(se[n]) * units[n][1] for n in names],
            "unit": [units[n][0] for n in names],
            "temperature": T,
            "clamped": clamped,
        }
    )


def temperature_coefficients(cal: Calibration) -> pd.DataFrame | None:
    """Largest |d parameter / dT| over the calibrated span (display unit per °C), from the
    calibration's own curve (its interpolation, or its temperature terms), evaluated on
    ``TC_SAMPLES`` temperatures; None for a calibration at a single temperature."""
    lo, hi = cal.grid.span
    if not hi > lo:
        return None
    temps = np.linspace(lo, hi, TC_SAMPLES)
    curves = parameter_curves(cal, temps)
    units = _display(cal)
    slope = {n: float(np.max(np.abs(np.gradient(v, temps, edge_order=2)))) for n, v in curves.items()}
    return pd.DataFrame(
        {
            "parameter": list(slope),
            "value": list(slope.values()),
            "unit": [f"{units[n][0]}/°C" for n in slope],
        }
    )


def parameter_table(calibrations: Iterable, *, temperature: float | None = None) -> pd.DataFrame:
    """One row per calibration: device, batch, session and every parameter (display units)
    at ``temperature`` (default: each one's reference temperature); the input of
    :func:`fleet_outliers`. Parameters a unit's model lacks are NaN in its row."""
    rows = []
    for cal in calibrations:
        cal = cal if isinstance(cal, Calibration) else load_calibration(cal)
        p = parameters_at(cal, temperature)
        rows.append(
            {
                **{k: cal.meta.get(k) for k in ("device", "batch", "session")},
                **dict(zip(p["parameter"], p["value"], strict=False)),
            }
        )
    return pd.DataFrame(rows)
