"""The unit report: one page per unit and session.

Jinja2 with autoescape (every string that came from data is escaped); figures are inline
SVG from :mod:`gyrocal.report.plots`; no script, stylesheet, font or image is fetched from
anywhere, so a report opens offline and can be archived as one file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..calibration.file import Calibration, dumps, load_calibration, standard_coefficients
from ..fit import METHODS
from ..io.columns import Columns, present
from ..io.formats import FAILURE
from ..io.runs import last_two, read_runs
from ..io.unit_folder import part_exists, read_part_columns, read_part_doc, read_part_json, unit_paths
from . import plots
from .pages import render_page


@dataclass
class UnitResults:
    """Everything a unit report shows, from a run in memory or a results folder: its
    tables as :class:`gyrocal.io.columns.Columns`, so drawing a folder's report does not
    import pandas."""

    meta: dict
    calibration: Calibration
    seg_info: dict
    observations: Columns
    segments: Columns
    timeline: Columns
    summary: dict
    holds: Columns
    table_holds: Columns
    table_samples: Columns
    by_temperature: Columns
    log: str = ""
    command: str = ""
    extra: dict = field(default_factory=dict)
    diagnosis: dict | None = None  # gyrocal.diagnosis/1, or a failure record
    residuals: Columns | None = None  # observations with normalised residuals
    heatmaps: dict = field(default_factory=dict)
    protocol: dict | None = None  # the servo's or the sweep's own methods
    protocol_figures: list = field(default_factory=list)
    free_points: Columns | None = None  # continuous models: free per-point fits
    runs: tuple = (None, None)  # this run and the last of another model (gyrocal.io.runs)
    # The device was not given: the page names the log (its file name), not a device id
    # made up from it.
    device_unknown: bool = False

    @classmethod
    def from_run(cls, run, command: str = "", diagnosis=None, analysis=None) -> UnitResults:
        """``diagnosis``: a :class:`gyrocal.diagnosis.Diagnosis` of the same run, if any;
        ``analysis``: its protocol's own methods (:func:`gyrocal.protocols.registry.analysis`)."""
        seg, val = run.segmentation, run.validation
        extra = (
            {}
            if diagnosis is None
            else dict(
                diagnosis=json.loads(dumps(diagnosis.to_dict())),
                residuals=Columns.from_frame(diagnosis.residuals),
                heatmaps=diagnosis.heatmaps,
            )
        )
        if analysis is not None:
            extra.update(protocol=analysis[0], protocol_figures=list(analysis[1]))
        table = Columns.from_frame
        return cls(
            run.calibration.meta,
            run.calibration,
            seg.info,
            table(seg.observations),
            table(seg.segments),
            table(seg.timeline),
            val.summary,
            table(val.holds),
            table(val.table_holds),
            table(val.table_samples),
            table(val.by_temperature),
            seg.info.get("path", ""),
            command,
            free_points=table(val.free_points),
            **extra,
        )

    @classmethod
    def from_folder(cls, folder) -> UnitResults:
        p = unit_paths(folder)
        obs, extra = read_part_columns(folder, "observations")
        table = lambda k: read_part_columns(folder, k)[0]  # noqa: E731
        summary = read_part_json(folder, "validation")["summary"]
        cal = load_calibration(p["calibration"])
        diagnosis, residuals, heat = read_part_doc(folder, "diagnosis"), None, {}
        if diagnosis is not None and diagnosis.get("format") != FAILURE and part_exists(folder, "residuals"):
            residuals, meta = read_part_columns(folder, "residuals")
            heat = meta.get("heatmaps", {})
        own = read_part_json(folder, "protocol")
        runs = last_two(read_runs(folder), cal.provenance.get("config_sha256"))
        return cls(
            cal.meta,
            cal,
            extra["info"],
            obs,
            table("segments"),
            table("timeline"),
            summary,
            table("holds"),
            table("table_hold_means"),
            table("table_samples"),
            table("by_temperature"),
            extra.get("log", ""),
            diagnosis=diagnosis,
            residuals=residuals,
            heatmaps=heat,
            protocol=own["results"],
            protocol_figures=own["figures"],
            free_points=table("free_points") if part_exists(folder, "free_points") else None,
            runs=runs,
        )


