"""Calibrations for firmware: a C header with a reference implementation, or plain JSON.

``gyrocal export CAL.json --format {c-header,json} -o FILE`` (contract section 6).

What firmware computes is what ``gyrocal apply`` computes: the model's coefficients are
interpolated across the grid temperatures (:func:`gyrocal.fit.thermal.interpolation_weights`),
and the affine model is then inverted at the sample's temperature. For the seed-000 terms
K and B are linear in the coefficients (``K = I + scale + misalignment``, ``B = bias``,
seed 000 Eq 11-12), and every interpolation rule is linear in the grid values with weights
summing to one, so interpolating the entries of K and B per grid point and then solving
``K(T) w_true = w - B(T)`` gives apply's result to rounding. Interpolating K⁻¹ per point
instead would not in general: the inverse of an interpolated matrix is not the interpolated
inverse. So the export carries K and B per point (and K⁻¹ per point, for information only).

Rules, as in :mod:`gyrocal.fit.thermal`; temperatures outside the grid are clamped to its ends:

* ``lagrange3`` (seed 000 Eq 21-22) and ``linear``: weights computed from the grid
  temperatures exactly as gyrocal does, applied to the per-point K and B;
* ``spline`` (natural cubic): per interval ``i`` the cubic coefficients of every entry,
  ``v(T) = sum_k c[i][k] (T - T_i)^(3-k)``, on ``T_i <= T < T_{i+1}``;
* ``poly`` (one least-squares polynomial): Legendre coefficients of every entry in
  ``x = (T - centre) / half_range``.

With fewer than three points ``lagrange3`` and ``spline`` are linear (as in gyrocal).
A temperature-continuous calibration (``model.kind: continuous``, e.g. a sweep's bias
polynomial, seed 003 Eq 16) of bias, scale, misalignment and their temperature
polynomials (``bias_temp_poly``, ``scale_temp_poly``, ``misalignment_temp``) has K(T) and
B(T) polynomial in T: they are exported exactly as ``poly`` over its calibrated span, the
degree being the lowest that reproduces them (checked on 201 temperatures to 1e-12).
Histories of the raw output the diagnosis offers (:data:`HISTORY_FORMS`: a slow pole, heat
from turning) are first-order lags run per output axis over the samples, added to B (a slow
pole's true rate to K's diagonal): ``histories`` in the JSON, ``gyrocal_run_histories`` in C.
Histories of the temperature (:data:`TEMPERATURE_HISTORY_FORMS`: its direction through a
play operator, a Duhem state, a switch with hysteresis) run on the logged temperature through
the lag apply reads it by, from a unit brought from the room, added to B:
``temperature_histories`` in the JSON, ``gyrocal_temperature_history`` in C.
Other terms (``scale_quadratic``, ``scale_cubic``, ``scale_asymmetry``, ``g_sensitivity``,
``temp_rate``, user terms) make the output more than ``K(T) w_true + B(T)``: such models
are refused, naming the terms; compensate them with ``gyrocal apply``. A temperature grid
takes the base terms only (its coefficients are interpolated, not its terms' products).
A term of the rig (:data:`RIG_TERMS`: the fixture's faces) is zero off the fixture and is
left behind.

JSON keys (``format: gyrocal.firmware/1``): ``device``, ``batch``, ``session``,
``protocol``, ``source`` (file name and SHA-256 of the calibration), ``gyrocal_version``,
``units``, ``model`` and ``compensation`` (the formulas), ``interpolation`` (``method``,
``calibration_method``, ``degree``, ``interpolated``, ``outside_range: clamp``, ``range``),
``temperature`` (P), ``K`` (P x 3 x 3, ``K[p][a][b]``: output axis a, input axis b),
``B`` (P x 3), ``K_inv`` (P x 3 x 3, information); for ``spline`` also ``spline.K``
((P-1) x 4 x 3 x 3) and ``spline.B``; for ``poly`` also ``poly.degree``, ``poly.centre``,
``poly.half_range``, ``poly.K`` ((d+1) x 3 x 3) and ``poly.B``. Numbers are written as
the shortest text that reads back to the same double (Python ``repr``; valid C literals).
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__
from ..io import atomic
from ..io.errors import ConfigError, InputError

if TYPE_CHECKING:  # the CLI registers export at start-up: what it reads is imported on use
    from .file import Calibration

FORMAT = "gyrocal.firmware/1"
FORMATS = {"c-header": ".h", "json": ".json"}
BASE_TERMS = ("bias", "scale", "misalignment")  # the terms of w = K(T) w_true + B(T)
# The rig's, not the sensor's: zero off the fixture, where firmware runs (their
# coefficients are left behind, K and B hold the sensor).
RIG_TERMS = ("misalignment_faces",)
# Where T is the die's: the logged temperature through a first-order lag, run as a filter.
DIE_TERM = "die_temperature"
DIE_FILTER = (
    "T_die[k] = a T_die[k-1] + T[k] - a T[k-1] - (T[k] - T[k-1]) (tau / dt) (1 - a), "
    "a = exp(-dt / tau), dt = t[k] - t[k-1] > 0 (T_die kept when dt <= 0 or an input "
    "is not finite); T_die[0] = T[0]"
)
# Continuous models may add these: affine in the rate, polynomial in temperature.
TEMPERATURE_TERMS = ("bias_temp_poly", "scale_temp_poly", "misalignment_temp")
MAX_DEGREE = 8  # of K(T), B(T) in a continuous model (the terms allow 5)
POLY_RTOL = 1e-12  # the Legendre series must reproduce K(T), B(T) to this (of max |K|, |B|, 1)
UNITS = {"rate": "deg/s", "temperature": "degC", "K": "1", "B": "deg/s"}


class UnsupportedModelError(InputError):
    """The calibration's model is more than the firmware rule w_true = K(T)^-1 (w - B(T))."""


