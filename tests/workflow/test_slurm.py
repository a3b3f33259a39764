"""The workflow on a real scheduler: a one-node SLURM cluster (tests/workflow/slurm.py) runs a fleet
through profiles/slurm as a site's would, byte for byte as a local run, and the fleet
survives the scheduler's faults: a job cancelled with scancel mid-write, slurmd restarted
while a job is queued, and a unit past its requested time, retried once with doubled
resources and recorded as failed when it runs out again."""

from __future__ import annotations

import contextlib
import html
import importlib.util
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.io import atomic
from gyrocal.io.errors import CalibrationFileError
from gyrocal.io.unit_folder import part_failure
from gyrocal.simulate import TurntableProtocol, simulate_unit

from .. import pg
from . import slurm
from .conftest import (
    BAD,
    BAD_ROW,
    CONFIG,
    CORRUPT,
    GOOD,
    HEADER,
    REPO,
    ROW,
    assert_every_file_whole,
    fleet_folder,
    leftovers,
    needs,
    shard_the_day,
    snakemake,
    snakemake_command,
)

pytestmark = [
    pytest.mark.slow,
    needs(
        {
            **slurm.found(),
            "snakemake-executor-plugin-slurm": importlib.util.find_spec("snakemake_executor_plugin_slurm")
            is not None,
        },
        f"{slurm.INSTALL}; the plugin is a test extra",
    ),
]

# The profile as a site without an accounting database runs it (job states from squeue;
# the command's --cores 2 caps a job's threads at the node's two CPUs); the first status
# check after a second rather than the profile's 20 (jobs of seconds here), and the SLURM
# log of every job kept, to read which units it ran.
SLURM = [
    "--profile",
    REPO / "profiles" / "slurm",
    "--slurm-status-command",
    "squeue",
    "--slurm-init-seconds-before-status-checks",
    "1",
    "--slurm-keep-successful-logs",
]


def outputs(root: Path, units) -> dict[str, bytes]:
    """Every file the workflow leaves for ``units`` (results, report, simulated log), by
    relative path; timings in results/benchmark and the logs excepted."""
    files = []
    for b, d, s in units:
        files += sorted((root / "results" / b / d / s).iterdir())
        files.append(root / "reports" / b / d / f"{s}.html")
        if d != BAD[1]:
            files.append(root / "demo" / "logs" / b / d / f"{s}.parquet")
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def fleet_outputs(root: Path) -> dict[str, bytes]:
    """The fleet summary, its table and the end-of-line verdicts."""
    files = [
        root / "reports" / "index.html",
        root / "results" / "fleet.parquet",
        root / "results" / "eol.json",
    ]
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def run_id(text: str) -> str:
    """The plugin's name for this run's jobs (``sbatch --job-name``)."""
    return re.search(r"SLURM run ID: (\S+)", text).group(1)


def submitted(text: str) -> dict[str, Path]:
    """SLURM job id -> its log, for every job Snakemake submitted with sbatch."""
    return {
        m.group(2): Path(m.group(3))
        for m in re.finditer(r"Job (\S+) has been submitted with SLURM jobid (\d+) \(log: (.*?)\)\.", text)
    }


def devices_in(log: Path) -> set[str]:
    """The devices whose jobs a SLURM job ran, from its log."""
    return set(re.findall(r"wildcards: batch=\w+, device=(\w+),", log.read_text()))


def wait_for(found, what: str, proc: subprocess.Popen, log: Path, timeout: float = 300):
    deadline = time.monotonic() + timeout
    while not (value := found()):
        assert proc.poll() is None, f"the run ended before {what}:\n{log.read_text()[-4000:]}"
        assert time.monotonic() < deadline, f"no {what} in {timeout:g} s"
        time.sleep(0.1)
    return value


def start(wd: Path, env: dict, *args) -> tuple[subprocess.Popen, Path]:
    log = wd.parent / f"{wd.name}.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            snakemake_command(wd, *args),
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    return proc, log


