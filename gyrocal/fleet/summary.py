"""Fleet operations over a manifest's results: end-of-line verdicts and yield, outliers
against the batch, drift audits of devices calibrated more than once, and the fleet summary
page (:func:`write_fleet_report`).

The settings come from the workflow config's ``spec``, ``outliers`` and ``drift`` sections
(:class:`FleetSettings`); the numbers from :mod:`gyrocal.fleet.eol`, :mod:`gyrocal.fleet.outliers` and
:mod:`gyrocal.fleet.drift`. The output is JSON-plain, written to the fleet's ``eol.json`` for
production systems and rendered in the fleet summary and one drift page per audited device:
documents the pages and ``eol.json`` read whole, hence ``dict[str, Any]``.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from ..calibration.file import dumps
from ..io import atomic, failure, schema
from ..io.errors import ConfigError, GyrocalError
from ..io.formats import finite_or_none as _finite
from ..io.formats import json_safe
from ..protocols import registry
from ..report import plots
from ..report.pages import render_page
from ..terms import AXES


@dataclass(frozen=True)
class FleetSettings:
    spec: dict = field(default_factory=dict)  # protocol -> SpecLimits
    outlier_threshold: float = schema.defaults("config", "outliers")["threshold"]
    drift_tolerance: dict = field(default_factory=dict)
    drift_temperature: float | None = None
    drift_max_excess: float | None = None

    @classmethod
    def from_dict(cls, values: dict | None) -> FleetSettings:
        from .limits import SpecLimits

        values = dict(values or {})
        spec = values.get("spec") or {}
        if not isinstance(spec, dict):
            raise ConfigError("spec must map protocols to limits")
        limits = {}
        for protocol, section in spec.items():
            if protocol not in registry.names():
                raise ConfigError(f"unknown protocol spec.{protocol}; known: {', '.join(registry.names())}")
            limits[protocol] = SpecLimits.from_dict(section, key=f"spec.{protocol}")
        outliers = schema.check(values.get("outliers") or {}, "config", "outliers")
        drift = schema.check(values.get("drift") or {}, "config", "drift")
        return cls(
            limits,
            float(outliers["threshold"]),
            dict(drift.get("tolerance", {})),
            drift.get("temperature"),
            drift.get("max_excess"),
        )


def _records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    return [
        {k: _finite(v.item() if hasattr(v, "item") else v) for k, v in row.items()}
        for row in frame.to_dict("records")
    ]


def end_of_line(units: list[dict], settings: FleetSettings, inputs: dict) -> dict[str, Any]:
    """Verdict per unit (``unit["row"]`` manifest row; ``inputs``, what :func:`_unit_row`
    read of its folder, by (batch, device, session)), yield per batch. Units of a protocol
    without limits are not judged."""
    from .eol import batch_yield, judge

    verdicts = {}
    for unit in units:
        row = unit["row"]
        limits = settings.spec.get(row["protocol"])
        if limits is None:
            continue
        key = (row["batch"], row["device"], row["session"])
        verdicts[key] = judge(*inputs[key], limits)
    yields = batch_yield(list(verdicts.values())) if verdicts else pd.DataFrame()
    return {"verdicts": verdicts, "yield": _records(yields) if len(yields) else []}


def outliers(calibrated: list[dict], settings: FleetSettings) -> tuple[list[dict[str, Any]], list[str], str]:
    """Units of a protocol with fleet audits (the turntable) against their batch: (flagged
    rows, notes, distributions figure)."""
    from ..calibration.parameters import parameter_table
    from .outliers import fleet_outliers, plot_parameter_distributions

    rows = [u for u in calibrated if registry.get(u["protocol"]).fleet_audits]
    if not rows:
        return [], [], ""
    table = parameter_table([u["calibration"] for u in rows])
    table["session"] = [u["session"] for u in rows]
    flagged = fleet_outliers(table, threshold=settings.outlier_threshold)
    figure = plot_parameter_distributions(table, flagged)
    return _records(flagged), list(flagged.attrs.get("notes", [])), figure


def drift_audits(
    units: list[dict],
    calibrated: list[dict],
    folders: dict,
    settings: FleetSettings,
    earlier: Sequence[dict] = (),
) -> list[dict[str, Any]]:
    """Every device :func:`drift_devices` gives a page: parameter changes with their
    significance across its calibrated sessions, and the previous session's calibration
    re-validated on the newest session's holds; where fewer than two sessions calibrated
    (or an earlier one's file changed), the page says which. ``earlier``: sessions of the
    run's devices from earlier runs (:func:`gyrocal.calibration.registry.earlier_sessions`),
    audited beside the run's own and listed in the audit (``earlier``: session, batch, path
    and hash), so the end-of-line file records the history its pages rest on."""
    from .drift import parameter_changes, plot_drift, revalidate

    audited: dict[str, dict[str, list]] = {}
    for device in drift_devices([u["row"] for u in units], earlier):
        audited[device] = {"sessions": [], "missing": [], "earlier": []}
    for unit in calibrated:
        if unit["device"] in audited and registry.get(unit["protocol"]).fleet_audits:
            audited[unit["device"]]["sessions"].append(unit)
    done = {(c["batch"], c["device"], c["session"]) for c in calibrated}
    for unit in units:
        row = unit["row"]
        failed = (row["batch"], row["device"], row["session"]) not in done
        if failed and row["device"] in audited and registry.get(row["protocol"]).fleet_audits:
            audited[row["device"]]["missing"].append(f"{row['session']} did not calibrate")
    for unit in earlier:
        if unit["device"] in audited and _audited_protocol(unit["protocol"]):
            held = audited[unit["device"]]
            held["earlier"].append({k: unit[k] for k in ("session", "batch", "path", "file_hash")})
            if "problem" in unit:
                held["missing"].append(f"{unit['session']} (an earlier run's): {unit['problem']}")
            else:
                held["sessions"].append(unit)
                folders = {**folders, (unit["batch"], unit["device"], unit["session"]): unit["folder"]}
    audits = []
    for device, held in sorted(audited.items()):
        sessions = sorted(held["sessions"], key=lambda u: u["session"])
        audit = {
            "device": device,
            "sessions": [u["session"] for u in sessions],
            "batch": sessions[-1]["batch"] if sessions else "",
        }
        if held["earlier"]:
            audit["earlier"] = sorted(held["earlier"], key=lambda e: (e["session"], e["path"]))
        if len(sessions) < 2:
            audit["error"] = "fewer than two calibrated sessions to compare: " + "; ".join(held["missing"])
            audits.append(audit)
            continue
        try:
            changes = parameter_changes(
                [u["calibration"] for u in sessions],
                temperature=settings.drift_temperature,
                tolerance=settings.drift_tolerance,
            )
            audit["changes"] = _records(changes)
            audit["flagged"] = _records(changes[changes["flagged"]])
            audit["figure"] = plot_drift(changes)
            previous, newest = sessions[-2], sessions[-1]
            reval = revalidate(
                previous["calibration"],
                folders[(newest["batch"], device, newest["session"])],
                max_excess=settings.drift_max_excess,
            )
            audit["revalidation"] = {
                **{k: _finite(v) for k, v in reval.items() if k != "table"},
                "table": _records(reval["table"]),
                "calibration_session": previous["session"],
                "log_session": newest["session"],
            }
        except GyrocalError as exc:
            audit["error"] = str(exc)
        audits.append(audit)
    return audits


def audit(
    units: list[dict],
    calibrated: list[dict],
    settings: FleetSettings,
    inputs: dict,
    earlier: Sequence[dict] = (),
) -> dict[str, Any]:
    folders = {(u["row"]["batch"], u["row"]["device"], u["row"]["session"]): Path(u["folder"]) for u in units}
    eol = end_of_line(units, settings, inputs)
    flagged, notes, figure = outliers(calibrated, settings)
    return {
        "eol": eol,
        "outliers": flagged,
        "outlier_notes": notes,
        "outlier_figure": figure,
        "drift": drift_audits(units, calibrated, folders, settings, earlier),
    }


def fleet_summary(
    units: list[dict], settings: FleetSettings | None = None, earlier: Sequence[dict] = ()
) -> dict[str, Any]:
    """What the fleet page shows, read from every unit's folder (``units``: each with its
    manifest ``row``, results ``folder`` and ``report`` link): a row per unit session,
    calibrated or failed, the calibrated ones (``ok``), the fleet audit with ``settings``
    (end of line, outliers, drift over the run's sessions and the ``earlier`` ones the
    registry holds; each unit's verdict also in its row) and the servo versus turntable
    comparisons."""
    read = [_unit_row(unit) for unit in units]
    rows = [row for row, _ in read]
    ok = [r for r in rows if r["status"] == "ok"]
    fleet = None
    if settings is not None:
        inputs = {(r["batch"], r["device"], r["session"]): i for r, i in read}
        fleet = audit(units, ok, settings, inputs, earlier)
        for row in rows:
            verdict = fleet["eol"]["verdicts"].get((row["batch"], row["device"], row["session"]))
            if verdict is not None:
                row["eol"] = {"passed": verdict.passed, "reasons": list(verdict.reasons)}
    return {"rows": rows, "ok": ok, "fleet": fleet, "servo_vs_turntable": servo_versus_turntable(ok)}


# (coefficient, column heading, factor to the unit shown, significant digits)
KEY_PARAMETERS = (
    ("scale.x", "scale x, ppm", 1e6, 4),
    ("scale.y", "scale y, ppm", 1e6, 4),
    ("scale.z", "scale z, ppm", 1e6, 4),
    ("misalignment.x.y", "K[x,y]", 1.0, 4),
    ("misalignment.y.x", "K[y,x]", 1.0, 4),
    ("bias.x", "bias x, deg/s", 1.0, 3),
    ("bias.y", "bias y, deg/s", 1.0, 3),
    ("bias.z", "bias z, deg/s", 1.0, 3),
)


def _unit_row(unit: dict) -> tuple[dict, tuple]:
    """A unit session's row of the fleet table, and what :func:`gyrocal.fleet.eol.judge`
    takes, from one read of its folder (:func:`gyrocal.fleet.eol.read_unit`; a fleet job
    reads thousands): calibrated, or failed with the first failure record its parts hold
    (validation, calibration, observations), or with what made a part unreadable."""
    from ..io.errors import CorruptFileError
    from .eol import read_unit

    row = dict(unit["row"])
    folder = unit["folder"]
    row["report"] = unit["report"]
    try:
        cal, summary, info = read_unit(folder)
    except GyrocalError as exc:  # a part that cannot be read: this unit's failure alone
        row.update(status="failed", stage="fleet", error=str(exc), internal=False)
        return row, (exc, None, None)
    inputs = (
        cal
        if cal is not None
        else CorruptFileError("no such file", source=Path(folder) / "calibration.json"),
        summary,
        info,
    )
    rec = next(
        (d for d in (summary, cal, info) if isinstance(d, dict) and d.get("format") == failure.FORMAT), None
    )
    if rec is not None:
        row.update(
            status="failed", stage=rec["stage"], error=rec["error"], internal=rec.get("internal", False)
        )
        return row, inputs
    if summary is None or cal is None:
        row.update(
            status="failed",
            stage="workflow",
            error="no results: the unit's jobs did not run to the end (see the workflow's logs)",
            internal=True,
        )
        return row, inputs
    at_ref = cal.coefficients([cal.reference_temperature], warn=False)
    row["calibration"] = cal
    row["warnings"] = cal.extra.get("warnings", [])
    session_noise = (cal.extra.get("noise") or {}).get("session")
    row["noise"] = (
        {k: _largest_axis(session_noise, k) for k in ("arw", "bias_instability")} if session_noise else None
    )
    # a session that logged no temperature has no span, only its stand-in
    logged = not any(w.get("code") == "temperature_not_logged" for w in row["warnings"])
    row.update(
        status="ok",
        span=cal.grid.span if logged else None,
        summary=summary,
        reference=cal.reference_temperature,
        missing=_missing_effect(folder),
        params={n: float(at_ref[n][0]) * f for n, _, f, _ in KEY_PARAMETERS if n in at_ref},
        **_model_columns(cal, folder),
    )
    return row, inputs


def _model_columns(cal, folder) -> dict:
    """The unit's model for the fleet table: its terms, the config's ``models:`` entry it
    takes, each term beyond its protocol's model (kept or dropped, with the held-out error
    without and with it), and the run of the model before this one (:mod:`gyrocal.io.runs`)."""
    from ..io.runs import last_two, read_runs

    added = [
        {
            "term": a["term"],
            "kept": a["kept"],
            "reason": a.get("reason"),
            "without": (a.get("without") or {}).get("excess"),
            "with": (a.get("with") or {}).get("excess"),
        }
        for a in cal.extra.get("added_terms", ())
    ]
    current, previous = last_two(read_runs(folder), cal.provenance.get("config_sha256"))
    since = None
    if previous is not None:
        since = {
            "model": ", ".join(previous["model"]["terms"]),
            "before": previous["excess"],
            "after": current["excess"],
            "next_before": (previous.get("next_session") or {}).get("excess"),
            "next_after": (current.get("next_session") or {}).get("excess"),
            "next_session": (current.get("next_session") or {}).get("session"),
        }
    return {
        "model": ", ".join(t.spec_string() for t in cal.model.terms)
        + (" (continuous)" if cal.kind == "continuous" else ""),
        "model_entry": cal.extra.get("model_entry"),
        "added_terms": added,
        "since_last": since,
    }


def _missing_effect(folder) -> str:
    """The diagnosis in a few words, for the fleet table."""
    from ..io.unit_folder import read_part_doc

    try:
        diag = read_part_doc(folder, "diagnosis")
    except GyrocalError as exc:  # the calibration stands; its diagnosis cannot be read
        return f"diagnosis unreadable: {exc}"
    if diag is None:
        return "–"
    if diag.get("format") == failure.FORMAT:
        return f"diagnosis failed: {diag['error']}"
    if diag.get("best"):
        return f"{diag['best']['term']} ({diag['best']['gain_pct']:.0f} % less error)"
    found = "nothing" if diag.get("explains_the_data") else "unexplained excess"
    why = diag.get("unexplained")
    # A finding no term holds (fixed in the lab, between temperature points) is news even
    # where the fit explains the data.
    return f"{found}: {why['reason']}" if why else found


def _largest_axis(terms: dict, name: str) -> tuple[float, float]:
    """(value, standard error) of a noise term on the axis where it is largest."""
    values = np.atleast_1d(terms[name])
    i = int(np.argmax(values))
    return float(values[i]), float(np.atleast_1d(terms[f"{name}_stderr"])[i])


def servo_versus_turntable(rows: list[dict]) -> list[dict[str, Any]]:
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
            table = min(
                tables,
                key=lambda r: abs(
                    np.datetime64(r["session"] or "1970-01-01")
                    - np.datetime64(servo["session"] or "1970-01-01")
                ),
            )
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
                    (f"bias.{a}", f"bias {a}, deg/s", 1.0, s_B[i], t_B[i]),
                ):
                    diff = float(s_val - t_val)
                    se = float(np.hypot(s_err[name][0], t_err[name][0])) if name in t_err else None
                    params.append(
                        {
                            "parameter": label,
                            "servo": float(s_val) * factor,
                            "servo_se": float(s_err[name][0]) * factor,
                            "turntable": float(t_val) * factor,
                            "turntable_se": None if se is None else float(t_err[name][0]) * factor,
                            "difference": diff * factor,
                            "sigmas": diff / se if se else None,
                        }
                    )
            params.sort(key=lambda p: not p["parameter"].startswith("scale"))
            out.append(
                {
                    "device": device,
                    "servo_session": servo["session"],
                    "turntable_session": table["session"],
                    "temperature": float(temp[0]),
                    "servo_report": servo["report"],
                    "turntable_report": table["report"],
                    "rows": params,
                }
            )
    return out


def eol_document(result: dict[str, Any], settings: FleetSettings) -> dict[str, Any]:
    """The machine-readable end-of-line record: every judged unit and the batch yields."""
    verdicts = [
        {**v.to_dict(), "batch": key[0], "device": key[1], "session": key[2]}
        for key, v in sorted(result["eol"]["verdicts"].items())
    ]
    return {
        "format": "gyrocal.eol/1",
        "spec": {p: limits.to_dict() for p, limits in sorted(settings.spec.items())},
        "yield": result["eol"]["yield"],
        "units": verdicts,
        "outliers": result["outliers"],
        "drift": [{k: v for k, v in a.items() if k != "figure"} for a in result["drift"]],
    }


def drift_page_name(device: str) -> str:
    return f"drift/{device}.html"


def _audited_protocol(name: str) -> bool:
    """A protocol with fleet audits (the turntable) that this version knows: an earlier
    run's session of another is passed over."""
    return name in set(registry.names()) and registry.get(name).fleet_audits


