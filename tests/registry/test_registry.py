"""The calibration registry: the same lookups as the folder scan, stale rows never served,
one transaction per write, and a schema version it checks."""

from __future__ import annotations

import datetime as dt
import json
import multiprocessing
import re
import shutil
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gyrocal.calibration import registry
from gyrocal.calibration.file import save_calibration
from gyrocal.calibration.lookup import NoCalibrationError, find_calibration
from gyrocal.io.errors import ConfigError, GyrocalError
from gyrocal.io.failure import record
from gyrocal.run.cli import main

from ..calibration.test_lookup import caldir, calibration, put  # noqa: F401 - the scan's own cases

DIRECTIONS = (None, "before", "after")


def answer(root, device, date, direction, max_days, where=None):
    """What a lookup says, as comparable values: the choice, or the error's kind."""
    try:
        r = find_calibration(root, device, date, direction, max_days, registry=where)
    except NoCalibrationError as exc:
        return ("none", str(exc).split(": ")[1].split(":")[0])  # the problem, before the notes
    return (
        r.path,
        r.session,
        r.days_away,
        r.warning,
        r.candidates,
        r.skipped,
        r.calibration.grid.values.tobytes(),
    )


def queries(devices, dates):
    for device in devices:
        for date in (None, *dates):
            for direction in DIRECTIONS if date else (None,):
                yield device, date, direction


def assert_same_answers(root, devices, dates, where, max_days=30):
    scanned = {q: answer(root, *q, max_days) for q in queries(devices, dates)}
    registry.rebuild(root, where)
    for q, expected in scanned.items():
        assert answer(root, *q, max_days, where=where) == expected, q


def test_the_scans_own_cases_answer_alike(caldir, where):  # noqa: F811
    dates = ("2025-01-01", "2026-01-05", "2026-02-20", "2026-04-01", "2026-05-20", "2027-01-01")
    assert_same_answers(caldir, ("U001", "U002", "U404"), dates, where)
    # the registry in the folder is found by itself
    registry.rebuild(caldir)
    assert find_calibration(caldir, "U001").source == "registry"


@st.composite
def fleets(draw):
    """Folders of calibrations as a year of production leaves them: several sessions a unit,
    recalibrations into other batch folders, failures, unreadable files, copies elsewhere."""
    days = st.integers(0, 400)
    units = draw(st.lists(st.sampled_from(["U1", "U2", "U3"]), min_size=1, max_size=8))
    files = []
    for device in units:
        kind = draw(st.sampled_from(["ok", "ok", "ok", "failed", "broken", "copy"]))
        day = dt.date(2026, 1, 1) + dt.timedelta(days=draw(days))
        batch = draw(st.sampled_from(["B1", "B2"]))
        files.append((device, day.isoformat(), batch, kind, draw(st.floats(-1, 1))))
    return files


def write_fleet(root, files):
    for i, (device, session, batch, kind, bias) in enumerate(files):
        if kind == "ok":
            put(root, device, session, batch=batch, bias=bias)
        elif kind == "copy":  # an archived copy outside the layout
            path = root / "archive" / f"{device}-{i}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            save_calibration(calibration(device, session, batch, bias), path)
        else:
            path = root / batch / device / session / "calibration.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            if kind == "failed":
                meta = {"device": device, "batch": batch, "session": session}
                path.write_text(json.dumps(record("fit", ConfigError("the fit failed"), meta)))
            else:
                path.write_text('{"format": "gyrocal.calibration/1", "device": "' + device + '", "ses')


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(files=fleets())
def test_generated_fleets_answer_alike(tmp_path_factory, files):
    root = tmp_path_factory.mktemp("fleet")
    write_fleet(root, files)
    dates = sorted({s for _, s, *_ in files})[:3] + ["2025-12-01", "2027-06-01"]
    assert_same_answers(
        root, ("U1", "U2", "U3"), dates, str(root.parent / f"{root.name}.sqlite"), max_days=45
    )


def test_generated_fleets_answer_alike_on_postgresql(tmp_path_factory, postgres_server):
    """The same on PostgreSQL, for a handful of fleets (a database each)."""
    for seed in range(5):
        files = _fleet_of(seed)
        root = tmp_path_factory.mktemp("fleet")
        write_fleet(root, files)
        dates = sorted({s for _, s, *_ in files})[:3] + ["2025-12-01", "2027-06-01"]
        where = postgres_server.create_database(f"fleet_{seed}_{root.name.lower()}")
        assert_same_answers(root, ("U1", "U2", "U3"), dates, where, max_days=45)


def _fleet_of(seed: int):
    """A fleet drawn with numpy's generator, as fleets() draws them."""
    import numpy as np

    rng = np.random.default_rng(seed)
    kinds = ["ok", "ok", "ok", "failed", "broken", "copy"]
    return [
        (
            str(rng.choice(["U1", "U2", "U3"])),
            (dt.date(2026, 1, 1) + dt.timedelta(days=int(rng.integers(0, 401)))).isoformat(),
            str(rng.choice(["B1", "B2"])),
            str(rng.choice(kinds)),
            float(rng.uniform(-1, 1)),
        )
        for _ in range(int(rng.integers(3, 9)))
    ]