@dataclass(frozen=True)
class FirmwareTables:
    """Everything the firmware rule needs, in float64."""

    temperature: np.ndarray  # (P,) °C, increasing
    K: np.ndarray  # (P, 3, 3)
    B: np.ndarray  # (P, 3) deg/s
    K_inv: np.ndarray  # (P, 3, 3), information only
    method: str  # the rule applied: lagrange3, linear, spline, poly
    calibration_method: str  # what the calibration file says
    degree: int | None = None  # poly: the degree used
    spline_K: np.ndarray | None = None  # (P-1, 4, 3, 3)
    spline_B: np.ndarray | None = None  # (P-1, 4, 3)
    poly_centre: float | None = None
    poly_half_range: float | None = None
    poly_K: np.ndarray | None = None  # (d+1, 3, 3)
    poly_B: np.ndarray | None = None  # (d+1, 3)
    die_tau: float | None = None  # s: T is the die's, the logged one lagged
    splines: tuple = ()  # empirical terms: dicts of input, by, knots, coefficients
    histories: tuple = ()  # lags of the raw output: dicts of input, tau, coefficients
    temperature_histories: tuple = ()  # play or Duhem operators of the temperature


# Empirical terms firmware evaluates beside K and B: a spline of time since power-on or of
# the temperature, added to B or (times the own rate) to K's diagonal, keeps the model
# affine in the true rate.
SPLINE_TERM = "smooth"
SPLINE_INPUTS = ("t", "temp")


# Histories of the gyro's output firmware runs as filters beside K and B: the
# formulas the diagnosis offers, each a first-order lag of a function of the raw output,
# added to B, a slow pole's "- rate_own" to K's diagonal (it reads the true rate).
HISTORY_TERM = "expression"
_SQUARED = "rate_x ** 2 + rate_y ** 2 + rate_z ** 2"
HISTORY_FORMS = {  # the formula as ast.unparse writes it -> (input of the lag, K's diagonal)
    "lag(rate_own, tau) - rate_own": ("own", -1.0),
    "lag(rate_own, tau)": ("own", 0.0),
    "lag(abs(rate_own), tau)": ("abs_own", 0.0),
    f"lag(sqrt({_SQUARED}), tau)": ("magnitude", 0.0),
    f"lag({_SQUARED}, tau)": ("squared", 0.0),
}
HISTORY_INPUTS = {
    "own": "w[a]",
    "abs_own": "|w[a]|",
    "magnitude": "sqrt(w[0]^2 + w[1]^2 + w[2]^2)",
    "squared": "w[0]^2 + w[1]^2 + w[2]^2",
}
LAG_FILTER = (
    "y[k] = e y[k-1] + u[k] - e u[k-1] - (u[k] - u[k-1]) (tau / dt) (1 - e), "
    "e = exp(-dt / tau), dt = t[k] - t[k-1] (y kept when dt <= 0); y[0] = u[0]; a sample "
    "whose time or input is not finite leaves the state and gives NaN; one filter per "
    "output axis, u its input on that axis (w the raw output, deg/s)"
)


