"""The calibration a run produces, its file format ``gyrocal.calibration/1``, and applying it.

The file (contract section 4) holds the model's terms and, per grid temperature, every
fitted coefficient with its standard error plus the matrix ``K`` and vector ``B`` they
imply, so that firmware and other tools can use ``w = K(T) w_true + B(T)`` without
knowing the terms. :func:`Calibration.from_dict` is the only parser: every loader calls
it, it checks the format version, rebuilds the terms from the registry and verifies that
``K`` and ``B`` agree with the coefficients.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from ..fit.model import Model
from ..fit.thermal import DIAGONAL_RTOL, ConstantCoefficients, TemperatureGrid, check_method, warn_outside
from ..io import atomic, formats
from ..io.errors import CalibrationFileError, CorruptFileError, GyrocalError, MissingInputError
from ..terms import AXES
from ..terms.signals import SERIES_INPUTS, Inputs

FORMAT = formats.CALIBRATION
FORMAT_FAMILY, FORMAT_VERSION = FORMAT.split("/")
UNITS = {"rate": "deg/s", "temperature": "degC", "K": "1", "B": "deg/s"}


def distinct_rows(columns: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of float columns (each (n,)), compared bit for bit: a
    representative row of each, and each row's distinct row (``first[index]`` is a row
    equal to every row)."""
    import pandas as pd  # loaded already by the calibration's modules; hashing, no sort

    n = len(columns[0])
    index = np.zeros(n, np.int64)
    for column in columns:
        bits = np.ascontiguousarray(column, dtype=np.float64).view(np.int64)
        own, values = pd.factorize(bits)
        index = pd.factorize(index * len(values) + own)[0]
    first = np.empty(int(index.max()) + 1 if n else 0, np.int64)
    first[index] = np.arange(n)
    return first, index


