"""The workflow run again on the small fleet of tests/conftest.py (fleet_run, copied): from
nothing, the same bytes; after the diagnosis' fix for the whole fleet or for one unit, only
the jobs it concerns and an error that falls; and the workflow catalogue's smallest case."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.io.unit_folder import read_part_json

from .conftest import REPO, job_counts, snakemake

GOOD = [("B1", "A1", "2026-01-01"), ("B1", "A1", "2026-03-01"), ("B2", "A2", "2026-01-02")]


@pytest.mark.slow
def test_the_report_names_the_missing_effect_and_adding_it_lowers_the_error(fleet_run, tmp_path):
    """The loop of the README: read the diagnosis, add the term, re-run, see the error fall.
    The unit with the effect is run again (which jobs the model change re-runs across the
    fleet is planned in test_fleet_workflow.py)."""
    folder = ("results", "B2", "A2", "2026-01-02")
    diagnosis = read_part_json(fleet_run.joinpath(*folder), "diagnosis")
    assert diagnosis["best"]["term"] == "scale_quadratic"
    page = (fleet_run / "reports" / "B2" / "A2" / "2026-01-02.html").read_text()
    line = "terms: [bias, scale, misalignment, scale_quadratic]"
    assert diagnosis["best"]["config_line"] == line and f'<pre id="config-line">{line}</pre>' in page
    for batch, device, session in GOOD[:2]:  # the units without the effect: nothing missing
        other = read_part_json(fleet_run / "results" / batch / device / session, "diagnosis")
        assert other["best"] is None and other["explains_the_data"], other["verdict"]

    again = tmp_path / "again"
    shutil.copytree(fleet_run, again, symlinks=True)
    config = (
        (again / "config.yaml")
        .read_text()
        .replace("model: {terms: [bias, scale, misalignment]}", "model: {" + line + "}")
    )
    (again / "config.yaml").write_text(config)
    out = snakemake(again, *(f"{'/'.join(folder)}/{name}" for name in ("calibration.json", "analysis.zip")))
    assert out.returncode == 0, out.stderr[-2000:]
    assert job_counts(out) == {"analyse": 1, "total": 1}  # its segmentation and log kept
    after = read_part_json(again.joinpath(*folder), "diagnosis")
    # Three temperature points leave the interpolation error of the cubic bias at 20 °C,
    # the same for every unit; what the term removes is the rest.
    assert after["validation_rms"] < 0.2 * diagnosis["validation_rms"]
    assert after["explains_the_data"] and after["best"] is None


@pytest.mark.slow
def test_rerun_from_scratch_is_byte_identical(fleet_run, tmp_path):
    """Every unit's simulated log, calibration and diagnosis, and one unit's report (its
    figures included), made again from nothing: the same bytes."""
    before = {
        p.relative_to(fleet_run): p.read_bytes()
        for p in [
            *fleet_run.glob("results/*/*/*/calibration.json"),
            *fleet_run.glob("demo/logs/*/*/*.parquet"),
            *fleet_run.glob("results/*/*/*/analysis.zip"),  # the validation, diagnosis and tables
            *fleet_run.glob("results/*/*/*/segmentation.zip"),  # the observations and tables
            fleet_run / "reports" / "B1" / "A1" / "2026-01-01.html",
        ]
    }
    assert len(before) == 7 + 5 + 7 + 7 + 1  # the job logs inside the archives too
    again = tmp_path / "again"
    again.mkdir()
    for name in ("devices.tsv", "config.yaml"):
        shutil.copy(fleet_run / name, again / name)
    shutil.copytree(fleet_run / "logs", again / "logs")
    # The logs come with the jobs that make these.
    targets = sorted({str(path) for path in before if path.suffix != ".parquet"})
    out = snakemake(again, *targets)
    assert out.returncode == 0, out.stderr[-2000:]
    for path, content in before.items():
        assert (again / path).read_bytes() == content, path


@pytest.mark.slow
def test_the_catalogue_test_case_runs_as_the_catalogue_runs_it(tmp_path):
    """`.test/` in the Snakemake workflow catalogue's layout: `snakemake --directory .test`
    finds its config/config.yaml through the Snakefile, simulates its one unit's log and
    calibrates it. Run on a copy of its config, so nothing is written into the repository."""
    shutil.copytree(REPO / ".test" / "config", tmp_path / "config")
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "snakemake",
            "--snakefile",
            str(REPO / "Snakefile"),
            "--directory",
            str(tmp_path),
            "--cores",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    folder = tmp_path / "results" / "B1" / "T1" / "2026-01-01"
    cal = load_calibration(folder / "calibration.json")
    assert (cal.meta["device"], cal.meta["batch"], cal.meta["session"]) == ("T1", "B1", "2026-01-01")
    assert (tmp_path / "demo" / "logs" / "B1" / "T1" / "2026-01-01.parquet").exists()
    assert read_part_json(folder, "diagnosis")["explains_the_data"]
    assert (tmp_path / "reports" / "B1" / "T1" / "2026-01-01.html").exists()
    assert "1 unit session: 1 calibrated" in (tmp_path / "reports" / "index.html").read_text()


@pytest.mark.slow
def test_a_fix_for_one_unit_reaches_that_unit_alone_and_its_report_shows_the_fall(fleet_run, tmp_path):
    """The README's loop with a unit's own model: the diagnosis' lines for A2 appended to the
    config; the workflow analyses A2 alone again, every other unit's calibration stays byte
    for byte, and A2's report, the fleet page and its table show the error before and after."""
    import pyarrow.parquet as pq

    a2 = ("results", "B2", "A2", "2026-01-02")
    before = read_part_json(fleet_run.joinpath(*a2), "diagnosis")
    lines = before["best"]["unit_config_line"]
    assert lines == "models:\n  A2: {add: [scale_quadratic]}"
    again = tmp_path / "again"
    shutil.copytree(fleet_run, again, symlinks=True)
    (again / "config.yaml").write_text((again / "config.yaml").read_text() + lines + "\n")
    assert job_counts(snakemake(again, "--dry-run")) == {"analyse": 1, "fleet": 1, "all": 1, "total": 3}
    out = snakemake(again)
    assert out.returncode == 0, out.stderr[-2000:]
    for path in (fleet_run / "results").glob("*/*/*/calibration.json"):
        if path.parent.name != a2[-1] or path.parent.parent.name != "A2":
            assert (again / path.relative_to(fleet_run)).read_bytes() == path.read_bytes(), path

    cal = json.loads(again.joinpath(*a2, "calibration.json").read_text())
    assert {"name": "scale_quadratic"} in cal["model"]["terms"] and cal["model_entry"] == "A2"
    (added,) = cal["added_terms"]
    assert added["kept"] and added["with"]["excess"] < added["without"]["excess"]
    after = read_part_json(again.joinpath(*a2), "validation")["summary"]
    runs = json.loads(again.joinpath(*a2, "runs.json").read_text())["runs"]
    assert [r["model"]["terms"] for r in runs] == [
        ["bias", "scale", "misalignment"],
        ["bias", "scale", "misalignment", "scale_quadratic"],
    ]
    assert runs[0]["fix"]["term"] == "scale_quadratic" and runs[0]["excess"] == before["excess"]
    page = (again / "reports" / "B2" / "A2" / "2026-01-02.html").read_text()
    from gyrocal.report.pages import fmt

    fell = f"from <b>{fmt(before['excess'], 3)}</b> to <b>{fmt(after['excess'], 3)}</b> times the noise floor"
    assert 'id="since-last"' in page and fell in page
    assert page.count('class="last-run"') == 2  # the last run's model and the fix it named
    rows = {
        r["device"]: r
        for r in pq.read_table(again / "results" / "fleet.parquet").to_pylist()
        if r["status"] == "ok" and r["session"] in ("2026-01-01", "2026-01-02")
    }
    assert rows["A2"]["model_entry"] == "A2" and rows["A2"]["previous_excess"] == before["excess"]
    assert rows["A1"]["model_entry"] is None and rows["A1"]["previous_excess"] is None
    index = (again / "reports" / "index.html").read_text()
    assert f"{fmt(before['excess'], 3)} → {fmt(after['excess'], 3)}" in index