# Histories of the temperature firmware runs as filters: a play or Duhem operator
# of the logged temperature through the lag apply reads it by, its value times a coefficient
# per output axis added to B. The formula as ast.unparse writes it -> (operator, parameters).
TEMPERATURE_HISTORY_FORMS = {
    "2 * (temp - play(temp, w)) / w": ("direction", {"w"}),
    "duhem(temp, w)": ("duhem", {"w"}),
    "sign(play(temp, w) - T0 - m)": ("switch", {"w", "T0", "m"}),
}
TEMPERATURE_HISTORY_VALUES = {
    "direction": "2 (T - y) / w, T the temperature as clamped to the calibration's range, y the play operator of width w: y[k] = clamp(y[k-1], x[k] - w/2, x[k] + w/2)",
    "switch": "sign(y - T0 - m), y the play operator of width w: y[k] = clamp(y[k-1], x[k] - w/2, x[k] + w/2)",
    "duhem": (
        "s, y the play operator of width w/20 (its dead band) and s[k] = d + (s[k-1] - d) "
        "exp(-|y[k] - y[k-1]| / w), d = sign(y[k] - y[k-1]), s kept while y stands"
    ),
}
TEMPERATURE_HISTORY_START = (
    "a unit brought from a {room:g} degC room: y[0] = clamp({room:g}, x[0] - h, "
    "x[0] + h), h the play's half width; for duhem s[0] = d0 (1 - exp(-|y[0] - "
    "{room:g}| / w)), d0 = sign(x[0] - {room:g}) where |x[0] - {room:g}| > h, else 0"
)


def _history_formula(spec) -> str | None:
    """An expression term's formula as ``ast.unparse`` writes it (the forms' spelling), else
    None."""
    import ast

    if not isinstance(spec, dict) or spec.get("name") != HISTORY_TERM or spec.get("drop"):
        return None
    try:
        return ast.unparse(ast.parse(str(spec.get("formula")), mode="eval"))
    except SyntaxError:
        return None


def temperature_history_form(spec) -> str | None:
    """The operator (``direction``, ``duhem``, ``switch``) of an expression term firmware
    runs as a filter of the temperature, else None."""
    formula = _history_formula(spec)
    form = None if formula is None else TEMPERATURE_HISTORY_FORMS.get(formula)
    given = set(spec.get("parameters") or {}) | set(spec.get("profile") or {})
    return form[0] if form is not None and given == form[1] else None


def history_form(spec) -> tuple[str, float] | None:
    """(input, K's diagonal) of an expression term firmware runs as a filter, else None."""
    formula = _history_formula(spec)
    if formula is None:
        return None
    if set(spec.get("parameters") or {}) | set(spec.get("profile") or {}) != {"tau"}:
        return None
    return HISTORY_FORMS.get(formula)


def supported_terms(kind: str) -> tuple[str, ...]:
    return BASE_TERMS + (DIE_TERM, SPLINE_TERM) + (TEMPERATURE_TERMS if kind == "continuous" else ())


def unsupported_terms(specs, kind: str = "temperature_grid") -> list[str]:
    """Names of terms (specs as in a calibration file) the firmware rule cannot hold."""
    names = []
    for spec in specs:
        if history_form(spec) is not None or temperature_history_form(spec) is not None:
            continue
        name = spec.get("name") if isinstance(spec, dict) else spec
        if name in RIG_TERMS:
            continue
        spline_ok = not isinstance(spec, dict) or (
            spec.get("input") in SPLINE_INPUTS and not spec.get("drop")
        )
        if name not in supported_terms(kind) or (name == SPLINE_TERM and not spline_ok):
            names.append(str(name) + (f"(input={spec.get('input')})" if name == SPLINE_TERM else ""))
    return names