def test_a_session_that_is_not_a_date_is_unreadable_as_in_the_scan(tmp_path, where):
    root = tmp_path / "results"
    put(root, "U5", "2026-02-02")
    odd = put(root, "U5", "2026-03-03")
    doc = json.loads(odd.read_text())
    doc["session"] = "spring"
    odd.write_text(json.dumps(doc))
    assert_same_answers(root, ("U5",), ("2026-03-01",), where)
    assert find_calibration(root, "U5", registry=where).skipped == {"failed_sessions": 0, "unreadable": 1}


def test_a_changed_missing_or_unlisted_file_is_never_served(caldir, where):  # noqa: F811
    registry.rebuild(caldir, where)
    chosen = find_calibration(caldir, "U001", "2026-06-01", registry=where).path
    doc = json.loads(chosen.read_text())
    doc["grid"]["B"][0][0] = doc["grid"]["B"][0][0]  # same values, rewritten: bytes differ
    chosen.write_text(json.dumps(doc))
    with pytest.raises(registry.RegistryError, match="changed since it was registered.*registry check"):
        find_calibration(caldir, "U001", "2026-06-01", registry=where)
    chosen.unlink()
    # gone from the layout: the registry is behind the folder, and the files answer, saying so
    behind = find_calibration(caldir, "U001", "2026-06-01", registry=where)
    assert (behind.source, behind.session) == ("scan", "2026-03-01")
    assert "listed but gone" in behind.note and "registry rebuild" in behind.note
    put(caldir, "U001", "2026-06-02")  # and a new file it does not list yet
    newer = find_calibration(caldir, "U001", "2026-06-01", registry=where)
    assert (newer.source, newer.session) == ("scan", "2026-06-02") and "unlisted" in newer.note
    newer.path.unlink()
    put(caldir, "U009", "2026-07-01")
    problems = registry.check(caldir, where)
    rel = chosen.relative_to(caldir).as_posix()
    assert f"{rel}: listed, but the file is missing" in problems
    assert "B1/U009/2026-07-01/calibration.json: not in the registry" in problems
    registry.rebuild(caldir, where)
    assert registry.check(caldir, where) == []
    assert find_calibration(caldir, "U001", "2026-06-01", registry=where).session == "2026-03-01"


def test_rebuild_gives_the_same_rows_again(caldir, where):  # noqa: F811
    def rows():
        backend = registry.connect(where, create=False)
        try:
            sessions = backend.execute("SELECT * FROM unit_sessions ORDER BY root, path").fetchall()
            params = backend.execute("SELECT * FROM parameters ORDER BY root, path, point, name").fetchall()
        finally:
            backend.close()
        return sessions, params

    registry.rebuild(caldir, where)
    first = rows()
    registry.rebuild(caldir, where)
    assert rows() == first
    sessions, params = first
    statuses = sorted(r[registry.SESSION_COLUMNS.index("status")] for r in sessions)
    # the failed session's record stands in both its calibration and its validation file
    assert statuses == ["calibrated"] * 5 + ["failed"] * 2 + ["unreadable"]
    # 12 coefficients at each of 2 temperature points, for each of the 5 calibrations
    assert len(params) == 5 * 2 * 12


def test_a_write_that_fails_midway_leaves_the_registry_as_it_was(caldir, where):  # noqa: F811
    registry.rebuild(caldir, where)
    backend = registry.connect(where)
    before = backend.execute("SELECT COUNT(*) FROM unit_sessions").fetchone()
    rows = registry.rows_of(caldir)
    broken = [*rows[:2], registry.Row({**rows[2].session, "status": None})]  # NOT NULL fails
    with pytest.raises(Exception, match="(?i)not.null"):
        registry.upsert(backend, broken, replace_under=registry.root_of(caldir))
    assert backend.execute("SELECT COUNT(*) FROM unit_sessions").fetchone() == before
    backend.close()


def set_schema_version(where: str, version: str) -> None:
    """The registry's schema version made ``version``, as another gyrocal would leave it."""
    backend = registry.connect(where)
    with backend.transaction():
        backend.execute("UPDATE registry_meta SET value = ? WHERE key = 'schema_version'", (version,))
    backend.close()


def test_an_older_schema_is_refused_with_the_command_that_makes_it_again(caldir, where):  # noqa: F811
    registry.rebuild(caldir, where)
    set_schema_version(where, "0")
    with pytest.raises(registry.RegistryError, match="schema version 0, this gyrocal reads 2.*--fresh"):
        find_calibration(caldir, "U001", registry=where)
    with pytest.raises(registry.RegistryError, match="schema version 0"):
        registry.rebuild(caldir, where)
    registry.rebuild(caldir, where, fresh=True)
    assert find_calibration(caldir, "U001", registry=where).session == "2026-06-05"


