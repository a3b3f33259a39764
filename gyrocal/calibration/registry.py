"""The calibration registry: an index of a results folder's calibrations in a database.

The calibration files stay the source of truth; the registry is an index that
``gyrocal registry rebuild RESULTS`` makes again from them, row for row. One row per
calibration file or failure record below the folder (``unit_sessions``, keyed by the file's
path relative to the folder, as the folder scan of :mod:`gyrocal.calibration.lookup` breaks
ties by it), and the coefficients of each calibration per temperature point (``parameters``).
Two back ends behind one interface: SQLite (the standard library's; the default, a file
beside the results) and PostgreSQL (psycopg 3) where a factory has one.

A lookup reads the device's rows, chooses as the folder scan chooses, and serves the file
only when its hash is still the one registered: a row whose file is missing or changed is an
error naming ``gyrocal registry check``, never a silent answer.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from ..io import formats
from ..io.errors import ConfigError, GyrocalError, InputError

SCHEMA_VERSION = 2  # 2: byte-order text on PostgreSQL, a unit folder's files keyed by its layout
DRIFT_WITHIN = 5.0  # °C: how far a calibration's point may lie from the drift's temperature
SCHEMA_LOCK = 0x67797263616C  # "gyrcal": PostgreSQL's advisory lock around making the schema
DEFAULT_NAME = "registry.sqlite"  # in the results folder, where lookup finds it by itself
STATUSES = ("calibrated", "failed", "unreadable")

SESSION_COLUMNS = (
    "root",  # the results folder, absolute: shards with folders of their own share one registry
    "path",  # the file below the results folder, '/'-separated
    "device",
    "batch",
    "session",
    "session_day",  # the session's date as days since 1970-01-01; NULL when not a date
    "protocol",
    "status",  # calibrated | failed | unreadable
    "reason",  # a failure's one-line error, or what makes the file unreadable
    "model",  # the model's terms, comma-separated
    "gyrocal_version",
    "file_hash",
    "hash_algorithm",
    "validation_rms",  # deg/s, the leave-temperature-out RMS
    "noise_floor",
    "excess",  # validation_rms / noise_floor
    "verdict",  # the diagnosis' verdict
    "best_option",  # the option that adds the fix the diagnosis offers
)
PARAMETER_COLUMNS = ("root", "path", "point", "temperature", "name", "value", "stderr")

_REAL, _INT = "DOUBLE PRECISION", "BIGINT"
_TYPES = {"session_day": _INT, "validation_rms": _REAL, "noise_floor": _REAL, "excess": _REAL}


def schema(kind: str = "sqlite") -> tuple[str, ...]:
    """The registry's tables and indexes on the back end ``kind``. Text compares byte by
    byte on both (SQLite's BINARY; PostgreSQL's "C", not the database's locale): the same
    order of devices and paths, so the same ties, neighbours and folder ranges."""
    text = 'TEXT COLLATE "C"' if kind == "postgresql" else "TEXT"
    return (
        f"CREATE TABLE IF NOT EXISTS registry_meta (key {text} PRIMARY KEY, value TEXT NOT NULL)",
        "CREATE TABLE IF NOT EXISTS unit_sessions ("
        + ", ".join(
            f"{c} {_TYPES.get(c, text)}"
            f"{' NOT NULL' if c in ('root', 'path', 'status', 'file_hash', 'hash_algorithm') else ''}"
            for c in SESSION_COLUMNS
        )
        + ", PRIMARY KEY (root, path))",
        # a device's sessions by date (lookup), a batch's over months (drift)
        "CREATE INDEX IF NOT EXISTS unit_sessions_device ON unit_sessions (device, session_day)",
        "CREATE INDEX IF NOT EXISTS unit_sessions_batch ON unit_sessions (batch, session_day)",
        f"CREATE TABLE IF NOT EXISTS parameters (root {text} NOT NULL, path {text} NOT NULL, "
        f"point INTEGER NOT NULL, temperature {_REAL}, name {text} NOT NULL, value {_REAL} NOT NULL, "
        f"stderr {_REAL}, PRIMARY KEY (root, path, point, name))",
    )


_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
EPOCH = dt.date(1970, 1, 1)


class RegistryError(InputError):
    """A registry that cannot serve: unreachable, of another schema version, or a row whose
    file is missing or changed."""


class RegistryUnavailable(RegistryError):
    """A registry out of reach for now (no server, a lost connection, a lock held too long):
    the workflow goes on without it and says so; anything else about a registry stops it."""


class NoRegistryError(RegistryError):
    """No registry where one was to be read: no file, or a database without its tables."""


def day_number(session) -> int | None:
    """A ``YYYY-MM-DD`` session as days since 1970-01-01 (None for anything else)."""
    if not isinstance(session, str) or not _DATE.fullmatch(session):
        return None
    try:
        return (dt.date.fromisoformat(session) - EPOCH).days
    except ValueError:
        return None


# ---------------------------------------------------------------------------------------
# Back ends: one connection, '?' placeholders, the SQL both speak (ON CONFLICT upserts).


class Backend:
    """A connection to the registry's database; SQL is written once with ``?``."""

    kind = ""
    placeholder = "?"

    def __init__(self, connection, location: str):
        self.connection = connection
        self.location = location

    def sql(self, text: str) -> str:
        if self.placeholder == "?":
            return text
        return text.replace("%", "%%").replace("?", self.placeholder)  # a literal % (LIKE) kept

    def execute(self, text: str, params: Sequence = ()):
        cursor = self.connection.cursor()
        cursor.execute(self.sql(text), tuple(params))
        return cursor

    def executemany(self, text: str, rows: Iterable[Sequence]) -> None:
        self.connection.cursor().executemany(self.sql(text), [tuple(r) for r in rows])

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """Everything inside commits together or not at all (a killed job leaves nothing)."""
        raise NotImplementedError

    def serialise(self) -> None:
        """Inside a transaction: the others wait for it (SQLite's BEGIN IMMEDIATE does)."""

    @contextmanager
    def transaction_for_reading(self) -> Iterator[None]:
        """A read that takes no writer's lock (PostgreSQL: a failed read ends its transaction)."""
        yield

    def tables(self) -> set[str]:
        """Which of the registry's :data:`TABLES` the database holds (from its catalogue:
        no failed statement, so a transaction around it goes on)."""
        cursor = self.execute(
            f"SELECT name FROM sqlite_master WHERE type = 'table' AND name IN ({', '.join('?' * len(TABLES))})",
            TABLES,
        )
        return {r[0] for r in cursor.fetchall()}

    def insert_many(self, table: str, columns: Sequence[str], rows: Sequence[Sequence]) -> None:
        """Rows appended to ``table``, inside the caller's transaction."""
        self.executemany(
            f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})", rows
        )

    def close(self) -> None:
        self.connection.close()


