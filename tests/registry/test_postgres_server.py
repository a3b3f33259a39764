"""The PostgreSQL server the registry's tests run against (tests/pg.py): it is a real one,
run by an unprivileged user, two transactions write at once and one waits on the other's
lock, and a server stopped leaves no process and no folder behind."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from .. import pg
from .conftest import needs_postgres

pytestmark = needs_postgres


@pytest.fixture
def table(postgres_url):
    """A table of this test's in the session's database, dropped afterwards."""
    import psycopg

    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("CREATE TABLE smoke (key integer PRIMARY KEY, writer text NOT NULL)")
    yield "smoke"
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("DROP TABLE smoke")


def uid_of(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(next(line for line in status.splitlines() if line.startswith("Uid:")).split()[1])


def test_the_server_is_the_installed_one_run_by_its_user(postgres_server, postgres_url, record_property):
    """The URL the registry is given; the server is the machine's PostgreSQL (its version in
    the test report's properties and pytest's header), never run as root."""
    import psycopg

    assert postgres_url == f"postgresql://gyrocal@127.0.0.1:{postgres_server.port}/gyrocal"
    with psycopg.connect(postgres_url) as conn:
        user, database, encoding, version = conn.execute(
            "SELECT current_user, current_database(), pg_encoding_to_char(encoding), version()"
            " FROM pg_database WHERE datname = current_database()"
        ).fetchone()
    record_property("postgresql", version)
    assert (user, database, encoding) == ("gyrocal", "gyrocal", "UTF8")
    assert pg.installed_version().split()[2] in version
    assert uid_of(postgres_server.pid) != 0


def test_two_transactions_write_at_once(postgres_url, table):
    """Each sees its own rows, not the other's, until it commits; then a third sees all.
    A key the other holds uncommitted waits on its lock and fails once that one commits."""
    import psycopg

    with (
        psycopg.connect(postgres_url) as a,
        psycopg.connect(postgres_url) as b,
        psycopg.connect(postgres_url, autocommit=True) as reader,
    ):
        for key in range(3):
            a.execute("INSERT INTO smoke VALUES (%s, 'a')", (key,))
            b.execute("INSERT INTO smoke VALUES (%s, 'b')", (key + 10,))
        assert a.execute("SELECT count(*) FROM smoke").fetchone()[0] == 3
        assert b.execute("SELECT count(*) FROM smoke WHERE writer = 'a'").fetchone()[0] == 0
        assert reader.execute("SELECT count(*) FROM smoke").fetchone()[0] == 0
        a.commit()
        b.commit()
        rows = reader.execute("SELECT writer, count(*) FROM smoke GROUP BY writer ORDER BY writer").fetchall()
        assert rows == [("a", 3), ("b", 3)]

        a.execute("INSERT INTO smoke VALUES (100, 'a')")
        b_pid = b.info.backend_pid
        failed: list[BaseException] = []

        def b_writes_the_same_key():
            try:
                b.execute("INSERT INTO smoke VALUES (100, 'b')")
            except psycopg.errors.UniqueViolation as error:
                failed.append(error)
                b.rollback()

        writer = threading.Thread(target=b_writes_the_same_key)
        writer.start()
        deadline = time.monotonic() + 20
        while reader.execute(
            "SELECT wait_event_type IS DISTINCT FROM 'Lock' FROM pg_stat_activity WHERE pid = %s", (b_pid,)
        ).fetchone()[0]:
            assert time.monotonic() < deadline, "the second writer never waited on the first's lock"
            time.sleep(0.02)
        a.commit()
        writer.join(20)
        assert not writer.is_alive() and len(failed) == 1
        assert reader.execute("SELECT writer FROM smoke WHERE key = 100").fetchall() == [("a",)]


def test_a_stopped_server_leaves_no_process_and_no_folder():
    """Stopped by its process id while a client still holds a transaction open (fast
    shutdown ends it): the postmaster, its backends and workers, and its folder are gone."""
    import psycopg

    with pg.Server() as server:
        pid, root = server.pid, server.root
        client = psycopg.connect(server.url())
        client.execute("SELECT 1")  # and the transaction it began stays open
        children = pg.children_of(pid)
        assert len(children) >= 3 and (root / "data" / "PG_VERSION").exists()
    client.close()
    assert not root.exists()
    assert not [p for p in (pid, *children) if cmdline(p).startswith(("postgres", str(server.bin)))]
    assert not [p for p in all_pids() if str(root) in cmdline(p)]


def test_a_server_that_cannot_start_says_why():
    """The server's own words from its log, and nothing left behind."""
    server = pg.Server("shared_buffers=nonsense")
    with pytest.raises(RuntimeError, match='invalid value for parameter "shared_buffers"'):
        server.start()
    assert server.pid is None and not server.root.exists()


def all_pids() -> list[int]:
    return [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and int(p.name) != os.getpid()]


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def test_a_server_whose_test_process_is_killed_outright_is_stopped_by_its_watchdog():
    """A test process SIGKILLed (as a scheduler ends a job) cannot stop its server: the
    watchdog it started sees the pipe close and stops the postmaster and its backends, and
    removes the folder."""
    import signal
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[2]
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from tests import pg; s = pg.Server().start(); "
            "print(s.pid, s.root, flush=True); time.sleep(600)",
        ],
        cwd=repo,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        pid, root = child.stdout.readline().split()
        pid, root = int(pid), Path(root)
        children = pg.children_of(pid)
        assert children and (root / "data" / "PG_VERSION").exists()
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    deadline = time.monotonic() + 60
    server = ("postgres", str(pg.bin_dir()))
    while [p for p in (pid, *children) if cmdline(p).startswith(server)] or root.exists():
        assert time.monotonic() < deadline, "the server outlived its test process"
        time.sleep(0.1)