def replace_tables(where: str, statements: list[str]) -> None:
    """The registry's database made to hold ``statements``' tables alone, outside gyrocal."""
    connection = raw_connection(where)
    for statement in [*(f"DROP TABLE IF EXISTS {t}" for t in registry.TABLES), *statements]:
        connection.execute(statement)
    connection.commit()
    connection.close()


def test_an_older_layout_is_refused_then_replaced_when_asked(caldir, where):  # noqa: F811
    """A registry as an older gyrocal laid it out (other columns, schema version 0) is
    refused, not read, by a lookup, a rebuild and a writer; ``--fresh`` replaces it."""
    replace_tables(
        where,
        [
            "CREATE TABLE registry_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
            "INSERT INTO registry_meta VALUES ('schema_version', '0')",
            "CREATE TABLE unit_sessions (path TEXT PRIMARY KEY, device TEXT, session TEXT, sha256 TEXT)",
            "INSERT INTO unit_sessions VALUES ('U001/2026-06-05/calibration.json', 'U001', '2026-06-05', 'ab')",
        ],
    )
    for attempt in (
        lambda: find_calibration(caldir, "U001", registry=where),
        lambda: registry.rebuild(caldir, where),
        lambda: registry.connect(where),
    ):
        with pytest.raises(registry.RegistryError, match="schema version 0, this gyrocal reads 2.*--fresh"):
            attempt()
    registry.rebuild(caldir, where, fresh=True)
    assert find_calibration(caldir, "U001", registry=where).session == "2026-06-05"


@pytest.mark.parametrize("table", ["parameters", "registry_meta"])
def test_another_programs_tables_of_the_same_names_are_never_written_nor_dropped(caldir, where, table):  # noqa: F811
    """Tables named as the registry's without its schema version (a factory's own
    ``parameters``, or a ``registry_meta`` of another program): every reader and writer
    refuses in one line, ``--fresh`` too, and the table and its rows stay as they were."""
    replace_tables(
        where,
        [
            f"CREATE TABLE {table} (id INTEGER PRIMARY KEY, what TEXT)",
            f"INSERT INTO {table} VALUES (1, 'x')",
        ],
    )
    for attempt in (
        lambda: find_calibration(caldir, "U001", registry=where),
        lambda: registry.rebuild(caldir, where),
        lambda: registry.rebuild(caldir, where, fresh=True),
        lambda: registry.connect(where),
        lambda: registry.planned_history(caldir, where, {"U001"}, set()),
        lambda: registry.plan_history(caldir, where, {"U001"}, set()),  # not a warning: it stops
    ):
        with pytest.raises(registry.RegistryError, match="not a registry gyrocal wrote, and left as it is"):
            attempt()
    connection = raw_connection(where)
    assert connection.execute(f"SELECT id, what FROM {table}").fetchall() == [(1, "x")]
    connection.close()


def test_a_fleets_plan_reads_the_devices_earlier_calibrated_sessions_of_its_folder(
    caldir,  # noqa: F811
    where,
    tmp_path,
    monkeypatch,
):
    """What planning a fleet takes from the registry for its drift pages: each calibrated
    session of the run's devices in its results folder but its own, once, by device and
    date (failures and unreadable files not); nothing where there is no registry yet, where
    the run keeps none, or for another folder sharing the registry. Asked a device at a time
    (the bound on a statement's parameters), the same rows."""
    own = {("U001", "2026-06-05")}
    assert registry.planned_history(caldir, where, {"U001"}, own) == []  # no registry yet
    registry.rebuild(caldir, where)
    assert registry.planned_history(caldir, "", {"U001"}, own) == []
    rows = registry.planned_history(caldir, where, {"U001", "U002", "U404"}, own)
    assert [(r["device"], r["session"], r["path"]) for r in rows] == [
        ("U001", "2025-11-20", "archive/U001-first.json"),
        ("U001", "2026-01-05", "B1/U001/2026-01-05/calibration.json"),
        ("U001", "2026-03-01", "B1/U001/2026-03-01/calibration.json"),
        ("U002", "2026-02-20", "B1/U002/2026-02-20/calibration.json"),
    ]
    monkeypatch.setattr(registry, "DEVICES_PER_QUERY", 1)
    assert registry.planned_history(caldir, where, {"U001", "U002", "U404"}, own) == rows
    other = shutil.copytree(caldir, tmp_path / "other")
    registry.rebuild(other, where)  # the registry shared: the other folder lends no session
    assert registry.planned_history(caldir, where, {"U001", "U002"}, own) == rows