def _refuse(names: list[str], kind: str, source) -> None:
    what = "a temperature-continuous" if kind == "continuous" else "a temperature-grid"
    raise UnsupportedModelError(
        f"cannot export for firmware: term{'s' * (len(names) > 1)} {', '.join(names)} "
        f"{'are' if len(names) > 1 else 'is'} beyond the rule w_true = K(T)^-1 (w - B(T)), which "
        f"for {what} calibration holds {', '.join(supported_terms(kind))}; compensate with "
        "gyrocal apply",
        source=source,
    )


def _legendre_fit(cal: Calibration, source) -> dict:
    """K(T), B(T) of a continuous calibration as Legendre series over its span: the lowest
    degree whose interpolation at Chebyshev points reproduces them everywhere."""
    lo, hi = cal.grid.span
    centre, half = (lo + hi) / 2, max((hi - lo) / 2, 1e-12)  # as thermal.poly_weights
    check_T = np.linspace(lo, hi, 201)
    K, B = cal.matrices_at(check_T)
    want = np.concatenate([K.reshape(-1, 9), B], axis=1)
    tol = POLY_RTOL * max(1.0, float(np.abs(want).max()))
    for degree in range(0, MAX_DEGREE + 1 if hi > lo else 1):
        x = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
        K, B = cal.matrices_at(centre + half * x)
        L = np.linalg.solve(
            np.polynomial.legendre.legvander(x, degree), np.concatenate([K.reshape(-1, 9), B], axis=1)
        )
        got = np.polynomial.legendre.legvander((check_T - centre) / half, degree) @ L
        if np.max(np.abs(got - want)) <= tol:
            return dict(
                degree=degree,
                poly_centre=float(centre),
                poly_half_range=float(half),
                poly_K=L[:, :9].reshape(degree + 1, 3, 3),
                poly_B=L[:, 9:].copy(),
            )
    raise UnsupportedModelError(
        f"cannot export for firmware: K(T) and B(T) are not polynomials of "
        f"degree {MAX_DEGREE} or less in temperature",
        source=source,
    )


def _splines(cal: Calibration) -> tuple:
    """The calibration's empirical terms as firmware evaluates them: the clamped cubic
    B-spline's full knot vector and, per output axis, the coefficients of all its basis
    functions (those the term leaves out at 0). Their coefficients are session-wide or
    continuous: the same at every grid point."""
    from ..terms.empirical import Smooth

    out = []
    for term in cal.model.terms:
        if not isinstance(term, Smooth):  # SPLINE_TERM
            continue
        knots = np.asarray(term.knots, dtype=float)
        vector = np.r_[[knots[0]] * 3, knots, [knots[-1]] * 3]
        dropped = 2 - int(term.linear)
        values = cal.grid.at(np.array([cal.grid.temperatures[0]]), warn=False)
        coefficients = np.zeros((3, len(knots) + 2))
        for i, a in enumerate("xyz"):
            for j in range(term.size):
                coefficients[i, dropped + j] = float(values[f"{term.label}.{a}.k{j + 1}"][0])
        out.append(
            {
                "label": term.label,
                "input": term.input,
                "by": term.by,
                "knots": vector,
                "coefficients": coefficients,
            }
        )
    return tuple(out)


def _session_wide(cal: Calibration, label: str, source) -> np.ndarray:
    """A history's coefficient per output axis. Its effect belongs to the session's time,
    not to a temperature point: the same at every grid point, or the export is refused."""
    values = cal.grid.at(np.asarray(cal.grid.temperatures, dtype=float), warn=False)
    c = np.array([values[f"{label}.{a}"] for a in "xyz"], dtype=float)  # (3, P)
    if not np.all(c == c[:, :1]):
        raise UnsupportedModelError(
            f"cannot export for firmware: {label}'s coefficients differ between temperature points",
            source=source,
        )
    return c[:, 0].copy()


