"""Mutated rig logs and the properties ingest and the command line must keep.

Shared by ``tests/io/test_fuzzed_logs.py`` (a few examples in every run) and ``benchmarks/fuzz.py``
(the long campaign). A case is a small valid log, simulated once, and a list of mutations,
each a plain tuple, so a failing case prints as its own reproducer:
``write_case(base_table, case, folder)`` rebuilds the file from the printed ``Case``.

The properties (``check_ingest``, ``check_cli``) return the outcome's class (``"success"``
or the gyrocal error's class name) and raise :class:`Violation` when the property fails.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import shutil
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from hypothesis import strategies as st

from gyrocal.io import log as gio
from gyrocal.io import readahead
from gyrocal.io.errors import GyrocalError, InputError
from gyrocal.run import cli

REQUIRED = gio.REQUIRED
COLUMNS = (*REQUIRED, "mount", *gio.ACCEL)

# The base log: three temperature points, two rates, 20 Hz; about 4000 rows that calibrate
# in a tenth of a second, so that most of an example's time is the mutated part.
BASE_RIG = dict(
    temperatures=(0.0, 20.0, 40.0),
    rates=(10.0, 100.0),
    sample_rate=20.0,
    soak_s=10.0,
    hold_s=3.0,
    handling_s=2.0,
)


def make_base_log(directory: Path) -> Path:
    from gyrocal.simulate import GyroUnit, TurntableProtocol, simulate_unit

    path = Path(directory) / "base.parquet"
    simulate_unit(
        path,
        rig=TurntableProtocol.quick(**BASE_RIG),
        unit=GyroUnit.seed000(),
        rng=np.random.default_rng(1),
        device="F001",
        seed=1,
    )
    return path


# ---------------------------------------------------------------------------------------
# Mutations: ("op", *arguments). Row positions are fractions of the current length so that
# a mutation means the same thing after others changed the length.

VALUES = (
    math.nan,
    math.inf,
    -math.inf,
    0.0,
    -0.0,
    1e308,
    -1e308,
    3.4028235e38,
    1e38,
    1e-310,
    5e-324,
    1e20,
    -1e20,
    2.0**63,
    1e6,
    -1.0,
)
TYPES = (
    "float16",
    "float32",
    "float64",
    "int8",
    "int32",
    "int64",
    "uint64",
    "bool",
    "string",
    "large_string",
    "binary",
    "timestamp[s]",
    "timestamp[ms]",
    "timestamp[us]",
    "timestamp[ns]",
    "timestamp[ns, UTC]",
    "date32",
    "duration[s]",
    "decimal",
    "dictionary",
    "null",
    "list",
    "struct",
)
NAMES = (*COLUMNS, "T", "Gyro_x", "gyro_x ", "", "extra", "__index_level_0__")
LABELS = ("+x", "-z", "", "x", "+X", " +x", "+x ", "±x", "\x00", "+x" * 40, "None", "nan")
UNIT_STRINGS = ("deg/s", "rad/s", "dps", "g", "m/s^2", "m/s2", "K", "degC", "°C", "C", "F", "", "RAD/S")
UNITS_PAYLOADS = (
    b"",
    b"{",
    b"null",
    b"[]",
    b"42",
    b'"rad/s"',
    b"\xff\xfe",
    b"NaN",
    b'{"gyro": "rad/s", "ref_rate": "rad/s"}',
    b'{"gyro": 5}',
    b'{"gyro": ["rad/s"]}',
    b'{"gyro": {"unit": "rad/s"}}',
    b'{"gyro": null}',
    b'{"temp": "K"}',
    b'{"accel": "m/s^2"}',
    b'{"gyro": "dps"}',
    b'{"other": "thing"}',
    b'{"gyro": "rad/s", "gyro": "deg/s"}',
    b'{"temp": ["K"]}',
    b'{"ref_rate": true}',
)
METADATA_KEYS = (gio.UNITS_KEY, b"ARROW:schema", b"pandas", b"other")

fraction = st.floats(0.0, 1.0)
small_count = st.integers(0, 50)


def _json_values():
    scalars = (
        st.none()
        | st.booleans()
        | st.floats()
        | st.integers()
        | st.sampled_from(UNIT_STRINGS)
        | st.text(max_size=6)
    )
    return st.recursive(
        scalars,
        lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=6), c, max_size=3),
        max_leaves=6,
    )


units_payload = st.one_of(
    st.sampled_from(UNITS_PAYLOADS),
    st.dictionaries(
        st.sampled_from(("gyro", "ref_rate", "temp", "accel", "t", "mount")),
        st.sampled_from(UNIT_STRINGS) | _json_values(),
        max_size=4,
    ).map(lambda d: json.dumps(d).encode()),
    _json_values().map(lambda v: json.dumps(v).encode()),
    st.binary(max_size=12),
)

column = st.sampled_from(COLUMNS)
mutation = st.one_of(
    st.tuples(st.just("drop"), column),
    st.tuples(st.just("rename"), column, st.sampled_from(NAMES)),
    st.tuples(st.just("duplicate"), column),
    st.tuples(st.just("add"), st.sampled_from(NAMES), st.sampled_from(TYPES)),
    st.tuples(st.just("cast"), column, st.sampled_from(TYPES)),
    st.tuples(st.just("nulls"), column, fraction, small_count),
    st.tuples(st.just("set"), column, fraction, small_count, st.sampled_from(VALUES)),
    st.tuples(st.just("set_all"), column, st.sampled_from(VALUES)),
    st.tuples(st.just("scale"), column, st.sampled_from((0.0, -1.0, 1e-3, 1e3, 1e30, 1e300))),
    st.tuples(st.just("offset"), column, st.sampled_from((-1e6, 1e9, 1e15, 1e300))),
    st.tuples(
        st.just("rows"), st.sampled_from(("reverse", "duplicate", "delete", "shuffle")), fraction, small_count
    ),
    st.tuples(st.just("sort"), column),
    st.tuples(st.just("head"), st.sampled_from((0, 1, 2, 3, 5, 17, 100))),
    st.tuples(st.just("tail"), st.sampled_from((1, 2, 7, 100))),
    st.tuples(st.just("units"), units_payload),
    st.tuples(st.just("meta"), st.sampled_from(METADATA_KEYS), st.binary(max_size=16)),
    st.tuples(
        st.just("mount_label"),
        fraction,
        small_count,
        st.sampled_from(LABELS) | st.text(max_size=4) | st.none(),
    ),
)
# Mutations a log can take and still calibrate: they send examples past ingest, deeper
# into segmentation and the fit.
soft_mutation = st.one_of(
    st.tuples(st.just("set"), column, fraction, small_count, st.sampled_from(VALUES)),
    st.tuples(st.just("nulls"), column, fraction, small_count),
    st.tuples(st.just("drop"), st.sampled_from(("mount", *gio.ACCEL))),
    st.tuples(
        st.just("cast"),
        st.sampled_from(COLUMNS),
        st.sampled_from(
            (
                "float32",
                "float64",
                "float16",
                "string",
                "large_string",
                "dictionary",
                "timestamp[ns]",
                "timestamp[ms]",
                "timestamp[ns, UTC]",
            )
        ),
    ),
    st.tuples(
        st.just("units"),
        st.sampled_from(
            (
                b'{"gyro": "rad/s", "ref_rate": "rad/s"}',
                b'{"temp": "K"}',
                b'{"accel": "m/s^2"}',
                b'{"gyro": "rad/s"}',
                b'{"other": 1}',
            )
        ),
    ),
    st.tuples(st.just("mount_label"), fraction, small_count, st.sampled_from(("+x", "-z", None))),
    st.tuples(st.just("rows"), st.just("delete"), fraction, small_count),
    st.tuples(
        st.just("scale"),
        st.sampled_from(("gyro_x", "gyro_y", "gyro_z", "temp", "accel_x")),
        st.sampled_from((0.0, -1.0, 1e3, 1e30)),
    ),
)
damage = st.one_of(
    st.tuples(st.just("truncate"), fraction),
    st.tuples(st.just("flip"), fraction, st.integers(1, 255)),
    st.tuples(st.just("flip_tail"), st.integers(1, 400), st.integers(1, 255)),
    st.tuples(st.just("zero"), fraction, st.integers(1, 64)),
    st.tuples(st.just("append"), st.binary(max_size=16)),
    st.just(("empty",)),
)


@dataclass(frozen=True)
class Case:
    """One mutated log: table mutations, how it is written, byte damage, its file name."""

    mutations: tuple = ()
    row_group_rows: int | None = None
    parts: int = 0  # 0: one file; k: a directory of k files
    part_mutations: tuple = ()  # (part, mutation): one file of a directory differs
    damage: tuple = ()  # byte-level, to the file (or a directory's first part)
    name: str = "log.parquet"
    read_batch_rows: int | None = None  # ingest's batch size (None: gyrocal's own)


NAME_CHOICES = ("log.parquet", "a log ü.parquet", "log", "log.PARQUET")


@st.composite
def cases(draw, soft: bool = False):
    ops = st.lists(soft_mutation if soft else st.one_of(mutation, mutation, soft_mutation), max_size=4)
    parts = draw(st.sampled_from((0, 0, 0, 1, 2, 3)))
    return Case(
        mutations=tuple(draw(ops)),
        row_group_rows=draw(st.sampled_from((None, None, 1000, 97))),
        parts=parts,
        part_mutations=tuple(draw(st.lists(st.tuples(st.integers(0, 2), mutation), max_size=1)))
        if parts > 1 and not soft
        else (),
        damage=tuple(draw(st.lists(damage, max_size=2))) if not soft and draw(st.booleans()) else (),
        name=draw(st.sampled_from(NAME_CHOICES)) if not soft else "log.parquet",
        read_batch_rows=draw(st.sampled_from((None, None, 61, 1000))),
    )


# ---------------------------------------------------------------------------------------
# Building the file


def _values(col: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """A column as float64, whatever it became (a non-numeric one as its row numbers)."""
    if isinstance(col, pa.ChunkedArray):
        col = col.combine_chunks() if col.num_chunks else pa.array([], col.type)
    if pa.types.is_dictionary(col.type):
        col = col.dictionary_decode() if hasattr(col, "dictionary_decode") else col.cast(col.type.value_type)
    try:
        if pa.types.is_timestamp(col.type) or pa.types.is_duration(col.type):
            col = col.cast(pa.int64())
        return col.cast(pa.float64(), safe=False).to_numpy(zero_copy_only=False).astype(float)
    except (pa.ArrowException, ValueError, TypeError):
        return np.arange(len(col), dtype=float)


EPOCH_S = 1_700_000_000


def convert(values: np.ndarray, kind: str, source: pa.Array | None = None) -> pa.Array:
    """float64 values as a column of type ``kind`` (non-finite values become nulls where the
    type has no NaN)."""
    n = len(values)
    finite = np.isfinite(values)
    mask = ~finite
    with np.errstate(all="ignore"):
        safe = np.where(finite, values, 0.0)
        if kind in ("float16", "float32", "float64"):
            return pa.array(values.astype(kind), type=getattr(pa, kind)())
        if kind in ("int8", "int32", "int64", "uint64"):
            info = np.iinfo(kind)
            ints = np.clip(np.round(safe), info.min, info.max).astype(kind)
            return pa.array(ints, mask=mask)
        if kind == "bool":
            return pa.array(safe != 0, mask=mask)
        if kind in ("string", "large_string", "binary"):
            if source is not None and (
                pa.types.is_dictionary(source.type) or pa.types.is_string(source.type)
            ):
                text = source.cast(pa.string()) if pa.types.is_dictionary(source.type) else source
                return text.cast(
                    {"string": pa.string(), "large_string": pa.large_string(), "binary": pa.binary()}[kind]
                )
            texts = [repr(float(v)) for v in values]
            typ = {"string": pa.string(), "large_string": pa.large_string(), "binary": pa.binary()}[kind]
            return pa.array(texts, type=typ)
        if kind.startswith("timestamp"):
            unit = kind[kind.index("[") + 1 :].split(",")[0].rstrip("]")
            per = {"s": 1, "ms": 10**3, "us": 10**6, "ns": 10**9}[unit]
            limit = 9e18 / per - EPOCH_S
            ticks = (np.clip(safe, -limit, limit) * per).astype(np.int64) + EPOCH_S * per
            return pa.array(ticks, type=pa.timestamp(unit, tz="UTC" if "UTC" in kind else None), mask=mask)
        if kind == "date32":
            return pa.array(np.clip(safe / 86400, -1e6, 1e6).astype(np.int32), type=pa.date32(), mask=mask)
        if kind == "duration[s]":
            return pa.array(np.clip(safe, -9e18, 9e18).astype(np.int64), type=pa.duration("s"), mask=mask)
        if kind == "decimal":
            clipped = np.clip(safe, -1e8, 1e8)
            return pa.array(clipped, mask=mask).cast(pa.decimal128(12, 3), safe=False)
        if kind == "dictionary":
            if source is not None and pa.types.is_dictionary(source.type):
                return source
            if source is not None and pa.types.is_string(source.type):
                return source.dictionary_encode()
            return pa.array(values).dictionary_encode()
        if kind == "null":
            return pa.nulls(n)
        if kind == "list":
            return pa.array([[float(v)] for v in values], type=pa.list_(pa.float64()))
        if kind == "struct":
            return pa.StructArray.from_arrays([pa.array(values)], names=["value"])
    raise ValueError(f"unknown type {kind}")


def _index(table: pa.Table, name: str) -> int | None:
    names = table.column_names
    return names.index(name) if name in names else None


def _column(table: pa.Table, i: int) -> pa.Array:
    col = table.column(i)
    return col.combine_chunks() if col.num_chunks else pa.array([], col.type)


def _replace(table: pa.Table, i: int, array: pa.Array) -> pa.Table:
    return table.set_column(i, pa.field(table.schema.field(i).name, array.type), array)


def _span(n: int, frac: float, count: int) -> tuple[int, int]:
    start = min(int(frac * n), n)
    return start, min(start + count, n)


def mutate(table: pa.Table, op: tuple) -> pa.Table:
    """``table`` after one mutation (a mutation of a column the table lacks does nothing)."""
    kind, args = op[0], op[1:]
    n = table.num_rows
    if kind in ("drop", "rename", "duplicate", "cast", "nulls", "set", "set_all", "scale", "offset", "sort"):
        i = _index(table, args[0])
        if i is None:
            return table
        col = _column(table, i)
        if kind == "drop":
            return table.remove_column(i)
        if kind == "rename":
            names = list(table.column_names)
            names[i] = args[1]
            return table.rename_columns(names)
        if kind == "duplicate":
            return table.append_column(table.schema.field(i), col)
        if kind == "cast":
            return _replace(table, i, convert(_values(col), args[1], col))
        if kind == "sort":
            return table.take(pa.array(np.argsort(_values(col), kind="stable")))
        if kind == "nulls":
            lo, hi = _span(n, args[1], args[2])
            keep = np.ones(n, bool)
            keep[lo:hi] = False
            return _replace(table, i, pc.if_else(pa.array(keep), col, pa.nulls(n, col.type)))
        if pa.types.is_dictionary(col.type) or pa.types.is_string(col.type):
            return table  # value mutations are for numbers; labels have their own
        values = _values(col).copy()
        with np.errstate(all="ignore"):
            if kind == "set":
                lo, hi = _span(n, args[1], args[2])
                values[lo:hi] = args[3]
            elif kind == "set_all":
                values[:] = args[1]
            elif kind == "scale":
                values = values * args[1]
            else:
                values = values + args[1]
        typ = col.type
        kind_of = {pa.float32(): "float32", pa.float64(): "float64", pa.float16(): "float16"}
        target = kind_of.get(typ) or ("timestamp[ns]" if pa.types.is_timestamp(typ) else "float64")
        return _replace(table, i, convert(values, target))
    if kind == "add":
        values = np.arange(n, dtype=float) * 0.05
        return table.append_column(args[0], convert(values, args[1]))
    if kind == "rows":
        order = np.arange(n)
        lo, hi = _span(n, args[1], args[2])
        how = args[0]
        if how == "reverse":
            order[lo:hi] = order[lo:hi][::-1]
        elif how == "duplicate":
            order = np.concatenate([order[:hi], order[lo:hi], order[hi:]])
        elif how == "delete":
            order = np.concatenate([order[:lo], order[hi:]])
        else:
            part = order[lo:hi].copy()
            np.random.default_rng(lo + hi).shuffle(part)
            order[lo:hi] = part
        return table.take(pa.array(order, type=pa.int64()))
    if kind == "head":
        return table.slice(0, args[0])
    if kind == "tail":
        return table.slice(max(n - args[0], 0))
    if kind == "units":
        return table.replace_schema_metadata({**(table.schema.metadata or {}), gio.UNITS_KEY: args[0]})
    if kind == "meta":
        return table.replace_schema_metadata({**(table.schema.metadata or {}), args[0]: args[1]})
    if kind == "mount_label":
        i = _index(table, "mount")
        if i is None:
            return table
        col = _column(table, i)
        if not (
            pa.types.is_dictionary(col.type)
            or pa.types.is_string(col.type)
            or pa.types.is_large_string(col.type)
        ):
            return table
        labels = (col.cast(pa.string()) if pa.types.is_dictionary(col.type) else col).to_pylist()
        lo, hi = _span(n, args[0], args[1])
        labels[lo:hi] = [args[2]] * (hi - lo)
        array = pa.array(labels, type=pa.string())
        return _replace(table, i, array.dictionary_encode() if pa.types.is_dictionary(col.type) else array)
    raise ValueError(f"unknown mutation {op!r}")


def corrupt(data: bytes, op: tuple) -> bytes:
    kind, args = op[0], op[1:]
    n = len(data)
    if kind == "truncate":
        return data[: int(args[0] * n)]
    if kind == "flip" and n:
        i = min(int(args[0] * n), n - 1)
        return data[:i] + bytes([data[i] ^ args[1]]) + data[i + 1 :]
    if kind == "flip_tail" and n:
        i = max(n - args[0], 0)
        return data[:i] + bytes([data[i] ^ args[1]]) + data[i + 1 :]
    if kind == "zero" and n:
        i = min(int(args[0] * n), n)
        return data[:i] + bytes(min(args[1], n - i)) + data[i + args[1] :]
    if kind == "append":
        return data + args[0]
    if kind == "empty":
        return b""
    return data


def _write_table(table: pa.Table, path: Path, row_group_rows: int | None) -> None:
    try:
        pq.write_table(table, path, row_group_size=row_group_rows)
    except (pa.ArrowException, ValueError, TypeError) as exc:
        # A table Parquet cannot hold (a column of a type Parquet lacks): no such file can
        # reach gyrocal, so the example is discarded.
        raise Unwritable(str(exc)) from None


class Unwritable(Exception):
    """The mutated table cannot be written as Parquet."""


def write_case(base: pa.Table, case: Case, folder: Path) -> Path:
    """Write ``case`` into ``folder`` (fresh or empty); the path gyrocal is given."""
    table = base
    for op in case.mutations:
        table = mutate(table, op)
    path = Path(folder) / case.name
    if case.parts == 0:
        _write_table(table, path, case.row_group_rows)
        targets = [path]
    else:
        path.mkdir()
        n = table.num_rows
        bounds = [round(k * n / case.parts) for k in range(case.parts + 1)]
        targets = []
        for k in range(case.parts):
            part = table.slice(bounds[k], bounds[k + 1] - bounds[k])
            for index, op in case.part_mutations:
                if index == k:
                    part = mutate(part, op)
            # Names that sort against time order: the reader must order parts by time.
            target = path / f"part-{case.parts - k}.parquet"
            _write_table(part, target, case.row_group_rows)
            targets.append(target)
    data = targets[0].read_bytes()
    for op in case.damage:
        data = corrupt(data, op)
    if case.damage:
        targets[0].write_bytes(data)
    return path


# ---------------------------------------------------------------------------------------
# Properties


class Violation(AssertionError):
    """A property failed: ``kind`` says which, the message says how."""

    def __init__(self, kind: str, detail: str):
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


def signature(exc: BaseException) -> str:
    """Where an unexpected exception comes from (its type and innermost gyrocal frame): one
    bug, however many examples hit it."""
    import traceback

    frames = [
        f
        for f in traceback.extract_tb(exc.__traceback__)
        if "gyrocal" in f.filename and "/tests/" not in f.filename
    ]
    where = f"{Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else "?"
    return f"{type(exc).__name__} at {where}"


def check_error_message(exc: GyrocalError, path: Path) -> str:
    """A refused log: bad input (exit status 2), one line, naming the file first."""
    text = str(exc)
    if not isinstance(exc, InputError):
        raise Violation("not bad input", f"{type(exc).__name__} (exit status {exc.exit_status}): {text}")
    if "\n" in text or "\r" in text:
        raise Violation("message not one line", repr(text))
    if not text.startswith(f"{path}: ") or len(text) <= len(f"{path}: "):
        raise Violation("message does not name the file", repr(text))
    return type(exc).__name__


@contextlib.contextmanager
def batch_rows(rows: int | None):
    """Ingest reads batches of ``rows`` rows: a small log crosses the batch boundaries a
    log of millions of rows would."""
    saved = gio.READ_BATCH_ROWS
    if rows is not None:
        gio.READ_BATCH_ROWS = rows
    try:
        yield
    finally:
        gio.READ_BATCH_ROWS = saved


PIPELINE_KEEP = (None, 384 * 2**20, 0)  # in memory; gyrocal.pipeline.chain's budget; re-read


def check_ingest(path: Path, keep_bytes: float | None = None, read_rows: int | None = None) -> str:
    """Read ``path`` as the pipeline does (``read_log`` with segmentation's optional
    columns and a block sink). Success: every kept row finite in the required columns,
    ``t`` strictly increasing across batches, mount codes known, rows counted, block
    statistics free of NaN. Failure: a gyrocal input error naming the file in one line."""
    from gyrocal.io.blocks import BlockSink
    from gyrocal.protocols.turntable.segment import LOG_COLUMNS

    sink = BlockSink(1.0)
    try:
        with batch_rows(read_rows):
            log = gio.read_log(path, optional=LOG_COLUMNS, sink=sink, keep_bytes=keep_bytes)
            batches = list(log.scan())
    except GyrocalError as exc:
        return check_error_message(exc, path)
    except Exception as exc:  # noqa: BLE001 - any other exception is what we look for
        raise Violation(
            "exception", f"{signature(exc)}: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
        ) from exc
    kept = sum(len(b["t"]) for b in batches)
    if kept < 1 or kept != len(log) or log.rows_read != kept + log.rows_dropped:
        raise Violation(
            "row count", f"read {log.rows_read}, kept {len(log)} (scan {kept}), dropped {log.rows_dropped}"
        )
    previous = -math.inf
    for b in batches:
        for name in REQUIRED:
            if not np.all(np.isfinite(b[name])):
                raise Violation("non-finite value kept", f"column {name}")
        t = b["t"]
        if t[0] <= previous or np.any(np.diff(t) <= 0):
            raise Violation("t not increasing", f"after {previous}: {t[:5]}")
        previous = t[-1]
        if "mount" in b and (
            b["mount"].dtype != np.int8 or b["mount"].min() < -1 or b["mount"].max() >= len(gio.MOUNTS)
        ):
            raise Violation("mount code", repr(np.unique(b["mount"])))
    stats, _, _ = sink.result()
    for key in ("t_first", "t_last", "ref", "temp", "gyro"):
        if key in stats and np.isnan(stats[key]).any():
            raise Violation("NaN in block statistics", key)
    return "success"


def _strict_json(text: str):
    def refuse(constant):
        raise Violation("NaN written", f"the output holds {constant}")

    return json.loads(text, parse_constant=refuse)


@contextlib.contextmanager
def recording_errors():
    """The gyrocal errors made meanwhile, so that a command's refusal is tallied by its
    class (the CLI prints only the message)."""
    made: list[GyrocalError] = []
    original = GyrocalError.__init__

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    GyrocalError.__init__ = init
    try:
        yield made
    finally:
        GyrocalError.__init__ = original


def run_cli(argv: list[str], *, as_process_start: bool = False) -> tuple[int, str, str, str]:
    """``gyrocal ARGV`` in this process: (exit status, stdout, stderr, the class of the
    error it printed or ""). With ``as_process_start`` the command line is read from
    ``sys.argv`` as the console entry point does, so the log is decoded ahead on a thread
    (gyrocal.io.readahead)."""
    out, err = io.StringIO(), io.StringIO()
    saved_argv = sys.argv
    try:
        # catch_warnings: a warning shown by an earlier example is shown again (a fresh
        # process), and the command's one-line warning printer is undone afterwards.
        with (
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            recording_errors() as made,
            warnings.catch_warnings(),
        ):
            if as_process_start:
                sys.argv = ["gyrocal", *argv]
                status = cli.main()
            else:
                status = cli.main(argv)
    except SystemExit as exc:  # argparse's own exit
        status = exc.code if isinstance(exc.code, int) else 2
    finally:
        sys.argv = saved_argv
        # One command is one process in real use: a read-ahead the command never took
        # (it failed before reading) must not outlive this example.
        with readahead._lock:
            for ahead in readahead._pending.values():
                ahead.stopped.set()
            readahead._pending.clear()
    printed = err.getvalue()
    shown = [e for e in made if f"gyrocal: error: {e}" in printed]
    return status, out.getvalue(), printed, type(shown[-1]).__name__ if shown else ""


def check_stderr(status: int, stderr: str, path: Path) -> None:
    lines = stderr.splitlines()
    if "Traceback" in stderr:
        raise Violation("traceback", stderr[-600:])
    for line in lines:
        if not line.startswith(("gyrocal: error: ", "gyrocal: warning: ")):
            raise Violation("stderr line not gyrocal's", repr(line[:300]))
    errors = [line for line in lines if line.startswith("gyrocal: error: ")]
    if status == 0 and errors:
        raise Violation("error printed on success", errors[0])
    if status != 0:
        if len(errors) != 1 or lines[-1] != errors[0]:
            raise Violation("not one error line", repr(stderr[-600:]))
        if f"{path}" not in errors[0]:
            raise Violation("message does not name the file", errors[0])


def check_cli(
    command: str,
    path: Path,
    scratch: Path,
    *,
    calibration: Path | None = None,
    protocol: str = "turntable",
    as_process_start: bool = False,
) -> tuple[str, str]:
    """Run ``gyrocal COMMAND`` on the log at ``path``: exit status 0 or 2 (never 1, an
    internal error), stderr gyrocal's one-line messages (exactly one error line naming the
    file on failure), no output left on failure, and no NaN in what is written
    (calibrations; a compensated log only where the command said it wrote NaN).
    Returns (outcome, the command's error line or "")."""
    if command == "calibrate":
        out = scratch / "cal.json"
        argv = ["calibrate", str(path), "-o", str(out), "--protocol", protocol]
    elif command == "apply":
        out = scratch / "out.parquet"
        argv = ["apply", str(calibration), str(path), "-o", str(out)]
    else:
        raise ValueError(command)
    status, stdout, stderr, shown = run_cli(argv, as_process_start=as_process_start)
    if status not in (0, 2):
        raise Violation(f"exit status {status}", stderr.strip()[-600:])
    check_stderr(status, stderr, path)
    leftovers = sorted(p.name for p in scratch.iterdir() if p.name.endswith(".tmp"))
    if leftovers:
        raise Violation("temporary file left", ", ".join(leftovers))
    if status != 0:
        if out.exists():
            raise Violation("output written on failure", out.name)
        return shown or "error of no gyrocal class", stderr.strip()
    if not out.exists():
        raise Violation("no output on success", out.name)
    if command == "calibrate":
        doc = _strict_json(out.read_text())
        if doc.get("format") != "gyrocal.calibration/1":
            raise Violation("not a calibration", repr(doc.get("format")))
    else:
        _check_applied(out, stderr)
    return "success", ""


def _check_applied(out: Path, stderr: str) -> None:
    """Every non-finite rate written is a NaN the command counted in its warning."""
    import re

    table = pq.read_table(out)
    gyro = np.column_stack([table.column(c).to_numpy(zero_copy_only=False) for c in gio.GYRO])
    if np.isinf(gyro).any():
        raise Violation("NaN written", "an infinite rate")
    nan_rows = int(np.isnan(gyro).any(axis=1).sum())
    said = re.search(r"(\d+) rows with a non-finite gyro .* were written as NaN", stderr)
    if nan_rows != (int(said.group(1)) if said else 0):
        raise Violation(
            "NaN written", f"{nan_rows} rows of NaN, the command said {said.group(1) if said else 0}"
        )


def fresh(folder: Path) -> Path:
    """An empty folder for one example."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    return folder