class SQLiteBackend(Backend):
    kind = "sqlite"

    @classmethod
    def open(cls, path: Path) -> SQLiteBackend:
        import sqlite3

        path.parent.mkdir(parents=True, exist_ok=True)
        # autocommit off by hand: BEGIN IMMEDIATE takes the write lock at once, so writers
        # queue (busy timeout) rather than fail on upgrading a read lock
        connection = sqlite3.connect(path, timeout=600, isolation_level=None)
        # Switching a new file to WAL takes its lock without the busy wait: several
        # processes opening a new registry at once take turns here.
        deadline = time.monotonic() + 600
        while True:
            try:
                connection.execute("PRAGMA journal_mode=WAL")
                break
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.01)
        connection.execute("PRAGMA synchronous=NORMAL")
        return cls(connection, str(path))

    @contextmanager
    def transaction(self) -> Iterator[None]:
        self.connection.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self.connection.execute("ROLLBACK")
            raise
        self.connection.execute("COMMIT")


class PostgresBackend(Backend):
    kind = "postgresql"
    placeholder = "%s"

    @classmethod
    def open(cls, url: str) -> PostgresBackend:
        try:
            import psycopg
        except ImportError:
            raise ConfigError(
                "a PostgreSQL registry needs psycopg 3: pip install 'psycopg[binary]'"
            ) from None
        try:
            connection = psycopg.connect(url, autocommit=True)
        except psycopg.Error as exc:
            raise RegistryUnavailable(
                f"cannot connect ({' '.join(str(exc).split())})", source=_redacted(url)
            ) from None
        return cls(connection, _redacted(url))

    @contextmanager
    def transaction(self) -> Iterator[None]:
        with self.connection.transaction():
            yield

    @contextmanager
    def transaction_for_reading(self) -> Iterator[None]:
        with self.connection.transaction():
            yield

    def tables(self) -> set[str]:
        # the search path's tables, as the statements that follow name them
        return {t for t in TABLES if self.execute("SELECT to_regclass(?)", (t,)).fetchone()[0] is not None}

    def serialise(self) -> None:
        # two first writers creating the tables at once would collide in the catalogue
        self.execute("SELECT pg_advisory_xact_lock(?)", (SCHEMA_LOCK,))

    def insert_many(self, table: str, columns: Sequence[str], rows: Sequence[Sequence]) -> None:
        # COPY: a statement per row costs 8 µs of round trip each, a day's 5.9 M coefficients 46 s
        with self.connection.cursor().copy(f"COPY {table} ({', '.join(columns)}) FROM STDIN") as copy:
            for row in rows:
                copy.write_row(row)


def shown(where: str) -> str:
    """A registry's location as messages and pages name it: a URL without its password."""
    return _redacted(where)


def _redacted(url: str) -> str:
    """The URL without its password, to name it in messages: in ``user:pw@`` (up to the last
    ``@``) and in a ``password=`` parameter."""
    url = re.sub(r"(://[^:/@]+):.*@", r"\1:***@", url)
    return re.sub(r"([?&]password=)[^&]*", r"\1***", url)


def location(results: Path, registry: str | None = None) -> str:
    """Where a results folder's registry is: ``registry`` (a ``postgresql://`` URL, a
    ``sqlite:///`` URL or a file path) or the SQLite file in the folder."""
    return registry if registry else str(Path(results) / DEFAULT_NAME)