def end(proc: subprocess.Popen) -> None:
    """End a run that is still going, with what it started."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def finish(proc: subprocess.Popen, timeout: float) -> None:
    """Wait for the run; past ``timeout``, end it."""
    try:
        proc.wait(timeout)
    finally:
        end(proc)


@pytest.fixture(scope="module")
def cluster():
    with slurm.Cluster() as running:
        yield running


# A unit held in its segmentation for ten minutes, on a cluster of its own so that its
# minutes of waiting for the scheduler's time limit overlap the other tests. Its whole
# job asks for `attempt` minutes (SLURM's smallest limit, one minute; two on the retry):
# segment's runtime, analyse (which reports too) none of its own. Its memory doubles by the rules.
SLOW = Path("results", "B1", "T1", "2026-01-01")
SLOW_RESOURCES = ["--set-resources", "segment:runtime=attempt", "analyse:runtime=0"]


@pytest.fixture(scope="module", autouse=True)
def slow_unit(tmp_path_factory):
    """Started before the module's first test, finished by the last."""
    base = tmp_path_factory.mktemp("slurm-time")
    wd = base / "fleet"
    (wd / "logs").mkdir(parents=True)
    simulate_unit(
        wd / "logs" / "T1.parquet",
        rig=TurntableProtocol.quick(temperatures=(0.0, 20.0, 40.0), rates=(10.0, 100.0, 400.0)),
        rng=np.random.default_rng(29),
        device="T1",
        seed=29,
    )
    (wd / "devices.tsv").write_text(HEADER + "T1\tB1\t2026-01-01\tturntable\tlogs/T1.parquet\n")
    (wd / "config.yaml").write_text(CONFIG)
    with slurm.Cluster() as running:
        env = {**running.env, atomic.PAUSE_ENV: "T1/2026-01-01/observations.parquet:600"}
        proc, log = start(wd, env, *SLURM, *SLOW_RESOURCES)
        try:
            yield running, wd, proc, log
        finally:
            end(proc)


@pytest.fixture(scope="module")
def runs(cluster, small_fleet_local, tmp_path_factory):
    """The small fleet (tests/workflow/conftest.py: two good units in two batches and a
    corrupt one) run on the cluster through profiles/slurm, and its local run on two cores."""
    remote = fleet_folder(tmp_path_factory.mktemp("slurm") / "slurm")
    out = snakemake(remote, *SLURM, env=cluster.env)
    assert out.returncode == 0, (out.stdout + out.stderr)[-4000:] + cluster.logs()
    return small_fleet_local, remote, out.stdout + out.stderr


def test_the_cluster_is_this_machine_and_runs_a_job(cluster, record_property):
    """One node with this machine's CPUs; srun runs on it. The version it runs is in the
    test report's properties and pytest's header."""
    record_property("slurm", cluster.version)
    assert cluster.version == slurm.installed_version() and cluster.version.startswith("slurm")
    node = cluster.client("scontrol", "show", "node", cluster.node).stdout
    assert f"CPUTot={os.cpu_count()} " in node
    assert cluster.client("srun", "hostname").stdout.strip() == os.uname().nodename


def test_the_fleet_on_slurm_gives_the_local_runs_outputs_byte_for_byte(runs):
    local, remote, _ = runs
    units = [*GOOD, BAD]
    expected, got = outputs(local, units), outputs(remote, units)
    assert got.keys() == expected.keys()
    for path, content in {**expected, **fleet_outputs(local)}.items():
        assert (remote / path).read_bytes() == content, path
    index = (remote / "reports" / "index.html").read_text()
    assert "3 unit sessions: 2 calibrated" in index and "not a readable Parquet file" in index


def test_jobs_were_submitted_with_sbatch_and_grouped_as_the_profile_says(runs, cluster):
    """Five units to a job: the three units' chains in one SLURM job, the fleet summary in
    another; both in the controller's queue under the run's name, completed, with the
    requests Snakemake made for them (threads, memory, the steps' time)."""
    _, remote, text = runs
    jobs = {row["id"]: row for row in cluster.jobs() if row["name"] == run_id(text)}
    logs = submitted(text)
    assert set(jobs) == set(logs) and len(jobs) == 2
    assert {row["state"] for row in jobs.values()} == {"COMPLETED"}
    group = [i for i, row in jobs.items() if row["comment"].startswith("rule_unit_")]
    fleet = [i for i, row in jobs.items() if row["comment"] == "rule_fleet"]
    assert len(group) == 1 and len(fleet) == 1
    assert devices_in(logs[group[0]]) == {"A1", "A2", "BAD"}
    assert set(re.findall(r"^\s*rule (\w+):$", logs[group[0]].read_text(), flags=re.M)) == {
        "simulate",
        "segment",
        "analyse",
    }
    job = jobs[group[0]]
    # three units' one-thread chains side by side, capped at the node's two CPUs; at least
    # one chain's memory (simulate's 1500 MB); a chain's minutes (simulate 5, segment 2, analyse 2)
    assert job["cpus"] == "2" and slurm.memory_mb(job["memory"]) >= 1500
    assert slurm.seconds(job["time_limit"]) >= 9 * 60


