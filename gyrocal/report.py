"""HTML reports: per unit and session, and the fleet summary.

Jinja2 with autoescape (every string that came from data is escaped); figures are inline
SVG from :mod:`gyrocal.plots`; no script, stylesheet, font or image is fetched from
anywhere, so a report opens offline and can be archived as one file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import jinja2
import numpy as np
import pandas as pd

from . import failure, plots
from .calibration import Calibration, dumps, load_calibration, standard_coefficients
from .errors import GyrocalError
from .io import read_table_with_metadata
from .model import DEFAULT_TERMS, Model
from .terms import AXES
from .thermal import fit_grid
from .validate import METHODS

_ENV = jinja2.Environment(loader=jinja2.PackageLoader("gyrocal", "templates"),
                          autoescape=jinja2.select_autoescape(["html", "j2"]),
                          undefined=jinja2.StrictUndefined, keep_trailing_newline=True)


def fmt(value, digits: int = 4) -> str:
    """Numbers as engineers read them: fixed for ordinary sizes, scientific otherwise."""
    if value is None or isinstance(value, str):
        return "–" if value is None else value
    value = float(value)
    if not np.isfinite(value):
        return "–"
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:.{digits}g}"
    return f"{value:.{max(digits - 1, 1)}e}"


def pvalue(value) -> str:
    """p-values below double precision's resolution of 1 - p print as a bound."""
    return "< 1e-16" if value is not None and float(value) < 1e-16 else fmt(value, 2)


_ENV.filters["fmt"] = fmt
_ENV.filters["pvalue"] = pvalue
_ENV.filters["prel"] = lambda v: pvalue(v) if pvalue(v).startswith("<") else "= " + pvalue(v)


@dataclass
class UnitResults:
    """Everything a unit report shows, from a run in memory or a results folder."""

    meta: dict
    calibration: Calibration
    seg_info: dict
    observations: pd.DataFrame
    segments: pd.DataFrame
    timeline: pd.DataFrame
    summary: dict
    holds: pd.DataFrame
    table_holds: pd.DataFrame
    table_samples: pd.DataFrame
    by_temperature: pd.DataFrame
    log: str = ""
    command: str = ""
    extra: dict = field(default_factory=dict)
    diagnosis: dict | None = None            # gyrocal.diagnosis/1, or a failure record
    residuals: pd.DataFrame | None = None    # observations with normalised residuals
    heatmaps: dict = field(default_factory=dict)
    protocol: dict | None = None              # the servo's or the sweep's own methods
    protocol_figures: list = field(default_factory=list)

    def __post_init__(self):
        from .protocols import analysis
        if self.protocol is None:
            try:
                self.protocol, self.protocol_figures = analysis(self.meta.get("protocol"),
                                                                self.observations)
            except GyrocalError as exc:  # the common sections still stand
                self.protocol = {"protocol": self.meta.get("protocol"), "error": str(exc)}

    @classmethod
    def from_run(cls, run, command: str = "", diagnosis=None) -> UnitResults:
        """``diagnosis``: a :class:`gyrocal.diagnose.Diagnosis` of the same run, if any."""
        seg, val = run.segmentation, run.validation
        extra = {} if diagnosis is None else dict(
            diagnosis=json.loads(dumps(diagnosis.to_dict())), residuals=diagnosis.residuals,
            heatmaps=diagnosis.heatmaps)
        return cls(run.calibration.meta, run.calibration, seg.info, seg.observations,
                   seg.segments, seg.timeline, val.summary, val.holds, val.table_holds,
                   val.table_samples, val.by_temperature, seg.info.get("path", ""), command,
                   **extra)

    @classmethod
    def from_folder(cls, folder) -> UnitResults:
        from .stages import unit_paths
        p = unit_paths(folder)
        obs, extra = read_table_with_metadata(p["observations"])
        table = lambda k: read_table_with_metadata(p[k])[0]  # noqa: E731
        summary = failure.load_json(p["validation"])["summary"]
        cal = load_calibration(p["calibration"])
        diagnosis = residuals = None
        heat = {}
        if p["diagnosis"].exists():
            diagnosis = failure.read(p["diagnosis"]) or failure.load_json(p["diagnosis"])
            if diagnosis.get("format") != "gyrocal.failure/1" and p["residuals"].exists():
                residuals, meta = read_table_with_metadata(p["residuals"])
                heat = meta.get("heatmaps", {})
        return cls(cal.meta, cal, extra["info"], obs, table("segments"), table("timeline"),
                   summary, table("holds"), table("table_hold_means"), table("table_samples"),
                   table("by_temperature"), extra.get("log", ""), diagnosis=diagnosis,
                   residuals=residuals, heatmaps=heat)