def connect(where: str, *, create: bool = True, fresh: bool = False) -> Backend:
    """The registry at ``where`` (see :func:`location`). A writer (``create``) makes its
    tables where there are none; a reader only checks the schema's version, taking no lock,
    so a lookup does not wait for a fleet job's write. ``fresh`` drops the tables first
    (every results folder's rows: the migration, by a rebuild). Any database error is one
    line naming the registry (:class:`RegistryError`)."""
    with database_errors(where):
        if where.startswith(("postgresql://", "postgres://")):
            backend: Backend = PostgresBackend.open(where)
        else:
            path = Path(where.removeprefix("sqlite:///") if where.startswith("sqlite:///") else where)
            if not create and not path.is_file():
                raise NoRegistryError(
                    "no registry here: gyrocal registry rebuild RESULTS makes it", source=path
                )
            backend = SQLiteBackend.open(path)
        try:
            if fresh:
                _drop(backend)
            version = _version(backend)
            if version is None and create:
                version = _create(backend)
            if version is None:
                if backend.tables():
                    _not_ours(backend)
                raise NoRegistryError(
                    "no registry here: gyrocal registry rebuild RESULTS makes it", source=backend.location
                )
            if version != str(SCHEMA_VERSION):
                newer = version.isdigit() and int(version) > SCHEMA_VERSION
                raise RegistryError(
                    f"registry schema version {version}, this gyrocal reads {SCHEMA_VERSION}: "
                    + (
                        "a newer gyrocal wrote it; upgrade gyrocal"
                        if newer
                        else "gyrocal registry rebuild RESULTS --fresh makes it again from the files"
                    ),
                    source=backend.location,
                )
        except BaseException:
            backend.close()
            raise
    return backend


@contextmanager
def database_errors(where: str) -> Iterator[None]:
    """A database's own errors (a file that is not a database, a lock held too long, a lost
    connection) as one line naming the registry and what to do."""
    import sqlite3

    kinds: tuple[type[BaseException], ...] = (sqlite3.Error,)
    try:
        import psycopg

        kinds += (psycopg.Error,)
    except ImportError:
        pass
    try:
        yield
    except kinds as exc:
        said = " ".join(str(exc).split())
        kind: type[RegistryError] = RegistryError
        if "locked" in said or "busy" in said:  # passing: another writer, not a broken registry
            advice, kind = "another process held it past the wait; try again", RegistryUnavailable
        elif "permission denied" in said or "readonly" in said or "read-only" in said:
            advice = "the registry's user may not do this: grant it the right, or name another registry"
        elif "connection" in said.lower() or "server" in said.lower():
            advice, kind = "the database server was lost; try again when it is back", RegistryUnavailable
        else:
            advice = "gyrocal registry rebuild RESULTS --fresh makes it again from the files"
        raise kind(f"{said} ({type(exc).__name__}); {advice}", source=shown(where)) from None


TABLES = ("registry_meta", "unit_sessions", "parameters")


def _version(backend: Backend) -> str | None:
    """The registry's schema version; None where it has no registry_meta (no tables yet)."""
    with backend.transaction_for_reading():
        if "registry_meta" not in backend.tables():
            return None
        return _stored_version(backend)


def _stored_version(backend: Backend) -> str | None:
    """registry_meta's schema version (None: no such row); a registry_meta of other columns
    is another program's."""
    try:
        found = backend.execute("SELECT value FROM registry_meta WHERE key = 'schema_version'").fetchone()
    except Exception as exc:  # noqa: BLE001 - the back ends raise their own kinds
        if str(exc).startswith("no such column") or getattr(exc, "sqlstate", None) == "42703":
            _not_ours(backend)
        raise  # a right the user lacks, a lost connection: said as such (database_errors)
    return None if found is None else str(found[0])


def _not_ours(backend: Backend) -> NoReturn:
    raise RegistryError(
        "holds a table named unit_sessions, parameters or registry_meta but no schema version: not a registry "
        "gyrocal wrote, and left as it is; give the registry a database (or file) of its own",
        source=backend.location,
    )


def _drop(backend: Backend) -> None:
    """The registry's tables dropped (the migration, by a rebuild): only where its
    registry_meta says they are gyrocal's; another program's tables of the same names stay."""
    with backend.transaction():
        backend.serialise()
        found = backend.tables()
        if "registry_meta" in found and _stored_version(backend) is None:
            _not_ours(backend)
        if "registry_meta" in found:
            for table in ("parameters", "unit_sessions", "registry_meta"):
                backend.execute(f"DROP TABLE IF EXISTS {table}")
        elif found:
            _not_ours(backend)


def _create(backend: Backend) -> str:
    """The tables and the version, made by one writer at a time where there are none (the
    check under the writers' lock: two processes opening a new registry at once make it
    once); the version found or made. Tables of the registry's names without its
    registry_meta are another program's: refused, left alone."""
    with backend.transaction():
        backend.serialise()
        found = backend.tables()
        if "registry_meta" not in found:
            if found:
                _not_ours(backend)
            for statement in schema(backend.kind):
                backend.execute(statement)
            backend.execute(
                "INSERT INTO registry_meta (key, value) VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
            )
            return str(SCHEMA_VERSION)
        version = _stored_version(backend)
        if version is None:  # another program's registry_meta
            _not_ours(backend)
        return version


# ---------------------------------------------------------------------------------------
# Rows from files


@dataclass(frozen=True)
class Row:
    """One file's row and its coefficients."""

    session: dict[str, Any]
    parameters: tuple[tuple, ...] = ()


