"""The Snakemake workflow end to end on the small fleet of tests/conftest.py (fleet_run): the
outputs contract section 6 names, holding the library's numbers; what a second run plans;
the Snakefile's lint and format."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.io.errors import CalibrationFileError
from gyrocal.io.unit_folder import read_part_json, read_part_table
from gyrocal.pipeline.chain import run
from gyrocal.pipeline.config import Settings
from gyrocal.run.cli import main

from .conftest import HEADER, REPO, ROW, fleet_folder, job_counts, snakemake

GOOD = [("B1", "A1", "2026-01-01"), ("B1", "A1", "2026-03-01"), ("B2", "A2", "2026-01-02")]
FAILED = [
    ("B2", "BAD", "2026-01-02", "not a readable Parquet file"),
    ("B2", "GONE", "2026-01-03", "no such file"),
]


@pytest.mark.slow
def test_every_unit_has_its_outputs_where_the_contract_says(fleet_run):
    for batch, device, session in GOOD:
        folder = fleet_run / "results" / batch / device / session
        cal = load_calibration(folder / "calibration.json")
        assert (cal.meta["device"], cal.meta["batch"], cal.meta["session"]) == (device, batch, session)
        assert (fleet_run / "reports" / batch / device / f"{session}.html").exists()
    assert (fleet_run / "reports" / "index.html").exists()


@pytest.mark.slow
def test_the_tables_hold_the_numbers_the_library_computes(fleet_run):
    for batch, device, session in GOOD:
        folder = fleet_run / "results" / batch / device / session
        log = fleet_run / "demo" / "logs" / batch / device / f"{session}.parquet"
        direct = run(log, Settings())
        summary = read_part_json(folder, "validation")["summary"]
        assert summary.keys() == direct.validation.summary.keys()
        for key, value in direct.validation.summary.items():
            assert summary[key] == (pytest.approx(value, rel=1e-12) if isinstance(value, float) else value)
        grid = load_calibration(folder / "calibration.json").grid
        np.testing.assert_array_equal(grid.values, direct.calibration.grid.values)
        np.testing.assert_array_equal(grid.stderr, direct.calibration.grid.stderr)
        import pandas as pd

        table = read_part_table(folder, "table_hold_means")[0]
        pd.testing.assert_frame_equal(table, direct.validation.table_holds, check_exact=False, rtol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize(
    "batch, device, session, protocol",
    [("B3", "S1", "2026-01-04", "servo"), ("B3", "W1", "2026-01-05", "sweep")],
)
def test_servo_and_sweep_units_run_through_the_workflow_as_the_library_runs_them(
    fleet_run, batch, device, session, protocol
):
    folder = fleet_run / "results" / batch / device / session
    log = fleet_run / "demo" / "logs" / batch / device / f"{session}.parquet"
    direct = run(log, Settings(), protocol=protocol)
    cal = load_calibration(folder / "calibration.json")
    assert cal.meta["protocol"] == protocol
    np.testing.assert_array_equal(cal.grid.values, direct.calibration.grid.values)
    summary = read_part_json(folder, "validation")["summary"]
    assert summary["validation_rms"] == pytest.approx(direct.validation.summary["validation_rms"], rel=1e-12)
    diagnosis = read_part_json(folder, "diagnosis")
    html = (fleet_run / "reports" / batch / device / f"{session}.html").read_text()
    assert diagnosis["verdict"].split(":")[0] in html
    if protocol == "servo":
        assert "Six-observation calibration (seed 001)" in html and "Algorithm 1" in html
        assert diagnosis["explains_the_data"]  # the 12 parameters absorb the mounting tilt
    else:
        assert "Drift models and bias stability (seed 003)" in html and "BS3" in html
        assert diagnosis["best"]["term"] == "bias_temp_poly"  # ΔT² (Eq 16) is missing
        assert diagnosis["ladder"][-1]["excess"] < 1.2


@pytest.mark.slow
def test_a_corrupt_or_missing_log_fails_its_unit_alone(fleet_run):
    index = (fleet_run / "reports" / "index.html").read_text()
    assert "7 unit sessions: 5 calibrated" in index and "2 failed" in index
    for batch, device, session, message in FAILED:
        folder = fleet_run / "results" / batch / device / session
        with pytest.raises(CalibrationFileError, match="holds no calibration: the segment stage failed"):
            load_calibration(folder / "calibration.json")
        assert message in index
        page = (fleet_run / "reports" / batch / device / f"{session}.html").read_text()
        assert "the <b>segment</b> stage failed" in page and message in page


@pytest.mark.slow
def test_nothing_to_do_the_second_time_and_a_model_change_reruns_only_its_jobs(fleet_run):
    out = snakemake(fleet_run, "--dry-run")
    assert "Nothing to be done" in out.stdout + out.stderr
    out = snakemake(
        fleet_run,
        "--dry-run",
        "--config",
        'model={"terms": ["bias", "scale", "misalignment"], "interpolation": "spline"}',
    )
    counts = job_counts(out)
    assert counts == {"analyse": 5, "fleet": 1, "all": 1, "total": 7}
    out = snakemake(fleet_run, "--dry-run", "--config", 'diagnosis={"ladder": ["scale_cubic"]}')
    assert job_counts(out) == {"analyse": 5, "fleet": 1, "all": 1, "total": 7}


@pytest.mark.slow
@pytest.mark.parametrize("table", ["timeline.parquet", "validation_holds.parquet"])
def test_a_report_over_a_missing_table_names_it(fleet_run, tmp_path, table):
    """The tables only the report reads are parts of the jobs' archives, not declared:
    a report rendered after one was deleted says which, and how to rebuild it."""
    unit = tmp_path / "unit"
    shutil.copytree(fleet_run / "results" / "B1" / "A1" / "2026-01-01", unit)
    archive = next(
        unit / name
        for name in ("segmentation.zip", "analysis.zip")
        if table in zipfile.ZipFile(unit / name).namelist()
    )
    with zipfile.ZipFile(archive) as old:
        kept = {n: old.read(n) for n in old.namelist() if n != table}
    with zipfile.ZipFile(archive, "w") as new:
        for name, data in kept.items():
            new.writestr(name, data)
    html = tmp_path / "report.html"
    assert (
        main(
            [
                "report",
                str(unit),
                "-o",
                str(html),
                "--device",
                "A1",
                "--batch",
                "B1",
                "--session",
                "2026-01-01",
                "--protocol",
                "turntable",
                "--record-failures",
            ]
        )
        == 0
    )
    page = html.read_text()
    assert "the <b>report</b> stage failed" in page
    assert f"{table} is missing from the unit&#39;s results" in page


@pytest.mark.slow
def test_snakemake_report_bundles_the_fleet_and_every_unit(fleet_run):
    out = snakemake(fleet_run, "--report", "report.zip")
    assert out.returncode == 0, out.stderr[-2000:]
    names = zipfile.ZipFile(fleet_run / "report.zip").namelist()
    assert "report/report.html" in names
    pages = [n for n in names if n.startswith("report/data/raw/") and n.endswith(".html")]
    assert sum(n.endswith("/index.html") for n in pages) == 2  # the fleet, the bundle's index
    for batch, device, session in [*GOOD, *[f[:3] for f in FAILED]]:
        assert sum(n.endswith(f"/{batch}/{device}/{session}.html") for n in pages) == 1


@pytest.mark.slow
def test_invalid_settings_stop_before_any_job_naming_the_key(fleet_run, tmp_path):
    (tmp_path / "config.yaml").write_text(
        (fleet_run / "config.yaml").read_text() + "segmentation: {trim_seconds: 1}\n"
    )
    shutil.copy(fleet_run / "devices.tsv", tmp_path)
    out = snakemake(tmp_path, "--dry-run")
    assert out.returncode != 0
    assert "trim_seconds" in out.stdout + out.stderr


@pytest.mark.slow
def test_a_bad_manifest_stops_with_the_line_named(fleet_run, tmp_path):
    (tmp_path / "config.yaml").write_text((fleet_run / "config.yaml").read_text())
    (tmp_path / "devices.tsv").write_text(
        (fleet_run / "devices.tsv").read_text() + "bad id!\tB1\t2026-01-01\tturntable\tx.parquet\n"
    )
    out = snakemake(tmp_path, "--dry-run")
    assert out.returncode == 2 and 'File "' not in out.stderr  # one line, not Snakemake's frames
    assert "gyrocal: error: " in out.stderr and "line 9: device 'bad id!' does not match" in out.stderr


# The unit jobs' logs are written by the guard (--log) and packed into the job's archive:
# a `log:` directive would leave an empty file in each unit folder (workflow/rules/segment.smk).
ACCEPTED_LINTS = {("segment", "No log directive defined"), ("analyse", "No log directive defined")}


def test_lint_clean_and_formatted():
    # Snakemake 9 exits 1 on lints and on a workflow it cannot parse, 0 when clean.
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "snakemake",
            "--lint",
            "--snakefile",
            str(REPO / "Snakefile"),
            "--directory",
            str(REPO),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    text = out.stdout + out.stderr
    lints = {
        (rule, title)
        for rule, body in re.findall(r"^Lints for rule (\w+) .*?:\n((?:    .*\n|\n)*)", text, flags=re.M)
        for title in re.findall(r"^    \* (.+):$", body, flags=re.M)
    }
    assert out.returncode == 0 or (lints and lints <= ACCEPTED_LINTS), text[-3000:]
    assert "Lints for" not in text or lints, text[-3000:]  # every lint parsed
    fmt = subprocess.run(
        [sys.executable, "-m", "snakefmt", "--check", "Snakefile", "workflow"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert fmt.returncode == 0, fmt.stderr[-2000:]


@pytest.mark.slow
def test_the_ladder_in_the_report_holds_the_librarys_numbers(fleet_run):
    import re

    from gyrocal.diagnosis import diagnose
    from gyrocal.report.pages import fmt

    folder = fleet_run / "results" / "B2" / "A2" / "2026-01-02"
    obs = read_part_table(folder, "observations")[0]
    settings = Settings.from_dict(
        {"diagnosis": {"ladder": [{"name": "+ nonlinearity", "add": ["scale_quadratic"]}]}}
    )
    ladder = diagnose(settings, obs).ladder
    page = (fleet_run / "reports" / "B2" / "A2" / "2026-01-02.html").read_text()
    table = page[page.index('<table id="ladder-table">') :]
    table = table[: table.index("</table>")]
    rows = [re.findall(r"<td[^>]*>(.*?)</td>", row, re.S) for row in re.split(r"<tr[^>]*>", table)[2:]]
    # the configured model, the ladder's step, and the fix the diagnosis names last
    assert len(rows) == len(ladder) == 3 and ladder[-1]["fix"]
    for cells, step in zip(rows, ladder, strict=False):
        assert cells[1].startswith(step["name"])
        assert cells[3:7] == [
            fmt(step["validation_rms"]),
            fmt(step["excess"], 3),
            fmt(step["expected_rms"]),
            fmt(step["chi2_red"], 3),
        ]
    added = rows[1][7]
    for p in ladder[1]["parameters"]:
        assert f"{p['coefficient']} = {fmt(p['value'], 3)} ± {fmt(p['stderr'], 2)}" in added


@pytest.mark.slow
def test_the_paper_rule_is_planned_by_name_and_not_by_default(fleet_run):
    out = snakemake(fleet_run, "--dry-run", "paper")
    assert out.returncode == 0, out.stderr[-2000:]
    assert job_counts(out) == {"paper": 1, "total": 1}


@pytest.mark.slow
def test_end_of_line_verdicts_yield_and_drift_pages(fleet_run):
    eol = json.loads((fleet_run / "results" / "eol.json").read_text())
    units = {(u["device"], u["session"]): u for u in eol["units"]}
    # A2 carries a scale nonlinearity the model lacks: 16× the floor fails the 5× limit
    # (three set points: interpolating the clean units' bias leaves them about 2.5×)
    a2 = units[("A2", "2026-01-02")]
    assert not a2["passed"] and any("excess over the noise floor" in r for r in a2["reasons"])
    assert units[("A1", "2026-01-01")]["passed"] and units[("A1", "2026-03-01")]["passed"]
    assert not units[("BAD", "2026-01-02")]["calibrated"]
    yields = {y["batch"]: y for y in eol["yield"]}
    assert yields["B1"]["yield_pct"] == 100.0 and yields["B1"]["units"] == 2
    assert yields["B2"]["passed"] == 0 and yields["B2"]["no_calibration"] == 2
    assert ("S1", "2026-01-04") not in units  # no servo limits: not judged
    # A1 twice, the same simulated unit: no drift, and the old calibration still holds
    (a1,) = eol["drift"]
    assert a1["device"] == "A1" and a1["flagged"] == []
    assert a1["revalidation"]["holds"], a1["revalidation"]["verdict"]
    page = (fleet_run / "reports" / "drift" / "A1.html").read_text()
    assert "No parameter changed beyond its tolerance" in page
    index = (fleet_run / "reports" / "index.html").read_text()
    assert 'href="drift/A1.html"' in index and "End of line: yield per batch" in index


@pytest.mark.slow
def test_a_device_with_two_sessions_is_diagnosed_against_the_other(fleet_run):
    """The workflow hands each session of A1 the other's observations, and the diagnosis
    it writes is the library's with both; A2, with one session, is diagnosed alone."""
    from gyrocal.diagnosis import diagnose
    from gyrocal.terms.signals import read_observations

    def folder(key):
        return fleet_run / "results" / key[0] / key[1] / key[2]

    for this, other in ((GOOD[0], GOOD[1]), (GOOD[1], GOOD[0])):
        written = read_part_json(folder(this), "diagnosis")
        direct = diagnose(Settings(), read_observations(folder(this))[0], read_observations(folder(other))[0])
        assert written["next_session"] is not None
        for key in ("validation_rms", "excess", "repeat_p_value"):
            assert written["next_session"][key] == pytest.approx(direct.next_session[key], rel=1e-12)
        assert written["verdict"] == direct.verdict
    alone = read_part_json(folder(GOOD[2]), "diagnosis")
    assert alone["next_session"] is None


