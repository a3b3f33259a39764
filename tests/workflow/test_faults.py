"""Faults in the workflow and the stage guard (gyrocal.run.guard): a job killed mid-write leaves nothing a rerun would
take as complete and the rerun finishes; a job past its memory or time limit is its
unit's failure, with the reason, in the fleet summary. Real Snakemake runs on a fleet of
tiny logs."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.io import atomic, failure
from gyrocal.io.tables import write_table
from gyrocal.io.unit_folder import job_log, part_failure, read_part_json
from gyrocal.run import guard
from gyrocal.simulate import TurntableProtocol, simulate_unit

from .conftest import REPO, assert_every_file_whole, leftovers, snakemake

SESSION = "2026-01-01"
CONFIG = """devices: devices.tsv
model: {terms: [bias, scale, misalignment]}
diagnosis: {ladder: []}
spec: {turntable: {excess: 5}}
"""


@pytest.fixture(scope="module")
def tiny_logs(tmp_path_factory):
    """Three units' logs of three set points and rates (a few seconds of holds each)."""
    folder = tmp_path_factory.mktemp("fault-logs")
    rig = TurntableProtocol.quick(temperatures=(0.0, 20.0, 40.0), rates=(10.0, 100.0, 400.0))
    for i, device in enumerate(("K1", "K2", "K3")):
        simulate_unit(
            folder / f"{device}.parquet",
            rig=rig,
            rng=np.random.default_rng(70 + i),
            device=device,
            seed=70 + i,
        )
    return folder


def fleet(tmp_path, logs, devices, config=CONFIG):
    wd = tmp_path / "fleet"
    (wd / "logs").mkdir(parents=True)
    rows = ["device\tbatch\tsession\tprotocol\tpath"]
    for device in devices:
        shutil.copy(logs / f"{device}.parquet", wd / "logs")
        rows.append(f"{device}\tB1\t{SESSION}\tturntable\tlogs/{device}.parquet")
    (wd / "devices.tsv").write_text("\n".join(rows) + "\n")
    (wd / "config.yaml").write_text(config)
    return wd


def unit(wd, device):
    return wd / "results" / "B1" / device / SESSION