def _layout(rel: str) -> tuple[str | None, str | None, str | None]:
    """Batch, device and session from the workflow layout ``{batch}/{device}/{session}/calibration.json``."""
    parts = rel.split("/")
    if len(parts) == 4 and parts[-1] == "calibration.json":
        return parts[0], parts[1], parts[2]
    return None, None, None


def file_row(path: Path, rel: str, root: str) -> Row | None:
    """The row of one JSON file below the results folder: a calibration, a failure record,
    or an unreadable file the layout names; None for other JSON (validation, diagnosis)."""
    from ..io.log import HASH_ALGORITHM

    batch, device, session = _layout(rel)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        return _unreadable(root, rel, batch, device, session, f"cannot read ({exc.strerror})", None)
    family = formats.CALIBRATION.split("/")[0]
    if b'"' + family.encode() not in raw and b'"' + formats.FAILURE.split("/")[0].encode() not in raw:
        return None
    digest = bytes_digest(raw, HASH_ALGORITHM)  # the bytes parsed below, not a second read
    try:
        doc = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return _unreadable(root, rel, batch, device, session, "not valid JSON", digest)
    if not isinstance(doc, dict) or not isinstance(doc.get("format"), str):
        return None
    device = doc.get("device") or device
    session = doc.get("session") or session
    base = {
        "root": root,
        "path": rel,
        "device": device,
        "batch": doc.get("batch") or batch,
        "session": None if session is None else str(session),
        "session_day": day_number(session),
        "protocol": doc.get("protocol"),
        "file_hash": digest,
        "hash_algorithm": HASH_ALGORITHM,
    }
    if doc["format"] == formats.FAILURE:
        return Row(_complete({**base, "status": "failed", "reason": doc.get("error")}))
    if doc["format"].split("/")[0] != family:
        return None
    if base["session_day"] is None:
        problem = f"session {session!r} is not a date YYYY-MM-DD"
        return _unreadable(root, rel, base["batch"], device, session, problem, digest)
    from .file import Calibration

    try:
        cal = Calibration.from_dict(doc, source=path)
    except GyrocalError as exc:
        return _unreadable(root, rel, base["batch"], device, session, str(exc), digest)
    return Row(
        _complete(
            {
                **base,
                "status": "calibrated",
                "model": _model_text(doc),
                "gyrocal_version": (cal.provenance.get("versions") or {}).get("gyrocal"),
                **_headline(path.parent),
            }
        ),
        tuple(_coefficients(root, rel, cal)),
    )


def bytes_digest(raw: bytes, algorithm: str) -> str:
    """The hash of bytes already read, as :func:`gyrocal.io.log.file_digest` hashes a file."""
    from ..io.log import _hasher

    hasher = _hasher(algorithm)
    hasher.update(raw)
    return hasher.hexdigest()


def _model_text(doc: dict) -> str | None:
    """The model's terms as the file records them, comma-separated."""
    terms = (doc.get("model") or {}).get("terms")
    if not isinstance(terms, list):
        return None

    def text(term) -> str:
        if not isinstance(term, dict):
            return str(term)
        rest = {k: v for k, v in term.items() if k != "name"}
        return str(term.get("name")) + (f"({json.dumps(rest, sort_keys=True)})" if rest else "")

    return ", ".join(text(t) for t in terms)


def _unreadable(root, rel, batch, device, session, problem: str, digest: str | None) -> Row:
    from ..io.log import HASH_ALGORITHM

    return Row(
        _complete(
            {
                "root": root,
                "path": rel,
                "device": device,
                "batch": batch,
                "session": session,
                "session_day": day_number(session),
                "status": "unreadable",
                "reason": problem,
                "file_hash": digest or "",
                "hash_algorithm": HASH_ALGORITHM,
            }
        )
    )


def _complete(values: dict) -> dict:
    return {c: values.get(c) for c in SESSION_COLUMNS}


def _headline(folder: Path) -> dict[str, Any]:
    """The unit session's validation and diagnosis figures, where its results folder has
    them (a calibration file outside the workflow's layout has none)."""
    from ..io import unit_folder

    out: dict[str, Any] = {}
    try:
        validation = unit_folder.read_part_doc(folder, "validation") or {}
        diagnosis = unit_folder.read_part_doc(folder, "diagnosis") or {}
    except (GyrocalError, OSError, ValueError):
        return out
    summary = validation.get("summary") or {}
    for key in ("validation_rms", "noise_floor", "excess"):
        value = summary.get(key)
        out[key] = float(value) if isinstance(value, int | float) and value == value else None
    if isinstance(diagnosis.get("verdict"), str):
        out["verdict"] = diagnosis["verdict"]
        out["best_option"] = (diagnosis.get("best") or {}).get("option")
    return out


def _coefficients(root: str, rel: str, cal) -> Iterator[tuple]:
    """The calibration's coefficients: per temperature point for a grid, one set (point -1,
    no temperature) for a continuous model."""
    import numpy as np

    grid = cal.grid
    values = np.atleast_2d(np.asarray(grid.values, dtype=float))
    stderr = np.atleast_2d(np.asarray(grid.stderr, dtype=float))
    temps = getattr(grid, "temperatures", None)
    for i, row in enumerate(values):
        point, temperature = (i, float(temps[i])) if temps is not None else (-1, None)
        for j, name in enumerate(grid.names):
            se = float(stderr[i, j])
            yield (root, rel, point, temperature, name, float(row[j]), se if np.isfinite(se) else None)