FAULT_UNITS = [GOOD[0], BAD]


@pytest.fixture(scope="module")
def faults(cluster, runs, tmp_path_factory):
    """A good unit and the corrupt one again, each its own SLURM job (``--group-components
    unit=1``), both made to ask for the node's two CPUs, so that one waits in the queue while
    the other runs. When the running one holds its validation.json (a result or a failure
    record) between the temporary file and the rename, slurmd is restarted, the other job
    still queued, then the running job is cancelled with scancel. The logs are the local
    run's, at the same paths (no simulate job); the units' reports are the targets (no
    fleet job)."""
    local, _, _ = runs
    wd = fleet_folder(tmp_path_factory.mktemp("slurm-faults") / "fleet", ROW.format(*GOOD[0]) + BAD_ROW)
    for path in (Path("demo", "logs", *GOOD[0][:2], f"{GOOD[0][2]}.parquet"), CORRUPT):
        (wd / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(local / path, wd / path)
    env = {**cluster.env, atomic.PAUSE_ENV: "validation.json:5"}
    reports = [f"reports/{b}/{d}/{s}.html" for b, d, s in FAULT_UNITS]
    # each job on both CPUs (the rules ask for one), so that the second waits in the queue
    proc, log = start(
        wd, env, *reports, *SLURM, "--group-components", "unit=1", "--set-threads", "segment=2", "analyse=2"
    )
    seen = {}
    try:
        held = wait_for(
            lambda: sorted(wd.glob("results/*/*/*/.validation.json.*.tmp")),
            "a job holding its validation.json",
            proc,
            log,
        )[0]
        seen["job"] = environ(int(held.name.split(".")[3]))["SLURM_JOB_ID"]  # .NAME.PID.X.tmp
        seen["queued"] = [r["id"] for r in cluster.jobs() if r["state"] == "PENDING"]
        cluster.restart_slurmd()
        seen["held at the cancel"] = held.exists()
        cluster.client("scancel", seen["job"])
        finish(proc, 600)
        seen["exit"] = proc.returncode
    finally:
        end(proc)
    return wd, log.read_text(), seen


def environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode().split("=", 1) for item in raw if b"=" in item)


def test_a_cancelled_job_and_a_restarted_slurmd_leave_the_local_runs_outputs(faults, runs, cluster):
    """The cancelled job is retried (doubled memory and time) and the queued one runs on
    the restarted slurmd; the run completes, with nothing partial and every unit's files
    byte for byte the local run's."""
    wd, text, seen = faults
    local, _, _ = runs
    assert seen["queued"] and seen["held at the cancel"]
    assert seen["exit"] == 0, text[-4000:] + cluster.logs()
    assert_every_file_whole(wd)
    assert not leftovers(wd)
    expected, got = outputs(local, FAULT_UNITS), outputs(wd, FAULT_UNITS)
    assert got.keys() == expected.keys()
    for path, content in expected.items():
        assert got[path] == content, path
    jobs = {r["id"]: r for r in cluster.jobs() if r["name"] == run_id(text)}
    logs = submitted(text)
    assert jobs[seen["job"]]["state"] == "CANCELLED"
    cancelled = devices_in(logs[seen["job"]])
    retry = [i for i in logs if i != seen["job"] and devices_in(logs[i]) == cancelled]
    assert len(retry) == 1 and jobs[retry[0]]["state"] == "COMPLETED"
    first, second = jobs[seen["job"]], jobs[retry[0]]
    assert slurm.memory_mb(second["memory"]) == 2 * slurm.memory_mb(first["memory"])
    assert slurm.seconds(second["time_limit"]) == 2 * slurm.seconds(first["time_limit"])
    assert all(jobs[i]["state"] == "COMPLETED" for i in seen["queued"])
    assert {d for i in logs for d in devices_in(logs[i])} == {u[1] for u in FAULT_UNITS}