def drift_devices(rows: Iterable[dict], earlier: Iterable[dict] = ()) -> list[str]:
    """Devices with two or more sessions of a protocol with fleet audits (the turntable):
    the manifest's ``rows``, whatever they come to, and the ``earlier`` sessions of their
    devices the registry holds (:func:`gyrocal.calibration.registry.earlier_rows`). Their
    drift pages; known when the run is planned."""
    counts: dict[str, int] = {}
    for row in rows:
        if registry.get(row["protocol"]).fleet_audits:
            counts[row["device"]] = counts.get(row["device"], 0) + 1
    for row in earlier:
        if row["device"] in counts and _audited_protocol(row["protocol"]):
            counts[row["device"]] += 1
    return sorted(d for d, n in counts.items() if n >= 2)


def other_sessions(rows: list[dict]) -> dict[tuple, tuple]:
    """For each unit session, another session of the same device and protocol whose
    carry-over judges the diagnosis' candidates (:func:`gyrocal.diagnosis.diagnose`): the
    next in session order, the one before for the last. Sessions of protocols whose
    observations carry the true rate only (not a servo's hand mount)."""
    by_device: dict[tuple, list[tuple]] = {}
    for row in rows:
        if registry.get(row["protocol"]).known_rate:
            key = (row["batch"], row["device"], row["session"])
            by_device.setdefault((row["device"], row["protocol"]), []).append(key)
    out = {}
    for keys in by_device.values():
        keys.sort(key=lambda k: (k[2], k[0]))
        for i, key in enumerate(keys):
            if len(keys) > 1:
                out[key] = keys[i + 1] if i + 1 < len(keys) else keys[i - 1]
    return out