def _files(results: Path) -> Iterator[tuple[Path, str]]:
    """``*.json`` below ``results`` in a fixed order, hidden folders left out (as the scan)."""
    for root, dirs, files in os.walk(results):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            if name.endswith(".json"):
                path = Path(root) / name
                yield path, path.relative_to(results).as_posix()


def rows_of(results: Path, only: Iterable[str] | None = None) -> list[Row]:
    """The rows of every registrable file below ``results`` (or of the folders ``only``
    names, relative to it: a fleet job's unit sessions), each keyed by :func:`key_of`."""
    results = Path(results)
    if only is None:
        found: Iterable[Path] = (path for path, _ in _files(results))
    else:
        found = (p for folder in only for p in sorted((results / folder).glob("*.json")))
    rows = []
    for path in found:
        root, rel = key_of(results, path)
        row = file_row(path, rel, root)
        if row is not None:
            rows.append(row)
    return rows


def key_of(results: Path, path: Path) -> tuple[str, str]:
    """How the registry keys a file found below ``results``: a file of a unit folder
    (``{batch}/{device}/{session}/*.json``: three or more folders below ``results``, which
    may be a batch's folder) by the results folder above that layout, as the fleet job keys
    it, whichever folder a rebuild starts from; a file nearer ``results`` (an archived copy)
    by ``results`` and the path below it. Writers delete what lies below their folders
    first (:func:`upsert`), so a file is listed once."""
    rel = path.relative_to(results)
    absolute = Path(root_of(results)) / rel
    if len(rel.parts) >= 3 and len(absolute.parents) > 3:  # a unit folder's file, or one as deep
        return absolute.parents[3].as_posix(), absolute.relative_to(absolute.parents[3]).as_posix()
    return root_of(results), rel.as_posix()


def under(folder: str, table: str = "") -> tuple[str, list[str]]:
    """The SQL condition (and its parameters) for rows whose file lies below ``folder`` (as
    :func:`root_of` names it): rows of that results folder, of folders below it (a day's
    shards), and of a folder above it whose path leads below it (a batch's folder asked
    about). Byte-order ranges, not LIKE: no escaping, and the primary key's index serves them.
    ``table``: the columns' table prefix in a join (``s.``)."""
    from pathlib import PurePosixPath

    folder = folder.rstrip("/") or "/"
    if folder == "/":
        return "1 = 1", []
    root, path = f"{table}root", f"{table}path"
    terms, params = [f"{root} = ?", f"({root} >= ? AND {root} < ?)"], [folder, folder + "/", folder + "0"]
    for above in PurePosixPath(folder).parents:
        rel = PurePosixPath(folder).relative_to(above).as_posix()
        terms.append(f"({root} = ? AND {path} >= ? AND {path} < ?)")
        params += [above.as_posix(), rel + "/", rel + "0"]
    return "(" + " OR ".join(terms) + ")", params


def root_of(results: Path) -> str:
    """A results folder as the registry names it: absolute, '/'-separated."""
    return Path(results).resolve().as_posix()


# ---------------------------------------------------------------------------------------
# Writing


_UPSERT = (
    f"INSERT INTO unit_sessions ({', '.join(SESSION_COLUMNS)}) VALUES ({', '.join('?' * len(SESSION_COLUMNS))}) "
    "ON CONFLICT (root, path) DO UPDATE SET "
    + ", ".join(f"{c} = excluded.{c}" for c in SESSION_COLUMNS if c not in ("root", "path"))
)


def upsert(
    backend: Backend,
    rows: Sequence[Row],
    *,
    replace_under: str | None = None,
    unit_folders: Sequence[tuple[str, str]] = (),
) -> int:
    """Write ``rows`` in one transaction: each file's row replaced whole, with its
    coefficients; ``replace_under`` first drops every row of a file below that folder (a
    rebuild); ``unit_folders`` ((results folder, ``batch/device/session``): a fleet job's),
    every row of a file in those unit folders (a failure record the unit's new calibration
    replaced is no longer listed). Returns the rows written."""
    rows = sorted(rows, key=lambda row: (row.session["root"], row.session["path"]))
    with database_errors(backend.location), backend.transaction():
        # writers one at a time (SQLite's BEGIN IMMEDIATE; an advisory lock on PostgreSQL):
        # two replacing one file's coefficients at once would otherwise both insert them
        backend.serialise()
        if replace_under is not None:
            condition, params = under(replace_under)
            backend.execute(f"DELETE FROM parameters WHERE {condition}", params)
            backend.execute(f"DELETE FROM unit_sessions WHERE {condition}", params)
        else:
            keys = [(row.session["root"], row.session["path"]) for row in rows]
            backend.executemany("DELETE FROM parameters WHERE root = ? AND path = ?", keys)
        if unit_folders:  # one primary-key range a folder: its files are keyed by their layout
            ranges = [(root_of(Path(r)), f"{f}/", f"{f}0") for r, f in unit_folders]
            for table in ("parameters", "unit_sessions"):
                backend.executemany(f"DELETE FROM {table} WHERE root = ? AND path >= ? AND path < ?", ranges)
        backend.executemany(_UPSERT, [[row.session[c] for c in SESSION_COLUMNS] for row in rows])
        backend.insert_many("parameters", PARAMETER_COLUMNS, [p for row in rows for p in row.parameters])
    return len(rows)


