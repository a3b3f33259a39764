"""A day's manifest run as shards (gyrocal shard --run, gyrocal.run.shards): each shard a
workflow of its own, a few at a time, and the day's view their union."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.fleet.manifest import read_manifest, write_shards
from gyrocal.run.shards import (
    DayCounts,
    ShardRun,
    _terminate_as_interrupt,
    day_view,
    run_shards,
    workflow_command,
)

from .conftest import FLEET_CONFIG, REPO, shard_the_day

# Stands in for a shard's workflow: writes a fleet table of its manifest's rows (a
# parameter column only some shards have), records when it ran, and fails where told to.
FAKE_WORKFLOW = r"""
import json, sys, time, pathlib
import pyarrow as pa, pyarrow.parquet as pq
folder, manifest = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
start = time.time()
rows = [line.split("\t") for line in manifest.read_text().splitlines()[1:]]
time.sleep(0.6)
if any(r[0] == "STOP" for r in rows):
    print("the workflow stopped <here>"); sys.exit(3)
(folder / "results").mkdir(parents=True, exist_ok=True)
columns = {"device": [r[0] for r in rows], "batch": [r[1] for r in rows],
           "status": ["failed" if r[0].startswith("F") else "ok" for r in rows],
           "eol_passed": [None if r[0].startswith("F") else r[0] != "E1" for r in rows]}
if rows[0][1] == "B2":
    columns["bias.x"] = [0.01] * len(rows)
pq.write_table(pa.table(columns), folder / "results" / "fleet.parquet")
(folder / "reports").mkdir(exist_ok=True)
(folder / "reports" / "index.html").write_text("<html></html>")
(folder / "ran.json").write_text(json.dumps([start, time.time()]))
"""


def fake(shard, snakefile, configfile, args):
    return [sys.executable, "-c", FAKE_WORKFLOW, str(shard.folder), str(shard.manifest)]


def manifests(tmp_path, batches: dict[str, list[str]]):
    paths = []
    for k, (batch, devices) in enumerate(batches.items(), start=1):
        path = tmp_path / f"shard-{k:04d}.tsv"
        path.write_text(
            "device\tbatch\tsession\tprotocol\tpath\n"
            + "".join(f"{d}\t{batch}\t2026-03-02\tturntable\t/logs/{d}.parquet\n" for d in devices)
        )
        paths.append(path)
    return paths


def test_shards_run_a_few_at_a_time_and_the_day_is_their_union(tmp_path):
    paths = manifests(tmp_path, {"B1": ["A1", "E1", "F1"], "B2": ["A2"], "B3": ["STOP"], "B4": ["A4", "A5"]})
    # what an earlier run of the shard left: not counted when this run stops
    (tmp_path / "shard-0003" / "results").mkdir(parents=True)
    pq.write_table(
        pa.table({"device": ["OLD"], "batch": ["B0"], "status": ["ok"]}),
        tmp_path / "shard-0003" / "results" / "fleet.parquet",
    )
    said = []
    runs = run_shards(
        paths,
        tmp_path,
        [],
        at_once=2,
        snakefile=REPO / "Snakefile",
        configfile=None,
        command=fake,
        echo=said.append,
    )
    assert [r.status for r in runs] == [0, 0, 3, 0]
    assert any("shard-0003: failed (exit status 3" in line for line in said)
    # never more than two at once: of the three that ran to the end, the third started
    # after one of the first two had ended
    spans = sorted(json.loads((r.folder / "ran.json").read_text()) for r in runs if r.status == 0)
    assert spans[2][0] >= min(spans[0][1], spans[1][1]) - 0.05
    totals = day_view(runs, tmp_path)
    assert totals == DayCounts(units=6, ok=5, failed=1, eol_passed=4, eol_failed=1)
    day = pq.read_table(tmp_path / "fleet.parquet")
    assert day.column_names[0] == "shard" and day.num_rows == 6
    assert day.column("shard").to_pylist() == ["shard-0001"] * 3 + ["shard-0002"] + ["shard-0004"] * 2
    assert day.column("bias.x").to_pylist() == [None, None, None, 0.01, None, None]
    assert day.schema.metadata[b"gyrocal.format"] == b"gyrocal.fleet/1"
    page = (tmp_path / "index.html").read_text()
    assert 'href="shard-0001/reports/index.html"' in page and 'href="shard-0003/snakemake.log"' in page
    assert 'href="shard-0003/reports' not in page  # it made no summary
    assert "stopped (exit status 3)" in page and "6 unit sessions: 5 calibrated, 1 failed" in page
    assert "the workflow stopped <here>" in (tmp_path / "shard-0003" / "snakemake.log").read_text()


def test_the_users_config_items_go_with_the_shards_manifest(tmp_path, monkeypatch):
    """Snakemake keeps the last --config it is given: the user's items and the shard's
    manifest go in one, the manifest last."""
    monkeypatch.delenv("SNAKEMAKE_PROFILE", raising=False)
    shard = ShardRun(tmp_path / "shard-0001.tsv", tmp_path / "shard-0001")
    command = workflow_command(
        shard,
        REPO / "Snakefile",
        tmp_path / "c.yaml",
        [
            "--profile",
            "profiles/slurm",
            "--config",
            "spec={}",
            "devices=other.tsv",
            "--keep-going",
            "-C",
            "drift={}",
            "--config=model={}",
        ],
    )
    at = command.index("--config")
    registry = f"registry={(tmp_path / 'registry.sqlite').resolve()}"  # the day's, beside the shards
    assert command[at:] == [
        "--config",
        "spec={}",
        "drift={}",
        "model={}",
        registry,
        f"devices={shard.manifest}",
    ]
    assert command.count("--config") == 1 and "-C" not in command and "--keep-going" in command
    assert command[command.index("--configfile") + 1] == str(tmp_path / "c.yaml")
    assert "--cores" not in command  # the profile says
    own = workflow_command(shard, REPO / "Snakefile", tmp_path / "c.yaml", ["--configfile", "mine.yaml"])
    assert own.count("--configfile") == 1 and "mine.yaml" in own
    assert own[own.index("--cores") + 1] == "all"  # nothing said how many
    for given in (["-j4"], ["--cores=3"], ["-c", "2"], ["--jobs", "8"]):
        assert "all" not in workflow_command(shard, REPO / "Snakefile", None, given), given


def test_shards_rewritten_only_where_their_rows_changed(tmp_path):
    rows = read_manifest_rows(tmp_path, {"B1": ["A1", "A2"], "B2": ["A3"], "B3": ["A4"]})
    first = write_shards(rows, 2, tmp_path / "runs")
    stamps = {p.name: p.stat().st_mtime_ns for p in first}
    time.sleep(0.02)
    again = write_shards(rows, 2, tmp_path / "runs")
    assert {p.name: p.stat().st_mtime_ns for p in again} == stamps  # a rerun has nothing new to do
    fewer = write_shards(rows[:2], 2, tmp_path / "runs")
    assert [p.name for p in fewer] == ["shard-0001.tsv"] and fewer[0].stat().st_mtime_ns == stamps[
        "shard-0001.tsv"
    ]
    assert sorted(p.name for p in (tmp_path / "runs").glob("shard-*.tsv")) == ["shard-0001.tsv"]


def _runs(pid: str, marker: str) -> bool:
    """Whether process ``pid`` is running with ``marker`` on its command line."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return marker.encode() in f.read()
    except OSError:
        return False


