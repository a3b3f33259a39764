"""End of line: does each calibrated unit meet its spec, how many of a batch do, and which
units stand out from their batch.

* :class:`SpecLimits` — the limits, from the config's ``spec`` mapping (every key checked).
* :func:`judge` — one unit's :class:`Verdict`, every failed limit listed with its value, limit
  and unit; a unit whose calibration failed fails with that failure as its reason.
* :func:`batch_yield` — units, passed, failed and yield per batch.
* :func:`fleet_outliers` — robust z-scores (median/MAD) per parameter within a batch.
* :func:`plot_parameter_distributions` — each parameter's distribution per batch, outliers
  marked.

Parameters are the calibration's coefficients at one temperature (:func:`parameters_at`), in
engineering units: ``scale.*`` (``K_aa − 1``) in ppm, ``misalignment.*`` (``K_ab``, a small
angle) in mrad, ``bias.*`` in deg/s, other dimensionless coefficients in ppm and the rest in
their term's own unit (``gyrocal/terms``). For continuous models ``bias``, ``scale`` and
``misalignment`` are read from ``K(T)`` and ``B(T)``, so that temperature terms
(``bias_temp_poly`` ...) are included.
"""

from __future__ import annotations

import fnmatch
import json
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .calibration import Calibration, load_calibration, standard_coefficients
from .errors import ConfigError, GyrocalError, InputError

AXES = ("x", "y", "z")
# term name -> (display unit, factor from the coefficient's own unit)
DISPLAY = {"scale": ("ppm", 1e6), "misalignment": ("mrad", 1e3), "bias": ("deg/s", 1.0)}
STANDARD_TERMS = ("bias", "scale", "misalignment")
MIN_BATCH = 5            # fewer units than this: a median/MAD says nothing, no outlier flags
MAD_Z = 0.6745           # Φ⁻¹(0.75): MAD / 0.6745 estimates σ for normal data (Iglewicz & Hoaglin)
TC_SAMPLES = 401         # temperatures at which d/dT is evaluated across the calibrated span
NOISE_LIMITS = {"arw": ("angle random walk", "deg/√h"), "bias_instability": ("bias instability", "deg/h"),
                "rrw": ("rate random walk", "deg/h/√h"), "quantisation": ("quantisation noise", "arcsec")}


# -- parameters of a calibration ------------------------------------------------------------
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
    """Every parameter at ``temps`` (clamped to the calibrated span), in display units."""
    temps = np.atleast_1d(np.asarray(temps, dtype=float))
    values = cal.coefficients(temps, warn=False)
    if cal.kind == "continuous":
        K, B = cal.matrices_at(temps)
        values = {**values, **_standard_from_KB(K, B, values)}
    return {n: np.asarray(values[n], dtype=float) * f for n, (_, f) in _display(cal).items()}


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
    if cal.kind == "continuous":
        se = dict(zip(cal.grid.names, np.asarray(cal.grid.stderr, dtype=float)))
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
    return pd.DataFrame({
        "parameter": names,
        "value": [float(values[n]) for n in names],
        "stderr": [float(se[n]) * units[n][1] for n in names],
        "unit": [units[n][0] for n in names],
        "temperature": T,
        "clamped": clamped,
    })


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
    return pd.DataFrame({"parameter": list(slope), "value": list(slope.values()),
                         "unit": [f"{units[n][0]}/°C" for n in slope]})


def parameter_table(calibrations: Iterable, *, temperature: float | None = None) -> pd.DataFrame:
    """One row per calibration: device, batch, session and every parameter (display units)
    at ``temperature`` (default: each one's reference temperature); the input of
    :func:`fleet_outliers`. Parameters a unit's model lacks are NaN in its row."""
    rows = []
    for cal in calibrations:
        cal = cal if isinstance(cal, Calibration) else load_calibration(cal)
        p = parameters_at(cal, temperature)
        rows.append({**{k: cal.meta.get(k) for k in ("device", "batch", "session")},
                     **dict(zip(p["parameter"], p["value"]))})
    return pd.DataFrame(rows)


# -- spec limits ----------------------------------------------------------------------------
_PATTERN = re.compile(r"^[A-Za-z0-9_*?]+(\.[A-Za-z0-9_*?]+)*$")


