"""Benchmark: the calibration registry at a year's size (100,000 unit sessions a day).

A synthetic year is written straight into the registry's tables (rows, not files: bulk
inserts in one transaction, SQLite's journal off; COPY for PostgreSQL, into tables made in
the same transaction so that ``wal_level=minimal`` skips the WAL), then indexed with the
registry's own schema (:func:`gyrocal.calibration.registry.schema`). The year:

* devices ``G26-00000000`` ...: 2,000 to a production batch (``B26-0000`` ...), each
  calibrated 1 to 5 times (uniform, mean 3) at even spacing from a random day, so that the
  sessions spread over the 365 days ending 2026-11-30 and every batch's over the year;
* 2 % of the sessions failed (a failure record's row), the rest calibrated, with
  validation and diagnosis figures;
* ``parameters`` for one batch in ``--parameters-every`` (100: 1 %, the drift query's batch
  among them), 5 temperature points x 12 coefficients per calibrated session. The full
  table (2.1 G rows; at the 360 bytes a row PostgreSQL takes here with its index, some
  0.7 TB) does not fit the disk; a batch's drift query reads its own rows through the
  indexes, so its cost is the batch's row count times the B-trees' depth (one level more
  at full size), which the subset keeps.

Measured, on each back end: 20 lookups of random devices at random dates (the query:
``registry.device_rows`` and ``lookup._choose`` on an open connection, with the registry's
pages warm and with them evicted from the page cache first), the whole ``python -m gyrocal
lookup`` process on the same devices (their rows made to point at real small calibration
files with their real BLAKE3), one lookup of an unknown device (the process), the drift of
the middle batch per month (as ``gyrocal drift --batch B --name bias`` computes it, and by
the docs' query; 3 times each, the first with pages evicted), and a
day's 100,000 sessions with their parameters written as the fleet job writes them
(``registry.upsert`` of ``registry.Row``, 50 jobs of 2,000), then removed again.

The registries are built under ``$GYROCAL_BENCH_CACHE/registry`` (else
``~/.cache/gyrocal/benchmarks/registry``) and removed at the end unless ``--keep [DIR]``
(then built there and kept, so a rerun skips generation). PostgreSQL runs as a throwaway
server (``tests/pg.py``) on a cluster in that folder, or, when root runs the benchmark and
the server's user cannot reach the folder, in the system's temporary folder.

    python benchmarks/registry.py [--sessions 36500000] [--backend sqlite,postgresql] [--keep [DIR]]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import random
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from host import cores, cpu_name

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from gyrocal.calibration import lookup, registry  # noqa: E402

CACHE = (
    Path(os.environ.get("GYROCAL_BENCH_CACHE", Path.home() / ".cache" / "gyrocal" / "benchmarks"))
    / "registry"
)
GENERATOR = 1  # bump when the synthetic year changes: a cached registry of another is made again
UNITS = 2000  # a production batch
FIRST = dt.date(2025, 12, 1)
DAYS = 365
# the year and the days after it (a small registry's ingest takes several)
DATES = [(FIRST + dt.timedelta(days=i)).isoformat() for i in range(2 * DAYS)]
EPOCH_DAYS = [(FIRST - registry.EPOCH).days + i for i in range(2 * DAYS)]
POINTS = (-40.0, -10.0, 25.0, 55.0, 85.0)
NAMES = tuple(
    sorted(
        [f"bias.{a}" for a in "xyz"]
        + [f"scale.{a}" for a in "xyz"]
        + [f"misalignment.{a}.{b}" for a in "xyz" for b in "xyz" if a != b]
    )
)
MODEL = "bias, scale, misalignment"
VERSION = "0.54.0"
REASON = "fit: the fit did not converge (the design matrix's condition number is 3.1e+07)"
LOOKUPS = 20
INGEST, JOB = 100_000, 2_000
MIN_FREE = 10 * 2**30


def documented_drift() -> str:
    """docs/fleet-table.md's drift query (a batch's bias per month, each calibration at its
    point nearest 25 °C), with its batch a parameter: the query a factory is told to run."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "fleet-table.md").read_text()
    page = page[page.index("## The registry") :]
    blocks = re.findall(r"```sql\n(.*?)```", page, flags=re.S)
    text = "\n".join(line for block in blocks for line in block.splitlines() if not line.startswith("--"))
    (query,) = [q.strip() for q in text.split(";") if "OVER (PARTITION" in q]
    assert query.count("'B7'") == 1, "the documented drift query names its batch once"
    return query.replace("'B7'", "?")