def test_a_unit_past_its_time_is_retried_with_doubled_resources_then_recorded(slow_unit):
    """T1 outlives its one-minute job: SLURM ends it (TIMEOUT), Snakemake resubmits it with
    two minutes and twice the memory; on that last attempt the guard stops the stage
    before the limit and records why, so the unit is a failure in the fleet summary and
    the run ends well."""
    running, wd, proc, log = slow_unit
    finish(proc, 600)
    text = log.read_text()
    assert proc.returncode == 0, text[-4000:] + running.logs()
    jobs = [r for r in running.jobs() if r["name"] == run_id(text)]
    units = [r for r in jobs if r["comment"].startswith("rule_unit_")]
    assert [(r["state"], r["time_limit"]) for r in units] == [("TIMEOUT", "1:00"), ("COMPLETED", "2:00")]
    assert slurm.memory_mb(units[1]["memory"]) == 2 * slurm.memory_mb(units[0]["memory"])
    assert [r["state"] for r in jobs if r["comment"] == "rule_fleet"] == ["COMPLETED"]
    folder = wd / SLOW
    reason = "would outrun its SLURM job's time limit (2:00, attempt 2 of 2)"
    record = part_failure(folder, "observations")
    assert record["stage"] == "segment" and record["error"] == reason
    with pytest.raises(CalibrationFileError, match="the segment stage failed"):
        load_calibration(folder / "calibration.json")
    index = html.unescape((wd / "reports" / "index.html").read_text())
    assert "1 unit session: 0 calibrated" in index and reason in index
    assert_every_file_whole(wd)
    assert not leftovers(wd)


@pytest.mark.parametrize("kind", ["sqlite", pytest.param("postgresql", marks=needs(pg.found(), pg.INSTALL))])
def test_two_shards_on_slurm_fill_one_registry(kind, cluster, small_fleet_local, tmp_path, monkeypatch):
    """A day as two shards through the SLURM profile, side by side, both indexing their runs
    in one registry (the day's SQLite file beside them, or a PostgreSQL database the config
    names): every unit session once, each where its shard wrote it."""
    from gyrocal.calibration import registry
    from gyrocal.calibration.lookup import find_calibration

    logs = small_fleet_local / "demo" / "logs"
    rows = "".join(f"{d}\t{b}\t{s}\tturntable\t{logs}/{b}/{d}/{s}.parquet\n" for b, d, s in GOOD)
    corrupt = tmp_path / "corrupt.parquet"
    corrupt.write_bytes(b"PAR1 not a parquet file")
    (tmp_path / "day.tsv").write_text(HEADER + rows + f"BAD\tB2\t{BAD[2]}\tturntable\t{corrupt}\n")
    (tmp_path / "config.yaml").write_text(CONFIG)
    for key, value in cluster.env.items():
        monkeypatch.setenv(key, value)
    monkeypatch.chdir(REPO)
    with contextlib.ExitStack() as stack:
        if kind == "postgresql":
            url = stack.enter_context(pg.Server()).create_database("day")
            named = ["--config", f"registry={url}"]
        else:
            url, named = str(tmp_path / "runs" / "registry.sqlite"), []
        status = shard_the_day(tmp_path, *SLURM, *named)
        runs = tmp_path / "runs"
        assert status == 0, [(p, p.read_text()[-2000:]) for p in runs.glob("*/snakemake.log")]
        backend = registry.connect(url, create=False)
        try:
            indexed = backend.execute(
                "SELECT root, device, session, status FROM unit_sessions "
                "WHERE path LIKE '%/calibration.json' ORDER BY device, session"
            ).fetchall()
        finally:
            backend.close()
        assert [(Path(r).parent.name, d, s, st) for r, d, s, st in indexed] == [
            ("shard-0001", "A1", "2026-01-01", "calibrated"),
            ("shard-0002", "A2", "2026-01-02", "calibrated"),  # a batch a shard
            ("shard-0002", "BAD", "2026-01-02", "failed"),
        ]
        found = find_calibration(runs, "A2", registry=url)
        assert found.path == runs / "shard-0002" / "results" / "B2" / "A2" / "2026-01-02" / "calibration.json"
    # the config's registry, or the day's file
    assert (runs / "registry.sqlite").exists() == (kind == "sqlite")