def _histories(cal: Calibration, source) -> tuple:
    """The calibration's histories of the raw output as firmware runs them: the lag's input
    and time constant, the coefficient per output axis and what a slow pole adds to K's
    diagonal."""
    from ..terms.user import Expression

    out = []
    for term, spec in zip(cal.model.terms, cal.model.spec(), strict=False):
        form = history_form(spec)
        if form is not None and isinstance(term, Expression):
            out.append(
                {
                    "label": term.label,
                    "input": form[0],
                    "diagonal": form[1],
                    "tau": float(term.parameters["tau"]),
                    "formula": term.formula,
                    "coefficients": _session_wide(cal, term.label, source),
                }
            )
    return tuple(out)


def _temperature_histories(cal: Calibration, source) -> tuple:
    """The calibration's histories of the temperature as firmware runs them: the operator,
    its parameters and the coefficient per output axis."""
    from ..terms.user import Expression

    out = []
    for term, spec in zip(cal.model.terms, cal.model.spec(), strict=False):
        operator = temperature_history_form(spec)
        if operator is not None and isinstance(term, Expression):
            p = term.parameters
            out.append(
                {
                    "label": term.label,
                    "operator": operator,
                    "formula": term.formula,
                    "w": float(p["w"]),
                    "T0": float(p.get("T0", 0.0)),
                    "m": float(p.get("m", 0.0)),
                    "coefficients": _session_wide(cal, term.label, source),
                }
            )
    return tuple(out)


def _without_splines(cal: Calibration) -> Calibration:
    """``cal`` without its empirical terms and histories (firmware adds them to K and B itself)."""
    from dataclasses import replace

    from ..fit.model import Model

    added = [
        t.name == SPLINE_TERM or history_form(s) is not None or temperature_history_form(s) is not None
        for t, s in zip(cal.model.terms, cal.model.spec(), strict=False)
    ]
    if not any(added):
        return cal
    model = Model(tuple(t for t, drop in zip(cal.model.terms, added, strict=False) if not drop))
    keep = [j for j, n in enumerate(cal.grid.names) if n in set(model.names)]
    g = cal.grid
    cov = None if g.covariance is None else g.covariance[..., keep, :][..., keep]
    grid = replace(
        g,
        names=tuple(g.names[j] for j in keep),
        values=g.values[..., keep],
        stderr=g.stderr[..., keep],
        covariance=cov,
    )
    return replace(cal, model=model, grid=grid)


def firmware_tables(cal: Calibration, *, source=None) -> FirmwareTables:
    """The tables of :class:`FirmwareTables` for ``cal``; refuses models beyond K and B."""
    extra = unsupported_terms(cal.model.spec(), cal.kind)
    if extra:
        _refuse(extra, cal.kind, source)
    temps = np.asarray(cal.grid.temperatures, dtype=float)
    splines = _splines(cal)
    histories = _histories(cal, source)
    temperature_histories = _temperature_histories(cal, source)
    cal = _without_splines(cal)
    K, B = cal.matrices()
    P = len(temps)
    declared = cal.grid.method
    method = declared if cal.kind == "temperature_grid" else "poly"
    if method in ("lagrange3", "spline") and P < 3:
        method = "linear"  # as thermal.lagrange3_weights / spline_weights
    from ..terms.effects import DieTemperature

    die = [t for t in cal.model.terms if isinstance(t, DieTemperature)]  # DIE_TERM
    tables: dict[str, Any] = dict(
        temperature=temps,
        K=K,
        B=B,
        K_inv=np.linalg.inv(K),
        method=method,
        calibration_method=declared,
        die_tau=float(die[0].tau) if die else None,
        splines=splines,
        histories=histories,
        temperature_histories=temperature_histories,
    )
    Y = np.concatenate([K.reshape(P, 9), B], axis=1)  # every entry, one column each
    if cal.kind == "continuous":
        tables.update(_legendre_fit(cal, source))
    elif method == "spline":
        from scipy.interpolate import CubicSpline  # half a second to import: only for a spline

        c = CubicSpline(temps, Y, bc_type="natural").c.transpose(1, 0, 2)  # (P-1, 4, 12)
        tables.update(spline_K=c[..., :9].reshape(P - 1, 4, 3, 3), spline_B=c[..., 9:].copy())
    elif method == "poly":
        # thermal.poly_weights: W = legvander(x) @ pinv(legvander(nodes)), so W @ Y is the
        # Legendre series with coefficients pinv(V) @ Y.
        degree = min(cal.grid.degree, P - 1)
        centre, half = (temps[0] + temps[-1]) / 2, max((temps[-1] - temps[0]) / 2, 1e-12)
        V = np.polynomial.legendre.legvander((temps - centre) / half, degree)
        L = np.linalg.pinv(V) @ Y
        tables.update(
            degree=degree,
            poly_centre=float(centre),
            poly_half_range=float(half),
            poly_K=L[:, :9].reshape(degree + 1, 3, 3),
            poly_B=L[:, 9:].copy(),
        )
    for name, value in tables.items():
        if isinstance(value, np.ndarray) and not np.all(np.isfinite(value)):
            raise InputError(f"cannot export for firmware: {name} is not finite", source=source)
    for s in (*splines, *histories, *temperature_histories):
        if not np.all(np.isfinite(s["coefficients"])):
            raise InputError(f"cannot export for firmware: {s['label']} is not finite", source=source)
    return FirmwareTables(**tables)