@pytest.mark.slow
def test_the_fleet_is_one_table_that_agrees_with_the_unit_files(fleet_run):
    import pyarrow.parquet as pq

    table = pq.read_table(fleet_run / "results" / "fleet.parquet")
    assert table.schema.metadata[b"gyrocal.format"] == b"gyrocal.fleet/1"
    rows = {(r["device"], r["session"]): r for r in table.to_pylist()}
    assert len(rows) == table.num_rows == 7  # every manifest row, failed ones too
    bad = rows[("BAD", "2026-01-02")]
    assert bad["status"] == "failed" and bad["failed_stage"] == "segment" and bad["error"]
    assert bad["scale.x"] is None and bad["input_hash"] is None
    a1 = rows[("A1", "2026-01-01")]
    cal = json.loads((fleet_run / "results" / "B1" / "A1" / "2026-01-01" / "calibration.json").read_text())
    assert a1["status"] == "ok" and a1["eol_passed"] is True and a1["warnings"] == []
    assert a1["input_hash"] == cal["provenance"]["input"][a1["input_hash_algorithm"]]
    validation = read_part_json(fleet_run / "results" / "B1" / "A1" / "2026-01-01", "validation")
    assert a1["excess"] == validation["summary"]["excess"]
    # parameters at the reference temperature in display units, as the unit's file gives them
    from gyrocal.calibration.file import load_calibration
    from gyrocal.calibration.parameters import parameters_at

    at_ref = parameters_at(
        load_calibration(fleet_run / "results" / "B1" / "A1" / "2026-01-01" / "calibration.json")
    ).set_index("parameter")
    for name in ("scale.x", "misalignment.x.y", "bias.z"):
        assert a1[name] == at_ref.loc[name, "value"] and a1[f"{name}_stderr"] == at_ref.loc[name, "stderr"]
    assert a1["scale.x_stderr"] > 0 and rows[("A2", "2026-01-02")]["eol_passed"] is False
    assert rows[("S1", "2026-01-04")]["eol_passed"] is None  # no servo limits: not judged
    # a drift audit is one query
    frame = table.to_pandas()
    drift = frame[frame.status == "ok"].groupby("device")["bias.x"].agg(["count", "max", "min"])
    assert drift.loc["A1", "count"] == 2