@pytest.mark.slow
@pytest.mark.parametrize("kill", ["the job", "the whole run"])
def test_a_job_killed_mid_write_is_redone_by_the_rerun(tiny_logs, tmp_path, kill):
    """The analyse job of K1 is held between its complete temporary validation.json and
    the rename (the test seam of gyrocal.io.atomic), then killed with SIGKILL: its writing
    process alone (Snakemake sees the job fail) or Snakemake with every job (a node lost)."""
    # Beside K1, K2 shows the rest of the fleet going on past a failed job.
    wd = fleet(tmp_path, tiny_logs, ("K1", "K2") if kill == "the job" else ("K1",))
    target = unit(wd, "K1") / "validation.json"
    env = {**os.environ, atomic.PAUSE_ENV: f"K1/{SESSION}/validation.json:600"}
    log = open(tmp_path / "snakemake.log", "w")  # noqa: SIM115 - the workflow's, closed when it ends
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "snakemake",
            "--snakefile",
            str(REPO / "Snakefile"),
            "--directory",
            str(wd),
            "--configfile",
            str(wd / "config.yaml"),
            "--cores",
            "2",
        ],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not (held := list(target.parent.glob(".validation.json.*.tmp"))):
            assert run.poll() is None and time.monotonic() < deadline, "the job never paused"
            time.sleep(0.1)
        if kill == "the job":
            os.kill(int(held[0].name.split(".")[3]), signal.SIGKILL)  # .NAME.PID.XXXXXX.tmp
        else:
            os.killpg(run.pid, signal.SIGKILL)
        run.wait(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
        log.close()
    assert run.returncode != 0
    assert not target.exists()
    assert_every_file_whole(wd)
    if kill == "the job":  # Snakemake removed the failed job's outputs; K2 went on
        assert not (unit(wd, "K1") / "calibration.json").exists()
        assert (wd / "reports" / "B1" / "K2" / f"{SESSION}.html").exists()
    else:
        assert snakemake(wd, "--unlock").returncode == 0
    plan = snakemake(wd, "--dry-run")
    assert re.search(r"rule analyse:\n(?:\s+\w+: .*\n)*?\s+wildcards: batch=B1, device=K1,", plan.stdout), (
        plan.stdout[-3000:]
    )

    out = snakemake(wd)
    assert out.returncode == 0, out.stderr[-3000:]
    assert_every_file_whole(wd)
    assert not leftovers(wd)
    cal = load_calibration(unit(wd, "K1") / "calibration.json")
    assert cal.meta["device"] == "K1"
    assert read_part_json(unit(wd, "K1"), "validation")["summary"]["validation_rms"] > 0
    units = "2 unit sessions: 2 calibrated" if kill == "the job" else "1 unit session: 1 calibrated"
    assert units in (wd / "reports" / "index.html").read_text()


@pytest.mark.slow
def test_a_job_past_its_memory_or_time_limit_fails_its_unit_with_the_reason(tiny_logs, tmp_path):
    """K2 may hold 50 MiB (a Python with pandas alone takes more); K3's segmentation is
    held past its 5 s. Both are recorded as failed with the reason; K1 is calibrated."""
    config = CONFIG + "job_limits: {devices: {K2: {memory_mb: 50}, K3: {timeout_s: 5}}}\n"
    wd = fleet(tmp_path, tiny_logs, ("K1", "K2", "K3"), config)
    env = {atomic.PAUSE_ENV: f"K3/{SESSION}/observations.parquet:120"}
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "snakemake",
            "--snakefile",
            str(REPO / "Snakefile"),
            "--directory",
            str(wd),
            "--configfile",
            str(wd / "config.yaml"),
            "--cores",
            "2",
        ],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    memory, time_out = "ran out of memory (limit 50 MiB)", "timed out after 5 s"

    record = part_failure(unit(wd, "K3"), "observations")
    assert (record["stage"], record["error"], record["device"]) == ("segment", time_out, "K3")
    assert memory in part_failure(unit(wd, "K2"), "validation")["error"]
    assert load_calibration(unit(wd, "K1") / "calibration.json").meta["device"] == "K1"

    index = (wd / "reports" / "index.html").read_text()
    assert "3 unit sessions: 1 calibrated" in index and "2 failed" in index
    assert memory in index and time_out in index
    eol = {u["device"]: u for u in json.loads((wd / "results" / "eol.json").read_text())["units"]}
    assert not eol["K2"]["calibrated"] and any(memory in r for r in eol["K2"]["reasons"])
    assert not eol["K3"]["calibrated"] and any(time_out in r for r in eol["K3"]["reasons"])
    assert eol["K1"]["calibrated"]
    assert time_out in (wd / "reports" / "B1" / "K3" / f"{SESSION}.html").read_text()
    assert_every_file_whole(wd)
    assert not leftovers(wd)
    # Each job's log is a part of its archive: what the stage printed, and the guard's
    # record of a failure it caught. What the job cost is on the job's stderr, in
    # Snakemake's output (benchmarks/requests.py and throughput.py read it there).
    cost_lines = {(stage, where) for stage, where, *_ in guard.costs(out.stderr)}
    for device in ("K1", "K2", "K3"):
        for stage in ("segment", "analyse"):  # analyse writes the report too
            assert not (unit(wd, device) / f"{stage}.log").exists()
            assert (stage, f"results/B1/{device}/{SESSION}") in cost_lines, sorted(cost_lines)
    assert job_log(unit(wd, "K1"), "segment").startswith(f"segmentation -> results/B1/K1/{SESSION}")
    assert job_log(unit(wd, "K2"), "analyse").endswith(f"gyrocal: analyse failed (recorded): {memory}\n")
    assert job_log(unit(wd, "K3"), "segment").endswith(f"gyrocal: segment failed (recorded): {time_out}\n")


def test_a_cost_line_is_read_where_it_lands_after_a_message_of_snakemakes():
    """Snakemake writes a multi-line message and its line end in two writes: a job's line
    written between them follows the message's last line."""
    text = (
        "rule segment:\n    resources: tmpdir=/tmp, mem_mib=477"
        "gyrocal.run.guard: segment of results/B1/K2/2026-01-01 took 0.44 s, 0.16 s CPU, 87 MiB peak\n"
        "\ngyrocal.run.guard: analyse of results/B1/K2/2026-01-01 took 2.40 s, 1.08 s CPU, 188 MiB peak\n"
    )
    assert guard.costs(text) == [
        ("segment", "results/B1/K2/2026-01-01", 0.44, 0.16, 87.0),
        ("analyse", "results/B1/K2/2026-01-01", 2.40, 1.08, 188.0),
    ]