def _source_info(source) -> dict | None:
    if source is None:
        return None
    path = Path(source)
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        digest = None
    return {"file": path.name, "sha256": digest}


def _interpolation(t: FirmwareTables) -> dict:
    return {
        "method": t.method,
        "calibration_method": t.calibration_method,
        **({"degree": t.degree} if t.degree is not None else {}),
        "interpolated": "K and B entries; K is inverted after interpolation"
        if t.calibration_method != "continuous"
        else "none: K and B entries are the continuous model's polynomials; K is inverted after",
        "outside_range": "clamp",
        "range": [float(t.temperature[0]), float(t.temperature[-1])],
    }


def to_document(cal: Calibration, tables: FirmwareTables, *, source=None) -> dict[str, Any]:
    """The ``gyrocal.firmware/1`` JSON document."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        **{k: cal.meta.get(k) for k in ("device", "batch", "session", "protocol")},
        "source": _source_info(source),
        "gyrocal_version": __version__,
        "units": UNITS,
        "model": "w = K(T) w_true + B(T)",
        "compensation": "w_true = K(T)^-1 (w - B(T))",
        "interpolation": _interpolation(tables),
        "temperature": tables.temperature.tolist(),
        "K": tables.K.tolist(),
        "B": tables.B.tolist(),
        "K_inv": tables.K_inv.tolist(),
    }
    if tables.method == "spline" and tables.spline_K is not None and tables.spline_B is not None:
        doc["spline"] = {"K": tables.spline_K.tolist(), "B": tables.spline_B.tolist()}
    if tables.method == "poly" and tables.poly_K is not None and tables.poly_B is not None:
        doc["poly"] = {
            "degree": tables.degree,
            "centre": tables.poly_centre,
            "half_range": tables.poly_half_range,
            "K": tables.poly_K.tolist(),
            "B": tables.poly_B.tolist(),
        }
    if tables.splines:
        doc["splines"] = _spline_entries(tables.splines)
        doc["time"] = "t: seconds since power-on"
    if tables.histories:
        doc["histories"] = _history_entries(tables.histories)
    if tables.temperature_histories:
        doc["temperature_histories"] = _temperature_history_entries(tables.temperature_histories)
    if tables.die_tau is not None:
        doc["model"] = "w = K(T_die) w_true + B(T_die)"
        doc["compensation"] = "w_true = K(T_die)^-1 (w - B(T_die))"
        doc["die_temperature"] = {
            "tau_s": tables.die_tau,
            "filter": DIE_FILTER,
            "time": "t in seconds, increasing",
        }
    return doc


def _spline_entries(splines: tuple) -> list[dict[str, Any]]:
    return [
        {
            "label": s["label"],
            "input": s["input"],
            "by": s["by"],
            "degree": 3,
            "knots": s["knots"].tolist(),
            "coefficients": s["coefficients"].tolist(),
            "adds_to": "K diagonal (times nothing: K_aa += s_a(x))" if s["by"] else "B (B_a += s_a(x))",
            "outside_knots": "clamp",
        }
        for s in splines
    ]


def _history_entries(histories: tuple) -> list[dict[str, Any]]:
    return [
        {
            "label": h["label"],
            "formula": h["formula"],
            "input": HISTORY_INPUTS[h["input"]],
            "tau_s": h["tau"],
            "filter": LAG_FILTER,
            "coefficients": h["coefficients"].tolist(),
            "adds_to": "B (B_a += c_a y_a)" + ("; K's diagonal: K_aa -= c_a" if h["diagonal"] else ""),
        }
        for h in histories
    ]


def _temperature_history_entries(histories: tuple) -> list[dict[str, Any]]:
    from ..terms.signals import ROOM_C, TEMPERATURE_SMOOTHING_S

    return [
        {
            "label": h["label"],
            "formula": h["formula"],
            "operator": h["operator"],
            "input": f"x: the logged temperature through a first-order lag of {TEMPERATURE_SMOOTHING_S:g} s "
            "(the filter of 'histories', u the temperature, one filter per term)",
            "lag_tau_s": TEMPERATURE_SMOOTHING_S,
            "w": h["w"],
            **({"T0": h["T0"], "m": h["m"]} if h["operator"] == "switch" else {}),
            "value": TEMPERATURE_HISTORY_VALUES[h["operator"]],
            "start": TEMPERATURE_HISTORY_START.format(room=ROOM_C),
            "filter": LAG_FILTER.split("; one filter")[0],
            "coefficients": h["coefficients"].tolist(),
            "adds_to": "B (B_a += c_a value)",
        }
        for h in histories
    ]


# -- C -------------------------------------------------------------------------------
def c_number(x) -> str:
    """Shortest decimal that reads back to the same double; also a valid C literal."""
    x = float(x)
    if not np.isfinite(x):
        raise InputError(f"cannot write the non-finite number {x!r} into C")
    return repr(x)


def c_array(values, indent: str = "    ", level: int = 0) -> str:
    """A nested C initialiser, innermost lists on one line."""
    if not isinstance(values, (list, tuple)):
        return c_number(values)
    if all(not isinstance(v, (list, tuple)) for v in values):
        return "{" + ", ".join(c_number(v) for v in values) + "}"
    inner = indent * (level + 1)
    return (
        "{\n"
        + ",\n".join(inner + c_array(v, indent, level + 1) for v in values)
        + "\n"
        + indent * level
        + "}"
    )


def c_string(value) -> str:
    """A C string literal; anything but printable ASCII as octal escapes."""
    out = []
    for byte in ("" if value is None else str(value)).encode():
        ch = chr(byte)
        if ch in '"\\?':
            out.append("\\" + ch)
        elif 32 <= byte < 127:
            out.append(ch)
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def c_comment(value) -> str:
    """Text safe inside a C block comment."""
    text = "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in ("-" if value is None else str(value)))
    return text.replace("*/", "* /").replace("/*", "/ *")


@cache
def _c_environment():
    """The header's Jinja environment, beside its template: nothing HTML-escaped (strings are
    made safe for C by the filters below), a name the template uses but is not given is an
    error, and block tags on lines of their own leave no blank lines."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("gyrocal.calibration", "templates"),
        autoescape=False,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters.update(
        c_number=c_number,
        c_string=c_string,
        c_comment=c_comment,
        c_array=lambda v: c_array(np.asarray(v).tolist()),
    )
    return env