@pytest.mark.slow
def test_the_fleet_job_fills_the_registry_and_its_summary_says_where(fleet_run, tmp_path):
    """Every unit session's calibration or failure record once, with its headline figures;
    lookups from it choose as the folder scan does."""
    from gyrocal.calibration import registry
    from gyrocal.calibration.lookup import find_calibration

    results = fleet_run / "results"
    where = results / registry.DEFAULT_NAME
    backend = registry.connect(str(where), create=False)
    try:
        rows = backend.execute(
            "SELECT device, session, status, validation_rms, excess, verdict FROM unit_sessions "
            "WHERE path LIKE '%/calibration.json' ORDER BY device, session"
        ).fetchall()
    finally:
        backend.close()
    units = sorted((d, s) for _, d, s in GOOD) + [("S1", "2026-01-04"), ("W1", "2026-01-05")]
    assert sorted((d, s) for d, s, status, *_ in rows if status == "calibrated") == units
    assert sorted((d, s) for d, s, status, *_ in rows if status == "failed") == sorted(
        (d, s) for _, d, s, _ in FAILED
    )
    for device, session, status, rms, excess, verdict in rows:
        if status == "calibrated":
            assert rms > 0 and excess > 0 and verdict, (device, session)
    assert registry.check(results) == []
    assert (
        "Registry: <code>results/registry.sqlite</code>" in (fleet_run / "reports" / "index.html").read_text()
    )
    scan_only = shutil.copytree(
        results, tmp_path / "results", ignore=shutil.ignore_patterns("registry.sqlite*")
    )
    for device in ("A1", "A2", "S1", "W1"):
        for date in (None, "2026-02-01"):
            indexed, scanned = (
                find_calibration(results, device, date),
                find_calibration(scan_only, device, date),
            )
            assert (indexed.source, scanned.source) == ("registry", "scan")
            assert (indexed.session, indexed.days_away, indexed.candidates, indexed.skipped) == (
                scanned.session,
                scanned.days_away,
                scanned.candidates,
                scanned.skipped,
            )
            assert indexed.path.relative_to(results) == scanned.path.relative_to(scan_only)