def _parameter_figure(cal: Calibration, obs: pd.DataFrame) -> str:
    """Grid models: the fitted grid and its interpolation. Continuous models: K and B of the
    calibration against temperature, over free per-point fits of the seed-000 terms (where
    the two disagree, the model's temperature dependence is wrong)."""
    g = cal.grid
    lo, hi = g.span
    temps = np.linspace(lo, hi, 200) if hi > lo else np.array([lo])
    if cal.kind != "continuous":
        curve = g.at(temps, warn=False)
        return plots.parameters(g.temperatures, {n: g.values[:, j] for j, n in enumerate(g.names)},
                                {n: g.stderr[:, j] for j, n in enumerate(g.names)}, temps, curve)
    K, B = cal.matrices_at(temps)
    curve = standard_coefficients(K, B)
    try:
        free = fit_grid(Model.from_spec(DEFAULT_TERMS), obs)
        grid = free.coefficients
        values = {n: grid.values[:, j] for j, n in enumerate(grid.names)}
        stderr = {n: grid.stderr[:, j] for j, n in enumerate(grid.names)}
        points = grid.temperatures
    except GyrocalError:  # too few points for free fits: the curve alone
        points, values, stderr = np.array([]), {n: [] for n in curve}, {n: [] for n in curve}
    return plots.parameters(points, values, stderr, temps, curve)


# Covariates of the residual plots: (label, residuals column), shown when the log has them.
RESIDUAL_COVARIATES = (("temperature, °C", "temp"), ("temperature rate, °C/min", "temp_rate"),
                       ("reference rate, deg/s", "ref_rate"), ("mount", "mount"),
                       ("accelerometer x, g", "accel_x"), ("accelerometer y, g", "accel_y"),
                       ("accelerometer z, g", "accel_z"), ("time since start, h", "time_h"),
                       ("hold duration, s", "duration"))


def _diagnosis_context(results: UnitResults) -> dict:
    diag = results.diagnosis
    if diag is None:
        return {"diagnosis": None}
    if diag.get("format") == "gyrocal.failure/1":
        return {"diagnosis": None, "diagnosis_error": diag["error"]}
    context = {"diagnosis": diag, "fig_residuals": "", "fig_heatmaps": "", "fig_ladder": ""}
    frame = results.residuals
    if frame is not None and len(frame):
        frame = frame.assign(time_h=(frame["t_start"] - frame["t_start"].min()) / 3600.0)
        shown = [(label, c) for label, c in RESIDUAL_COVARIATES
                 if c in frame and (c == "mount" or np.isfinite(frame[c].to_numpy(float)).any())]
        context["fig_residuals"] = plots.residuals(frame, shown)
    maps = [(label, "reference rate, deg/s", results.heatmaps[key])
            for key, label in (("mount_by_rate", "mount"), ("temperature_by_rate", "temperature, °C"))
            if results.heatmaps.get(key)]
    if maps:
        context["fig_heatmaps"] = plots.heatmaps(maps)
    if len(diag.get("ladder", [])) > 1:
        context["fig_ladder"] = plots.ladder(diag["ladder"])
    return context