def inverse3(M: np.ndarray) -> np.ndarray:
    """Inverses of 3 x 3 matrices (n, 3, 3) by their adjugates: vectorised, where LAPACK
    takes a call per matrix. For the well-conditioned Jacobians of a gyro's output (the
    identity within a few per cent); the solve's check catches any other."""
    a, b, c = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    d, e, f = M[:, 1, 0], M[:, 1, 1], M[:, 1, 2]
    g, h, i = M[:, 2, 0], M[:, 2, 1], M[:, 2, 2]
    adj = np.stack(
        [
            np.stack([e * i - f * h, c * h - b * i, b * f - c * e], axis=1),
            np.stack([f * g - d * i, a * i - c * g, c * d - a * f], axis=1),
            np.stack([d * h - e * g, b * g - a * h, a * e - b * d], axis=1),
        ],
        axis=1,
    )
    det = a * adj[:, 0, 0] + b * adj[:, 1, 0] + c * adj[:, 2, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return adj / det[:, None, None]


def standard_coefficients(K: np.ndarray, B: np.ndarray) -> dict[str, np.ndarray]:
    """K (n,3,3) and B (n,3) as the seed-000 terms' coefficients: ``bias.a`` = B_a,
    ``scale.a`` = K_aa − 1, ``misalignment.a.b`` = K_ab (Eq 12, names of docs/method.md)."""
    out = {}
    for i, a in enumerate(AXES):
        out[f"bias.{a}"] = B[:, i]
        out[f"scale.{a}"] = K[:, i, i] - 1.0
        for j, b in enumerate(AXES):
            if i != j:
                out[f"misalignment.{a}.{b}"] = K[:, i, j]
    return out


# The largest of N Gaussian readings lies near sqrt(2 ln N) standard deviations out (4.5 for
# a point's 30,000 samples); another session's largest passes 1.5 times that (6.8) with a
# chance of about 1e-7: a row beyond it is beyond the calibration's own scatter.
EXTREME_MARGIN = 1.5


@dataclass(frozen=True)
class Calibration:
    """A fitted model over a temperature grid, plus who and what it belongs to."""

    model: Model
    grid: TemperatureGrid | ConstantCoefficients  # per-point values, or one set
    reference_temperature: float = 25.0
    meta: dict = field(default_factory=dict)  # device, batch, session, protocol
    provenance: dict = field(default_factory=dict)  # input, versions, config hash
    extra: dict = field(default_factory=dict)  # carried along, not needed to apply
    covariates: dict = field(default_factory=dict)  # how apply derives inputs, e.g. temp_rate

    @property
    def kind(self) -> str:
        return "continuous" if isinstance(self.grid, ConstantCoefficients) else "temperature_grid"

    def coefficients(self, temp, *, warn: bool = True) -> dict[str, np.ndarray]:
        return self.grid.at(temp, warn=warn)

    def range_tolerance(self) -> tuple[float, float]:
        """How far below and above the calibrated range (°C) a temperature still counts as
        within it: :data:`EXTREME_MARGIN` times how far the calibration's own readings went
        beyond its end points (each used point's ``temp_range`` in the file: the lowest and
        highest temperature read during its holds, :class:`gyrocal.pipeline.chain.HeldTemperatures`).
        A turntable point sits at its holds' typical temperature while its samples scatter
        about it by the sensor's noise, and another session of the same rig scatters as far:
        such a row is read at the end point as the calibration's own were. Where the range
        already ends near the readings' extremes (a sweep's bins) little is left beyond it
        but their noise. A file
        that records no range (written before gyrocal kept it, or by a protocol with a
        calibration of its own) gives 0 too: its range is the grid's."""
        used = [p for p in self.extra.get("points", ()) if p.get("used", True) and "temperature" in p]
        if not used:
            return 0.0, 0.0
        lowest, highest = min(used, key=lambda p: p["temperature"]), max(used, key=lambda p: p["temperature"])
        lo, hi = self.grid.span
        below = lo - float(lowest["temp_range"][0]) if "temp_range" in lowest else 0.0
        above = float(highest["temp_range"][1]) - hi if "temp_range" in highest else 0.0
        return EXTREME_MARGIN * max(below, 0.0), EXTREME_MARGIN * max(above, 0.0)

    def beyond_tolerance(self, temp) -> np.ndarray:
        """Which temperatures lie outside the calibrated range by more than
        :meth:`range_tolerance`: the rows apply warns of (all outside it are clamped)."""
        temp = np.asarray(temp, dtype=float)
        (lo, hi), (below, above) = self.grid.span, self.range_tolerance()
        return (temp < lo - below) | (temp > hi + above)

    def clamp(self, temp) -> np.ndarray:
        """Temperatures limited to the calibrated range: terms never extrapolate."""
        lo, hi = self.grid.span
        return np.clip(np.asarray(temp, dtype=float), lo, hi)

    def _neutral(self, n: int, temp) -> dict[str, np.ndarray]:
        """Covariates at their reference values: temperature as given, others zero."""
        data = {name: np.zeros(n) for name in self.model.inputs if name not in SERIES_INPUTS}
        data["temp"] = np.broadcast_to(self.clamp(temp), (n,)).copy()
        return data

    @property
    def static_model(self) -> Model:
        """The model's terms that read no series signal: what K(T) and B(T) describe. Terms
        of time or temperature history (a warm-up, a lag) are the contract's "other terms"."""
        data = Inputs(self._neutral(1, [self.reference_temperature]))
        data.update({c: np.zeros(1) for c in ("rate_x", "rate_y", "rate_z")})
        keep = []
        for term in self.model.terms:
            probe = Inputs(data)
            try:
                term.columns(probe)
            except MissingInputError:
                continue
            if not probe.read & SERIES_INPUTS:
                keep.append(term)
        return Model(tuple(keep))

    def matrices_at(self, temps) -> tuple[np.ndarray, np.ndarray]:
        """K (n, 3, 3) and B (n, 3) at temperatures: the affine part of the model's static
        terms (:attr:`static_model`) with covariates other than temperature at zero."""
        temps = np.atleast_1d(np.asarray(temps, dtype=float))
        coefs = self.coefficients(temps, warn=False)
        return self.static_model.linearise(coefs, self._neutral(len(temps), temps), np.zeros((len(temps), 3)))

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """K and B at the calibration's own temperature points."""
        return self.matrices_at(self.grid.temperatures)

    def compensate(self, gyro: np.ndarray, data: dict, *, warn: bool = True) -> np.ndarray:
        """True rates (n, 3) from raw outputs (n, 3); ``data`` holds ``temp`` and whatever
        else the model's terms need. Temperatures outside the calibrated range use the
        calibration at the nearest end (warned). A model whose temperature is the die's
        filters ``temp`` over ``data``'s samples, taken as a record from its start, unless
        ``data`` holds it filtered already (``temp_logged`` beside it).

        Rows that differ only in their output share their coefficients and the model's
        linearisation at zero rate, the first step of the solve: those are made once per
        distinct row (a log's temperature takes tens to thousands of values in a batch of
        262,144 samples), the solve's check and any further step per sample."""
        self.model.check_inputs({**data, "rate_x": 0, "rate_y": 0, "rate_z": 0})
        if "temp_logged" not in data:  # samples from the record's start (apply filters batches)
            for transform in self.model.sample_transforms():
                data = transform(data)
        gyro = np.asarray(gyro, dtype=float)
        temp = np.asarray(data["temp"], dtype=float)
        if warn:
            warn_outside(self.grid, temp)
        covariates = {**data, "temp": self.clamp(temp)}
        reads = sorted(k for k in self.model.inputs if k in covariates and k != "temp")
        shared = (
            None
            if self.model.inputs & SERIES_INPUTS
            else distinct_rows([temp, *(covariates[k] for k in reads)])
        )
        if shared is None or len(shared[0]) > len(temp) // 2:  # little to share (time, noise)
            w_true, _ = self.model.compensate(self.coefficients(temp, warn=False), gyro, covariates)
            return w_true
        first, index = shared
        at = {k: v[first] if isinstance(v, np.ndarray) and v.ndim else v for k, v in covariates.items()}
        coefs = self.coefficients(temp[first], warn=False)
        J, c = self.model.linearise(coefs, at, np.zeros((len(first), 3)))
        # w_true = J^-1 (w - c) = A w + d per distinct row, spread to the rows in one gather
        A = inverse3(J)
        Ad = np.take(
            np.concatenate([A.reshape(-1, 9), -np.einsum("nij,nj->ni", A, c)], axis=1), index, axis=0
        )
        w_true = np.einsum("nij,nj->ni", Ad[:, :9].reshape(-1, 3, 3), gyro) + Ad[:, 9:]
        names = list(coefs)
        spread = np.take(np.stack([coefs[k] for k in names]), index, axis=1)
        w_true, _ = self.model.compensate(
            dict(zip(names, spread, strict=False)), gyro, covariates, start=(w_true, None)
        )
        return w_true

    # -- file format -----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        K, B = self.matrices()
        g = self.grid
        extra_grid = {}
        interpolation: dict[str, Any]
        if isinstance(g, ConstantCoefficients):  # kind continuous
            coefficients = {n: float(v) for n, v in zip(g.names, g.values, strict=False)}
            stderr = {n: float(v) for n, v in zip(g.names, g.stderr, strict=False)}
            interpolation = {"method": "none", "outside_range": "clamp"}
            if g.fitted_span is not None:
                extra_grid["span"] = [float(v) for v in g.fitted_span]
        else:
            coefficients = {n: g.values[:, j].tolist() for j, n in enumerate(g.names)}
            stderr = {n: g.stderr[:, j].tolist() for j, n in enumerate(g.names)}
            interpolation = {"method": g.method, "degree": g.degree, "outside_range": "clamp"}
        if g.covariance is not None:
            extra_grid["covariance"] = g.covariance.tolist()  # canonical: see thermal.py
        body = {
            "format": FORMAT,
            **{k: self.meta.get(k) for k in ("device", "batch", "session", "protocol")},
            "units": {**UNITS, "coefficients": self._coefficient_units()},
            "model": {
                "kind": self.kind,
                "terms": self.model.spec(),
                "interpolation": interpolation,
                "reference_temperature": self.reference_temperature,
                **({"covariates": self.covariates} if self.covariates else {}),
            },
            "grid": {
                "temperature": g.temperatures.tolist(),
                "K": K.tolist(),
                "B": B.tolist(),
                "coefficients": coefficients,
                "stderr": stderr,
                **extra_grid,
            },
            "provenance": self.provenance,
            **self.extra,
        }
        _check_finite(body)
        return body

    def _coefficient_units(self) -> dict[str, str]:
        return {t.name: t.unit for t in self.model.terms}

    @classmethod
    def from_dict(cls, d: dict, *, source=None) -> Calibration:
        """Parse and check a ``gyrocal.calibration/1`` document."""

        def fail(problem: str) -> NoReturn:
            raise CalibrationFileError(problem, source=source)

        if not isinstance(d, dict):
            fail("is not a JSON object")
        _check_format(d, fail)
        try:
            model_d, grid_d = d["model"], d["grid"]
            parsed = _model_section(model_d, fail)
            units = d.get("units", UNITS)
            wrong = {k: units.get(k) for k, v in UNITS.items() if units.get(k) != v}
            if wrong:
                fail(f"units {wrong} are not the {UNITS} this gyrocal writes and reads")
            names = tuple(parsed.model.names)
            temps, values, stderr = _grid_values(grid_d, parsed.kind, names, fail)
        except KeyError as exc:
            fail(f"missing key {exc.args[0]!r}")
        except (TypeError, AttributeError):
            fail("has a malformed model or grid section")
        grid = _grid(grid_d, parsed, names, temps, values, stderr, fail)
        known = {"format", "device", "batch", "session", "protocol", "units", "model", "grid", "provenance"}
        cal = cls(
            parsed.model,
            grid,
            float(parsed.reference),
            {k: d.get(k) for k in ("device", "batch", "session", "protocol")},
            d.get("provenance", {}),
            {k: v for k, v in d.items() if k not in known},
            parsed.covariates,
        )
        _check_matrices(cal, grid_d, fail)
        return cal


Fail = Callable[[str], NoReturn]


def _check_format(d: dict, fail: Fail) -> None:
    """A calibration document of the version this gyrocal reads (a failure record says which
    stage failed instead)."""
    fmt = d.get("format")
    if fmt == "gyrocal.failure/1":
        fail(f"holds no calibration: the {d.get('stage')} stage failed: {d.get('error')}")
    if not isinstance(fmt, str) or "/" not in fmt or fmt.split("/")[0] != FORMAT_FAMILY:
        fail(f"format is {fmt!r}, expected {FORMAT!r}")
    if fmt.split("/")[1] != FORMAT_VERSION:
        fail(f"format version {fmt.split('/')[1]} is not one this gyrocal reads (it reads {FORMAT_VERSION})")


@dataclass(frozen=True)
class _ModelSection:
    """A calibration file's ``model`` section, checked."""

    kind: str  # "temperature_grid" or "continuous"
    model: Model
    method: str
    degree: int
    reference: float
    covariates: dict


def _model_section(model_d: dict, fail: Fail) -> _ModelSection:
    kind = model_d.get("kind")
    if kind not in ("temperature_grid", "continuous"):
        fail(f"model kind {kind!r} is not known")
    try:
        model = Model.from_spec(model_d["terms"])
    except GyrocalError as exc:
        fail(f"model: {exc}")
    interp = model_d["interpolation"]
    method, degree = interp["method"], interp.get("degree", 3)
    if kind == "temperature_grid":
        try:
            check_method(method, degree)
        except GyrocalError as exc:
            fail(str(exc))
    reference = model_d.get("reference_temperature", 25.0)
    if isinstance(reference, bool) or not isinstance(reference, (int, float)) or not math.isfinite(reference):
        fail(f"model reference_temperature must be a number, got {reference!r}")
    covariates = model_d.get("covariates", {})
    window = covariates.get("temp_rate", {}).get("window_s", 60.0)
    if (
        isinstance(window, bool)
        or not isinstance(window, (int, float))
        or not math.isfinite(window)
        or window <= 0
    ):
        fail(f"model covariates temp_rate window_s must be a positive number, got {window!r}")
    return _ModelSection(kind, model, method, degree, reference, covariates)


def _grid_values(
    grid_d: dict, kind: str, names: tuple[str, ...], fail: Fail
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's temperatures, and its coefficients and standard errors: one set for a
    continuous model, one row per temperature for a grid."""
    temps = _floats(grid_d["temperature"], "grid.temperature", fail)
    if kind == "continuous":
        values = np.array([_number(grid_d["coefficients"][n], f"coefficient {n}", fail) for n in names])
        stderr = np.array([_number(grid_d["stderr"][n], f"stderr {n}", fail) for n in names])
        return temps, values, stderr
    values = (
        np.column_stack([_floats(grid_d["coefficients"][n], f"coefficient {n}", fail) for n in names])
        if names
        else np.zeros((len(temps), 0))
    )
    stderr = (
        np.column_stack([_floats(grid_d["stderr"][n], f"stderr {n}", fail) for n in names])
        if names
        else np.zeros((len(temps), 0))
    )
    return temps, values, stderr


def _grid(
    grid_d: dict,
    parsed: _ModelSection,
    names: tuple[str, ...],
    temps: np.ndarray,
    values: np.ndarray,
    stderr: np.ndarray,
    fail: Fail,
) -> TemperatureGrid | ConstantCoefficients:
    """The coefficients over temperature, their shapes, covariance and span checked."""
    continuous = parsed.kind == "continuous"
    if continuous and (len(temps) == 0 or np.any(np.diff(temps) <= 0)):
        fail("grid temperatures must increase strictly")
    if not continuous and (values.shape[0] != len(temps) or stderr.shape[0] != len(temps)):
        fail("grid coefficients and temperatures differ in length")
    covariance = _covariance(grid_d.get("covariance"), stderr, names, temps, fail)
    span = None
    if continuous and "span" in grid_d:
        ends = _floats(grid_d["span"], "grid.span", fail)
        if ends.shape != (2,) or not ends[0] <= temps[0] <= temps[-1] <= ends[1]:
            fail("grid.span must be [low, high] around the grid temperatures")
        span = (float(ends[0]), float(ends[1]))
    try:
        if continuous:
            return ConstantCoefficients(temps, names, values, stderr, fitted_span=span, covariance=covariance)
        return TemperatureGrid(temps, names, values, stderr, parsed.method, parsed.degree, covariance)
    except GyrocalError as exc:
        fail(f"grid: {exc}")


def _check_matrices(cal: Calibration, grid_d: dict, fail: Fail) -> None:
    """The file's K and B are what its coefficients give (a hand edit of one is refused)."""
    K, B = cal.matrices()
    try:
        stored_K = np.asarray(grid_d["K"], dtype=float)
        stored_B = np.asarray(grid_d["B"], dtype=float)
    except KeyError as exc:
        fail(f"missing key {exc.args[0]!r}")
    except (TypeError, ValueError):
        fail("grid K and B must be nested lists of numbers")
    if not (np.all(np.isfinite(stored_K)) and np.all(np.isfinite(stored_B))):
        fail("grid K and B must hold finite numbers")
    if (
        stored_K.shape != K.shape
        or stored_B.shape != B.shape
        or not np.allclose(stored_K, K, rtol=1e-9, atol=1e-12)
        or not np.allclose(stored_B, B, rtol=1e-9, atol=1e-12)
    ):
        fail("grid K and B do not match the coefficients (edited by hand?)")


# A covariance is judged at its own scale: entry (i, j) against sqrt(C_ii C_jj), so that the
# covariance between a coefficient of 1e-2 and one of 1e-9 is neither drowned by nor drowns
# the others. Rounding leaves about 1e-16 of that scale. The diagonal's tolerance
# (DIAGONAL_RTOL) is the one files already written were read with.
ASYMMETRY_RTOL = 1e-9  # |C_ij − C_ji| ≤ rtol sqrt(C_ii C_jj)
CORRELATION_SLACK = 1e-6  # |C_ij| ≤ (1 + slack) sqrt(C_ii C_jj): correlations within ±1


def covariance_problem(cov, stderr, names, temps) -> str | None:
    """What is wrong with a covariance (one per point (P, C, C), or one (C, C)) beside its
    standard errors, naming the point, the pair of coefficients and the size; None when
    nothing is."""
    cov, stderr = np.asarray(cov, dtype=float), np.asarray(stderr, dtype=float)
    if np.any(stderr < 0):
        return "stderr holds a negative number"
    per_point = cov.ndim == 3
    if not per_point:
        cov, stderr = cov[None], stderr[None]
    variance = stderr**2
    scale = stderr[:, :, None] * stderr[:, None, :]  # sqrt(C_ii C_jj) as written

    def at(p):
        return f" at {float(temps[p]):g} °C (point {p + 1} of {len(temps)})" if per_point else ""

    diag = np.diagonal(cov, axis1=-2, axis2=-1)
    off = np.abs(diag - variance)
    if np.any(off > DIAGONAL_RTOL * variance):
        p, i = np.unravel_index(np.argmax(off / np.where(variance > 0, variance, 1e-300)), off.shape)
        return (
            f"grid.covariance{at(p)}: C[{names[i]},{names[i]}] = {float(diag[p, i]):.17g} "
            f"is not the squared stderr {float(variance[p, i]):.17g}"
        )
    for size, limit, what in (
        (
            np.abs(cov - np.swapaxes(cov, -1, -2)),
            ASYMMETRY_RTOL * scale,
            "is not symmetric: |C[{a},{b}] − C[{b},{a}]| = {x:.3g}",
        ),
        (np.abs(cov), (1 + CORRELATION_SLACK) * scale, "is not a covariance: |C[{a},{b}]| = {x:.3g}"),
    ):
        bad = size > limit
        if bad.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(bad, size / scale, 0.0)  # against a zero: infinite
            p, i, j = np.unravel_index(np.argmax(ratio), ratio.shape)
            a, b = names[i], names[j]
            times = f"{float(ratio[p, i, j]):.3g} times" if np.isfinite(ratio[p, i, j]) else "against a zero"
            return (
                f"grid.covariance{at(p)} {what.format(a=a, b=b, x=float(size[p, i, j]))}, "
                f"{times} sqrt(C[{a},{a}] C[{b},{b}])"
            )
    return None


def _covariance(value, stderr: np.ndarray, names, temps, fail: Fail) -> np.ndarray | None:
    """The grid's coefficient covariances (per point, or one for a continuous model):
    finite, symmetric, within ±1 in correlation, their diagonal the squared standard
    errors, each entry judged at its own scale (:func:`covariance_problem`). Absent in
    files of older gyrocal versions: None."""
    if value is None:
        return None
    try:
        cov = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        fail("grid.covariance must be nested lists of numbers")
    C = stderr.shape[-1]
    if cov.shape != stderr.shape + (C,) or not np.all(np.isfinite(cov)):
        fail(f"grid.covariance must hold a finite {C} x {C} matrix per point")
    problem = covariance_problem(cov, stderr, names, temps)
    if problem:
        fail(problem)
    return cov


def _number(value, what: str, fail: Fail) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(f"{what} must be a finite number")
    return float(value)


def _floats(values, what: str, fail: Fail) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        fail(f"{what} must be a list of numbers")
    if a.ndim != 1 or not np.all(np.isfinite(a)):
        fail(f"{what} must be a list of finite numbers")
    return a


def _check_finite(value, path: str = "") -> None:
    """Refuse to write NaN or infinity anywhere in a calibration file."""
    if isinstance(value, float) and not math.isfinite(value):
        raise GyrocalError(f"refusing to write a non-finite value at {path or 'top level'}")
    if isinstance(value, dict):
        for k, v in value.items():
            _check_finite(v, f"{path}.{k}" if path else str(k))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_finite(v, f"{path}[{i}]")


def dumps(document, indent: str = "  ", level: int = 0) -> str:
    """JSON with objects indented and lists of scalars (rows of K, B, grids) on one line."""
    return _dump(document, indent, level) + ("\n" if level == 0 else "")


def _dump(value, indent: str, level: int) -> str:
    pad, inner = indent * level, indent * (level + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{json.dumps(str(k))}: {_dump(v, indent, level + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, (list, tuple)):
        if all(not isinstance(v, (dict, list, tuple)) for v in value):
            return "[" + ", ".join(json.dumps(v, allow_nan=False) for v in value) + "]"
        return "[\n" + ",\n".join(inner + _dump(v, indent, level + 1) for v in value) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False)


def save_calibration(cal: Calibration, path) -> None:
    """Write the calibration file, read back with the loader every reader uses before it
    takes the target's name: a file that cannot be read, or that reads as another
    calibration, never leaves the stage."""
    path = Path(path)
    text = dumps(cal.to_dict())
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic.replacing(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
        try:
            again = dumps(load_calibration(tmp).to_dict())
        except GyrocalError as exc:
            raise GyrocalError(
                f"the calibration written does not read back "
                f"({str(exc).removeprefix(f'{tmp}: ')}); nothing written",
                source=path,
            ) from None
        if again != text:
            old, new = text.splitlines(), again.splitlines()
            line = next(
                (i for i, (a, b) in enumerate(zip(old, new, strict=False)) if a != b), min(len(old), len(new))
            )
            raise GyrocalError(
                f"the calibration written reads back as another one (line {line + 1} "
                "differs); nothing written",
                source=path,
            )


def load_calibration(path) -> Calibration:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CorruptFileError(f"cannot read ({exc})", source=path) from None
    try:
        d = json.loads(text)
    except ValueError as exc:
        raise CalibrationFileError(f"not valid JSON ({exc})", source=path) from None
    return Calibration.from_dict(d, source=path)