def test_a_memory_error_is_recorded_as_such():
    rec = failure.record("fit", MemoryError("Unable to allocate 8.00 GiB"), {"device": "K1"})
    assert rec["error"] == "ran out of memory (Unable to allocate 8.00 GiB)" and not rec["internal"]
    assert failure.record("fit", "timed out after 5 s")["error"] == "timed out after 5 s"


def test_a_write_that_fails_leaves_the_file_it_replaces(tmp_path):
    path = tmp_path / "table.parquet"
    write_table(pd.DataFrame({"x": [1.0, 2.0]}), path, {"run": 1})
    before = path.read_bytes()
    with pytest.raises(pa.ArrowException):  # a column Parquet cannot hold
        write_table(pd.DataFrame({"x": [object()]}), path, {"run": 2})
    assert path.read_bytes() == before
    with pytest.raises(RuntimeError), atomic.replacing(path) as tmp:
        tmp.write_bytes(b"PAR1 half a file")
        raise RuntimeError("killed")
    assert path.read_bytes() == before
    folder = tmp_path / "bundle"
    folder.mkdir()
    (folder / "index.html").write_text("old")
    with pytest.raises(RuntimeError), atomic.replacing_folder(folder) as tmp:
        (tmp / "index.html").write_text("half")
        raise RuntimeError("killed")
    assert (folder / "index.html").read_text() == "old"
    with atomic.replacing_folder(folder) as tmp:
        (tmp / "index.html").write_text("new")
    assert (folder / "index.html").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle", "table.parquet"]


@pytest.mark.parametrize(
    "left, limit, keep",
    [("1:40", "2:00", 70.0), ("1-02:03:04", "2-00:00:00", 93754.0), ("0:20", "1:00", 0.0)],
)
def test_on_its_jobs_last_attempt_the_guard_stops_a_stage_before_slurms_time_limit(
    tmp_path, monkeypatch, left, limit, keep
):
    """Inside a SLURM job, on the last of the workflow's attempts, the guard asks squeue
    for the job's time left and keeps 30 s of it for the steps after segmentation (none
    left: stopped at once). Before the last attempt, and outside SLURM, it does not: the
    scheduler ends the job and Snakemake retries it with more time."""
    from gyrocal.run import guard

    squeue = tmp_path / "squeue"
    squeue.write_text(f'#!/bin/sh\necho "$@" > {tmp_path / "args"}\necho "{left}|{limit}"\n')
    squeue.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("SLURM_JOB_ID", "29")
    monkeypatch.setenv(guard.ATTEMPTS_ENV, "2")
    reason = f"would outrun its SLURM job's time limit ({limit}, attempt 2 of 2)"
    assert guard.scheduler_limit("segment", 2) == (keep, reason)
    assert (tmp_path / "args").read_text().split() == ["--noheader", "--jobs=29", "--format=%L|%l"]
    assert guard.scheduler_limit("segment", 1) is None
    monkeypatch.delenv(guard.ATTEMPTS_ENV)  # run by hand: every attempt is the last
    assert guard.scheduler_limit("segment", 1)[1] == f"would outrun its SLURM job's time limit ({limit})"
    monkeypatch.delenv("SLURM_JOB_ID")
    assert guard.scheduler_limit("segment", 2) is None