def _noise_context(noise: dict | None) -> dict:
    """The sensor-noise section: which floor applies, the terms per temperature point (each
    axis x / y / z) and the Allan deviation figure."""
    if not noise:  # observations written before noise characterisation
        return {"noise": None}
    from .floor import floor_terms
    rows = []
    entries = ([("all static stretches", noise["session"], noise["stretches"], noise["static_seconds"])]
               if "session" in noise else [])
    entries += [(f"{p['temp']:.4g} °C", p, p["stretches"], p["seconds"]) for p in noise["points"]]
    for label, entry, count, seconds in entries:
        terms = entry.get("terms")
        rows.append({"label": label, "stretches": count, "seconds": seconds,
                     **({k: np.atleast_1d(terms[k]).tolist() for k in
                         ("arw", "bias_instability", "rrw", "quantisation", "bias_instability_min")}
                        if terms else {}),
                     "from_point": entry.get("noise_from_point")})
    used = None
    if "session" in noise:
        t = floor_terms(noise["session"])
        used = {"bias_instability": np.atleast_1d(t.bias_instability).tolist(),
                "rrw": np.atleast_1d(t.rrw).tolist()}
    return {"noise": noise, "noise_rows": rows, "noise_used": used,
            "fig_allan": plots.allan(noise) if "session" in noise else None}


def write_unit_report(results: UnitResults, path) -> None:
    cal, info = results.calibration, results.seg_info
    counts = pd.crosstab(results.observations["point_temp"].round(2),
                         results.observations["mount"].astype(str))
    rejected = results.segments[results.segments["kind"] == "rejected"]
    g = cal.grid
    if cal.kind == "continuous":
        units = {c: t.unit for t in cal.model.terms for c in t.coefficients()}
        grid_rows = []
        constants = [(n, float(v), float(e), units.get(n, ""))
                     for n, v, e in zip(g.names, g.values, g.stderr)]
    else:
        grid_rows = [{"temp": float(t), **{n: (float(g.values[p, j]), float(g.stderr[p, j]))
                                           for j, n in enumerate(g.names)}}
                     for p, t in enumerate(g.temperatures)]
        # Session-wide (scope global) terms hold one value at every grid point.
        units = {c: t.unit for t in cal.model.terms for c in t.coefficients()}
        session = {c for t in cal.model.terms if t.coefficient_scope == "global" for c in t.coefficients()}
        constants = [(n, float(g.values[0, j]), float(g.stderr[0, j]), units.get(n, ""))
                     for j, n in enumerate(g.names) if n in session]
    html = _ENV.get_template("unit_report.html.j2").render(
        profiled=cal.extra.get("profiled", []),
        meta=cal.meta, span=g.span, summary=results.summary, methods=METHODS, info=info,
        interpolation=g.method, reference=cal.reference_temperature,
        counts_columns=list(counts.columns),
        counts=[(t, [int(v) for v in r]) for t, r in counts.iterrows()],
        rejected_counts=rejected["reason"].value_counts().sort_index().to_dict(),
        rejected=rejected[["reason", "detail", "t_start", "t_end", "ref_rate"]].to_dict("records"),
        points=cal.extra.get("points", []), names=list(g.names), grid_rows=grid_rows,
        constants=constants,
        table_holds=results.table_holds.to_dict("records"),
        table_samples=results.table_samples.to_dict("records"),
        by_temperature=results.by_temperature.to_dict("records"),
        provenance=cal.provenance, log=results.log, command=results.command,
        fig_timeline=plots.timeline(results.timeline, results.segments),
        **(dict(fig_servo=plots.servo_errors(results.holds)) if cal.meta.get("protocol") == "servo"
           else dict(  # servo: section 2-3 of its own
            fig_parameters=_parameter_figure(cal, results.observations),
            fig_by_temperature=plots.by_temperature(results.by_temperature),
            fig_before=plots.error_distribution(results.holds, "uncompensated"),
            fig_after=plots.error_distribution(results.holds, "interpolated"))),
        kind=cal.kind, protocol=results.protocol, protocol_figures=results.protocol_figures,
        **_noise_context(info.get("noise")), **_diagnosis_context(results))
    _write(path, html)