def read_manifest_rows(tmp_path, batches):
    return [row for path in manifests(tmp_path, batches) for row in read_manifest(path)]


def test_shards_still_running_are_stopped_with_the_run(tmp_path):
    """An interrupted run (Ctrl-C, or SIGTERM, which it takes as Ctrl-C) stops the shards'
    workflows it started, rather than leaving them running with their locks held."""
    paths = manifests(tmp_path, {"B1": ["A1"], "B2": ["A2"]})
    script = "import pathlib, sys, time; pathlib.Path(sys.argv[1]).write_text('x'); time.sleep(120)"
    started = []

    def interrupt(line):
        started.append(line)
        if len(started) == 2:
            raise KeyboardInterrupt

    children = []

    def command(shard, snakefile, configfile, args):
        children.append(shard.folder / "alive")
        return [sys.executable, "-c", script, str(shard.folder / "alive")]

    t0 = time.monotonic()
    # started in the background by a script, a run ignores SIGINT and its children would too
    ignored = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_shards(
                paths,
                tmp_path,
                [],
                at_once=2,
                snakefile=REPO / "Snakefile",
                configfile=None,
                command=command,
                echo=interrupt,
            )
    finally:
        signal.signal(signal.SIGINT, ignored)
    assert time.monotonic() - t0 < 30 and len(children) == 2  # stopped, not waited for
    assert not [pid for pid in os.listdir("/proc") if pid.isdigit() and _runs(pid, str(tmp_path))]
    with pytest.raises(KeyboardInterrupt), _terminate_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
    assert signal.getsignal(signal.SIGTERM) is not _terminate_as_interrupt._raise