def test_the_plan_records_the_history_it_read_and_rewrites_it_only_when_it_changes(caldir, where):  # noqa: F811
    """The plan's record (results/drift_history.jsonl): what the registry said, the same
    bytes and time stamp when it says it again (the fleet job is not made again), new bytes
    when a session's file changed; a scheduler's job reads it without asking the registry;
    a record not of this form is one line naming it."""
    record = caldir / registry.HISTORY_NAME
    own = {("U001", "2026-06-05")}
    assert registry.plan_history(caldir, where, {"U001"}, own) == [] and record.read_text() == ""
    registry.rebuild(caldir, where)
    planned = registry.plan_history(caldir, where, {"U001"}, own)
    assert [r["session"] for r in planned] == ["2025-11-20", "2026-01-05", "2026-03-01"]
    assert set(planned[0]) == set(registry.HISTORY_FIELDS)
    stamp, text = record.stat().st_mtime_ns, record.read_text()
    assert registry.plan_history(caldir, where, {"U001"}, own) == planned
    assert (record.stat().st_mtime_ns, record.read_text()) == (stamp, text)
    assert (
        registry.plan_history(caldir, "postgresql://nobody@127.0.0.1:1/x", {"U001"}, own, query=False)
        == planned
    )
    earlier = caldir / "B1" / "U001" / "2026-01-05" / "calibration.json"
    earlier.write_text(json.dumps(json.loads(earlier.read_text()), indent=1))
    registry.rebuild(caldir, where)
    assert registry.plan_history(caldir, where, {"U001"}, own) != planned and record.read_text() != text
    record.write_text('{"device": "U001"}\n')
    with pytest.raises(GyrocalError, match=r"drift_history.jsonl: line 1 is not a session"):
        registry.read_history(record)


def raw_connection(where: str):
    """A plain DB-API connection to the registry's database, outside gyrocal."""
    if where.startswith("postgresql://"):
        import psycopg

        return psycopg.connect(where)
    import sqlite3

    return sqlite3.connect(where)


def _write(args):
    where, root, only, seed = args
    backend = registry.connect(where)
    try:
        for _ in range(5):
            registry.upsert(backend, registry.rows_of(root, only))
    finally:
        backend.close()
    return seed


def test_writers_at_once_lose_and_duplicate_nothing(tmp_path, where):
    """Four processes upserting their own unit sessions and one shared one, five times each."""
    root = tmp_path / "results"
    folders = []
    for i in range(4):
        for j in range(3):
            folders.append(put(root, f"U{i}{j}", "2026-03-01").parent.relative_to(root).as_posix())
    shared = put(root, "U99", "2026-03-02").parent.relative_to(root).as_posix()
    registry.connect(where).close()
    jobs = [(where, root, [*folders[3 * i : 3 * i + 3], shared], i) for i in range(4)]
    with multiprocessing.get_context("spawn").Pool(4) as pool:
        assert sorted(pool.map(_write, jobs)) == [0, 1, 2, 3]
    backend = registry.connect(where)
    paths = [r[0] for r in backend.execute("SELECT path FROM unit_sessions ORDER BY path").fetchall()]
    count = backend.execute("SELECT COUNT(*) FROM parameters").fetchone()[0]
    backend.close()
    assert len(paths) == len(set(paths)) == 13
    assert count == 13 * 2 * 12
    assert registry.check(root, where) == []