def _parameter_figure(cal: Calibration, free_points: Columns | None) -> str:
    """Grid models: the fitted grid and its interpolation. Continuous models: K and B of the
    calibration against temperature, over free per-point fits of the seed-000 terms
    (:func:`gyrocal.fit.validate.free_point_fits`; where the two disagree, the model's
    temperature dependence is wrong)."""
    g = cal.grid
    lo, hi = g.span
    temps = np.linspace(lo, hi, 200) if hi > lo else np.array([lo])
    if cal.kind != "continuous":
        curve = g.at(temps, warn=False)
        return plots.parameters(
            g.temperatures,
            {n: g.values[:, j] for j, n in enumerate(g.names)},
            {n: g.stderr[:, j] for j, n in enumerate(g.names)},
            temps,
            curve,
        )
    K, B = cal.matrices_at(temps)
    curve = standard_coefficients(K, B)
    if free_points is None or free_points.empty:  # too few points for free fits: the curve alone
        points, values, stderr = np.array([]), {n: [] for n in curve}, {n: [] for n in curve}
    else:
        names = [c for c in free_points.columns if c != "temp" and not c.endswith("_stderr")]
        points = free_points["temp"]
        values = {n: free_points[n] for n in names}
        stderr = {n: free_points[f"{n}_stderr"] for n in names}
    return plots.parameters(points, values, stderr, temps, curve)


# Covariates of the residual plots: (label, residuals column), shown when the log has them.
RESIDUAL_COVARIATES = (
    ("temperature, °C", "temp"),
    ("temperature rate, °C/min", "temp_rate"),
    ("reference rate, deg/s", "ref_rate"),
    ("mount", "mount"),
    ("accelerometer x, g", "accel_x"),
    ("accelerometer y, g", "accel_y"),
    ("accelerometer z, g", "accel_z"),
    ("time since start, h", "time_h"),
    ("hold duration, s", "duration"),
)


def _diagnosis_context(results: UnitResults) -> dict:
    diag = results.diagnosis
    if diag is None:
        return {"diagnosis": None}
    if diag.get("format") == "gyrocal.failure/1":
        return {"diagnosis": None, "diagnosis_error": diag["error"]}
    context = {
        "diagnosis": diag,
        "fig_residuals": "",
        "fig_heatmaps": "",
        "fig_ladder": "",
        "fig_shape": plots.shape_estimate(diag["shape_estimate"]) if diag.get("shape_estimate") else "",
    }
    frame = results.residuals
    if frame is not None and len(frame):
        start = np.asarray(frame["t_start"], float)
        frame = frame.assign(time_h=(start - plots.data_span(start)[0]) / 3600.0)
        shown = [
            (label, c)
            for label, c in RESIDUAL_COVARIATES
            if c in frame and (c == "mount" or np.isfinite(np.asarray(frame[c], float)).any())
        ]
        context["fig_residuals"] = plots.residuals(frame, shown)
    maps = [
        (label, "reference rate, deg/s", results.heatmaps[key])
        for key, label in (("mount_by_rate", "mount"), ("temperature_by_rate", "temperature, °C"))
        if results.heatmaps.get(key)
    ]
    if maps:
        context["fig_heatmaps"] = plots.heatmaps(maps)
    if len(diag.get("ladder", [])) > 1:
        context["fig_ladder"] = plots.ladder(diag["ladder"])
    current, previous = results.runs
    if previous is not None:
        context["since_last"] = {"previous": previous, "current": current}
    return context


def _noise_context(noise: dict | None) -> dict:
    """The sensor-noise section: which floor applies, the terms per temperature point (each
    axis x / y / z) and the Allan deviation figure."""
    if not noise:  # observations written before noise characterisation
        return {"noise": None}
    from ..fit.floor import floor_terms

    rows = []
    entries = (
        [("all static stretches", noise["session"], noise["stretches"], noise["static_seconds"])]
        if "session" in noise
        else []
    )
    entries += [(f"{p['temp']:.4g} °C", p, p["stretches"], p["seconds"]) for p in noise["points"]]
    for label, entry, count, seconds in entries:
        terms = entry.get("terms")
        rows.append(
            {
                "label": label,
                "stretches": count,
                "seconds": seconds,
                **(
                    {
                        k: np.atleast_1d(terms[k]).tolist()
                        for k in ("arw", "bias_instability", "rrw", "quantisation", "bias_instability_min")
                    }
                    if terms
                    else {}
                ),
                "from_point": entry.get("noise_from_point"),
            }
        )
    used = None
    if "session" in noise:
        t = floor_terms(noise["session"])
        used = {
            "bias_instability": np.atleast_1d(t.bias_instability).tolist(),
            "rrw": np.atleast_1d(t.rrw).tolist(),
        }
    return {
        "noise": noise,
        "noise_rows": rows,
        "noise_used": used,
        "fig_allan": plots.allan(noise) if "session" in noise else None,
    }