def test_workflow_options_without_run_and_no_workflow_are_refused(tmp_path, monkeypatch, capsys):
    from gyrocal.run.cli import main

    (tmp_path / "day.tsv").write_text(
        "device\tbatch\tsession\tprotocol\tpath\nA1\tB1\t2026-03-02\tturntable\tA1.parquet\n"
    )
    monkeypatch.chdir(tmp_path)
    assert main(["shard", "--manifest", "day.tsv", "-o", "runs", "--", "--cores", "2"]) == 2
    assert "need --run" in capsys.readouterr().err
    assert main(["shard", "--manifest", "day.tsv", "-o", "runs", "--run"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Snakefile: no workflow here" in err and len(err.splitlines()) == 1


def registry_lookup(runs, device):
    """A lookup across the day's shards, from their one registry."""
    from gyrocal.calibration.lookup import find_calibration

    return find_calibration(runs, device, registry=str(runs / "registry.sqlite"))


@pytest.mark.slow
def test_a_day_runs_as_shards_through_the_workflow(fleet_run, tmp_path, monkeypatch):
    """Two shards through the real workflow side by side: a batch each, a missing log in
    one; each shard's summary and the day's table and page."""

    logs = fleet_run / "demo" / "logs"
    (tmp_path / "day.tsv").write_text(
        "device\tbatch\tsession\tprotocol\tpath\n"
        f"A1\tB1\t2026-01-01\tturntable\t{logs}/B1/A1/2026-01-01.parquet\n"
        f"A1\tB1\t2026-03-01\tturntable\t{logs}/B1/A1/2026-03-01.parquet\n"
        f"A2\tB2\t2026-01-02\tturntable\t{logs}/B2/A2/2026-01-02.parquet\n"
        "GONE\tB2\t2026-01-03\tturntable\tlogs/absent.parquet\n"
    )
    (tmp_path / "config.yaml").write_text(FLEET_CONFIG)
    monkeypatch.chdir(REPO)
    status = shard_the_day(tmp_path, "--cores", "1")
    runs = tmp_path / "runs"
    assert status == 0, [(p, p.read_text()[-2000:]) for p in runs.glob("*/snakemake.log")]
    for shard in ("shard-0001", "shard-0002"):
        assert (runs / shard / "reports" / "index.html").is_file()
    day = pq.read_table(runs / "fleet.parquet").to_pylist()
    assert [(r["shard"], r["device"], r["status"]) for r in day] == [
        ("shard-0001", "A1", "ok"),
        ("shard-0001", "A1", "ok"),
        ("shard-0002", "A2", "ok"),
        ("shard-0002", "GONE", "failed"),
    ]
    assert "4 unit sessions: 3 calibrated, 1 failed" in (runs / "index.html").read_text()
    # both shards indexed their runs in the day's one registry: every unit session once
    from gyrocal.calibration import registry

    backend = registry.connect(str(runs / "registry.sqlite"), create=False)
    try:
        rows = backend.execute(
            "SELECT root, device, session, status FROM unit_sessions WHERE path LIKE '%/calibration.json' "
            "ORDER BY device, session"
        ).fetchall()
    finally:
        backend.close()
    assert [(Path(r).parent.name, d, s, st) for r, d, s, st in rows] == [
        ("shard-0001", "A1", "2026-01-01", "calibrated"),
        ("shard-0001", "A1", "2026-03-01", "calibrated"),
        ("shard-0002", "A2", "2026-01-02", "calibrated"),
        ("shard-0002", "GONE", "2026-01-03", "failed"),
    ]
    found = registry_lookup(runs, "A2")
    assert found.path == runs / "shard-0002" / "results" / "B2" / "A2" / "2026-01-02" / "calibration.json"


@pytest.mark.parametrize("flags", [["--configfile=mine.yaml"], ["--configfiles", "a.yaml", "mine.yaml"]])
def test_a_registry_the_users_config_names_is_kept(tmp_path, monkeypatch, flags):
    """The day's registry beside the shards is a default: a config that names one keeps it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.yaml").write_text("spec: {}\n")
    (tmp_path / "mine.yaml").write_text("registry: postgresql://gyrocal@db/calibrations\n")
    shard = ShardRun(tmp_path / "shard-0001.tsv", tmp_path / "shard-0001")
    command = workflow_command(shard, REPO / "Snakefile", None, ["--cores", "1", *flags])
    assert not any(item.startswith("registry=") for item in command)
    plain = workflow_command(shard, REPO / "Snakefile", None, ["--cores", "1"])
    assert f"registry={(tmp_path / 'registry.sqlite').resolve()}" in plain