def render_c_header(cal: Calibration, tables: FirmwareTables, *, source=None) -> str:
    from ..terms.signals import DUHEM_BAND, ROOM_C, TEMPERATURE_SMOOTHING_S

    return (
        _c_environment()
        .get_template("compensation.h.j2")
        .render(
            t=tables,
            meta={k: cal.meta.get(k) for k in ("device", "batch", "session", "protocol")},
            source=_source_info(source),
            version=__version__,
            format=FORMAT,
            n=len(tables.temperature),
            room=ROOM_C,
            smoothing=TEMPERATURE_SMOOTHING_S,
            band=DUHEM_BAND,
        )
    )


def _render(cal: Calibration, tables: FirmwareTables, fmt: str, source) -> str:
    if fmt == "json":
        from .file import dumps

        return dumps(to_document(cal, tables, source=source))
    return render_c_header(cal, tables, source=source)


def _check_format(fmt: str) -> None:
    if fmt not in FORMATS:
        raise ConfigError(f"export format {fmt!r} is not known; choose one of {', '.join(FORMATS)}")


def export_text(cal: Calibration, fmt: str, *, source=None) -> str:
    """The export of ``cal`` in ``fmt`` (``c-header`` or ``json``) as text."""
    _check_format(fmt)
    return _render(cal, firmware_tables(cal, source=source), fmt, source)


