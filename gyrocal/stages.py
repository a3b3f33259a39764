"""The workflow's stages: one function per rule, files in and files out.

Each unit and session has a results folder (``UNIT_FILES`` names its files). A stage that
cannot process its unit writes failure records in place of its outputs (see
:mod:`gyrocal.failure`), so a fleet run always completes and reports every unit.
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import failure
from .calibration import dumps, load_calibration, save_calibration
from .config import Settings
from .errors import GyrocalError
from .io import read_table_with_metadata, write_table
from .pipeline import calibrate_observations, segment_log
from .signals import Series
from .thermal import fit_model
from .validate import validate

UNIT_FILES = {
    "observations": "observations.parquet",
    "history": "history.parquet",
    "segments": "segments.parquet",
    "timeline": "timeline.parquet",
    "calibration": "calibration.json",
    "validation": "validation.json",
    "holds": "validation_holds.parquet",
    "table_hold_means": "table_hold_means.parquet",
    "table_samples": "table_samples.parquet",
    "by_temperature": "by_temperature.parquet",
    "diagnosis": "diagnosis.json",
    "residuals": "residuals.parquet",
}
VALIDATION_TABLES = ("holds", "table_hold_means", "table_samples", "by_temperature")
DIAGNOSIS_FILES = ("diagnosis", "residuals")


def unit_paths(folder) -> dict[str, Path]:
    return {k: Path(folder) / v for k, v in UNIT_FILES.items()}


def run_stage(stage: str, outputs, meta: dict, work: Callable[[], None], *,
              record_failures: bool) -> int:
    """Run ``work``; when it fails and failures are recorded, write the record to every
    output and return 0 so the rest of the fleet goes on (the error goes to stderr)."""
    try:
        work()
        return 0
    except Exception as exc:  # noqa: BLE001 - recorded in the outputs, not lost
        if not record_failures:
            raise
        rec = exc.record if isinstance(exc, failure.UpstreamFailure) else failure.record(stage, exc, meta)
        failure.write(outputs, rec)
        kind = "passed on" if isinstance(exc, failure.UpstreamFailure) else "recorded"
        print(f"gyrocal: {stage} failed ({kind}): {rec['error']}", file=sys.stderr)
        return 0


def segment_stage(log, folder, settings: Settings, meta: dict) -> None:
    seg = segment_log(log, settings, meta.get("protocol") or "turntable")
    paths = unit_paths(folder)
    paths["observations"].parent.mkdir(parents=True, exist_ok=True)
    extra = {"info": seg.info, "meta": meta, "log": str(log),
             "segmentation": settings.to_dict()["segmentation"]}
    series = seg.observations.attrs.get("series")
    if series is not None:
        write_table(series.to_frame(), paths["history"], series.metadata())
    write_table(seg.observations, paths["observations"], extra)
    write_table(seg.segments, paths["segments"], {"meta": meta})
    write_table(seg.timeline, paths["timeline"], {"meta": meta})


def read_observations(paths):
    """A unit's observation table and its metadata (``paths``: the unit's paths, or the
    observations file), the table carrying the session's record when segmentation wrote
    one beside it (``history.parquet``)."""
    observations = Path(paths["observations"] if isinstance(paths, dict) else paths)
    obs, extra = read_table_with_metadata(observations)
    if isinstance(extra.get("info"), dict) and isinstance(extra["info"].get("noise"), dict):
        obs.attrs["static_seconds"] = float(extra["info"]["noise"].get("static_seconds") or 0.0)
    history = observations.with_name(UNIT_FILES["history"])
    if history.exists():
        frame, meta = read_table_with_metadata(history)
        obs.attrs["series"] = Series.from_frame(frame, meta)
    return obs, extra


def fit_stage(folder, settings: Settings, meta: dict) -> None:
    paths = unit_paths(folder)
    failure.check_inputs(paths["observations"])
    obs, extra = read_observations(paths)
    cal, _ = calibrate_observations(obs, settings, meta=meta, source=extra["info"]["source"],
                                    label=paths["observations"], noise=extra["info"].get("noise"))
    save_calibration(cal, paths["calibration"])


def validate_stage(folder, settings: Settings) -> None:
    paths = unit_paths(folder)
    failure.check_inputs(paths["observations"], paths["calibration"])
    obs, _ = read_observations(paths)
    cal = load_calibration(paths["calibration"])
    stale = GyrocalError("the calibration was not fitted from these observations with these "
                         "settings: run the fit stage again", source=paths["calibration"])
    if cal.meta.get("protocol") == "servo":
        from .protocols import servo_calibration, servo_validation
        again = servo_calibration(obs, reference_temperature=settings.model.reference_temperature,
                                  meta=cal.meta, provenance=cal.provenance)
        if not np.array_equal(again.grid.values, cal.grid.values):
            raise stale
        val = servo_validation(obs, cal)
    else:
        model = settings.model.build()
        fitted = fit_model(model, obs, kind=settings.model.kind, method=settings.model.interpolation,
                           degree=settings.model.degree, source=paths["observations"])
        if not np.array_equal(fitted.coefficients.values, cal.grid.values):
            raise stale
        val = validate(fitted.model, obs, fitted, reference_temperature=settings.model.reference_temperature)
    write_table(val.holds, paths["holds"], {"summary": val.summary})
    write_table(val.table_holds, paths["table_hold_means"], {"summary": val.summary})
    write_table(val.table_samples, paths["table_samples"], {"summary": val.summary})
    write_table(val.by_temperature, paths["by_temperature"], {"summary": val.summary})
    tmp = paths["validation"].with_name(paths["validation"].name + ".tmp")
    tmp.write_text(dumps({"format": "gyrocal.validation/1", **cal.meta, "summary": val.summary}))
    tmp.replace(paths["validation"])


def diagnose_stage(folder, settings: Settings, meta: dict, *, output=None, residuals=None,
                   other=None) -> str:
    """The diagnosis of the unit's observations (JSON) and its normalised residuals
    (Parquet, heat maps in the metadata); returns the verdict. ``other``, the results
    folder of another session of the unit, judges the candidates by how they carry over."""
    from .diagnose import diagnose
    paths = unit_paths(folder)
    failure.check_inputs(paths["observations"])
    obs, _ = read_observations(paths)
    other_obs, other_note = None, {}
    if other is not None:
        # Another session only sharpens the judgement: one whose segmentation failed is
        # noted in the diagnosis, which goes on without it.
        try:
            other_paths = unit_paths(other)
            failure.check_inputs(other_paths["observations"])
            other_obs, _ = read_observations(other_paths)
        except GyrocalError as exc:
            other_note = {"other_session_error": str(exc)}
    diag = diagnose(settings, obs, other_obs)
    out = Path(output or paths["diagnosis"])
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(dumps({**diag.to_dict(), **other_note, **meta}))
    tmp.replace(out)
    if residuals is not False:
        write_table(diag.residuals, residuals or paths["residuals"], {"heatmaps": diag.heatmaps})
    return diag.verdict


def analyse_stage(folder, settings: Settings, meta: dict, *, record_failures: bool,
                  other=None) -> str | None:
    """Fit, validate and diagnose a segmented unit in one process: the workflow's
    ``analyse`` rule, one job where three would each start Python and cost Snakemake a
    job to plan. Each step runs as its own stage (:func:`run_stage`) with the outputs and
    failure records that ``gyrocal fit``, ``validate`` and ``diagnose --unit`` write: a
    failed fit is recorded in the calibration and passed on to the validation, and the
    diagnosis, which reads only the observations, still runs. Returns the diagnosis
    verdict (None when it failed and was recorded)."""
    paths = unit_paths(folder)
    verdict = []
    steps = (("fit", ["calibration"], lambda: fit_stage(folder, settings, meta)),
             ("validate", ["validation", *VALIDATION_TABLES], lambda: validate_stage(folder, settings)),
             ("diagnose", list(DIAGNOSIS_FILES),
              lambda: verdict.append(diagnose_stage(folder, settings, meta, other=other))))
    for stage, outputs, work in steps:
        run_stage(stage, [paths[k] for k in outputs], meta, work, record_failures=record_failures)
    return verdict[0] if verdict else None


def report_stage(folder, out_html, settings: Settings | None = None) -> None:
    from .report import UnitResults, write_unit_report
    paths = unit_paths(folder)
    failure.check_inputs(*(v for k, v in paths.items() if k not in DIAGNOSIS_FILES))
    # The workflow declares the unit's products, not the tables written beside them
    # (workflow/rules/analyse.smk): name a table deleted since they were made.
    missing = [name for key, name in UNIT_FILES.items()
               if key not in (*DIAGNOSIS_FILES, "history") and not paths[key].exists()]
    if missing:
        raise GyrocalError(f"{missing[0]} is missing from the unit's results: delete the "
                           "folder and run the workflow again to rebuild it", source=folder)
    results = UnitResults.from_folder(folder)
    if settings is not None:
        results.command = reproduce_command(results, settings)
    write_unit_report(results, out_html)


def reproduce_command(results, settings: Settings) -> str:
    meta = results.meta
    words = ["gyrocal", "calibrate", results.log or "LOG.parquet", "--protocol",
             meta.get("protocol") or "turntable"]
    for key in ("device", "batch", "session"):
        if meta.get(key):
            words += [f"--{key}", str(meta[key])]
    words += ["--settings-json", json.dumps(settings.to_dict(), sort_keys=True), "-o",
              "calibration.json"]
    return " ".join(shlex.quote(w) for w in words)


def fleet_stage(rows: list[dict], results_root, reports_root, out_index, bundle=None,
                settings=None, eol_json=None) -> None:
    """The fleet summary over every manifest row, calibrated or failed (with ``settings``,
    a :class:`gyrocal.fleet.FleetSettings`: end of line, outliers, drift pages and
    ``eol_json``), and (optionally) a self-contained folder of all unit reports for
    ``snakemake --report``."""
    from .report import write_fleet_report
    units = []
    for row in rows:
        folder = Path(results_root) / row["batch"] / row["device"] / row["session"]
        units.append({"row": row, "folder": folder,
                      "report": f"{row['batch']}/{row['device']}/{row['session']}.html"})
    write_fleet_report(units, out_index, settings, eol_json)
    if bundle is not None:
        bundle = Path(bundle)
        if bundle.exists():
            shutil.rmtree(bundle)
        bundle.mkdir(parents=True)
        for unit in units:
            source = Path(reports_root) / unit["report"]
            target = bundle / unit["report"]
            target.parent.mkdir(parents=True, exist_ok=True)
            if source.exists():
                shutil.copyfile(source, target)
        shutil.copyfile(out_index, bundle / "index.html")
        drift_pages = Path(out_index).parent / "drift"
        if settings is not None and drift_pages.is_dir():
            from .fleet import drift_devices
            (bundle / "drift").mkdir()
            for device in drift_devices(rows):
                if (drift_pages / f"{device}.html").exists():
                    shutil.copyfile(drift_pages / f"{device}.html", bundle / "drift" / f"{device}.html")