def _write(path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


# (coefficient, column heading, factor to the unit shown, significant digits)
KEY_PARAMETERS = (("scale.x", "scale x, ppm", 1e6, 4), ("scale.y", "scale y, ppm", 1e6, 4),
                  ("scale.z", "scale z, ppm", 1e6, 4), ("misalignment.x.y", "K[x,y]", 1.0, 4),
                  ("misalignment.y.x", "K[y,x]", 1.0, 4), ("bias.x", "bias x, deg/s", 1.0, 3),
                  ("bias.y", "bias y, deg/s", 1.0, 3), ("bias.z", "bias z, deg/s", 1.0, 3))


def _missing_effect(path) -> str:
    """The diagnosis in a few words, for the fleet table."""
    if not Path(path).exists():
        return "–"
    rec = failure.read(path)
    if rec is not None:
        return f"diagnosis failed: {rec['error']}"
    diag = failure.load_json(path)
    if diag.get("best"):
        return f"{diag['best']['term']} ({diag['best']['gain_pct']:.0f} % less error)"
    return "nothing" if diag.get("explains_the_data") else "unexplained excess"


def write_fleet_report(units: list[dict], path, settings=None, eol_json=None) -> None:
    """The fleet summary: per batch, one row per unit and session; failed units with
    their error; distributions of the key parameters across the calibrated units. With
    ``settings`` (:class:`gyrocal.fleet.FleetSettings`): end-of-line verdicts and yield,
    outliers against the batch, drift pages of devices with several sessions (beside the
    summary, ``drift/<device>.html``) and the machine-readable ``eol_json``."""
    from .stages import unit_paths
    rows = []
    for unit in units:
        row = dict(unit["row"])
        p = unit_paths(unit["folder"])
        row["report"] = unit["report"]
        records = (failure.read(p[k]) for k in ("validation", "calibration", "observations"))
        rec = next((r for r in records if r is not None), None)
        if rec is not None:
            row.update(status="failed", stage=rec["stage"], error=rec["error"],
                       internal=rec.get("internal", False))
        elif not p["validation"].exists() or not p["calibration"].exists():
            row.update(status="failed", stage="workflow", error="no results: the unit's jobs "
                       "did not run to the end (see the workflow's logs)", internal=True)
        else:
            cal = load_calibration(p["calibration"])
            summary = json.loads(p["validation"].read_text())["summary"]
            at_ref = cal.coefficients([cal.reference_temperature], warn=False)
            row["calibration"] = cal
            session_noise = (cal.extra.get("noise") or {}).get("session")
            row["noise"] = {k: _largest_axis(session_noise, k) for k in ("arw", "bias_instability")} \
                if session_noise else None
            row.update(status="ok", span=cal.grid.span, summary=summary,
                       reference=cal.reference_temperature, missing=_missing_effect(p["diagnosis"]),
                       params={n: float(at_ref[n][0]) * f for n, _, f, _ in KEY_PARAMETERS if n in at_ref})
        rows.append(row)
    batches = {}
    for row in rows:
        batches.setdefault(row["batch"], []).append(row)
    ok = [r for r in rows if r["status"] == "ok"]
    figures = [(label, plots.histogram(np.array(values), label)) for label, values in [
        *[(heading, [r["params"].get(n, np.nan) for r in ok]) for n, heading, _, _ in KEY_PARAMETERS],
        ("validation RMS, deg/s", [r["summary"]["validation_rms"] for r in ok]),
        ("excess over the noise floor", [r["summary"]["excess"] for r in ok]),
        ("angle random walk, deg/√h (largest axis)", [r["noise"]["arw"][0] if r["noise"] else np.nan
                                                       for r in ok])]]
    fleet = None
    if settings is not None:
        from .fleet import audit, drift_page_name, eol_document, json_safe
        fleet = audit(units, ok, settings)
        for row in rows:
            verdict = fleet["eol"]["verdicts"].get((row["batch"], row["device"], row["session"]))
            if verdict is not None:
                row["eol"] = {"passed": verdict.passed, "reasons": list(verdict.reasons)}
        for unit in fleet["drift"]:
            unit["page"] = drift_page_name(unit["device"])
            page = _ENV.get_template("drift_report.html.j2").render(unit=unit, tolerance=settings.drift_tolerance)
            _write(Path(path).parent / unit["page"], page)
        if eol_json is not None:
            _write(eol_json, dumps(json_safe(eol_document(fleet, settings))) + "\n")
    html = _ENV.get_template("fleet_report.html.j2").render(
        batches=sorted(batches.items()), key_parameters=KEY_PARAMETERS, figures=figures,
        total=len(rows), calibrated=len(ok), failed=len(rows) - len(ok),
        servo_vs_turntable=servo_versus_turntable(ok), fleet=fleet)
    _write(path, html)


def _largest_axis(terms: dict, name: str) -> tuple[float, float]:
    """(value, standard error) of a noise term on the axis where it is largest."""
    values = np.atleast_1d(terms[name])
    i = int(np.argmax(values))
    return float(values[i]), float(np.atleast_1d(terms[f"{name}_stderr"])[i])


def servo_versus_turntable(rows: list[dict]) -> list[dict]:
    """Units calibrated both on the servo and on the turntable: scale factor (K[a,a] − 1) and
    bias of each calibration at the servo session's temperature, their difference and its
    size in combined standard errors (seed 001 Tables II–III compare the two methods so).
    The turntable session nearest in date stands for the unit; its standard errors count
    where it is a temperature grid (a continuous model's K and B combine several terms)."""
    by_device: dict[str, dict[str, list]] = {}
    for row in rows:
        by_device.setdefault(row["device"], {}).setdefault(row["protocol"], []).append(row)
    out = []
    for device, sessions in sorted(by_device.items()):
        for servo in sessions.get("servo", []):
            tables = sessions.get("turntable", [])
            if not tables:
                continue
            table = min(tables, key=lambda r: abs(np.datetime64(r["session"] or "1970-01-01")
                                                  - np.datetime64(servo["session"] or "1970-01-01")))
            s_cal, t_cal = servo["calibration"], table["calibration"]
            temp = np.array([s_cal.grid.temperatures[0]])
            s_err = s_cal.grid.stderr_at(temp)
            t_err = t_cal.grid.stderr_at(temp) if t_cal.kind == "temperature_grid" else {}
            (s_K,), (s_B,) = s_cal.matrices_at(temp)
            (t_K,), (t_B,) = t_cal.matrices_at(temp)
            params = []
            for i, a in enumerate(AXES):
                for name, label, factor, s_val, t_val in (
                        (f"scale.{a}", f"scale {a}, ppm", 1e6, s_K[i, i] - 1, t_K[i, i] - 1),
                        (f"bias.{a}", f"bias {a}, deg/s", 1.0, s_B[i], t_B[i])):
                    diff = float(s_val - t_val)
                    se = float(np.hypot(s_err[name][0], t_err[name][0])) if name in t_err else None
                    params.append({"parameter": label, "servo": float(s_val) * factor,
                                   "servo_se": float(s_err[name][0]) * factor,
                                   "turntable": float(t_val) * factor,
                                   "turntable_se": None if se is None else float(t_err[name][0]) * factor,
                                   "difference": diff * factor,
                                   "sigmas": diff / se if se else None})
            params.sort(key=lambda p: not p["parameter"].startswith("scale"))
            out.append({"device": device, "servo_session": servo["session"],
                        "turntable_session": table["session"], "temperature": float(temp[0]),
                        "servo_report": servo["report"], "turntable_report": table["report"],
                        "rows": params})
    return out