def rebuild(results: Path, where: str | None = None, *, fresh: bool = False) -> tuple[str, int]:
    """The registry of ``results`` made again from its files (``fresh``: the whole
    registry dropped first); returns (where, rows)."""
    results = Path(results)
    if not results.is_dir():
        raise InputError("is not a results folder", source=results)
    target = location(results, where)
    backend = connect(target, fresh=fresh)
    try:
        return target, upsert(backend, rows_of(results), replace_under=root_of(results))
    finally:
        backend.close()


# ---------------------------------------------------------------------------------------
# Reading


def device_rows(backend: Backend, device: str, folder: str | None = None) -> list[dict[str, Any]]:
    """Every row of ``device`` (of files below ``folder``, as :func:`root_of` names it,
    where given: see :func:`under`), by session date (undated first) then root and path."""
    where, params = "device = ?", [device]
    if folder is not None:
        condition, more = under(folder)
        where, params = f"{where} AND {condition}", params + more
    with database_errors(backend.location):
        cursor = backend.execute(
            f"SELECT {', '.join(SESSION_COLUMNS)} FROM unit_sessions WHERE {where} "
            "ORDER BY session_day IS NOT NULL, session_day, root, path",  # undated first
            params,
        )
        return [dict(zip(SESSION_COLUMNS, values, strict=True)) for values in cursor.fetchall()]


def devices_near(backend: Backend, device: str, count: int = 5) -> list[str]:
    """Devices listed from ``device``'s place in name order on (a misspelt name shows its
    neighbours): read through the device index, as fast at a year's 12 million as at ten."""
    with database_errors(backend.location):
        cursor = backend.execute(
            "SELECT DISTINCT device FROM unit_sessions WHERE device >= ? ORDER BY device LIMIT ?",
            (device, count),
        )
        return [r[0] for r in cursor.fetchall()]


def served_file(row: dict[str, Any]) -> tuple[Path, bytes]:
    """The row's file and its bytes, when they are still the ones registered (the bytes
    hashed are the bytes served: a file replaced meanwhile cannot slip between); else a
    :class:`RegistryError`."""
    path = Path(row["root"]) / row["path"]
    try:
        raw = path.read_bytes()
    except OSError:
        raise RegistryError(
            f"the registry lists {row['path']}, which is missing: gyrocal registry check says which "
            "rows are stale, rebuild makes them again",
            source=path,
        ) from None
    if bytes_digest(raw, row["hash_algorithm"]) != row["file_hash"]:
        raise RegistryError(
            "changed since it was registered (its hash differs): gyrocal registry check says which "
            "rows are stale, rebuild makes them again",
            source=path,
        )
    return path, raw


def check(results: Path, where: str | None = None) -> list[str]:
    """What the registry says that its folder no longer does: rows of files below it whose
    file is missing or changed, and files below it it does not list (each as a path below
    ``results``). An empty list: the index is true."""
    results = Path(results)
    top = Path(root_of(results))
    backend = connect(location(results, where), create=False)
    try:
        condition, params = under(top.as_posix())
        with database_errors(backend.location):
            cursor = backend.execute(
                f"SELECT root, path, file_hash, hash_algorithm FROM unit_sessions WHERE {condition}", params
            )
            listed = cursor.fetchall()
    finally:
        backend.close()
    from ..io.log import file_digest

    problems = []
    known = set()
    for root, path, digest, algorithm in listed:
        rel = (Path(root) / path).relative_to(top).as_posix()
        known.add(rel)
        if not (top / rel).is_file():
            problems.append(f"{rel}: listed, but the file is missing")
        elif digest and file_digest(top / rel, algorithm) != digest:
            problems.append(f"{rel}: changed since it was registered (its hash differs)")
    for path, rel in _files(results):
        if rel not in known and file_row(path, rel, root_of(results)) is not None:
            problems.append(f"{rel}: not in the registry")
    return sorted(problems)


# Devices one query asks for: few statements for a fleet's 100,000, each well below the
# bound on a statement's parameters (SQLite's 32,766; PostgreSQL's 65,535).
DEVICES_PER_QUERY = 500


def earlier_rows(
    backend: Backend, devices: Iterable[str], own: set[tuple[str, str]], results: Path
) -> list[dict[str, Any]]:
    """The calibrated sessions the registry holds of ``devices`` in the results folder
    ``results`` (earlier runs into the same folder: another folder's rows, a shard's, would
    make a page depend on which job wrote first) other than ``own`` ((device, session)
    pairs: the run's), each once (its first path), by device, session date and path. Rows
    only, no file read: what planning a fleet needs to know which drift pages it makes."""
    condition, params = under(root_of(results))
    wanted = sorted(set(devices))
    found, seen = [], set(own)
    with database_errors(backend.location):
        for start in range(0, len(wanted), DEVICES_PER_QUERY):
            chunk = wanted[start : start + DEVICES_PER_QUERY]
            cursor = backend.execute(
                f"SELECT {', '.join(SESSION_COLUMNS)} FROM unit_sessions "
                f"WHERE device IN ({', '.join('?' * len(chunk))}) AND {condition} AND status = 'calibrated' "
                "ORDER BY device, session_day, root, path",
                [*chunk, *params],
            )
            for values in cursor.fetchall():
                row = dict(zip(SESSION_COLUMNS, values, strict=True))
                if (row["device"], row["session"]) not in seen:
                    seen.add((row["device"], row["session"]))
                    found.append(row)
    return found