def check_patterns(patterns: Iterable[str], key: str) -> None:
    """Parameter patterns (``scale.x``, ``bias.*``) must be well formed and their first
    part must name a registered term, so that a typo is refused rather than never checked."""
    from .terms import TERMS
    for p in patterns:
        if not isinstance(p, str) or not _PATTERN.match(p):
            raise ConfigError(f"{key}: {p!r} is not a parameter name or pattern like 'scale.x' or 'bias.*'")
        term = p.split(".")[0]
        if not any(fnmatch.fnmatchcase(t, term) for t in TERMS):
            raise ConfigError(f"{key}: {p!r} names no known term (known: {', '.join(sorted(TERMS))})")


def match_pattern(patterns: Iterable[str], name: str) -> str | None:
    """The pattern that governs ``name``: an exact name first, else the matching pattern with
    the most literal characters (``scale.x*`` before ``scale.*`` before ``*``), else None."""
    best, best_key = None, None
    for p in patterns:
        if not fnmatch.fnmatchcase(name, p):
            continue
        key = (p == name, len(p) - p.count("*") - p.count("?"))
        if best_key is None or key > best_key:
            best, best_key = p, key
    return best


def _number(value, key: str, *, positive: bool = False, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{key} must be a finite number, got {value!r}")
    if integer and value != int(value):
        raise ConfigError(f"{key} must be a whole number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{key} must be positive, got {value!r}")
    return float(value)


def _range(value, key: str) -> tuple[float, float]:
    """A limit: a number L means ±L; a pair [low, high] an explicit range."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{key} must be a number (±limit) or [low, high], got {value!r}")
        lo, hi = (_number(v, key) for v in value)
        if lo > hi:
            raise ConfigError(f"{key}: low {lo:g} exceeds high {hi:g}")
        return lo, hi
    limit = _number(value, key, positive=True)
    return -limit, limit


@dataclass(frozen=True)
class SpecLimits:
    """End-of-line limits; any limit left out is not checked.

    ``parameters``: pattern -> (low, high) at ``temperature`` (default: each calibration's
    reference temperature), display units. ``temperature_coefficients``: pattern -> largest
    allowed |d/dT| over the calibrated span (display unit per °C). ``validation_rms`` (deg/s)
    and ``excess`` (validation RMS over the noise floor) from the validation summary.
    ``temperature_span``: the calibrated points must reach both ends (°C), within
    ``temperature_span_tolerance``. ``min_holds``, ``min_hold_share`` (accepted holds over
    candidate holds, 0–1) and ``min_temperature_points`` from the segmentation info.
    ``noise``: the largest axis' IEEE Std 952 term of the session's static data, from the
    calibration file's ``noise`` (:data:`NOISE_LIMITS` names the terms and units).
    """

    parameters: tuple[tuple[str, tuple[float, float]], ...] = ()
    temperature_coefficients: tuple[tuple[str, float], ...] = ()
    temperature: float | None = None
    validation_rms: float | None = None
    excess: float | None = None
    temperature_span: tuple[float, float] | None = None
    temperature_span_tolerance: float = 0.0
    min_holds: int | None = None
    min_hold_share: float | None = None
    min_temperature_points: int | None = None
    noise: tuple[tuple[str, float], ...] = ()

    KEYS = ("parameters", "temperature_coefficients", "temperature", "validation_rms", "excess",
            "temperature_span", "temperature_span_tolerance", "min_holds", "min_hold_share",
            "min_temperature_points", "noise")

    @classmethod
    def from_dict(cls, d: Mapping | None, key: str = "spec") -> SpecLimits:
        d = {} if d is None else d
        if not isinstance(d, Mapping):
            raise ConfigError(f"{key} must be a mapping, got {type(d).__name__}")
        unknown = sorted(str(k) for k in d if k not in cls.KEYS)
        if unknown:
            raise ConfigError(f"unknown setting {key}.{unknown[0]}; known: {', '.join(cls.KEYS)}")
        out: dict = {}
        for name in ("parameters", "temperature_coefficients"):
            section = d.get(name) or {}
            if not isinstance(section, Mapping):
                raise ConfigError(f"{key}.{name} must be a mapping of parameter patterns to limits")
            check_patterns(section, f"{key}.{name}")
            if name == "parameters":
                out[name] = tuple((p, _range(v, f"{key}.{name}.{p}")) for p, v in section.items())
            else:
                out[name] = tuple((p, _number(v, f"{key}.{name}.{p}", positive=True))
                                  for p, v in section.items())
        section = d.get("noise") or {}
        if not isinstance(section, Mapping) or any(k not in NOISE_LIMITS for k in section):
            raise ConfigError(f"{key}.noise must map noise terms ({', '.join(NOISE_LIMITS)}) to limits")
        out["noise"] = tuple((k, _number(v, f"{key}.noise.{k}", positive=True)) for k, v in section.items())
        for name in ("temperature", "validation_rms", "excess", "min_hold_share"):
            if d.get(name) is not None:
                out[name] = _number(d[name], f"{key}.{name}", positive=name != "temperature")
        if out.get("min_hold_share", 0.0) > 1.0:
            raise ConfigError(f"{key}.min_hold_share is a share (0 to 1), got {d['min_hold_share']!r}")
        for name in ("min_holds", "min_temperature_points"):
            if d.get(name) is not None:
                out[name] = int(_number(d[name], f"{key}.{name}", positive=True, integer=True))
        if d.get("temperature_span") is not None:
            span = d["temperature_span"]
            if not isinstance(span, (list, tuple)) or len(span) != 2:
                raise ConfigError(f"{key}.temperature_span must be [low, high] in °C, got {span!r}")
            out["temperature_span"] = _range(span, f"{key}.temperature_span")
        if d.get("temperature_span_tolerance") is not None:
            tol = _number(d["temperature_span_tolerance"], f"{key}.temperature_span_tolerance")
            if tol < 0:
                raise ConfigError(f"{key}.temperature_span_tolerance must be at least 0, got {tol!r}")
            out["temperature_span_tolerance"] = tol
        return cls(**out)

    def to_dict(self) -> dict:
        d = {"parameters": {p: (list(r) if r[0] != -r[1] else r[1]) for p, r in self.parameters},
             "temperature_coefficients": dict(self.temperature_coefficients)}
        if self.noise:
            d["noise"] = dict(self.noise)
        for name in self.KEYS[2:-1]:
            value = getattr(self, name)
            if value is not None:
                d[name] = list(value) if isinstance(value, tuple) else value
        return d


# -- verdicts -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """Pass or fail of one unit, every failed limit as one line, and every value checked
    (name -> value, limit, unit, passed; JSON-plain)."""

    passed: bool
    reasons: tuple[str, ...]
    checked: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)        # device, batch, session, protocol
    calibrated: bool = True                          # False: no calibration to judge

    def to_dict(self) -> dict:
        return {**self.meta, "passed": self.passed, "calibrated": self.calibrated,
                "reasons": list(self.reasons), "checked": self.checked}


def _failure_text(what: str, failed) -> str:
    if isinstance(failed, Mapping):
        return f"{what} failed: the {failed.get('stage')} stage failed: {failed.get('error')}"
    return f"{what} failed: {' '.join(str(failed).split())}"


def _is_failure(x) -> bool:
    from .failure import FORMAT
    return isinstance(x, BaseException) or (isinstance(x, Mapping) and x.get("format") == FORMAT)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def judge(calibration, summary: Mapping | None, seg_info: Mapping | None,
          limits: SpecLimits) -> Verdict:
    """Judge one unit against ``limits``.

    ``calibration`` is a :class:`Calibration`, or the failure record (``gyrocal.failure/1``)
    or exception that stands for one that failed: the unit then fails with that failure as
    its reason. ``summary`` is the validation summary (``validation.json``'s ``summary``),
    ``seg_info`` the segmentation info (the observations' metadata ``info``); either may be
    None or a failure record. A configured limit whose value cannot be had (no validation
    summary, a single-temperature calibration for a temperature coefficient, no rejection
    counts for a hold share) fails the unit, saying so: end of line passes only what it
    has checked.
    """
    if _is_failure(calibration) or calibration is None:
        meta = dict(calibration) if isinstance(calibration, Mapping) else {}
        reason = _failure_text("calibration", calibration) if calibration is not None \
            else "calibration failed: no calibration"
        return Verdict(False, (reason,), {},
                       {k: meta.get(k) for k in ("device", "batch", "session", "protocol")}, False)
    cal: Calibration = calibration
    reasons: list[str] = []
    checked: dict = {}

    def record(name, value, limit, unit, ok, reason=None):
        checked[name] = {"value": value, "limit": limit, "unit": unit, "passed": bool(ok)}
        if not ok:
            reasons.append(reason)

    def unavailable(name, what, why):
        checked[name] = {"value": None, "limit": None, "unit": None, "passed": False, "note": why}
        reasons.append(f"{what} not available: {why}")

    if limits.parameters:
        p = parameters_at(cal, limits.temperature)
        patterns = [pat for pat, _ in limits.parameters]
        ranges = dict(limits.parameters)
        T = float(p["temperature"].iloc[0])
        for name, value, unit, clamped in p[["parameter", "value", "unit", "clamped"]].itertuples(index=False):
            pat = match_pattern(patterns, name)
            if pat is None:
                continue
            lo, hi = ranges[pat]
            symmetric = lo == -hi
            limit_text = f"±{hi:g} {unit}" if symmetric else f"[{lo:g}, {hi:g}] {unit}"
            verb = "exceeds" if symmetric else "outside"
            where = f" at {T:g} °C" + (" (clamped to the calibrated span)" if clamped else "")
            record(name, float(value), [lo, hi], unit, lo <= value <= hi,
                   f"{name} = {_fmt(value)} {unit} {verb} {limit_text}{where}")

    if limits.temperature_coefficients:
        tc = temperature_coefficients(cal)
        patterns = [pat for pat, _ in limits.temperature_coefficients]
        limit_of = dict(limits.temperature_coefficients)
        if tc is None:
            for pat in patterns:
                unavailable(f"d({pat})/dT", f"d({pat})/dT",
                            f"calibrated at a single temperature ({cal.grid.span[0]:.1f} °C)")
        else:
            lo, hi = cal.grid.span
            for name, value, unit in tc.itertuples(index=False):
                pat = match_pattern(patterns, name)
                if pat is None:
                    continue
                lim = limit_of[pat]
                record(f"d({name})/dT", value, lim, unit, value <= lim,
                       f"d({name})/dT = {_fmt(value)} {unit} exceeds ±{lim:g} {unit} "
                       f"over {lo:.1f} to {hi:.1f} °C")

    for key, what, unit in (("validation_rms", "validation RMS", "deg/s"),
                            ("excess", "excess over the noise floor", "×")):
        lim = getattr(limits, key)
        if lim is None:
            continue
        if _is_failure(summary):
            unavailable(key, what, _failure_text("validation", summary).removeprefix("validation failed: "))
            continue
        value = None if summary is None else summary.get(key)
        if value is None or not math.isfinite(value):
            unavailable(key, what, "no validation summary" if summary is None else f"the summary has no {key}")
            continue
        text = f"{_fmt(value)} deg/s exceeds {lim:g} deg/s" if unit == "deg/s" \
            else f"{value:.3g}× exceeds {lim:g}×"
        record(key, float(value), lim, unit, value <= lim, f"{what} = {text}")

    noise = cal.extra.get("noise") or {}
    for term, lim in limits.noise:
        what, unit = NOISE_LIMITS[term]
        if "session" not in noise:
            unavailable(f"noise.{term}", what, noise.get("reason", "the calibration has no noise "
                                                                  "characterisation"))
            continue
        value = float(np.max(noise["session"][term]))
        record(f"noise.{term}", value, lim, unit, value <= lim,
               f"{what} = {value:.3g} {unit} exceeds {lim:g} {unit} (largest axis)")

    if limits.temperature_span is not None:
        want_lo, want_hi = limits.temperature_span
        tol = limits.temperature_span_tolerance
        lo, hi = cal.grid.span
        ok_lo, ok_hi = lo <= want_lo + tol, hi >= want_hi - tol
        checked["temperature_span"] = {"value": [lo, hi], "limit": [want_lo, want_hi], "unit": "°C",
                                       "tolerance": tol, "passed": bool(ok_lo and ok_hi)}
        within = f" (tolerance {tol:g} °C)" if tol else ""
        for ok, end in ((ok_lo, want_lo), (ok_hi, want_hi)):
            if not ok:
                reasons.append(f"calibrated span {lo:.1f} to {hi:.1f} °C does not reach {end:g} °C{within}")

    seg_failed = _is_failure(seg_info)
    info = {} if seg_info is None or seg_failed else seg_info
    why_no_info = _failure_text("segmentation", seg_info).removeprefix("segmentation failed: ") \
        if seg_failed else "no segmentation info"
    if limits.min_holds is not None:
        n = info.get("holds_accepted")
        if n is None:
            unavailable("min_holds", "accepted holds", why_no_info)
        else:
            record("min_holds", int(n), limits.min_holds, "holds", n >= limits.min_holds,
                   f"accepted holds = {int(n)} below the minimum {limits.min_holds}")
    if limits.min_hold_share is not None:
        share, why = hold_share(info) if info else (None, why_no_info)
        if share is None:
            unavailable("min_hold_share", "accepted hold share", why)
        else:
            record("min_hold_share", share, limits.min_hold_share, "1", share >= limits.min_hold_share,
                   f"accepted hold share = {100 * share:.1f} % below the minimum "
                   f"{100 * limits.min_hold_share:g} %")
    if limits.min_temperature_points is not None:
        n = info.get("temperature_points")
        if n is None and not seg_failed:
            n = len(cal.grid.temperatures)  # servo, sweep: the calibration's own points
        if n is None:
            unavailable("min_temperature_points", "temperature points", why_no_info)
        else:
            record("min_temperature_points", int(n), limits.min_temperature_points, "points",
                   n >= limits.min_temperature_points,
                   f"temperature points = {int(n)} below the minimum {limits.min_temperature_points}")

    meta = {k: cal.meta.get(k) for k in ("device", "batch", "session", "protocol")}
    return Verdict(not reasons, tuple(reasons), checked, meta)


def hold_share(info: Mapping) -> tuple[float | None, str]:
    """Accepted holds over candidate holds, and why not when it cannot be had.

    Turntable: candidates are the accepted holds plus those rejected by a hold check;
    ``handling_motion`` is the re-mounting between mounts, not a hold, and is not counted.
    Sweep: accepted windows over all windows. Servo sessions report no rejections."""
    accepted = info.get("holds_accepted")
    if accepted is None:
        return None, "the segmentation info has no holds_accepted"
    if "rejected_by_reason" in info:
        rejected = sum(int(v) for k, v in info["rejected_by_reason"].items() if k != "handling_motion")
        total = int(accepted) + rejected
    elif "windows_total" in info:
        total = int(info["windows_total"])
    else:
        return None, "the segmentation reports no rejected holds for this protocol"
    return (float(accepted) / total if total else None), "no candidate holds"


def unit_inputs(folder) -> tuple:
    """(calibration or failure record, validation summary or failure record or None,
    segmentation info or failure record or None) from a unit's results folder
    (``results/{batch}/{device}/{session}``), for :func:`judge`."""
    from . import failure
    from .io import OBS_META_KEY
    folder = Path(folder)
    cal_path, val_path, obs_path = (folder / n for n in ("calibration.json", "validation.json",
                                                         "observations.parquet"))
    cal = failure.read(cal_path) or load_calibration(cal_path)
    summary = None
    if val_path.exists():
        summary = failure.read(val_path) or json.loads(val_path.read_text()).get("summary")
    info = None
    if obs_path.exists():
        info = failure.read(obs_path)
        if info is None:
            import pyarrow.parquet as pq
            raw = (pq.read_schema(obs_path).metadata or {}).get(OBS_META_KEY)
            info = json.loads(raw).get("info") if raw else None
    return cal, summary, info


def judge_folder(folder, limits: SpecLimits) -> Verdict:
    """:func:`judge` on a unit's results folder; a folder without a readable calibration
    gives a failed verdict naming the problem."""
    try:
        cal, summary, info = unit_inputs(folder)
    except GyrocalError as exc:
        return judge(exc, None, None, limits)
    return judge(cal, summary, info, limits)


def batch_yield(verdicts_by_unit) -> pd.DataFrame:
    """Per batch (from each verdict's ``meta``): units, passed, failed (of which
    ``no_calibration``), yield in percent; one row per batch, sorted by batch name.
    Accepts a mapping unit -> :class:`Verdict` or an iterable of verdicts."""
    verdicts = list(verdicts_by_unit.values() if isinstance(verdicts_by_unit, Mapping) else verdicts_by_unit)
    frame = pd.DataFrame({
        "batch": [str(v.meta.get("batch")) if v.meta.get("batch") is not None else "" for v in verdicts],
        "passed": [bool(v.passed) for v in verdicts],
        "no_calibration": [not v.calibrated for v in verdicts],
    })
    if frame.empty:
        return pd.DataFrame({"batch": pd.Series([], dtype=str), "units": pd.Series([], dtype=int),
                             "passed": pd.Series([], dtype=int), "failed": pd.Series([], dtype=int),
                             "no_calibration": pd.Series([], dtype=int),
                             "yield_pct": pd.Series([], dtype=float)})
    g = frame.groupby("batch", sort=True)
    out = pd.DataFrame({"units": g.size(), "passed": g["passed"].sum().astype(int),
                        "no_calibration": g["no_calibration"].sum().astype(int)}).reset_index()
    out["failed"] = out["units"] - out["passed"]
    out["yield_pct"] = 100.0 * out["passed"] / out["units"]
    return out[["batch", "units", "passed", "failed", "no_calibration", "yield_pct"]]


# -- outliers -------------------------------------------------------------------------------
ID_COLUMNS = ("device", "batch", "session", "protocol", "unit")


def _parameter_columns(table: pd.DataFrame, by: str) -> list[str]:
    return [c for c in table.columns if c != by and c not in ID_COLUMNS
            and pd.api.types.is_numeric_dtype(table[c]) and not pd.api.types.is_bool_dtype(table[c])]


def fleet_outliers(table: pd.DataFrame, *, by: str = "batch", threshold: float = 3.5) -> pd.DataFrame:
    """Units whose parameter lies far from the rest of their batch.

    ``table`` has one row per unit: the ``by`` column, identifying columns (any of
    ``ID_COLUMNS`` or non-numeric ones) and one numeric column per parameter (e.g.
    :func:`parameter_table`). Within each batch and parameter the robust z-score is

        z = 0.6745 (x − median) / MAD,        MAD = median |x − median|

    (Iglewicz & Hoaglin's modified z-score: 0.6745 = Φ⁻¹(0.75) makes MAD/0.6745 estimate σ
    for normal data, so z is in standard deviations and one outlying unit cannot inflate
    the yardstick); |z| > ``threshold`` flags. When MAD is 0 (most units share one value),
    a value that differs from the median beyond 1e-9 relative is flagged with z = ±inf,
    note "differs from identical others". A batch with fewer than 5 units (per parameter:
    units with a value) gets no flags; ``result.attrs["notes"]`` says so, and
    ``result.attrs["small_batches"]`` maps such batches to their unit counts.

    Returns one row per flag: the row's identifying columns, parameter, value, median, mad,
    z, note; sorted by batch, parameter (table order) and row.
    """
    if by not in table.columns:
        raise InputError(f"outlier table has no column {by!r} (columns: {', '.join(map(str, table.columns))})")
    threshold = _number(threshold, "threshold", positive=True)
    params = _parameter_columns(table, by)
    ids = [c for c in table.columns if c not in params]
    long = table.reset_index(drop=True).rename_axis("_row").reset_index().melt(
        id_vars=["_row", *ids], value_vars=params, var_name="parameter", value_name="value")
    long = long[np.isfinite(long["value"].to_numpy(dtype=float))]
    long["batch_key"] = long[by].astype(str).where(long[by].notna(), "")
    keys = [long["batch_key"], long["parameter"]]
    grouped = long.groupby(keys, sort=False)["value"]
    long["median"] = grouped.transform("median")
    long["dev"] = (long["value"] - long["median"]).abs()
    long["mad"] = long.groupby(keys, sort=False)["dev"].transform("median")
    long["count"] = grouped.transform("size")
    big = long["count"] >= MIN_BATCH
    mad, dev = long["mad"].to_numpy(), long["dev"].to_numpy()
    diff = long["value"].to_numpy() - long["median"].to_numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(mad > 0, MAD_Z * diff / np.where(mad > 0, mad, 1.0), 0.0)
    tiny = 1e-9 * np.maximum(np.abs(long["value"].to_numpy()), np.abs(long["median"].to_numpy()))
    distinct = (mad == 0) & (dev > tiny)
    z = np.where(distinct, np.copysign(np.inf, diff), z)
    long["z"] = z
    long["note"] = np.where(distinct, "differs from identical others", "")
    flagged = long[big.to_numpy() & (np.abs(z) > threshold)]
    order = {p: i for i, p in enumerate(params)}
    flagged = flagged.assign(_p=flagged["parameter"].map(order)).sort_values(
        ["batch_key", "_p", "_row"], kind="stable")
    out = flagged[[*ids, "parameter", "value", "median", "mad", "z", "note"]].reset_index(drop=True)

    notes, small = [], {}
    units = table.groupby(table[by].astype(str).where(table[by].notna(), ""), sort=True).size()
    for batch, n in units.items():
        if n < MIN_BATCH:
            small[batch] = int(n)
            notes.append(f"batch {batch}: {n} unit{'s' if n != 1 else ''}, fewer than {MIN_BATCH}: "
                         "no outlier flags")
    few = long[~big.to_numpy()].drop_duplicates(["batch_key", "parameter"])
    few = few[~few["batch_key"].isin(small)]
    for batch, part in few.groupby("batch_key", sort=True):
        names = sorted(part["parameter"], key=order.get)
        notes.append(f"batch {batch}: {', '.join(names)} known for fewer than {MIN_BATCH} units: "
                     "not checked")
    out.attrs["notes"] = notes
    out.attrs["small_batches"] = small
    return out


def plot_parameter_distributions(table: pd.DataFrame, flagged: pd.DataFrame, path_or_none=None, *,
                                 by: str = "batch", label: str = "device") -> str:
    """Each parameter's values per batch (one panel per parameter, units as points, the
    batch median as a bar, batches too small to judge in grey, unit counts in the axis
    labels), flagged units ringed in red and labelled by ``label``.
    Deterministic SVG; written to ``path_or_none`` when given."""
    from matplotlib import rc_context

    from .plots import _RC, figure, to_svg
    params = _parameter_columns(table, by)
    batches = sorted(table[by].astype(str).where(table[by].notna(), "").unique())
    position = {b: i for i, b in enumerate(batches)}
    frame = table.reset_index(drop=True)
    bkey = frame[by].astype(str).where(frame[by].notna(), "")
    # Deterministic spread of a batch's points across ±0.3 of its slot, by row order.
    rank = bkey.groupby(bkey).cumcount().to_numpy()
    size = bkey.map(bkey.value_counts()).to_numpy()
    x = bkey.map(position).to_numpy(dtype=float) + np.where(size > 1, (rank / np.maximum(size - 1, 1) - 0.5) * 0.6, 0)
    ids = [c for c in flagged.columns if c in frame.columns and c not in params]
    hit = frame.reset_index().merge(flagged[ids + ["parameter"]], on=ids, how="inner") if len(flagged) else None
    counts = bkey.value_counts()
    ticks = [f"{b} ({counts[b]})" for b in batches]   # unit count; grey points: too few to judge
    cols = min(3, max(len(params), 1))
    rows = max(math.ceil(len(params) / cols), 1)
    with rc_context(_RC):
        fig, axes = figure(10, 2.3 * rows + 0.4, rows, cols)
        for k, axis in enumerate(axes.ravel()):
            if k >= len(params):
                axis.set_visible(False)
                continue
            p = params[k]
            v = frame[p].to_numpy(dtype=float)
            ok = np.isfinite(v)
            small = (size < MIN_BATCH)
            axis.plot(x[ok & ~small], v[ok & ~small], "o", ms=3, color="#1f77b4", alpha=0.8)
            axis.plot(x[ok & small], v[ok & small], "o", ms=3, color="#999999", alpha=0.8)
            medians = frame[ok].groupby(bkey[ok])[p].median()
            for b, m in medians.items():
                axis.plot([position[b] - 0.35, position[b] + 0.35], [m, m], color="#444", lw=1.2)
            if hit is not None:
                mine = hit[hit["parameter"] == p]
                idx = mine["index"].to_numpy()
                axis.plot(x[idx], v[idx], "o", ms=8, mfc="none", mec="#d62728", mew=1.5)
                if label in frame.columns:
                    for i in idx:
                        axis.annotate(str(frame[label].iloc[i]), (x[i], v[i]), xytext=(4, 3),
                                      textcoords="offset points", fontsize=7, color="#d62728",
                                      parse_math=False)
            axis.set_title(p, fontsize=9, parse_math=False)
            axis.set_xticks(range(len(batches)), ticks, rotation=30 if len(batches) > 4 else 0,
                            fontsize=7, parse_math=False)
            axis.set_xlim(-0.6, len(batches) - 0.4)
        return _write(to_svg(fig), path_or_none)


def _write(svg: str, path_or_none) -> str:
    if path_or_none is not None:
        path = Path(path_or_none)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(svg)
        tmp.replace(path)
    return svg
