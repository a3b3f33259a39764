"""The workflow on a batch system: resources on every rule, one submission per unit, and the
cluster-generic profile (profiles/cluster-generic, whose submit.sh stands in for a
scheduler on this machine) end to end on a small fleet, byte for byte as a local run; and
the analyse job, which does in one process what fit, validate and diagnose do in three."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil

import numpy as np
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.io import failure
from gyrocal.io.errors import CorruptFileError
from gyrocal.io.unit_folder import UNIT_FILES, pack_stage, part_exists, part_failure
from gyrocal.run.cli import main
from gyrocal.simulate import GyroUnit, TurntableProtocol, simulate_unit

from .conftest import BAD, GOOD, GOOD_ROWS, REPO, fleet_folder, needs, snakemake

PROFILES = REPO / "profiles"
UNITS = [*GOOD, BAD]  # the small fleet of tests/workflow/conftest.py
UNIT_RULES = {"simulate", "segment", "analyse"}  # analyse writes the report too

# The profile's submit.sh, status.sh and cancel.sh are bash scripts.
needs_plugin = needs(
    {
        "snakemake-executor-plugin-cluster-generic": importlib.util.find_spec(
            "snakemake_executor_plugin_cluster_generic"
        )
        is not None,
        "bash": shutil.which("bash") is not None,
    },
    "a test extra; bash: Debian's",
)


def unit_outputs(root) -> dict:
    """Every file the workflow leaves for the units and the fleet (summary, end-of-line
    verdicts), by relative path; timings in results/benchmark and the logs excepted."""
    files = [p for b, d, s in UNITS for p in (root / "results" / b / d / s).iterdir()]
    files += [root / "reports" / b / d / f"{s}.html" for b, d, s in UNITS]
    files += [root / "demo" / "logs" / b / d / f"{s}.parquet" for b, d, s in GOOD]
    files += [root / "reports" / "index.html", *sorted((root / "results").glob("*.json"))]
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


@pytest.fixture(scope="module")
def runs(small_fleet_local, tmp_path_factory):
    """The small fleet run through the cluster profile, and its local run on two cores."""
    local, cluster = small_fleet_local, fleet_folder(tmp_path_factory.mktemp("cluster") / "cluster")
    # Jobs of seconds here: status asked every second instead of every ten.
    out = snakemake(
        cluster,
        "--profile",
        str(PROFILES / "cluster-generic"),
        "--jobs",
        "2",
        "--seconds-between-status-checks",
        "1",
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return local, cluster


def test_every_rule_that_runs_a_command_declares_memory_and_runtime(tmp_path):
    """Snakemake's own plan of every rule (`all` runs nothing): mem_mb and runtime as the
    rules declare them, every unit rule on one thread (benchmarks/requests.py)."""
    folder = fleet_folder(tmp_path / "plan", GOOD_ROWS)
    out = snakemake(folder, "--dry-run", "--forceall", "all", "paper")
    assert out.returncode == 0, out.stderr[-3000:]
    blocks = re.split(r"^\s*(?:local)?rule (\w+):$", out.stdout + out.stderr, flags=re.M)[1:]
    planned = {}
    for name, body in zip(blocks[::2], blocks[1::2], strict=False):
        resources = re.search(r"resources: (.*)", body).group(1)
        threads = re.search(r"threads: (\d+)", body)
        planned[name] = (resources, int(threads.group(1)) if threads else 1)
    assert set(planned) == UNIT_RULES | {"fleet", "paper", "all"}
    for name, (resources, _) in planned.items():
        if name != "all":
            assert re.search(r"\bmem_mb=\d+", resources) and re.search(r"\bruntime=\d+", resources), name
    assert planned["segment"][1] == 1 and planned["analyse"][1] == 1


@pytest.mark.slow
@needs_plugin
def test_the_cluster_run_gives_the_local_runs_outputs_byte_for_byte(runs):
    local, cluster = runs
    expected, got = unit_outputs(local), unit_outputs(cluster)
    assert got.keys() == expected.keys()
    for path, content in expected.items():
        assert got[path] == content, path
    for batch, device, session in GOOD:
        cal = load_calibration(cluster / "results" / batch / device / session / "calibration.json")
        assert (cal.meta["device"], cal.meta["batch"], cal.meta["session"]) == (device, batch, session)


@pytest.mark.slow
@needs_plugin
def test_each_unit_is_one_submission_running_its_whole_chain(runs):
    """Grouping: one scheduler job per unit (simulate to report) and one for the fleet
    summary, each asking for the resources Snakemake adds up for it."""
    _, cluster = runs
    jobs = {p.stem: json.loads(p.read_text()) for p in (cluster / "logs" / "cluster").glob("*.json")}
    groups = {k: v for k, v in jobs.items() if v["type"] == "group"}
    singles = [v for v in jobs.values() if v["type"] == "single"]
    assert len(jobs) == len(UNITS) + 1
    assert [v["rule"] for v in singles] == ["fleet"]
    assert len(groups) == len(UNITS) and {v["groupid"] for v in groups.values()} == {"unit"}
    devices = []
    for job_id, props in groups.items():
        log = (cluster / "logs" / "cluster" / f"{job_id}.log").read_text()
        (device,) = set(re.findall(r"wildcards: batch=\w+, device=(\w+),", log))
        devices.append(device)
        rules = set(re.findall(r"^\s*(?:local)?rule (\w+):$", log, flags=re.M))
        assert (cluster / "logs" / "cluster" / f"{job_id}.rc").read_text().strip() == "0"
        # One unit's jobs run one after another: the widest sets threads and memory, and
        # the steps' minutes add up. One thread; simulate's 1500 MB and 5 + 2 + 2 minutes,
        # or, for the corrupt log's unit, which has no simulate job, segment's 1200 MB and 2 + 2.
        assert props["threads"] == 1
        if device == BAD[1]:
            assert rules == UNIT_RULES - {"simulate"}
            assert props["resources"]["mem_mb"] == 1200 and props["resources"]["runtime"] == 4
        else:
            assert rules == UNIT_RULES
            assert props["resources"]["mem_mb"] == 1500 and props["resources"]["runtime"] == 9
    assert sorted(devices) == sorted(d for _, d, _ in UNITS)
    assert singles[0]["resources"]["mem_mb"] == 2000 and singles[0]["resources"]["runtime"] == 30


@needs(
    {
        "snakemake-executor-plugin-slurm": importlib.util.find_spec("snakemake_executor_plugin_slurm")
        is not None
    },
    "a test extra",
)
def test_the_slurm_profile_plans_five_units_to_a_job(tmp_path):
    """The SLURM profile parses with its plugin and groups the units (a dry run;
    tests/workflow/test_slurm.py runs it on a SLURM cluster). Two units, five to a job: one group
    job of their 3 jobs each, the fleet summary and `all`."""
    folder = fleet_folder(tmp_path / "slurm", GOOD_ROWS)
    out = snakemake(folder, "--profile", str(PROFILES / "slurm"), "--dry-run")
    assert out.returncode == 0, out.stderr[-3000:]
    text = out.stdout + out.stderr
    assert text.count("Group job unit") == 1
    assert re.search(r"^total\s+8$", text, flags=re.M)


META = ["--device", "A1", "--batch", "B1", "--session", "2026-01-01", "--protocol", "turntable"]
SEGMENT_FILES = ("observations", "history", "segments", "timeline")
# A temperature-only term cannot be fitted point by point: the fit fails on its own.
SETTINGS = {
    "calibrated": {"model": {"terms": ["bias", "scale", "misalignment"]}},
    "fit fails": {"model": {"terms": ["bias", "scale", "misalignment", "bias_temp_poly"]}},
    "segment failed": {"model": {"terms": ["bias", "scale", "misalignment"]}},
}


@pytest.fixture(scope="module")
def segmented(tmp_path_factory):
    """A quick simulated log's segmentation (the segment stage's three files)."""
    base = tmp_path_factory.mktemp("analyse")
    log = base / "A1.parquet"
    simulate_unit(
        log,
        rig=TurntableProtocol.quick(temperatures=(0.0, 20.0, 40.0)),
        unit=GyroUnit.seed000(),
        rng=np.random.default_rng(11),
        device="A1",
        seed=11,
    )
    assert main(["segment", str(log), "--out", str(base / "unit"), *META]) == 0
    return base / "unit"


@pytest.mark.parametrize("case", list(SETTINGS))
def test_analyse_writes_what_fit_validate_and_diagnose_write(segmented, tmp_path, case):
    """The analyse job's files, failure records included, are byte for byte those of the
    three stage commands run one after another."""
    folders = {name: tmp_path / name for name in ("three", "one")}
    for folder in folders.values():
        folder.mkdir()
        if case == "segment failed":
            rec = failure.record(
                "segment",
                CorruptFileError("not a readable Parquet file", source="x"),
                {"device": "A1", "batch": "B1", "session": "2026-01-01"},
            )
            failure.write([folder / UNIT_FILES[k] for k in SEGMENT_FILES], rec)
            pack_stage(folder, "segment")
        else:
            shutil.copyfile(segmented / "segmentation.zip", folder / "segmentation.zip")
    args = [*META, "--settings-json", json.dumps(SETTINGS[case]), "--record-failures"]
    three = folders["three"]
    assert main(["fit", str(three), *args]) == 0
    assert main(["validate", str(three), *args]) == 0
    assert (
        main(
            [
                "diagnose",
                "--unit",
                str(three),
                "-o",
                str(three / "diagnosis.json"),
                "--residuals",
                str(three / "residuals.parquet"),
                *args,
            ]
        )
        == 0
    )
    assert main(["analyse", str(folders["one"]), *args]) == 0

    # a unit session's files: the calibration, two archives and, once it is calibrated, the
    # record of its runs
    names = sorted(p.name for p in three.iterdir())
    assert names == [
        "analysis.zip",
        "calibration.json",
        *(["runs.json"] if case == "calibrated" else []),
        "segmentation.zip",
    ]
    assert sorted(p.name for p in folders["one"].iterdir()) == names
    for name in names:
        assert (folders["one"] / name).read_bytes() == (three / name).read_bytes(), name
    # every part of a unit folder but free_points (a continuous model's, not this grid's)
    parts = [k for k in UNIT_FILES if part_exists(three, k)]
    assert sorted(parts) == sorted(k for k in UNIT_FILES if k != "free_points")
    stage = {UNIT_FILES[k]: (part_failure(folders["one"], k) or {}).get("stage") for k in parts}
    analysed = [UNIT_FILES[k] for k in parts if k not in SEGMENT_FILES]
    if case == "calibrated":
        assert not any(stage.values())
        assert load_calibration(folders["one"] / "calibration.json").meta["device"] == "A1"
    elif case == "fit fails":
        # recorded by the fit, passed on to the validation; the diagnosis ran and recorded
        # its own failure on the same model
        assert {name: stage[name] for name in analysed} == {
            name: "diagnose" if name in ("diagnosis.json", "residuals.parquet") else "fit"
            for name in analysed
        }
        assert "bias_temp_poly" in part_failure(folders["one"], "calibration")["error"]
    else:
        assert {stage[name] for name in analysed} == {"segment"}


def test_analyse_without_recording_failures_stops_at_the_failed_step(segmented, tmp_path, capsys):
    """Like `gyrocal fit`: one line, exit 2, and nothing written after the failure."""
    segment_files = ["segmentation.zip"]
    for name in segment_files:
        shutil.copyfile(segmented / name, tmp_path / name)
    code = main(["analyse", str(tmp_path), *META, "--settings-json", json.dumps(SETTINGS["fit fails"])])
    assert code == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == segment_files