HISTORY_NAME = "drift_history.jsonl"  # in the results folder: the plan's record, the fleet job's input
HISTORY_FIELDS = ("device", "batch", "session", "protocol", "root", "path", "file_hash", "hash_algorithm")


def planned_history(
    results: str | os.PathLike, registry: str | None, devices: Iterable[str], own: set[tuple[str, str]]
) -> list[dict[str, Any]]:
    """:func:`earlier_rows` for a fleet's plan: none where the run keeps no registry
    (``registry`` "") or it has none yet (no SQLite file, a database without its tables)."""
    if registry == "":
        return []
    results = Path(results)
    try:
        backend = connect(location(results, registry), create=False)
    except NoRegistryError:
        return []
    try:
        return earlier_rows(backend, devices, own, results)
    finally:
        backend.close()


def plan_history(
    results: str | os.PathLike,
    registry: str | None,
    devices: Iterable[str],
    own: set[tuple[str, str]],
    *,
    query: bool = True,
) -> list[dict[str, Any]]:
    """The earlier sessions a fleet's drift pages take, as the workflow plans them. The plan
    (``query``) asks the registry once (:func:`planned_history`) and records the answer in
    ``results/drift_history.jsonl``, rewritten only when it changed: the fleet job's input,
    so a changed history makes the pages again and an unchanged one leaves them be. A
    registry that cannot answer is a warning, and the record stands as it was (the units
    still run). A scheduler's job (not ``query``) reads the record: one query a run, not
    one a job."""
    record = Path(results) / HISTORY_NAME
    if not query:
        return read_history(record)
    try:
        rows = [{k: r[k] for k in HISTORY_FIELDS} for r in planned_history(results, registry, devices, own)]
    except RegistryUnavailable as exc:
        print(
            f"gyrocal: warning: {exc}; the drift pages are planned from {record} as it was", file=sys.stderr
        )
        rows = read_history(record)
    text = "".join(json.dumps(r, sort_keys=True, ensure_ascii=False) + "\n" for r in rows)
    if not record.is_file() or record.read_text(encoding="utf-8") != text:
        from ..io import atomic

        record.parent.mkdir(parents=True, exist_ok=True)
        atomic.write_text(record, text)
    return rows


def read_history(record: Path) -> list[dict[str, Any]]:
    """The sessions :func:`plan_history` recorded; none where there is no record."""
    try:
        lines = Path(record).read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise InputError(f"cannot read the drift pages' history ({exc.strerror})", source=record) from None
    rows = []
    for number, line in enumerate(lines, 1):
        try:
            row = json.loads(line)
        except ValueError:
            row = None
        if not isinstance(row, dict) or set(row) != set(HISTORY_FIELDS):
            raise InputError(
                f"line {number} is not a session of the drift pages' history; the next plan writes it again",
                source=record,
            )
        rows.append(row)
    return rows


def load_sessions(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Registry rows (:func:`earlier_rows`, :func:`read_history`) with each session's
    calibration loaded and its folder; a row whose file is missing or changed (never
    served) keeps its ``problem`` in place of a calibration, so that a drift page still
    says what it could not compare."""
    from .file import Calibration

    found = []
    for row in rows:
        session = {k: row[k] for k in ("device", "batch", "session", "protocol", "path", "file_hash")}
        try:
            path, raw = served_file(row)
            session["calibration"] = Calibration.from_dict(json.loads(raw), source=path)
            session["folder"] = path.parent
        except GyrocalError as exc:
            session["problem"] = str(exc)
        found.append(session)
    return found


def earlier_sessions(
    backend: Backend, devices: Iterable[str], own: set[tuple[str, str]], results: Path
) -> list[dict[str, Any]]:
    """:func:`earlier_rows`, loaded (:func:`load_sessions`)."""
    return load_sessions(earlier_rows(backend, devices, own, results))


def drift(
    backend: Backend,
    *,
    batch: str | None = None,
    device: str | None = None,
    temperature: float = 25.0,
    within: float | None = None,
    names: Sequence[str] = (),
    folder: str | None = None,
) -> list[dict[str, Any]]:
    """How a batch's (or a device's) coefficients move across sessions: each calibrated
    session's coefficients at its temperature point nearest ``temperature`` (within
    ``within`` °C; of two as near, the first), one dict per session and coefficient:
    session, device, name, value, stderr, temperature. ``names`` keeps only those
    coefficients (prefixes: ``bias``); ``folder``, only files below it (:func:`under`)."""
    if (batch is None) == (device is None):
        raise ConfigError("drift is of a batch or of a device: give one")
    within = DRIFT_WITHIN if within is None else within
    key, value = ("batch", batch) if batch is not None else ("device", device)
    condition, params = ("", []) if folder is None else under(folder, "s.")
    with database_errors(backend.location):
        cursor = backend.execute(
            "SELECT s.session, s.device, s.root, s.path, p.point, p.temperature, p.name, p.value, p.stderr "
            "FROM unit_sessions s JOIN parameters p ON p.root = s.root AND p.path = s.path "
            f"WHERE s.{key} = ? AND s.status = 'calibrated' AND p.point >= 0 "
            f"AND p.temperature BETWEEN ? AND ? {'AND ' + condition if condition else ''} "
            "ORDER BY s.session_day, s.root, s.path, p.point, p.name",
            (value, temperature - within, temperature + within, *params),
        )
        rows = cursor.fetchall()
    nearest: dict[tuple, tuple[float, int]] = {}
    for _, _, root, path, point, temp, *_ in rows:  # each file's point nearest the temperature
        here = (abs(temp - temperature), point)
        nearest[(root, path)] = min(here, nearest.get((root, path), here))
    out = []
    for session, dev, root, path, point, temp, name, val, se in rows:
        if point != nearest[(root, path)][1]:
            continue
        if names and not any(name == n or name.startswith(n + ".") for n in names):
            continue
        out.append(
            {"session": session, "device": dev, "name": name, "value": val, "stderr": se, "temperature": temp}
        )
    return out


def monthly(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """:func:`drift`'s rows per month and coefficient: calibrations, mean, standard deviation."""
    import numpy as np

    groups: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        groups.setdefault((str(r["session"])[:7], r["name"]), []).append(r["value"])
    return [
        {
            "month": month,
            "name": name,
            "calibrations": len(values),
            "mean": float(np.mean(values)),
            "std": float(np.std(values, ddof=1)) if len(values) > 1 else None,
        }
        for (month, name), values in sorted(groups.items())
    ]