@pytest.mark.slow
def test_a_devices_drift_page_takes_its_earlier_sessions_from_the_registry(fleet_run, tmp_path):
    """A1's later session alone in a run: its drift page still sets it beside the earlier
    one, which the registry holds from an earlier run."""
    from gyrocal.calibration import registry

    results = shutil.copytree(
        fleet_run / "results", tmp_path / "results", ignore=shutil.ignore_patterns("registry.sqlite*")
    )
    registry.rebuild(results)  # the earlier runs, indexed
    manifest = tmp_path / "later.tsv"
    logs = fleet_run / "demo" / "logs"
    manifest.write_text(
        "device\tbatch\tsession\tprotocol\tpath\n"
        f"A1\tB1\t2026-03-01\tturntable\t{logs}/B1/A1/2026-03-01.parquet\n"
    )
    reports = tmp_path / "reports"
    args = ["fleet", "--manifest", str(manifest), "--results", str(results), "--reports", str(reports)]
    assert main([*args, "-o", str(reports / "index.html"), "--settings-json", "{}"]) == 0
    page = (reports / "drift" / "A1.html").read_text()
    assert "2026-01-01" in page and "2026-03-01" in page
    assert 'href="drift/A1.html"' in (reports / "index.html").read_text()


@pytest.mark.slow
def test_a_drift_page_from_the_registry_is_planned_and_made_again_when_the_history_changes(tmp_path):
    """A workflow folder runs A1's first session, then a manifest of its later one alone: the
    plan reads the registry, declares A1's drift page (a page the fleet job wrote undeclared
    would not be Snakemake's to track or remove) and the end-of-line file records the earlier
    session it rests on; a second run has nothing to do, and once the earlier calibration is
    re-registered with other bytes, the fleet job runs again."""
    first, later = ("B1", "A1", "2026-01-01"), ("B1", "A1", "2026-03-01")
    wd = fleet_folder(tmp_path / "wd", ROW.format(*first))
    out = snakemake(wd)
    assert out.returncode == 0, out.stderr[-3000:]
    assert not (wd / "reports" / "drift").exists()

    (wd / "devices.tsv").write_text(HEADER + ROW.format(*later))
    out = snakemake(wd, "--dry-run")
    assert out.returncode == 0 and job_counts(out)["fleet"] == 1, out.stderr[-3000:]
    assert "reports/drift/A1.html" in out.stdout + out.stderr
    out = snakemake(wd)
    assert out.returncode == 0, out.stderr[-3000:]
    page = (wd / "reports" / "drift" / "A1.html").read_text()
    assert 'id="history"' in page and "B1/A1/2026-01-01/calibration.json" in page
    (a1,) = json.loads((wd / "results" / "eol.json").read_text())["drift"]
    assert a1["sessions"] == ["2026-01-01", "2026-03-01"]
    assert [e["path"] for e in a1["earlier"]] == ["B1/A1/2026-01-01/calibration.json"]
    again = snakemake(wd, "--dry-run")
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr

    earlier = wd / "results" / "B1" / "A1" / "2026-01-01" / "calibration.json"
    earlier.write_text(json.dumps(json.loads(earlier.read_text()), indent=1))  # the same, other bytes
    assert main(["registry", "rebuild", str(wd / "results")]) == 0
    out = snakemake(wd, "--dry-run")
    assert out.returncode == 0 and job_counts(out) == {"fleet": 1, "all": 1, "total": 2}, out.stdout[-3000:]


def test_a_plan_that_cannot_reach_its_registry_warns_in_one_line_and_goes_on(tmp_path):
    """The plan reads the registry (the drift pages' history): a PostgreSQL server it cannot
    reach is one line naming it, its password not shown, and the plan goes on from the
    history it recorded last (none yet), so the units still run."""
    wd = fleet_folder(tmp_path / "wd", ROW.format("B1", "A1", "2026-01-01"))
    with open(wd / "config.yaml", "a") as config:
        config.write("registry: postgresql://line3:secret@127.0.0.1:1/calibrations\n")
    out = snakemake(wd, "--dry-run")
    assert out.returncode == 0 and 'File "' not in out.stderr and "secret" not in out.stdout + out.stderr
    (said,) = [line for line in out.stderr.splitlines() if "gyrocal:" in line]
    assert said.startswith(
        "gyrocal: warning: postgresql://line3:***@127.0.0.1:1/calibrations: cannot connect"
    )
    assert said.endswith("the drift pages are planned from results/drift_history.jsonl as it was")
    assert job_counts(out)["analyse"] == 1 and job_counts(out)["fleet"] == 1
