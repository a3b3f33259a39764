"""The workflow's stages: one function per rule, files in and files out.

Each unit and session has a results folder (:mod:`gyrocal.io.unit_folder` names its files). A stage that
cannot process its unit writes failure records in place of its outputs (see
:mod:`gyrocal.io.failure`), so a fleet run always completes and reports every unit.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..calibration.file import dumps, load_calibration, save_calibration
from ..io import atomic, failure
from ..io.errors import GyrocalError
from ..io.runs import RunEntry, RunFix
from ..io.tables import write_table
from ..io.unit_folder import (
    DIAGNOSIS_FILES,
    OPTIONAL_FILES,
    UNIT_FILES,
    VALIDATION_TABLES,
    part_exists,
    part_failure,
    part_label,
    read_part_json,
    unit_paths,
)
from ..protocols import registry
from ..report.pages import write_failure
from ..terms.signals import read_observations

if TYPE_CHECKING:
    from ..pipeline.config import Settings


def run_stage(stage: str, outputs, meta: dict, work: Callable[[], None], *, record_failures: bool) -> int:
    """Run ``work``; when it fails and failures are recorded, write the record to every
    output and return 0 so the rest of the fleet goes on (the error goes to stderr)."""
    try:
        work()
        return 0
    except Exception as exc:  # noqa: BLE001 - recorded in the outputs, not lost
        if not record_failures:
            raise
        rec = exc.record if isinstance(exc, failure.UpstreamFailure) else failure.record(stage, exc, meta)
        write_failure(outputs, rec)
        kind = "passed on" if isinstance(exc, failure.UpstreamFailure) else "recorded"
        print(f"gyrocal: {stage} failed ({kind}): {rec['error']}", file=sys.stderr)
        return 0


def segment_stage(log, folder, settings: Settings, meta: dict) -> None:
    from ..pipeline.chain import segment_log  # the chain on use: a report needs none of it

    seg = segment_log(log, settings, meta.get("protocol"))
    paths = unit_paths(folder)
    paths["observations"].parent.mkdir(parents=True, exist_ok=True)
    extra = {
        "info": seg.info,
        "meta": meta,
        "log": str(log),
        "segmentation": settings.to_dict()["segmentation"],
    }
    series = seg.observations.attrs.get("series")
    if series is not None:
        write_table(series.to_frame(), paths["history"], series.metadata())
    write_table(seg.observations, paths["observations"], extra)
    write_table(seg.segments, paths["segments"], {"meta": meta})
    write_table(seg.timeline, paths["timeline"], {"meta": meta})


def fit_stage(folder, settings: Settings, meta: dict):
    from ..pipeline.chain import calibrate_observations

    """The unit's calibration; returns the common model's fit (None for a protocol with a
    calibration of its own) and the calibration, for the stages after it in the same job."""
    paths = unit_paths(folder)
    obs, extra = read_observations(folder)
    cal, fitted = calibrate_observations(
        obs,
        settings,
        meta=meta,
        source=extra["info"]["source"],
        label=part_label(folder, "observations"),
        noise=extra["info"].get("noise"),
        info=extra["info"],
    )
    save_calibration(cal, paths["calibration"])
    return fitted, cal


def validate_stage(folder, settings: Settings, fitted=None):
    from ..fit.thermal import fit_model
    from ..pipeline.chain import settings_used, validation

    """The calibration's validation tables and summary; returns the validation. ``fitted``,
    the fit the calibration was made from in the same job, spares fitting again (the
    leave-temperature-out validation needs the per-point fits, not only the file). A
    calibration made from another log or other settings than these is refused: staleness is
    read from the hashes the file records (the log's SHA-256, the settings')."""
    paths = unit_paths(folder)
    source = part_label(folder, "observations")
    obs, extra = read_observations(folder)
    failure.check_inputs(paths["calibration"])
    cal = load_calibration(paths["calibration"])
    if (
        cal.provenance.get("config_sha256") != settings.sha256()
        or cal.provenance.get("input") != extra["info"]["source"]
    ):
        raise GyrocalError(
            "the calibration was not fitted from these observations with these "
            "settings: run the fit stage again",
            source=paths["calibration"],
        )
    if fitted is None and registry.get(cal.meta.get("protocol")).validate is None:
        model = settings_used(settings, cal).model
        fitted = fit_model(
            model.build(),
            obs,
            kind=model.kind,
            method=model.interpolation,
            degree=model.degree,
            source=source,
        )
    val = validation(obs, cal, fitted, settings, source=source)
    results, figures = registry.analysis(cal.meta.get("protocol"), obs)
    _write_json(paths["protocol"], {"format": "gyrocal.protocol/1", "results": results, "figures": figures})
    if val.free_points is not None:
        write_table(val.free_points, paths["free_points"], {})
    write_table(val.holds, paths["holds"], {"summary": val.summary})
    write_table(val.table_holds, paths["table_hold_means"], {"summary": val.summary})
    write_table(val.table_samples, paths["table_samples"], {"summary": val.summary})
    write_table(val.by_temperature, paths["by_temperature"], {"summary": val.summary})
    _write_json(paths["validation"], {"format": "gyrocal.validation/1", **cal.meta, "summary": val.summary})
    return val


def _write_json(path: Path, document: dict) -> None:
    atomic.write_text(path, dumps(document))


def diagnose_stage(
    folder,
    settings: Settings,
    meta: dict,
    *,
    output=None,
    residuals=None,
    other=None,
    base=None,
    requested: Settings | None = None,
) -> str:
    """The diagnosis of the unit's observations (JSON) and its normalised residuals
    (Parquet, heat maps in the metadata); returns the verdict. ``other``, the results
    folder of another session of the unit, judges the candidates by how they carry over;
    ``base``, the configured model's fit and validation made in the same job
    (:func:`gyrocal.diagnosis.evaluation_of`), spares making them again. A diagnosis written as
    the unit's own is added to its record of runs when the unit's calibration was made with
    the settings asked for (``requested``, before the terms its data could not identify
    were dropped; ``settings`` themselves otherwise)."""
    from ..diagnosis import diagnose
    from ..diagnosis.evaluation import with_unit_lines

    paths = unit_paths(folder)
    obs, _ = read_observations(folder)
    other_obs, other_note = None, {}
    if other is not None:
        # Another session only sharpens the judgement: one whose segmentation failed is
        # noted in the diagnosis, which goes on without it.
        try:
            other_obs, _ = read_observations(other)
        except GyrocalError as exc:
            other_note = {"other_session_error": str(exc)}
    requested = requested or settings
    if base is None:
        from ..pipeline.identify import added_terms, identify

        if added_terms(settings, meta.get("protocol")):  # the model the unit would run with
            settings = identify(settings, obs, meta.get("protocol"), held_out=False).settings
    diag = diagnose(settings, obs, other_obs, base=base)
    out = Path(output or paths["diagnosis"])
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = with_unit_lines(diag.to_dict(), meta.get("device"), settings)
    if other is not None:
        other_note["other_session"] = Path(other).name
    _write_json(out, {**doc, **other_note, **meta})
    if residuals is not False:
        write_table(diag.residuals, residuals or paths["residuals"], {"heatmaps": diag.heatmaps})
    if out.resolve() == paths["diagnosis"].resolve():  # the unit's own: its record of runs
        _record_run(folder, settings, requested, doc, None if other is None else Path(other).name)
    return diag.verdict


def _record_run(folder, settings: Settings, requested: Settings, diagnosis: dict, other: str | None) -> None:
    """This run in the unit session's record (:mod:`gyrocal.io.runs`), where the folder
    holds its calibration and validation, made with the ``requested`` settings."""
    from ..io.runs import record_run

    paths = unit_paths(folder)
    if not paths["calibration"].is_file() or failure.read(paths["calibration"]) is not None:
        return
    cal = load_calibration(paths["calibration"])
    validation = read_part_json(folder, "validation")
    if "summary" in validation and cal.provenance.get("config_sha256") == requested.sha256():
        record_run(folder, run_entry(settings, cal, validation, diagnosis, other))


def analyse_stage(folder, settings: Settings, meta: dict, *, record_failures: bool, other=None) -> str | None:
    """Fit, validate and diagnose a segmented unit in one process: the workflow's
    ``analyse`` rule, one job where several would each start
    Python and cost Snakemake a job to plan. The configured model is fitted once: the
    validation and the diagnosis take that fit. Each step runs as its own stage
    (:func:`run_stage`) with the outputs and failure records that ``gyrocal fit``,
    ``validate`` and ``diagnose --unit`` write: a failed fit is recorded in the calibration
    and passed on to the validation, and the diagnosis, which reads only the observations,
    still runs (fitting for itself). Returns the diagnosis verdict (None when it failed and
    was recorded)."""
    from ..diagnosis import evaluation_of
    from ..pipeline.chain import settings_used

    paths = unit_paths(folder)
    made: dict = {}

    def fit():
        made["fitted"], made["cal"] = fit_stage(folder, settings, meta)

    def check():
        val = validate_stage(folder, settings, made.get("fitted"))
        if made.get("fitted") is not None:
            made["base"] = evaluation_of(
                settings_used(settings, made["cal"]), made["fitted"], val.summary, "configured model"
            )

    def diagnosis():
        # the model this unit runs with: without the terms its data could not identify
        used = settings_used(settings, made["cal"]) if "cal" in made else settings
        made["verdict"] = diagnose_stage(
            folder, used, meta, other=other, base=made.get("base"), requested=settings
        )

    steps = (
        ("fit", ["calibration"], fit),
        ("validate", ["validation", *VALIDATION_TABLES], check),
        ("diagnose", list(DIAGNOSIS_FILES), diagnosis),
    )
    for stage, outputs, work in steps:
        run_stage(stage, [paths[k] for k in outputs], meta, work, record_failures=record_failures)
    return made.get("verdict")


def run_entry(
    settings: Settings, cal, validation: dict[str, Any], diagnosis: dict[str, Any], other: str | None
) -> RunEntry:
    """What a unit session's record of runs keeps of this one (:mod:`gyrocal.io.runs`): the
    model as configured (its key) and as fitted, its figures in the session and on the other
    session (named ``other``), and the fix the diagnosis named with its figures."""
    import hashlib

    model = settings.model.to_dict()
    key = hashlib.sha256(json.dumps(model, sort_keys=True).encode()).hexdigest()[:16]
    s = validation["summary"]
    floor = s["noise_floor"]
    nxt = diagnosis.get("next_session") or {}
    best = diagnosis.get("best")
    fix: RunFix | None = None
    if best:
        fix_next = (best.get("next_session") or {}).get("excess")
        fix = {
            "term": best["term"],
            "together": best.get("together") or [],
            "reads": best.get("reads"),
            "excess": best["validation_rms_with"] / floor,
            "next_excess": fix_next,
            "option": best.get("option"),
            "config_line": best.get("config_line"),
        }
    return {
        "key": key,
        "config_sha256": cal.provenance.get("config_sha256"),
        "entry": settings.model_entry,
        "model": {
            "kind": "continuous" if cal.kind == "continuous" else "grid",
            "terms": [t.spec_string() for t in cal.model.terms],
        },
        "dropped": [a["term"] for a in cal.extra.get("added_terms", ()) if not a["kept"]],
        "validation_rms": s["validation_rms"],
        "noise_floor": floor,
        "excess": s["excess"],
        "held_out": s.get("held_out"),
        "next_session": (
            {"session": other, "excess": nxt["excess"]} if other and nxt.get("excess") is not None else None
        ),
        "fix": fix,
    }


def report_stage(folder, out_html, settings: Settings | None = None) -> None:
    from ..report.unit import UnitResults, write_unit_report

    for key in UNIT_FILES:
        if key not in DIAGNOSIS_FILES:
            found = part_failure(folder, key)
            if found is not None:
                raise failure.UpstreamFailure(found)
    # The workflow declares the unit's products, not the tables written beside them
    # (workflow/rules/analyse.smk): name a table deleted since they were made.
    missing = [
        name
        for key, name in UNIT_FILES.items()
        if key not in (*DIAGNOSIS_FILES, *OPTIONAL_FILES) and not part_exists(folder, key)
    ]
    if missing:
        raise GyrocalError(
            f"{missing[0]} is missing from the unit's results: delete the "
            "folder and run the workflow again to rebuild it",
            source=folder,
        )
    results = UnitResults.from_folder(folder)
    if settings is not None:
        results.command = reproduce_command(results, settings)
    write_unit_report(results, out_html, registry.get(results.meta.get("protocol")))


def reproduce_command(results, settings: Settings) -> str:
    meta = results.meta
    words = [
        "gyrocal",
        "calibrate",
        results.log or "LOG.parquet",
        "--protocol",
        meta.get("protocol") or registry.DEFAULT,
    ]
    for key in ("device", "batch", "session"):
        if meta.get(key):
            words += [f"--{key}", str(meta[key])]
    words += ["--settings-json", json.dumps(settings.to_dict(), sort_keys=True), "-o", "calibration.json"]
    return " ".join(shlex.quote(w) for w in words)


def fleet_stage(
    rows: list[dict],
    results_root,
    reports_root,
    out_index,
    bundle=None,
    settings=None,
    eol_json=None,
    table=None,
    registry: str | None = None,
    history=None,
) -> None:
    """The fleet summary over every manifest row, calibrated or failed (with ``settings``,
    a :class:`gyrocal.fleet.summary.FleetSettings`: end of line, outliers, drift pages and
    ``eol_json``), the fleet as one table (``table``: Parquet, a row per unit session) and
    (optionally) a self-contained folder of all unit reports for ``snakemake --report``.
    ``registry`` (a database URL or SQLite file; "" for none) indexes the run's calibration
    files and failure records, in one transaction: a job killed meanwhile leaves it as it was.
    The drift pages take the devices' earlier sessions from ``history`` (the workflow plan's
    record, :func:`gyrocal.calibration.registry.plan_history`), else from the registry."""
    from ..fleet.summary import fleet_summary, fleet_table, write_fleet_report

    units = []
    for row in rows:
        folder = Path(results_root) / row["batch"] / row["device"] / row["session"]
        units.append(
            {"row": row, "folder": folder, "report": f"{row['batch']}/{row['device']}/{row['session']}.html"}
        )
    from ..calibration import registry as index

    indexed, earlier, backend = None, [], None
    if registry != "":
        where = index.location(Path(results_root), registry)
        indexed = {"where": index.shown(where), "rows": 0}
        try:  # a registry out of reach costs the run its index, not its summary
            backend = index.connect(where)
        except index.RegistryError as exc:
            indexed["problem"] = str(exc)
    own = {(r["device"], r["session"]) for r in rows}
    try:
        if settings is not None and history is not None:  # the sessions the plan counted
            recorded = index.read_history(Path(history))
            earlier = index.load_sessions(r for r in recorded if (r["device"], r["session"]) not in own)
        elif settings is not None and backend is not None:  # the devices' earlier sessions
            try:
                earlier = index.earlier_sessions(backend, {d for d, _ in own}, own, Path(results_root))
            except index.RegistryError as exc:
                print(f"gyrocal: warning: the drift pages take no earlier session: {exc}", file=sys.stderr)
        for unit in earlier:
            if "problem" in unit:
                print(f"gyrocal: warning: a registry row passed over: {unit['problem']}", file=sys.stderr)
        summary = fleet_summary(units, settings, earlier)
        if backend is not None:
            folders = sorted({f"{r['batch']}/{r['device']}/{r['session']}" for r in rows})
            try:
                indexed["rows"] = index.upsert(
                    backend,
                    index.rows_of(Path(results_root), folders),
                    unit_folders=[(str(results_root), f) for f in folders],
                )
            except index.RegistryError as exc:
                indexed["problem"] = str(exc)
    finally:
        if backend is not None:
            backend.close()
    if indexed is not None and "problem" in indexed:
        print(f"gyrocal: warning: the run is not indexed: {indexed['problem']}", file=sys.stderr)
    write_fleet_report(summary, out_index, settings, eol_json, indexed)
    if table is not None:
        import pyarrow.parquet as pq

        frame = fleet_table(summary)
        frame = frame.replace_schema_metadata({b"gyrocal.format": b"gyrocal.fleet/1"})
        with atomic.replacing(table) as tmp:
            pq.write_table(frame, tmp)
    if bundle is not None:
        drift = [a["device"] for a in summary["fleet"]["drift"]] if summary["fleet"] else []
        _write_bundle(Path(bundle), units, reports_root, out_index, drift)


def _link_or_copy(source: Path, target: Path) -> None:
    """``target`` as a second name of ``source`` (no bytes and no file more on disk; a
    report rewritten later is a new file, so the bundle keeps the one it was made with), or
    a copy where the file system has no hard links."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)


def _write_bundle(bundle: Path, units, reports_root, out_index, drift_devices) -> None:
    """A self-contained folder of every unit report (hard links to them), the fleet summary
    and the pages of ``drift_devices``, put in place whole: a job killed while linking leaves the old folder."""
    bundle.parent.mkdir(parents=True, exist_ok=True)
    with atomic.replacing_folder(bundle) as tmp:
        for unit in units:
            source = Path(reports_root) / unit["report"]
            target = tmp / unit["report"]
            target.parent.mkdir(parents=True, exist_ok=True)
            if source.exists():
                _link_or_copy(source, target)
        shutil.copyfile(out_index, tmp / "index.html")
        from ..fleet.summary import batch_pages_of

        for page in batch_pages_of(out_index):  # a large fleet's pages of its batches
            _link_or_copy(page, tmp / page.name)
        if drift_devices:
            (tmp / "drift").mkdir()
            drift_pages = Path(out_index).parent / "drift"
            for device in drift_devices:
                shutil.copyfile(drift_pages / f"{device}.html", tmp / "drift" / f"{device}.html")