# ---------------------------------------------------------------------------------------
# Command line


def cmd_registry(args) -> int:
    import sys
    import time

    results = Path(args.results)
    if args.action == "rebuild":
        start = time.perf_counter()
        where, rows = rebuild(results, args.registry, fresh=args.fresh)
        print(f"registry {_redacted(where)}: {rows} files indexed in {time.perf_counter() - start:.1f} s")
        return 0
    problems = check(results, args.registry)
    for line in problems:
        print(f"gyrocal: stale: {line}", file=sys.stderr)
    where = _redacted(location(results, args.registry))
    if problems:
        print(
            f"registry {where}: {len(problems)} stale rows or files; gyrocal registry rebuild {results} makes it true"
        )
        return 1
    print(f"registry {where}: every row's file is there, as registered, and every file is listed")
    return 0


def cmd_drift(args) -> int:
    """A batch's coefficients per month, or a device's per session, from the registry."""
    results = Path(args.results)
    backend = connect(location(results, args.registry), create=False)
    try:
        rows = drift(
            backend,
            batch=args.batch,
            device=args.device,
            temperature=args.temperature,
            names=tuple(args.name or ()),
            folder=root_of(results),
        )
    finally:
        backend.close()
    if not rows:
        who = f"batch {args.batch}" if args.batch is not None else f"device {args.device}"
        raise RegistryError(
            f"no calibration of {who} below {results} with a point within {DRIFT_WITHIN:g} °C of "
            f"{args.temperature:g} °C"
        )
    if args.device is not None:
        print(f"{'session':<12} {'coefficient':<22} {'value':>14} {'stderr':>12} {'at °C':>8}")
        for r in rows:
            se = "–" if r["stderr"] is None else f"{r['stderr']:.4g}"
            print(f"{r['session']:<12} {r['name']:<22} {r['value']:>14.6g} {se:>12} {r['temperature']:>8.2f}")
        return 0
    print(f"{'month':<8} {'coefficient':<22} {'calibs':>6} {'mean':>14} {'std':>12}")
    for m in monthly(rows):
        std = "–" if m["std"] is None else f"{m['std']:.4g}"
        print(f"{m['month']:<8} {m['name']:<22} {m['calibrations']:>6} {m['mean']:>14.6g} {std:>12}")
    return 0


def add_drift_parser(subparsers):
    """Register ``gyrocal drift`` on the CLI's subparsers."""
    p = subparsers.add_parser("drift", help="a batch's coefficients per month, or a device's per session")
    p.add_argument("results", help="the results folder whose calibrations (and registry) to read")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--batch", help="the batch: its units' coefficients per month (mean, spread)")
    who.add_argument("--device", help="the unit: its coefficients at each session")
    p.add_argument(
        "--temperature",
        type=float,
        default=25.0,
        help="each calibration's point nearest this, °C, within 5 (default 25)",
    )
    p.add_argument(
        "--name", action="append", help="only this coefficient or family (bias, scale.x.x; repeatable)"
    )
    p.add_argument("--registry", help=f"the registry (default RESULTS/{DEFAULT_NAME})")
    p.set_defaults(func=cmd_drift)
    return p


def add_registry_parser(subparsers):
    """Register ``gyrocal registry rebuild|check`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        "registry", help="index a results folder's calibrations in a database (SQLite, PostgreSQL)"
    )
    p.add_argument(
        "action", choices=("rebuild", "check"), help="rebuild: index every file again; check: list stale rows"
    )
    p.add_argument("results", help="the results folder (the workflow's results/)")
    p.add_argument(
        "--registry",
        help=f"the database: a postgresql:// URL or an SQLite file (default RESULTS/{DEFAULT_NAME})",
    )
    p.add_argument(
        "--fresh",
        action="store_true",
        help="rebuild: drop the whole registry first (other results folders' rows too): "
        "how a registry of an older schema version is made again",
    )
    p.set_defaults(func=cmd_registry)
    return p