def test_on_its_jobs_last_attempt_the_guard_keeps_a_stage_within_its_slurm_jobs_memory(
    tiny_logs, tmp_path, monkeypatch
):
    """A SLURM job killed for memory on its last attempt would leave its unit with no
    record and hold back the fleet summary: there the guard's limit is 80 % of the job's
    request where that is lower, and the unit is recorded as out of memory, with the log
    of the job packed beside the record. Before the last attempt, and outside the SLURM
    executor, the configured limit alone holds (the scheduler's kill is retried with more
    memory; a local run inside an allocation has no such kill)."""
    from gyrocal.run import guard

    monkeypatch.setenv(guard.SLURM_MEMORY_ENV, "1")
    monkeypatch.setenv(guard.ATTEMPTS_ENV, "2")
    share = (400, "ran out of memory (limit 400 MiB: its SLURM job's memory, 500 MiB, attempt 2 of 2)")
    assert guard.scheduler_memory(None, 500, 2) == share
    assert guard.scheduler_memory(4096, 500, 2) == share
    assert guard.scheduler_memory(300, 500, 2) == (300, "ran out of memory (limit 300 MiB)")
    assert guard.scheduler_memory(4096, 500, 1) == (4096, "ran out of memory (limit 4096 MiB)")
    assert guard.scheduler_memory(None, 500, 1) == (None, None)
    monkeypatch.delenv(guard.SLURM_MEMORY_ENV)
    assert guard.scheduler_memory(4096, 500, 2) == (4096, "ran out of memory (limit 4096 MiB)")

    unit = tmp_path / "K1"
    env = {**os.environ, guard.SLURM_MEMORY_ENV: "1", guard.ATTEMPTS_ENV: "2", "PYTHONPATH": str(REPO)}
    env.pop("SLURM_JOB_ID", None)  # no time left to ask squeue for
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "gyrocal.run.guard",
            "--attempt",
            "2",
            "--job-memory-mb",
            "50",
            "--job-log",
            str(unit / "segment.log"),
            "segment",
            str(tiny_logs / "K1.parquet"),
            "--out",
            str(unit),
            "--device",
            "K1",
            "--record-failures",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert sorted(p.name for p in unit.iterdir()) == ["segmentation.zip"]
    reason = "ran out of memory (limit 40 MiB: its SLURM job's memory, 50 MiB, attempt 2 of 2)"
    assert part_failure(unit, "observations")["error"] == reason
    assert job_log(unit, "segment").endswith(f"gyrocal: segment failed (recorded): {reason}\n")
    assert ("segment", str(unit)) in [(stage, where) for stage, where, *_ in guard.costs(out.stderr)]


def test_a_job_log_an_earlier_attempt_left_is_shown_and_a_failed_job_leaves_its_log(tmp_path):
    """The scheduler's kill leaves the attempt's log beside the unit's archive (Snakemake
    removes the archive): the retry prints its end and starts its own, so that the archive
    is the same bytes as a run that needed no retry. A job that fails leaves its log where
    it was and prints its end."""
    unit = tmp_path / "K1"
    unit.mkdir()
    (unit / "segment.log").write_text("killed here\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "gyrocal.run.guard",
            "--job-log",
            str(unit / "segment.log"),
            "segment",
            str(tmp_path / "absent.parquet"),
            "--out",
            str(unit),
            "--device",
            "K1",
            "--record-failures",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "gyrocal.run.guard: the end of an earlier attempt's log:\nkilled here\n" in out.stderr
    log = job_log(unit, "segment")
    assert "killed here" not in log and "absent.parquet" in log
    assert not (unit / "segment.log").exists()
    out = subprocess.run(  # not recording failures: the job fails, its log stays
        [
            sys.executable,
            "-m",
            "gyrocal.run.guard",
            "--job-log",
            str(unit / "segment.log"),
            "segment",
            str(tmp_path / "absent.parquet"),
            "--out",
            str(unit),
            "--device",
            "K1",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode != 0
    assert (unit / "segment.log").exists() and "absent.parquet" in job_log(unit, "segment")
    assert f"gyrocal.run.guard: the end of {unit / 'segment.log'}:" in out.stderr


@pytest.mark.slow
def test_an_analyse_stopped_in_its_report_keeps_the_steps_it_finished(tiny_logs, tmp_path):
    """The report is the analyse job's last step: stopped there (its write held past the
    limit), the job keeps its calibration, validation and diagnosis, and the report says
    what stopped it."""
    from gyrocal.io.unit_folder import part_exists

    unit = tmp_path / "K1"
    log = tiny_logs / "K1.parquet"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    subprocess.run(
        [sys.executable, "-m", "gyrocal", "segment", str(log), "--out", str(unit)],
        check=True,
        env=env,
        capture_output=True,
    )
    report = tmp_path / "K1.html"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "gyrocal.run.guard",
            "--timeout-s",
            "40",
            "analyse",
            str(unit),
            "--report",
            str(report),
            "--device",
            "K1",
            "--record-failures",
        ],
        env={**env, atomic.PAUSE_ENV: "K1.html:600"},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "timed out after 40 s" in report.read_text()
    assert load_calibration(unit / "calibration.json").meta["device"] == "K1"
    for part in ("validation", "diagnosis", "holds", "residuals"):
        assert part_exists(unit, part) and part_failure(unit, part) is None, part
    assert read_part_json(unit, "validation")["summary"]["validation_rms"] > 0
    assert not leftovers(tmp_path)