# The fleet table's fixed columns (results/fleet.parquet; docs/fleet-table.md says each one).
TABLE_COLUMNS = (
    ("device", pa.string()),
    ("batch", pa.string()),
    ("session", pa.string()),
    ("protocol", pa.string()),
    ("status", pa.string()),
    ("failed_stage", pa.string()),
    ("error", pa.string()),
    ("reference_temperature", pa.float64()),
    ("temperature_min", pa.float64()),
    ("temperature_max", pa.float64()),
    ("validation_rms", pa.float64()),
    ("noise_floor", pa.float64()),
    ("excess", pa.float64()),
    ("excess_over_expected", pa.float64()),
    ("missing_effect", pa.string()),
    ("model", pa.string()),
    ("model_entry", pa.string()),
    ("terms_dropped", pa.list_(pa.string())),
    ("previous_model", pa.string()),
    ("previous_excess", pa.float64()),
    ("warnings", pa.list_(pa.string())),
    ("eol_passed", pa.bool_()),
    ("eol_reasons", pa.list_(pa.string())),
    ("input_name", pa.string()),
    ("input_hash", pa.string()),
    ("input_hash_algorithm", pa.string()),
    ("gyrocal_version", pa.string()),
)


def fleet_table(summary: dict) -> pa.Table:
    """One row per unit session of :func:`fleet_summary`'s result, calibrated or failed: its
    identity, outcome, validation, warnings, end-of-line verdict and input hash, then every
    parameter of its calibration at its reference temperature in display units (scale in
    ppm, misalignment in mrad, bias in deg/s: :func:`gyrocal.calibration.parameters.parameters_at`) with
    its standard error (``<name>_stderr``). A value a unit does not have is null."""
    from ..calibration.parameters import parameters_at
    from ..io.log import source_digest

    columns: dict[str, list] = {name: [] for name, _ in TABLE_COLUMNS}
    params: dict[str, dict[int, float]] = {}
    for i, row in enumerate(summary["rows"]):
        ok = row["status"] == "ok"
        cal = row.get("calibration")
        s = row.get("summary") or {}
        source = (cal.provenance.get("input") or {}) if cal is not None else {}
        algorithm, digest = source_digest(source) or (None, None)
        eol = row.get("eol")
        values = {
            "device": row["device"],
            "batch": row["batch"],
            "session": row["session"],
            "protocol": row["protocol"],
            "status": row["status"],
            "failed_stage": None if ok else row.get("stage"),
            "error": None if ok else row.get("error"),
            "reference_temperature": cal.reference_temperature if ok else None,
            "temperature_min": row["span"][0] if ok and row["span"] else None,
            "temperature_max": row["span"][1] if ok and row["span"] else None,
            **{
                k: _finite(s.get(k))
                for k in ("validation_rms", "noise_floor", "excess", "excess_over_expected")
            },
            "missing_effect": row.get("missing") if ok else None,
            "model": row.get("model") if ok else None,
            "model_entry": row.get("model_entry") if ok else None,
            "terms_dropped": [a["term"] for a in row["added_terms"] if not a["kept"]] if ok else None,
            "previous_model": (row.get("since_last") or {}).get("model") if ok else None,
            "previous_excess": _finite((row.get("since_last") or {}).get("before")) if ok else None,
            "warnings": [w["code"] for w in row.get("warnings", [])] if ok else None,
            "eol_passed": eol["passed"] if eol else None,
            "eol_reasons": eol["reasons"] if eol else None,
            "input_name": source.get("name"),
            "input_hash": digest,
            "input_hash_algorithm": algorithm,
            "gyrocal_version": (cal.provenance.get("versions") or {}).get("gyrocal") if ok else None,
        }
        for name, _ in TABLE_COLUMNS:
            columns[name].append(values[name])
        if ok:
            for name, value, stderr in parameters_at(cal)[["parameter", "value", "stderr"]].itertuples(
                index=False
            ):
                params.setdefault(name, {})[i] = _finite(value)
                params.setdefault(f"{name}_stderr", {})[i] = _finite(stderr)
    n = len(summary["rows"])
    arrays = {name: pa.array(columns[name], type=kind) for name, kind in TABLE_COLUMNS}
    for name in sorted(params, key=lambda k: (k.removesuffix("_stderr"), k.endswith("_stderr"))):
        arrays[name] = pa.array([params[name].get(i) for i in range(n)], type=pa.float64())
    return pa.table(arrays)