def mix(x: int) -> int:
    """A cheap 32-bit hash: the synthetic year is a function of the device number."""
    return ((x * 0x9E3779B97F4A7C15) >> 29) & 0xFFFFFFFF


def days_of(d: int) -> list[int]:
    k = 1 + mix(d) % 5
    phase = mix(d ^ 0x5BD1E995) % DAYS
    return sorted((phase + i * DAYS // k) % DAYS for i in range(k))


def device(d: int) -> str:
    return f"G26-{d:08d}"


def batch(b: int) -> str:
    return f"B26-{b:04d}"


def path(d: int, day: int) -> str:
    return f"{batch(d // UNITS)}/{device(d)}/{DATES[day]}/calibration.json"


def session_row(root: str, d: int, day: int) -> tuple:
    """One unit session's row, in registry.SESSION_COLUMNS order."""
    h = mix(d * 7 + day)
    digest = f"{(d * 366 + day + 1) * 0x9E3779B97F4A7C15F39CC0605CEDC834 & (2**256 - 1):064x}"
    common = (root, path(d, day), device(d), batch(d // UNITS), DATES[day], EPOCH_DAYS[day], "turntable")
    if h % 50 == 0:
        return (*common, "failed", REASON, None, None, digest, "blake3", None, None, None, None, None)
    rms = 0.0021 + (h % 997) * 2e-6
    floor = 0.0019 + (h % 89) * 1e-6
    odd = h % 20 == 1
    verdict, best = ("unexplained", "+temperature.slope") if odd else ("explained", None)
    return (
        *common,
        "calibrated",
        None,
        MODEL,
        VERSION,
        digest,
        "blake3",
        rms,
        floor,
        rms / floor,
        verdict,
        best,
    )


def parameter_rows(root: str, d: int, day: int) -> list[tuple]:
    """A calibrated session's coefficients, per temperature point (PK order)."""
    h = mix(d)
    rel = path(d, day)
    out = []
    for i, t in enumerate(POINTS):
        for j, name in enumerate(NAMES):
            if name[0] == "b":  # a bias that drifts over the year and with temperature
                value = ((h >> j) % 1000 - 500) * 2e-5 + 4e-4 * day / 30 + 1e-4 * t / 25
            else:
                value = ((h >> j) % 1000 - 500) * 1e-6
            out.append((root, rel, i, t, name, value, 1e-4))
    return out


def year(sessions: int):
    """(device number, day) of every session of the year, in (path) order, and how many
    devices and batches there are."""
    n, d = 0, 0
    while n < sessions:
        for day in days_of(d)[: sessions - n]:
            yield d, day
            n += 1
        d += 1


def shape(sessions: int) -> dict:
    devices = 0
    for devices, _ in year(sessions):  # noqa: B007
        pass
    devices += 1
    return {"sessions": sessions, "devices": devices, "batches": -(-devices // UNITS)}


def has_parameters(d: int, every: int) -> bool:
    return (d // UNITS) % every == 0


def drift_batch(batches: int, every: int) -> int:
    """The batch in the middle with parameters: the drift query's."""
    return (batches // 2) // every * every


# ---------------------------------------------------------------------------------------
# Building


def split_schema(kind: str):
    statements = registry.schema(kind)
    tables = [s for s in statements if not s.startswith("CREATE INDEX")]
    indexes = [s for s in statements if s.startswith("CREATE INDEX")]
    return tables, indexes


def build_sqlite(file: Path, root: str, sessions: int, every: int) -> int:
    """The year in an SQLite file; returns the parameter rows written."""
    import sqlite3

    tables, indexes = split_schema("sqlite")
    conn = sqlite3.connect(file, isolation_level=None)
    conn.execute("PRAGMA journal_mode=OFF")
    conn.execute("PRAGMA synchronous=OFF")
    conn.execute("PRAGMA cache_size=-1000000")  # 1 GB: the index builds sort in memory
    conn.execute("BEGIN")
    for statement in tables:
        conn.execute(statement)
    conn.execute("INSERT INTO registry_meta VALUES ('schema_version', ?)", (str(registry.SCHEMA_VERSION),))
    marks = ", ".join("?" * len(registry.SESSION_COLUMNS))
    conn.executemany(
        f"INSERT INTO unit_sessions VALUES ({marks})",
        (session_row(root, d, day) for d, day in year(sessions)),
    )
    count = 0

    def params():
        nonlocal count
        for d, day in year(sessions):
            if has_parameters(d, every) and mix(d * 7 + day) % 50:
                rows = parameter_rows(root, d, day)
                count += len(rows)
                yield from rows

    conn.executemany("INSERT INTO parameters VALUES (?, ?, ?, ?, ?, ?, ?)", params())
    for statement in indexes:
        conn.execute(statement)
    conn.execute("COMMIT")
    conn.execute("ANALYZE")  # the planner's statistics, as a maintained registry has them
    conn.close()
    registry.connect(str(file)).close()  # the schema version, WAL: as the fleet job leaves it
    return count


def text(row) -> str:
    return "\t".join("\\N" if v is None else str(v) for v in row) + "\n"


def build_postgresql(url: str, root: str, sessions: int, every: int) -> int:
    import psycopg

    tables, indexes = split_schema("postgresql")
    count = 0
    with psycopg.connect(url) as conn, conn.cursor() as cur:
        for statement in tables:
            cur.execute(statement)
        cur.execute(
            "INSERT INTO registry_meta VALUES ('schema_version', %s)", (str(registry.SCHEMA_VERSION),)
        )
        with cur.copy(f"COPY unit_sessions ({', '.join(registry.SESSION_COLUMNS)}) FROM STDIN") as copy:
            block = []
            for d, day in year(sessions):
                block.append(text(session_row(root, d, day)))
                if len(block) == 50_000:
                    copy.write("".join(block))
                    block = []
            copy.write("".join(block))
        with cur.copy(f"COPY parameters ({', '.join(registry.PARAMETER_COLUMNS)}) FROM STDIN") as copy:
            for d, day in year(sessions):
                if has_parameters(d, every) and mix(d * 7 + day) % 50:
                    rows = parameter_rows(root, d, day)
                    count += len(rows)
                    copy.write("".join(text(r) for r in rows))
        for statement in indexes:
            cur.execute(statement)
        conn.commit()
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("VACUUM ANALYZE")  # visibility map and statistics, as autovacuum leaves them
    registry.connect(url).close()
    return count


# ---------------------------------------------------------------------------------------
# Measuring


def evict(files: list[Path]) -> None:
    """Drop these files' clean pages from the page cache (only ours: others' stay)."""
    for f in files:
        with contextlib.suppress(OSError):
            fd = os.open(f, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            finally:
                os.close(fd)


def choose(backend, name: str, date: dt.date):
    """What a lookup does with the registry, after connecting: the device's rows, the choice."""
    rows = registry.device_rows(backend, name)
    pool = [
        (registry.EPOCH + dt.timedelta(days=r["session_day"]), (r["root"], r["path"]), r)
        for r in rows
        if r["status"] == "calibrated"
    ]

    def none_found(problem):
        raise LookupError(problem)

    return lookup._choose(pool, name, date, None, lookup.DEFAULT_MAX_DAYS, none_found)


def calibration(name: str, session: str, batch_name: str):
    """A small real calibration file's content (as the lookup tests' ``calibration()``)."""
    from gyrocal.calibration.file import Calibration
    from gyrocal.fit.model import DEFAULT_TERMS, Model
    from gyrocal.fit.thermal import TemperatureGrid

    model = Model.from_spec(DEFAULT_TERMS)
    values = np.zeros((len(POINTS), len(model.names)))
    grid = TemperatureGrid(np.array(POINTS), tuple(model.names), values, values + 1e-4)
    meta = {"device": name, "batch": batch_name, "session": session, "protocol": "turntable"}
    return Calibration(model, grid, meta=meta)


def real_files(where: str, results: Path, names: list[str]) -> None:
    """The devices' calibrated rows made to point at real files, with their real hash."""
    from gyrocal.calibration.file import save_calibration
    from gyrocal.io.log import HASH_ALGORITHM, file_digest

    backend = registry.connect(where, create=False)
    try:
        with backend.transaction():
            for name in names:
                for r in registry.device_rows(backend, name):
                    if r["status"] != "calibrated":
                        continue
                    file = results / r["path"]
                    file.parent.mkdir(parents=True, exist_ok=True)
                    save_calibration(calibration(name, r["session"], r["batch"]), file)
                    backend.execute(
                        "UPDATE unit_sessions SET file_hash = ? WHERE root = ? AND path = ?",
                        (file_digest(file, HASH_ALGORITHM), r["root"], r["path"]),
                    )
    finally:
        backend.close()


def process(argv: list[str], timeout: float) -> float | None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    try:
        out = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None
    wall = time.perf_counter() - t0
    if out.returncode and "no calibration" not in out.stderr:
        raise SystemExit(f"{' '.join(argv)} failed ({out.returncode}): {out.stderr[-800:]}")
    return wall


def ingest_rows(root: str, year_shape: dict) -> list[registry.Row]:
    """The day after the year: 100,000 devices spread over every batch calibrated again
    (a registry of fewer devices: each of them on the days after, one a day)."""
    devices = year_shape["devices"]
    rows = []
    for j in range(INGEST):
        d, day = (j * devices // INGEST, DAYS) if devices >= INGEST else (j % devices, DAYS + j // devices)
        values = session_row(root, d, day)
        session = dict(zip(registry.SESSION_COLUMNS, values, strict=True))
        params = tuple(parameter_rows(root, d, day)) if session["status"] == "calibrated" else ()
        rows.append(registry.Row(session, params))
    return rows


def remove(backend, keys) -> None:
    with backend.transaction():
        backend.executemany("DELETE FROM parameters WHERE root = ? AND path = ?", keys)
        backend.executemany("DELETE FROM unit_sessions WHERE root = ? AND path = ?", keys)


class Timed:
    """The backend's executemany, timed per statement: where an upsert's time goes."""

    def __init__(self, backend):
        self.spent: dict[str, float] = {}
        inner = backend.executemany

        def executemany(sql, rows):
            t0 = time.perf_counter()
            inner(sql, rows)
            key = " ".join(sql.split()[:3])
            self.spent[key] = self.spent.get(key, 0.0) + time.perf_counter() - t0

        backend.executemany = executemany


def spread(values: list[float], unit: float = 1e3, fmt: str = ".1f", what: str = "ms") -> str:
    return (
        f"median {statistics.median(values) * unit:{fmt}} {what}, "
        f"range {min(values) * unit:{fmt}}-{max(values) * unit:{fmt}} {what} (n={len(values)})"
    )


def load() -> str:
    a = os.getloadavg()
    return f"load {a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f}"


def measure(where: str, files, results: Path, year_shape: dict, every: int, seed: int = 54) -> dict:
    """Every figure of one registry; ``files()`` lists its files on disk (to evict)."""
    rng = random.Random(seed)
    picks = [
        (device(rng.randrange(year_shape["devices"])), FIRST + dt.timedelta(days=rng.randrange(DAYS)))
        for _ in range(LOOKUPS)
    ]
    out: dict = {}
    backend = registry.connect(where, create=False)
    try:
        for state in ("cold", "warm"):
            times = []
            for name, date in picks:
                if state == "cold":
                    evict(files())
                t0 = time.perf_counter()
                choose(backend, name, date)
                times.append(time.perf_counter() - t0)
            out[f"lookup {state}"] = times
            print(f"lookup query ({state}): {spread(times)}; {load()}", flush=True)
    finally:
        backend.close()

    real_files(where, results, [name for name, _ in picks])
    python = [sys.executable, "-m", "gyrocal", "lookup"]
    walls = [
        process([*python, str(results), n, "--date", d.isoformat(), "--registry", where], 120)
        for n, d in picks
    ]
    out["lookup process"] = walls
    print(f"lookup process: {spread(walls, 1, '.2f', 's')}; {load()}", flush=True)
    miss = process([*python, str(results), "G26-99999999", "--registry", where], 300)
    out["lookup miss"] = miss
    print(
        f"lookup process of an unknown device: {'> 300 s' if miss is None else f'{miss:.1f} s'}", flush=True
    )

    name = batch(drift_batch(year_shape["batches"], every))
    documented = documented_drift()
    backend = registry.connect(where, create=False)

    def by_command():  # what `gyrocal drift RESULTS --batch B --name bias` runs
        return registry.monthly(registry.drift(backend, batch=name, names=("bias",)))

    def by_docs():
        return backend.execute(documented, (name,)).fetchall()

    def timed(run) -> tuple[list[float], Any]:
        """Three runs of ``run``, the first with the registry's pages evicted; the last answer."""
        times = []
        for i in range(3):
            if i == 0:
                evict(files())
            t0 = time.perf_counter()
            found = run()
            times.append(time.perf_counter() - t0)
        return times, found

    ways = (("drift (gyrocal drift)", by_command), ("drift (the docs' query)", by_docs))
    try:
        for label, run in ways:
            out[label], found = timed(run)
            print(
                f"{label} of {name}, {len(found)} month-coefficient rows: "
                + ", ".join(f"{t:.3f} s" for t in out[label])
                + f" (the first cold); {load()}",
                flush=True,
            )
        explain = "EXPLAIN QUERY PLAN " if backend.kind == "sqlite" else "EXPLAIN "
        plan = backend.execute(explain + documented, (name,)).fetchall()
        print(
            "  the docs' query's plan: " + " | ".join(" ".join(str(r[-1]).split()) for r in plan), flush=True
        )
        if backend.kind == "postgresql":
            # The subset's parameters are small enough for a scan of the whole table; at full
            # size (60 times the rows) the join by the primary key is the only fast path.
            backend.execute("SET enable_seqscan = off")
            for label, run in ways:
                out[label + " by index"], _ = timed(run)
                print(
                    f"{label} through the indexes (enable_seqscan off): "
                    + ", ".join(f"{t:.3f} s" for t in out[label + " by index"]),
                    flush=True,
                )
    finally:
        backend.close()

    root = registry.root_of(results)
    rows = ingest_rows(root, year_shape)
    backend = registry.connect(where, create=False)
    try:
        timed = Timed(backend)
        t0 = time.perf_counter()
        for i in range(0, len(rows), JOB):  # as the fleet job writes: its unit folders replaced
            job = rows[i : i + JOB]
            folders = [(r.session["root"], r.session["path"].rsplit("/", 1)[0]) for r in job]
            registry.upsert(backend, job, unit_folders=folders)
        wall = time.perf_counter() - t0
        out["ingest"] = wall
        params = sum(len(r.parameters) for r in rows)
        print(
            f"ingest of {len(rows)} sessions, {params} parameter rows, as {len(rows) // JOB} fleet jobs: "
            f"{wall:.1f} s ({', '.join(f'{k}: {v:.1f} s' for k, v in timed.spent.items())}); {load()}",
            flush=True,
        )
        keys = [(r.session["root"], r.session["path"]) for r in rows]
        remove(backend, keys)  # the year as it was
    finally:
        backend.close()
    return out


# ---------------------------------------------------------------------------------------


def gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB"


def size(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())


def free(path: Path) -> int:
    return shutil.disk_usage(path).free


def reachable(folder: Path, uid: int) -> bool:
    """Whether a user other than root can reach the folder (every parent searchable)."""
    for p in [folder, *folder.parents]:
        if not p.exists():
            continue
        st = p.stat()
        if not (st.st_mode & 0o001 or (st.st_uid == uid and st.st_mode & 0o100)):
            return False
    return True


def cached(folder: Path, want: dict) -> dict | None:
    marker = folder / "built.json"
    if marker.is_file():
        done = json.loads(marker.read_text())
        if all(done.get(k) == v for k, v in want.items()):
            return done
    return None


def run_sqlite(place: Path, want: dict, year_shape: dict) -> None:
    folder = place / "sqlite"
    file = folder / "registry.sqlite"
    results = folder / "results"
    done = cached(folder, want)
    if done is None:
        shutil.rmtree(folder, ignore_errors=True)
        results.mkdir(parents=True)
        print(f"# generating {file} ({load()})", flush=True)
        t0 = time.perf_counter()
        params = build_sqlite(file, registry.root_of(results), want["sessions"], want["every"])
        done = {**want, "parameters": params, "generation_s": time.perf_counter() - t0, "load": load()}
        (folder / "built.json").write_text(json.dumps(done))
    print(
        f"sqlite: {file}, {gib(size(folder))} on disk; {done['parameters']:,} parameter rows; "
        f"generated in {done['generation_s']:.0f} s ({done['load']})",
        flush=True,
    )
    measure(str(file), lambda: [file, Path(f"{file}-wal")], results, year_shape, want["every"])


def run_postgresql(place: Path, want: dict, year_shape: dict) -> Path:
    import psycopg

    from tests.pg import Server, installed_version, run_as

    user = run_as()
    folder = place / "postgresql"
    if user is not None and not reachable(place, user.pw_uid):
        folder = Path(tempfile.gettempdir()) / "gyrocal-bench-registry" / "postgresql"
        print(f"# {place} is not reachable by {user.pw_name}: the cluster goes to {folder}", flush=True)
    results = place / "postgresql-results"
    fast = ("shared_buffers=1GB", "maintenance_work_mem=2GB")
    # generation: nothing logged; measurement: durable, as a production server runs
    build = (*fast, "wal_level=minimal", "max_wal_senders=0", "max_wal_size=4GB")
    # (the default max_wal_size, 1 GB: checkpoints during the ingest, as in production)
    durable = (*fast, "fsync=on", "synchronous_commit=on", "full_page_writes=on")
    done = cached(folder, want)
    if done is None:
        shutil.rmtree(folder, ignore_errors=True)
        shutil.rmtree(results, ignore_errors=True)
        results.mkdir(parents=True)
        print(f"# generating a PostgreSQL registry in {folder} ({load()})", flush=True)
        t0 = time.perf_counter()
        with Server(*build, folder=folder, timeout=600) as server:
            params = build_postgresql(
                server.url(), registry.root_of(results), want["sessions"], want["every"]
            )
        done = {**want, "parameters": params, "generation_s": time.perf_counter() - t0, "load": load()}
        (folder / "built.json").write_text(json.dumps(done))
    with Server(*durable, folder=folder, timeout=600) as server:
        url = server.url()
        with psycopg.connect(url) as conn:
            sizes = {
                t: conn.execute("SELECT pg_total_relation_size(%s)", (t,)).fetchone()[0]
                for t in ("unit_sessions", "parameters")
            }
            whole = conn.execute("SELECT pg_database_size(current_database())").fetchone()[0]
            relations = [
                server.data / r[0]
                for r in conn.execute(
                    "SELECT pg_relation_filepath(c.oid) FROM pg_class c "
                    "WHERE c.relname LIKE 'unit_sessions%' OR c.relname LIKE 'parameters%'"
                ).fetchall()
                if r[0]
            ]
        print(
            f"postgresql ({installed_version()}): {gib(whole)} database "
            f"(unit_sessions {gib(sizes['unit_sessions'])}, parameters {gib(sizes['parameters'])}, "
            f"with indexes), {gib(size(folder))} cluster; {done['parameters']:,} parameter rows; "
            f"generated in {done['generation_s']:.0f} s ({done['load']})",
            flush=True,
        )

        def files():
            return [f for r in relations for f in r.parent.glob(r.name + "*")]

        measure(url, files, results, year_shape, want["every"])
    return folder


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=36_500_000, help="at least 1,000")
    ap.add_argument("--backend", default="sqlite,postgresql")
    ap.add_argument("--parameters-every", type=int, default=100, help="one batch in N has parameters")
    ap.add_argument(
        "--keep",
        nargs="?",
        const=CACHE,
        type=Path,
        help="build the registries here and keep them (a rerun skips generation)",
    )
    args = ap.parse_args(argv)
    if args.sessions < 1000:
        ap.error("--sessions: at least 1,000 (a day's ingest of 100,000 sessions spreads over its devices)")
    place = (args.keep or CACHE).resolve()
    place.mkdir(parents=True, exist_ok=True)
    want = {
        "generator": GENERATOR,
        "schema": registry.SCHEMA_VERSION,
        "sessions": args.sessions,
        "every": args.parameters_every,
    }
    print(
        f"# {cpu_name()}, {cores()}, {os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB; "
        f"{dt.datetime.now().isoformat(timespec='minutes')}; Python {sys.version.split()[0]}; {load()}; "
        f"{gib(free(place))} free at {place}",
        flush=True,
    )
    year_shape = shape(args.sessions)
    print(
        f"# {args.sessions:,} sessions of {year_shape['devices']:,} devices in {year_shape['batches']:,} batches "
        f"over {DATES[0]}..{DATES[DAYS - 1]}; parameters for batch 1 in {args.parameters_every}, "
        f"{len(POINTS)} points x {len(NAMES)} coefficients",
        flush=True,
    )
    for kind in args.backend.split(","):
        if free(place) < MIN_FREE:
            raise SystemExit(
                f"only {gib(free(place))} free at {place}: {MIN_FREE // 2**30} GiB must stay free"
            )
        if kind == "sqlite":
            run_sqlite(place, want, year_shape)
            made = [place / "sqlite"]
        elif kind == "postgresql":
            made = [run_postgresql(place, want, year_shape), place / "postgresql-results"]
        else:
            raise SystemExit(f"unknown back end {kind!r}")
        if args.keep is None:
            for folder in made:
                print(f"# removing {folder} ({gib(size(folder))})", flush=True)
                shutil.rmtree(folder, ignore_errors=True)
        print(f"# {gib(free(place))} free at {place}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