def write_unit_report(results: UnitResults, path, protocol) -> None:
    """The unit's page; ``protocol``, its :class:`gyrocal.protocols.registry.Protocol`, gives
    the report's own parts of the protocol (sections, figures, how it names its validation)."""
    cal, info = results.calibration, results.seg_info
    temps, mounts, counts = _hold_counts(results.observations)
    rejected = results.segments[results.segments["kind"] == "rejected"]
    reasons, per_reason = np.unique(
        rejected["reason"][present(rejected["reason"])].astype(str), return_counts=True
    )
    own_figure = protocol.validation_figure
    g = cal.grid
    grid_rows, constants = _grid_tables(cal)
    html = render_page(
        "unit_report.html.j2",
        profiled=cal.extra.get("profiled", []),
        added_terms=cal.extra.get("added_terms", []),
        model_entry=cal.extra.get("model_entry"),
        meta=cal.meta,
        unit_name=Path(results.log).name
        if results.device_unknown and results.log
        else cal.meta.get("device"),
        device_known=not results.device_unknown,
        span=g.span,
        summary=results.summary,
        methods=METHODS,
        info=info,
        input_warnings=cal.extra.get("warnings", []),
        interpolation=g.method,
        reference=cal.reference_temperature,
        counts_columns=mounts.tolist(),
        counts=list(zip(temps.tolist(), counts.tolist(), strict=False)),
        rejected_counts=dict(zip(reasons.tolist(), per_reason.tolist(), strict=False)),
        rejected=rejected[["reason", "detail", "t_start", "t_end", "ref_rate"]].records(),
        points=cal.extra.get("points", []),
        names=list(g.names),
        grid_rows=grid_rows,
        constants=constants,
        table_holds=results.table_holds.records(),
        table_samples=results.table_samples.records(),
        by_temperature=results.by_temperature.records(),
        provenance=cal.provenance,
        log=results.log,
        command=results.command,
        calibration_extra=cal.extra,
        fig_timeline=plots.timeline(results.timeline, results.segments),
        **(
            dict(fig_servo=own_figure(results.holds))
            if own_figure is not None
            else dict(  # a protocol validated its own way: section 2-3 of its own
                fig_parameters=_parameter_figure(cal, results.free_points),
                fig_by_temperature=plots.by_temperature(results.by_temperature),
                fig_before=plots.error_distribution(results.holds, "uncompensated"),
                fig_after=plots.error_distribution(results.holds, "interpolated"),
            )
        ),
        kind=cal.kind,
        protocol=results.protocol,
        protocol_figures=results.protocol_figures,
        sections_template=protocol.report_sections,
        section_template=protocol.report_section,
        validated_as=protocol.validated_as,
        **_noise_context(info.get("noise")),
        **_diagnosis_context(results),
    )
    _write(path, html)


def _hold_counts(obs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The accepted holds per temperature point and mount: the points' temperatures, the
    mounts, and the counts (points × mounts)."""
    temps, temp_of = np.unique(np.round(np.asarray(obs["point_temp"], float), 2), return_inverse=True)
    mounts, mount_of = np.unique(obs["mount"].astype(str), return_inverse=True)
    counts = np.zeros((len(temps), len(mounts)), np.int64)
    np.add.at(counts, (temp_of, mount_of), 1)
    return temps, mounts, counts


def _grid_tables(cal) -> tuple[list[dict], list[tuple]]:
    """The calibration's coefficients as the page shows them: a row per grid point (value,
    standard error of each coefficient), and the constants (name, value, standard error,
    unit): a continuous model's coefficients, a grid's session-wide terms."""
    g = cal.grid
    units = {c: t.unit for t in cal.model.terms for c in t.coefficients()}
    if cal.kind == "continuous":
        constants = [
            (n, float(v), float(e), units.get(n, ""))
            for n, v, e in zip(g.names, g.values, g.stderr, strict=False)
        ]
        return [], constants
    grid_rows = [
        {
            "temp": float(t),
            **{n: (float(g.values[p, j]), float(g.stderr[p, j])) for j, n in enumerate(g.names)},
        }
        for p, t in enumerate(g.temperatures)
    ]
    # Session-wide (scope global) terms hold one value at every grid point.
    session = {c for t in cal.model.terms if t.coefficient_scope == "global" for c in t.coefficients()}
    constants = [
        (n, float(g.values[0, j]), float(g.stderr[0, j]), units.get(n, ""))
        for j, n in enumerate(g.names)
        if n in session
    ]
    return grid_rows, constants


def _write(path, text: str) -> None:
    from ..io.atomic import write_text

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)