def _write_page(path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(path, text)


def write_fleet_report(summary: dict, path, settings=None, eol_json=None, registry=None) -> None:
    """The fleet summary page from :func:`fleet_summary`: per batch, one row
    per unit and session; failed units with their error; distributions of the key
    parameters across the calibrated units. With ``settings``
    (:class:`FleetSettings`): end-of-line verdicts and yield, outliers
    against the batch, drift pages of devices with several sessions (beside the summary,
    ``drift/<device>.html``) and the machine-readable ``eol_json``. ``registry``: where the
    run's calibrations were indexed and how many files (said on the page)."""
    rows, ok, fleet = summary["rows"], summary["ok"], summary["fleet"]
    batches = {}
    for row in rows:
        batches.setdefault(row["batch"], []).append(row)
    ok = [r for r in rows if r["status"] == "ok"]
    figures = [
        (label, plots.histogram(np.array(values), label))
        for label, values in [
            *[(heading, [r["params"].get(n, np.nan) for r in ok]) for n, heading, _, _ in KEY_PARAMETERS],
            ("validation RMS, deg/s", [r["summary"]["validation_rms"] for r in ok]),
            ("excess over the noise floor", [r["summary"]["excess"] for r in ok]),
            (
                "angle random walk, deg/√h (largest axis)",
                [r["noise"]["arw"][0] if r["noise"] else np.nan for r in ok],
            ),
        ]
    ]
    if fleet is not None:
        for unit in fleet["drift"]:
            unit["page"] = drift_page_name(unit["device"])
            page = render_page("drift_report.html.j2", unit=unit, tolerance=settings.drift_tolerance)
            _write_page(Path(path).parent / unit["page"], page)
        if eol_json is not None:
            _write_page(eol_json, dumps(json_safe(eol_document(fleet, settings))) + "\n")
    batches = sorted(batches.items())
    for stale in batch_pages_of(path):  # an earlier fleet's pages: this one writes its own
        stale.unlink()
    pages = _batch_pages(batches, path) if len(rows) > PAGE_UNITS else None
    html = render_page(
        "fleet_report.html.j2",
        batches=batches,
        key_parameters=KEY_PARAMETERS,
        figures=figures,
        total=len(rows),
        calibrated=len(ok),
        failed=len(rows) - len(ok),
        warned=sum(1 for r in ok if r.get("warnings")),
        batch_pages=pages,
        page_units=PAGE_UNITS,
        servo_vs_turntable=summary["servo_vs_turntable"],
        fleet=fleet,
        registry=registry,
    )
    _write_page(path, html)


# Unit rows one page holds. A larger fleet's summary lists its batches, each batch's rows on
# pages of their own beside it: 100,000 rows are some 400 MB of HTML.
PAGE_UNITS = 1000


def batch_page_name(batch: str, page: int, index: str = "index") -> str:
    """A batch page's file name beside the summary ``index``.html: the batch's name made safe
    for a file name, a short hash of the name (names that differ only in unsafe characters
    stay apart), the page. Files, not a folder: a folder of pages could be a batch's folder
    of reports, since a batch may have any name."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", batch)[:40].strip("._") or "batch"
    digest = hashlib.sha256(batch.encode()).hexdigest()[:8]
    return f"{index}-batch-{safe}-{digest}-{page}.html"


def batch_pages_of(path) -> list[Path]:
    """The batch pages beside the summary at ``path`` (files named by :func:`batch_page_name`)."""
    path = Path(path)
    pattern = re.compile(rf"{re.escape(path.stem)}-batch-.*-[0-9a-f]{{8}}-[0-9]+\.html")
    return sorted(
        p for p in path.parent.glob(f"{path.stem}-batch-*.html") if pattern.fullmatch(p.name) and p.is_file()
    )


def _batch_pages(batches: list, path) -> list[dict]:
    """Every batch's rows on pages of at most :data:`PAGE_UNITS`, written beside the summary;
    the summary's table of them."""
    path = Path(path)
    index = []
    for batch, rows in batches:
        chunks = [rows[i : i + PAGE_UNITS] for i in range(0, len(rows), PAGE_UNITS)]
        names = [batch_page_name(batch, k + 1, path.stem) for k in range(len(chunks))]
        for k, chunk in enumerate(chunks):
            html = render_page(
                "fleet_batch.html.j2",
                batch=batch,
                rows=chunk,
                total=len(rows),
                part=f"page {k + 1} of {len(chunks)}" if len(chunks) > 1 else "",
                key_parameters=KEY_PARAMETERS,
                summary=path.name,
                previous=names[k - 1] if k else None,
                next=names[k + 1] if k + 1 < len(chunks) else None,
            )
            _write_page(path.parent / names[k], html)
        ok = [r for r in rows if r["status"] == "ok"]
        index.append(
            {
                "batch": batch,
                "units": len(rows),
                "calibrated": len(ok),
                "failed": len(rows) - len(ok),
                "warned": sum(1 for r in ok if r.get("warnings")),
                "pages": names,
            }
        )
    return index