def export_calibration(cal: Calibration, fmt: str, out, *, source=None) -> FirmwareTables:
    """Write the export of ``cal`` to ``out`` (atomically); return its tables."""
    _check_format(fmt)
    tables = firmware_tables(cal, source=source)
    text = _render(cal, tables, fmt, source)
    out = Path(out)
    try:
        atomic.write_text(out, text)
    except OSError as exc:
        raise InputError(f"cannot write the export ({exc.strerror})", source=out) from None
    return tables


def _precheck(path) -> None:
    """Refuse unsupported terms by name before parsing, so that a user term from a term
    file that is not loaded is named as such rather than as an unknown term."""
    try:
        model = json.loads(Path(path).read_text())["model"]
        kind = model.get("kind")
        extra = unsupported_terms(model["terms"], kind)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return  # load_calibration says what is wrong
    if extra and kind in ("temperature_grid", "continuous"):
        _refuse(extra, kind, path)


def infer_format(output) -> str:
    suffix = Path(output).suffix.lower()
    for fmt, ext in FORMATS.items():
        if suffix == ext:
            return fmt
    raise ConfigError(f"cannot tell the export format from {output!r}: give --format c-header or json")


def cmd_export(args) -> int:
    fmt = args.format or infer_format(args.output)
    from .file import load_calibration

    if args.device is not None:  # the unit's calibration at a date, as gyrocal lookup finds it
        from .lookup import find_calibration

        found = find_calibration(args.calibration, args.device, args.date, registry=args.registry)
        if found.warning:
            print(f"gyrocal: warning: {found.warning}", file=sys.stderr)
        args.calibration = str(found.path)
    elif args.date is not None or args.registry is not None:
        raise ConfigError("--date and --registry choose a unit's calibration: give --device too")
    _precheck(args.calibration)
    cal = load_calibration(args.calibration)
    tables = export_calibration(cal, fmt, args.output, source=args.calibration)
    lo, hi = tables.temperature[0], tables.temperature[-1]
    print(
        f"firmware {fmt} -> {args.output} ({len(tables.temperature)} points, {tables.method}, "
        f"{lo:g} to {hi:g} °C, clamped outside)"
    )
    return 0


def add_export_parser(subparsers):
    """Register ``gyrocal export`` on the CLI's subparsers."""
    p = subparsers.add_parser("export", help="a calibration for firmware: C header or JSON")
    p.add_argument(
        "calibration",
        help="calibration .json (gyrocal.calibration/1), or with --device a results folder to look it up in",
    )
    p.add_argument("--device", help="export this unit's calibration, found as gyrocal lookup finds it")
    p.add_argument(
        "--date", help="with --device: the session nearest this date, YYYY-MM-DD (default: the latest)"
    )
    p.add_argument(
        "--registry",
        help="with --device: the registry to look it up in (default: the folder's, else its files)",
    )
    p.add_argument(
        "--format",
        choices=list(FORMATS),
        help="c-header (grid, K, B and a reference C implementation) or json "
        "(default: from the suffix of -o, .h or .json)",
    )
    p.add_argument("-o", "--output", required=True, help="the file to write, .h or .json")
    p.set_defaults(func=cmd_export)
    return p
