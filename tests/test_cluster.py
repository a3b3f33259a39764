"""The workflow on a batch system: resources on every rule, one submission per unit, and the
cluster-generic profile (workflow/profiles/cluster-generic, whose submit.sh stands in for a
scheduler on this machine) end to end on a small fleet, byte for byte as a local run."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil

import pytest

from gyrocal.calibration import load_calibration

from .conftest import FLEET_CONFIG, REPO, snakemake

PROFILES = REPO / "workflow" / "profiles"
UNITS = [("B1", "A1", "2026-01-01"), ("B2", "A2", "2026-01-02")]
MANIFEST = "device\tbatch\tsession\tprotocol\tpath\n" + "".join(
    f"{d}\t{b}\t{s}\tturntable\tdemo/logs/{b}/{d}/{s}.parquet\n" for b, d, s in UNITS)
CONFIG = FLEET_CONFIG  # the workflow test's fleet settings
UNIT_RULES = {"simulate", "segment", "fit", "validate", "diagnose", "report"}

needs_plugin = pytest.mark.skipif(
    importlib.util.find_spec("snakemake_executor_plugin_cluster_generic") is None,
    reason="snakemake-executor-plugin-cluster-generic is not installed "
           "(pip install snakemake-executor-plugin-cluster-generic)")


def fleet_folder(path):
    path.mkdir()
    (path / "devices.tsv").write_text(MANIFEST)
    (path / "config.yaml").write_text(CONFIG)
    return path


def unit_outputs(root) -> dict:
    """Every file the workflow leaves for the units and the fleet (summary, end-of-line
    verdicts), by relative path; timings in results/benchmark and the logs excepted."""
    files = [p for b, d, s in UNITS for p in (root / "results" / b / d / s).iterdir()]
    files += [root / "reports" / b / d / f"{s}.html" for b, d, s in UNITS]
    files += [root / "demo" / "logs" / b / d / f"{s}.parquet" for b, d, s in UNITS]
    files += [root / "reports" / "index.html", *sorted((root / "results").glob("*.json"))]
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same two-unit fleet run locally on two cores and through the cluster profile."""
    if shutil.which("bash") is None:
        pytest.skip("the stand-in scheduler of the cluster profile needs bash")
    base = tmp_path_factory.mktemp("cluster")
    local, cluster = fleet_folder(base / "local"), fleet_folder(base / "cluster")
    out = snakemake(local)
    assert out.returncode == 0, out.stderr[-3000:]
    # Jobs of seconds here: status asked every second instead of every ten.
    out = snakemake(cluster, "--profile", str(PROFILES / "cluster-generic"), "--jobs", "2",
                    "--seconds-between-status-checks", "1")
    assert out.returncode == 0, out.stderr[-3000:]
    return local, cluster


def test_every_rule_that_runs_a_command_declares_memory_and_runtime(tmp_path):
    """Snakemake's own plan of every rule (`all` runs nothing): mem_mb and runtime as the
    rules declare them, segment on two threads."""
    folder = fleet_folder(tmp_path / "plan")
    out = snakemake(folder, "--dry-run", "--forceall", "all", "paper")
    assert out.returncode == 0, out.stderr[-3000:]
    blocks = re.split(r"^\s*(?:local)?rule (\w+):$", out.stdout + out.stderr, flags=re.M)[1:]
    planned = {}
    for name, body in zip(blocks[::2], blocks[1::2]):
        resources = re.search(r"resources: (.*)", body).group(1)
        threads = re.search(r"threads: (\d+)", body)
        planned[name] = (resources, int(threads.group(1)) if threads else 1)
    assert set(planned) == UNIT_RULES | {"fleet", "paper", "all"}
    for name, (resources, _) in planned.items():
        if name != "all":
            assert re.search(r"\bmem_mb=\d+", resources) and re.search(r"\bruntime=\d+", resources), name
    assert planned["segment"][1] == 2 and planned["fit"][1] == 1


@needs_plugin
def test_the_cluster_run_gives_the_local_runs_outputs_byte_for_byte(runs):
    local, cluster = runs
    expected, got = unit_outputs(local), unit_outputs(cluster)
    assert got.keys() == expected.keys()
    for path, content in expected.items():
        assert got[path] == content, path
    for batch, device, session in UNITS:
        cal = load_calibration(cluster / "results" / batch / device / session / "calibration.json")
        assert (cal.meta["device"], cal.meta["batch"], cal.meta["session"]) == (device, batch, session)


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
    for job_id, props in groups.items():
        log = (cluster / "logs" / "cluster" / f"{job_id}.log").read_text()
        assert set(re.findall(r"^\s*(?:local)?rule (\w+):$", log, flags=re.M)) == UNIT_RULES
        assert (cluster / "logs" / "cluster" / f"{job_id}.rc").read_text().strip() == "0"
        # One unit's jobs run one after another but for fit and diagnose side by side:
        # the widest layer sets threads and memory (segment: 2 threads, 2000 MB), and the
        # five layers of 5 minutes add up to the runtime.
        assert props["threads"] == 2
        assert props["resources"]["mem_mb"] == 2000 and props["resources"]["runtime"] == 25
    assert singles[0]["resources"]["mem_mb"] == 2000 and singles[0]["resources"]["runtime"] == 30


@pytest.mark.skipif(importlib.util.find_spec("snakemake_executor_plugin_slurm") is None,
                    reason="snakemake-executor-plugin-slurm is not installed")
def test_the_slurm_profile_plans_five_units_to_a_job(tmp_path):
    """The SLURM profile parses with its plugin and groups the units (a dry run: no
    SLURM here). Two units, five to a job: one group job."""
    folder = fleet_folder(tmp_path / "slurm")
    out = snakemake(folder, "--profile", str(PROFILES / "slurm"), "--dry-run")
    assert out.returncode == 0, out.stderr[-3000:]
    text = out.stdout + out.stderr
    assert text.count("Group job unit") == 1
    assert re.search(r"^total\s+14$", text, flags=re.M)