def test_the_command_line(caldir, capsys):  # noqa: F811
    assert main(["lookup", str(caldir), "U001", "--date", "2026-02-20"]) == 0
    assert "has no registry, so every file was read" in capsys.readouterr().err
    assert main(["registry", "rebuild", str(caldir)]) == 0
    assert "8 files indexed" in capsys.readouterr().out
    assert main(["lookup", str(caldir), "U001", "--date", "2026-02-20", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["session"] == "2026-03-01" and err == ""
    assert main(["registry", "check", str(caldir)]) == 0
    shutil.rmtree(caldir / "B1" / "U002")
    assert main(["registry", "check", str(caldir)]) == 1
    out, err = capsys.readouterr()
    assert "B1/U002/2026-02-20/calibration.json: listed, but the file is missing" in err
    assert "1 stale rows or files" in out


def test_no_registry_where_one_is_named(tmp_path):
    (tmp_path / "results").mkdir()
    with pytest.raises(GyrocalError, match="no registry here: gyrocal registry rebuild"):
        find_calibration(tmp_path / "results", "U1", registry=str(tmp_path / "absent.sqlite"))


def test_export_by_device_takes_the_calibration_lookup_finds(caldir, tmp_path, capsys):  # noqa: F811
    registry.rebuild(caldir)
    out = tmp_path / "u001.json"
    assert main(["export", str(caldir), "--device", "U001", "--date", "2026-02-20", "-o", str(out)]) == 0
    chosen = find_calibration(caldir, "U001", "2026-02-20").path
    direct = tmp_path / "direct.json"
    assert main(["export", str(chosen), "-o", str(direct)]) == 0
    assert json.loads(out.read_text())["source"] == json.loads(direct.read_text())["source"]
    assert main(["export", str(chosen), "--date", "2026-02-20", "-o", str(direct)]) == 2
    assert "give --device too" in capsys.readouterr().err


def test_drift_of_a_batch_per_month_and_of_a_device_per_session(tmp_path, where, capsys):
    """Biases put in by hand come back per month (their mean and spread) and per session."""
    root = tmp_path / "results"
    biases = {("U1", "2026-01-10"): 0.1, ("U2", "2026-01-20"): 0.3, ("U1", "2026-02-10"): 0.5}
    for (device, session), bias in biases.items():
        put(root, device, session, batch="B7", bias=bias)
    put(root, "U3", "2026-01-15", batch="B8", bias=9.0)  # another batch: not in B7's drift
    registry.rebuild(root, where)
    backend = registry.connect(where, create=False)
    try:
        rows = registry.drift(backend, batch="B7", names=("bias.x",), temperature=0.0)
        device = registry.drift(backend, device="U1", names=("bias",), temperature=40.0)
    finally:
        backend.close()
    months = registry.monthly(rows)
    assert [(m["month"], m["calibrations"]) for m in months] == [("2026-01", 2), ("2026-02", 1)]
    assert months[0]["mean"] == pytest.approx(0.2) and months[0]["std"] == pytest.approx(
        np.std([0.1, 0.3], ddof=1)
    )
    assert [
        (r["session"], r["name"], r["value"], r["temperature"]) for r in device if r["name"] == "bias.x"
    ] == [
        ("2026-01-10", "bias.x", 0.1, 40.0),
        ("2026-02-10", "bias.x", 0.5, 40.0),
    ]
    assert (
        main(
            [
                "drift",
                str(root),
                "--batch",
                "B7",
                "--name",
                "bias.x",
                "--temperature",
                "0",
                "--registry",
                where,
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "2026-01  bias.x" in out and "2026-02  bias.x" in out
    assert main(["drift", str(root), "--batch", "B9", "--registry", where]) == 2
    assert "no calibration of batch B9" in capsys.readouterr().err


KILLED_WRITER = """
import sys, time
from pathlib import Path
from gyrocal.calibration import registry
backend = registry.connect(sys.argv[1])
rows = registry.rows_of(Path(sys.argv[2]))
with backend.transaction():
    backend.serialise()
    backend.execute("DELETE FROM unit_sessions")
    backend.executemany(registry._UPSERT, [[r.session[c] for c in registry.SESSION_COLUMNS] for r in rows])
    print("written, not committed", flush=True)
    time.sleep(120)
"""


def test_a_writer_killed_inside_its_transaction_leaves_nothing_of_it(caldir, where, tmp_path):  # noqa: F811
    """The fleet job writes in one transaction: killed (SIGKILL) before it commits, the
    registry is as it was, and the next writer is not kept waiting by it."""
    registry.rebuild(caldir, where)

    def contents():
        backend = registry.connect(where, create=False)
        try:
            return backend.execute("SELECT * FROM unit_sessions ORDER BY root, path").fetchall()
        finally:
            backend.close()

    before = contents()
    other = tmp_path / "other"
    put(other, "U77", "2026-09-09")
    writer = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, where, str(other)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert writer.stdout.readline().strip() == "written, not committed"
    finally:
        writer.kill()
        writer.wait()
    assert contents() == before
    registry.rebuild(other, where)  # the lock went with the process
    assert len(contents()) == len(before) + 1


def documented_queries() -> list[str]:
    """The SQL docs/fleet-table.md gives a factory, statement by statement."""
    from pathlib import Path

    page = (Path(__file__).resolve().parents[2] / "docs" / "fleet-table.md").read_text()
    page = page[page.index("## The registry") :]  # the fleet table's own queries come before
    blocks = re.findall(r"```sql\n(.*?)```", page, flags=re.S)
    text = "\n".join(line for block in blocks for line in block.splitlines() if not line.startswith("--"))
    return [q.strip() for q in text.split(";") if q.strip()]


def test_the_documented_queries_run_and_answer(tmp_path, where):
    """The three queries of docs/fleet-table.md on a registry whose answers are known: points
    at measured temperatures (24.7 and 40.2 °C; one unit's at 20 and 30, as near), one unit
    its diagnosis does not explain."""
    root = tmp_path / "results"
    units = (
        ("U001", "2026-04-20", 0.1, 1.1, [24.7, 40.2]),
        ("U001", "2026-05-03", 0.2, 1.0, [24.7, 40.2]),
        ("U002", "2026-04-02", 0.3, 2.4, [24.7, 40.2]),
        ("U003", "2026-05-10", 0.4, 1.0, [20.0, 30.0]),  # two points as near: counted once
    )
    for device, session, bias, excess, temperatures in units:
        path = root / "B7" / device / session / "calibration.json"
        path.parent.mkdir(parents=True)
        cal = calibration(device, session, "B7", bias)
        save_calibration(replace(cal, grid=replace(cal.grid, temperatures=np.array(temperatures))), path)
        summary = {"validation_rms": 0.002 * excess, "noise_floor": 0.002, "excess": excess}
        (path.parent / "validation.json").write_text(json.dumps({"summary": summary}))
    registry.rebuild(root, where)
    queries = documented_queries()
    assert len(queries) == 3
    backend = registry.connect(where, create=False)
    try:
        # the queries name U001 at 2026-05-01 and batch B7, with literals as a factory's tools would
        serial, drift, unexplained = (backend.connection.execute(q).fetchall() for q in queries)
    finally:
        backend.close()
    assert serial == [(f"{registry.root_of(root)}/B7/U001/2026-04-20/calibration.json", "2026-04-20")]
    assert [(m, n, round(b, 12), u) for m, n, b, u in drift if n == "bias.x"] == [
        ("2026-04", "bias.x", round((0.1 + 0.3) / 2, 12), 2),
        ("2026-05", "bias.x", round((0.2 + 0.4) / 2, 12), 2),
    ]
    assert [(d, s, e) for d, s, e, _ in unexplained] == [("U002", "2026-04-02", 2.4)]


def test_a_device_the_registry_lacks_is_named_with_its_neighbours(caldir, where):  # noqa: F811
    registry.rebuild(caldir, where)
    with pytest.raises(
        NoCalibrationError, match=r"U000 in this folder: searched the registry .*from there on: U001, U002"
    ):
        find_calibration(caldir, "U000", registry=where)


def test_a_shared_registry_answers_for_the_folder_asked_about(tmp_path, where):
    """Two results folders in one registry: each lookup chooses among its own folder's files
    (and those of folders below it, a day's shards), as the scan of that folder does."""
    day = tmp_path / "day"
    put(day / "res", "U1", "2026-01-01")
    put(day / "res-a", "U1", "2026-05-01")
    for root in (day / "res", day / "res-a"):
        registry.rebuild(root, where)
    for folder in (day / "res", day / "res-a", day):
        for date in ("2026-01-01", "2026-03-02", "2026-06-01"):
            indexed, scanned = (
                find_calibration(folder, "U1", date, registry=where),
                find_calibration(folder, "U1", date),
            )
            assert indexed.source == "registry" and (indexed.path, indexed.session) == (
                scanned.path,
                scanned.session,
            )


def count_rows(where: str) -> int:
    backend = registry.connect(where, create=False)
    try:
        return backend.execute("SELECT COUNT(*) FROM unit_sessions").fetchone()[0]
    finally:
        backend.close()


def test_a_days_shards_in_one_registry_are_read_checked_and_rebuilt_from_their_parent(tmp_path, where):
    """A day's shards (RUNS/shard-N/results), each indexed by its own fleet job: a lookup
    from RUNS or from a batch folder inside a shard chooses as the scan does; a session a
    shard wrote but did not yet index is noticed (the files answer, saying so); check from
    RUNS finds an up-to-date registry true; a rebuild from RUNS lists each file once, keyed
    as its fleet job keyed it, so the drift counts each calibration once."""
    runs = tmp_path / "runs"
    one, two = runs / "shard-0001" / "results", runs / "shard-0002" / "results"
    put(one, "U1", "2026-01-01")
    put(two, "U2", "2026-01-01")
    for results in (one, two):  # as the fleet jobs write them
        backend = registry.connect(where)
        registry.upsert(backend, registry.rows_of(results, ["B1/U1/2026-01-01", "B1/U2/2026-01-01"]))
        backend.close()
    assert registry.check(runs, where) == [] and count_rows(where) == 2
    for folder, device in ((runs, "U1"), (runs, "U2"), (one / "B1", "U1"), (two / "B1" / "U2", "U2")):
        indexed, scanned = find_calibration(folder, device, registry=where), find_calibration(folder, device)
        assert (indexed.source, indexed.path, indexed.session) == ("registry", scanned.path, scanned.session)
    put(two, "U1", "2026-02-01")  # shard 2 calibrated U1 again; its fleet job has not run
    behind = find_calibration(runs, "U1", registry=where)
    assert (behind.source, behind.session) == ("scan", "2026-02-01")
    assert "shard-0002/results/B1/U1/2026-02-01/calibration.json unlisted" in behind.note
    assert registry.check(runs, where) == [
        "shard-0002/results/B1/U1/2026-02-01/calibration.json: not in the registry"
    ]
    registry.rebuild(runs, where)
    assert registry.check(runs, where) == [] and count_rows(where) == 3
    backend = registry.connect(where, create=False)
    keys = backend.execute("SELECT root, path FROM unit_sessions ORDER BY root, path").fetchall()
    drift = registry.drift(
        backend, device="U1", temperature=0.0, names=("bias.x",), folder=registry.root_of(runs)
    )
    backend.close()
    assert keys == [
        (registry.root_of(one), "B1/U1/2026-01-01/calibration.json"),
        (registry.root_of(two), "B1/U1/2026-02-01/calibration.json"),
        (registry.root_of(two), "B1/U2/2026-01-01/calibration.json"),
    ]
    assert [r["session"] for r in drift] == ["2026-01-01", "2026-02-01"]
    assert find_calibration(runs, "U1", registry=where).source == "registry"


def test_a_unit_folder_is_listed_once_whoever_indexed_it_and_as_it_is_now(tmp_path, where):
    """A unit that failed (its failure records), indexed by a rebuild from a batch's folder
    and from the day's parent, then recalibrated and indexed by its fleet job: each file
    listed once, under the fleet job's key, and the old failure records no longer listed,
    so the lookup's counts are the scan's."""
    results = tmp_path / "day" / "results"
    folder = results / "B1" / "U1" / "2026-01-02"
    folder.mkdir(parents=True)
    rec = record(
        "fit", ConfigError("the fit failed"), {"device": "U1", "batch": "B1", "session": "2026-01-02"}
    )
    for name in ("calibration.json", "validation.json"):
        (folder / name).write_text(json.dumps(rec))
    put(results, "U1", "2026-01-01")
    for start in (results / "B1", tmp_path / "day", results):
        registry.rebuild(start, where)
        assert count_rows(where) == 3 and registry.check(results, where) == []
    save_calibration(calibration("U1", "2026-01-02"), folder / "calibration.json")
    (folder / "validation.json").write_text('{"summary": {}}')
    backend = registry.connect(where)
    unit = [("" + str(results), "B1/U1/2026-01-02")]
    registry.upsert(backend, registry.rows_of(results, ["B1/U1/2026-01-02"]), unit_folders=unit)
    backend.close()
    assert count_rows(where) == 2 and registry.check(results, where) == []
    indexed, scanned = find_calibration(results, "U1", registry=where), find_calibration(results, "U1")
    assert indexed.source == "registry" and (indexed.session, indexed.skipped) == (
        scanned.session,
        scanned.skipped,
    )
    assert indexed.skipped == {"failed_sessions": 0, "unreadable": 0}


def test_a_file_of_another_device_or_an_empty_one_in_a_devices_folder_is_no_reason_to_scan(caldir, where):  # noqa: F811
    """A calibration file of another device, and an empty file, in U001's folders: each is
    listed by its own row, so the registry is up to date and answers."""
    stray = caldir / "B1" / "U001" / "2026-07-01" / "calibration.json"
    stray.parent.mkdir(parents=True)
    stray.write_bytes((caldir / "B1" / "U002" / "2026-02-20" / "calibration.json").read_bytes())
    empty = caldir / "B1" / "U001" / "2026-08-01" / "calibration.json"
    empty.parent.mkdir(parents=True)
    empty.write_text("")
    registry.rebuild(caldir, where)
    assert registry.check(caldir, where) == []
    indexed, scanned = find_calibration(caldir, "U001", registry=where), find_calibration(caldir, "U001")
    assert (indexed.source, indexed.note, indexed.path) == ("registry", None, scanned.path)


def test_names_that_differ_in_case_and_punctuation_sort_alike_on_both_back_ends(tmp_path, where):
    """Byte order on both back ends, whatever the database's language: a misspelt device's
    neighbours, and which of two copies of a session a drift page takes (the first path)."""
    results = tmp_path / "results"
    for device in ("A1", "a-1", "A2", "a1x"):
        put(results, device, "2026-01-01")
    put(results, "A1", "2026-02-01", batch="B2")
    put(results, "A1", "2026-02-01", batch="b1")
    registry.rebuild(results, where)
    backend = registry.connect(where, create=False)
    try:
        near = registry.devices_near(backend, "A")
        earlier = registry.earlier_rows(backend, {"A1"}, set(), results)
    finally:
        backend.close()
    assert near == ["A1", "A2", "a-1", "a1x"]  # byte order: upper case first
    assert [(r["session"], r["path"]) for r in earlier] == [
        ("2026-01-01", "B1/A1/2026-01-01/calibration.json"),
        ("2026-02-01", "B2/A1/2026-02-01/calibration.json"),
    ]


def test_a_user_who_may_not_read_the_registry_is_told_so_not_that_there_is_none(caldir, postgres_server):  # noqa: F811
    """A PostgreSQL role without SELECT on the registry's tables: one line saying so, from a
    lookup and from a fleet's plan, never "no registry here" (which a plan takes as no
    history)."""
    import psycopg

    where = postgres_server.create_database("registry_rights")
    registry.rebuild(caldir, where)
    with psycopg.connect(where, autocommit=True) as conn:
        conn.execute("CREATE ROLE outsider LOGIN")
    outsider = where.replace("//gyrocal@", "//outsider@")
    for attempt in (
        lambda: find_calibration(caldir, "U001", registry=outsider),
        lambda: registry.planned_history(caldir, outsider, {"U001"}, set()),
    ):
        with pytest.raises(registry.RegistryError, match="permission denied.*may not do this"):
            attempt()


def test_a_calibration_with_two_points_as_near_counts_once_in_the_drift(tmp_path, where):
    """Points at 0 and 40 °C, drift asked at 20: the first point, once per coefficient, so
    the monthly figures count the calibration once."""
    put(tmp_path / "results", "U1", "2026-01-01", bias=0.5)
    registry.rebuild(tmp_path / "results", where)
    backend = registry.connect(where, create=False)
    try:
        rows = registry.drift(backend, device="U1", temperature=20.0, within=25.0, names=("bias.x",))
    finally:
        backend.close()
    assert [(r["temperature"], r["value"]) for r in rows] == [(0.0, 0.5)]
    assert registry.monthly(rows)[0]["calibrations"] == 1


def test_several_processes_opening_one_new_registry_at_once_make_it_once(tmp_path):
    """Six processes open the same new SQLite registry at the same moment, thirty times over:
    each opens it (taking turns to switch it to WAL and to make the tables), none fails."""
    script = (
        "import sys, time; from gyrocal.calibration import registry\n"
        "start = float(sys.argv[2])\n"
        "for i in range(30):\n"
        "    time.sleep(max(0.0, start + 0.1 * i - time.time()))  # all at once, each time\n"
        "    registry.connect(f'{sys.argv[1]}/r{i}.sqlite').close()\n"
    )
    start = str(time.time() + 3)  # once the six interpreters have started
    procs = [
        subprocess.Popen([sys.executable, "-c", script, str(tmp_path), start], stderr=subprocess.PIPE)
        for _ in range(6)
    ]
    errors = [p.communicate(timeout=300)[1].decode() for p in procs]
    assert [p.returncode for p in procs] == [0] * 6, errors


def test_a_newer_schema_asks_for_a_newer_gyrocal_and_a_corrupt_file_is_one_line(caldir, where):  # noqa: F811
    registry.rebuild(caldir, where)
    set_schema_version(where, "3")
    with pytest.raises(
        registry.RegistryError, match="schema version 3, this gyrocal reads 2: a newer gyrocal"
    ):
        find_calibration(caldir, "U001", registry=where)
    junk = caldir / "junk.sqlite"
    junk.write_bytes(b"not a database, though named like one" * 100)
    with pytest.raises(registry.RegistryError, match=r"junk.sqlite: .*registry rebuild") as err:
        find_calibration(caldir, "U001", registry=str(junk))
    assert "\n" not in str(err.value)


def test_a_reader_does_not_wait_for_a_writer(tmp_path):
    """A lookup reads while a fleet job holds the writers' turn (SQLite's WAL)."""
    root = tmp_path / "results"
    put(root, "U1", "2026-01-01")
    where = str(root / registry.DEFAULT_NAME)
    registry.rebuild(root, where)
    writer = registry.connect(where)
    with writer.transaction():
        writer.serialise()
        writer.execute("DELETE FROM parameters")
        start = dt.datetime.now()
        assert find_calibration(root, "U1").source == "registry"
        assert (dt.datetime.now() - start).total_seconds() < 60  # a writer is waited for up to 600 s
    writer.close()


def test_a_password_never_shows_in_a_message():
    for url in (
        "postgresql://gyrocal:s3cr@t@db.line3/calibrations",
        "postgresql://gyrocal@db.line3/calibrations?sslmode=require&password=s3cr@t",
    ):
        assert "s3cr" not in registry.shown(url) and "db.line3" in registry.shown(url)


def test_a_fleet_job_whose_registry_is_out_of_reach_still_writes_its_summary(tmp_path, capsys):
    """The registry lost at the fleet job: the summary, its table and its drift pages are
    written all the same, and the page and the job's log say the run is not indexed and how
    to index it later; the password stays out of both."""
    from gyrocal.fleet.summary import FleetSettings
    from gyrocal.run.stages import fleet_stage

    results, reports = tmp_path / "results", tmp_path / "reports"
    put(results, "U1", "2026-01-01")
    row = {"batch": "B1", "device": "U1", "session": "2026-01-01", "protocol": "turntable", "path": "x"}
    lost = "postgresql://line3:secret@127.0.0.1:1/calibrations"
    fleet_stage([row], results, reports, reports / "index.html", settings=FleetSettings(), registry=lost)
    page = (reports / "index.html").read_text()
    said = capsys.readouterr().err
    assert "did not index this run" in page and "gyrocal registry rebuild RESULTS" in page
    assert "line3:***@127.0.0.1:1/calibrations: cannot connect" in page
    assert "gyrocal: warning: the run is not indexed: postgresql://line3:***@" in said
    assert "secret" not in page + said
