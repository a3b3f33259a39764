"""Reading rig logs (contract section 1) into validated column arrays.

Only the columns a stage needs are read. Everything downstream works on whole-column
numpy arrays in deg/s, °C, g and seconds, whatever units the log declared.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from . import readahead
from .errors import CorruptFileError, EmptyLogError, LogFormatError, first_line

if TYPE_CHECKING:
    from .plausibility import InputSummary

GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")
REQUIRED = ("t", *GYRO, "temp", "ref_rate")
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
# The `section` annotation of a hand-rotation session (docs/log-format.md): a face per sensor
# axis up (p) and down (a), a full turn about each axis.
FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
TURNS = ("x_rot", "y_rot", "z_rot")
SECTIONS = FACES + TURNS
UNITS_KEY = b"gyrocal.units"

# Accepted unit strings per quantity and the factor to the internal unit. The contract
# defines "gyro" and "ref_rate"; "accel" and "temp" are documented extensions.
UNIT_FACTORS = {
    "gyro": {"deg/s": 1.0, "rad/s": 180.0 / math.pi, "mdps": 1e-3},
    "ref_rate": {"deg/s": 1.0, "rad/s": 180.0 / math.pi, "mdps": 1e-3},
    "accel": {"g": 1.0, "m/s^2": 1.0 / 9.80665, "m/s2": 1.0 / 9.80665},
    "temp": {"degC": 0.0, "°C": 0.0, "C": 0.0, "K": -273.15},  # offsets, not factors
    # a float t counted in another unit than the contract's seconds (a timestamp carries
    # its own)
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
}
_QUANTITY_OF = {
    **{c: "gyro" for c in GYRO},
    "ref_rate": "ref_rate",
    **{c: "accel" for c in ACCEL},
    "temp": "temp",
}


@dataclass(frozen=True)
class RigLog:
    """Validated columns of one log, in internal units, batch by batch.

    Each batch maps column name to a numpy array; ``mount`` (when read) holds int8 indices
    into ``MOUNTS``, -1 where null. ``batches`` holds every batch when the log was kept in
    memory; a log read with a memory budget it exceeds keeps none (``batches`` is None) and
    :meth:`scan` reads the file again, batch by batch, for each stage that needs samples.
    ``blocks`` holds block statistics made while the log was read
    (:class:`gyrocal.io.blocks.BlockSink`), by block length.
    """

    path: str
    batches: tuple[dict[str, np.ndarray], ...] | None
    rows_read: int
    rows_dropped: int
    declared_units: dict[str, str] = field(default_factory=dict)
    time_origin: str | None = None  # ISO time of t = 0 when the log's t is a timestamp
    columns: tuple[str, ...] = ()  # the columns read (when ``batches`` is None)
    rows_kept: int = 0  # the rows kept (when ``batches`` is None)
    span: tuple[float, float] = (0.0, 0.0)  # first and last kept t (when ``batches`` is None)
    blocks: dict = field(default_factory=dict, compare=False)
    reread: Callable | None = field(default=None, compare=False, repr=False)
    input_stats: InputSummary | None = field(default=None, compare=False)  # what InputStats saw

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.batches[0]) if self.batches is not None else self.columns

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def __len__(self) -> int:
        return sum(len(b["t"]) for b in self.batches) if self.batches is not None else self.rows_kept

    @property
    def time_span(self) -> tuple[float, float]:
        """The first and last kept rows' t."""
        if self.batches is None:
            return self.span
        return float(self.batches[0]["t"][0]), float(self.batches[-1]["t"][-1])

    @property
    def in_memory(self) -> bool:
        return self.batches is not None

    def scan(self, names=None) -> Iterator[dict[str, np.ndarray]]:
        """The kept rows of ``names`` (default: every column read), batch by batch, in
        order: from memory, or read from the file again."""
        names = tuple(names or self.names)
        if self.batches is not None:
            for b in self.batches:
                yield {k: b[k] for k in names}
        else:
            yield from self.reread(names)

    def column(self, name: str) -> np.ndarray:
        parts = [b[name] for b in self.scan((name,))]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def rows(self, name: str, start: int, stop: int) -> np.ndarray:
        """Rows ``start:stop`` of one column, gathered across batches."""
        return self.row_ranges((name,), [(start, stop)])[0][name]

    def row_ranges(self, names, ranges) -> list[dict[str, np.ndarray]]:
        """Rows ``start:stop`` of the columns ``names`` for each (start, stop) in ``ranges``,
        gathered in one pass over the batches."""
        names, ranges = tuple(names), [(int(a), int(b)) for a, b in ranges]
        parts: list[list[dict]] = [[] for _ in ranges]
        end = max((b for _, b in ranges), default=0)
        offset = 0
        for batch in self.scan(names):
            n = len(batch[names[0]])
            for k, (start, stop) in enumerate(ranges):
                lo, hi = max(start - offset, 0), min(stop - offset, n)
                if lo < hi:
                    parts[k].append({c: batch[c][lo:hi] for c in names})
            offset += n
            if offset >= end:
                break
        return [
            {
                c: (p[0][c] if len(p) == 1 else np.concatenate([q[c] for q in p]) if p else np.empty(0))
                for c in names
            }
            for p in parts
        ]


def with_constants(log: RigLog, values: dict[str, float]) -> RigLog:
    """``log`` with a constant column for each name in ``values`` it does not hold (a
    protocol that does without a contract column, :attr:`gyrocal.protocols.registry.Protocol.without`)."""
    values = {k: float(v) for k, v in values.items() if k not in log}
    if not values:
        return log
    if log.batches is None:  # such a protocol reads whole columns (no reading_blocks)
        raise ValueError("constant columns are added to a log kept in memory")
    return replace(
        log,
        columns=log.columns + tuple(values),
        batches=tuple({**b, **{k: np.full(len(b["t"]), v) for k, v in values.items()}} for b in log.batches),
    )


def open_dataset(path: Path) -> ds.Dataset:
    """The log as an Arrow dataset; a directory's files ordered by their first time stamp."""
    try:
        if not path.is_dir():
            if not path.exists():
                raise CorruptFileError("no such file", source=path)
            dataset = ds.dataset(path, format="parquet")
            dataset.schema.names  # noqa: B018 - a damaged column name fails here (UTF-8)
            return dataset
        files = sorted(str(p) for p in path.rglob("*.parquet") if p.is_file())
        if not files:
            raise CorruptFileError("directory holds no .parquet files", source=path)
        dataset = ds.dataset(files, format="parquet")
        starts = [_first_time(fragment) for fragment in dataset.get_fragments()]
        if all(s is not None for s in starts):
            files = [f for _, f in sorted(zip(starts, files, strict=False))]
            dataset = ds.dataset(files, format="parquet")
        dataset.schema.names  # noqa: B018
        return dataset
    except (pa.ArrowInvalid, OSError) as exc:
        raise CorruptFileError(unreadable(path, exc), source=path) from None
    except UnicodeDecodeError:
        raise CorruptFileError(
            "not a readable Parquet file (a column name is not UTF-8)", source=path
        ) from None


PARQUET_MAGIC = b"PAR1"  # a Parquet file starts and ends with it
SNIFF_BYTES = 4096
DELIMITERS = {",": "CSV", "\t": "TSV", ";": "CSV"}


def unreadable(path: Path, exc: BaseException) -> str:
    """Why Arrow could not open ``path``, naming the fix where the bytes show it: a file
    cut short (the leading magic without the trailing one: a copy interrupted), or text
    with delimiters (a CSV or TSV file, which ``gyrocal import`` converts). The bytes decide,
    not the name: a CSV file is often saved as .parquet by a script, and a cut copy keeps
    its name."""
    reason = f"not a readable Parquet file ({first_line(exc)})"
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(SNIFF_BYTES)
            f.seek(max(size - len(PARQUET_MAGIC), 0))
            tail = f.read()
    except OSError:
        return reason
    if size < len(PARQUET_MAGIC):  # empty: Arrow's own words say so
        return reason
    if head.startswith(PARQUET_MAGIC):
        if tail != PARQUET_MAGIC:
            return (
                "not a readable Parquet file, truncated: the file ends without Parquet's "
                f"footer ({size} bytes; a cut copy?)"
            )
        return reason
    found = _delimited_text(head)
    if found is None:
        return reason
    import shlex

    kind, delimiter = found
    fmt = "" if path.suffix.lower() == f".{kind.lower()}" else f" --format {kind.lower()}"
    # import reads commas (CSV) and tabs (TSV) by itself; another delimiter is the map's
    mapped = "" if delimiter in ",\t" else f" --map MAP.yaml (with delimiter: {delimiter!r})"
    return (
        f"not a readable Parquet file: it looks like {kind} text; "
        f"gyrocal import {shlex.quote(str(path))} -o LOG.parquet{fmt}{mapped} converts it (docs/import.md)"
    )


def _delimited_text(head: bytes) -> tuple[str, str] | None:
    """The kind of text (CSV or TSV) the file's first bytes are, and its delimiter:
    printable UTF-8 whose first line a delimiter splits; None for anything else."""
    text = head.decode("utf-8", errors="ignore")  # a character cut at the end is dropped
    if len(text) < len(head) // 2:  # mostly not UTF-8: binary
        return None
    if any(not (c.isprintable() or c in "\r\n\t") for c in text.lstrip("\ufeff")):
        return None
    first = text.lstrip("\ufeff").splitlines()[0] if text.strip() else ""
    counts = {d: first.count(d) for d in DELIMITERS}
    delimiter = max(counts, key=lambda d: counts[d])
    return (DELIMITERS[delimiter], delimiter) if counts[delimiter] else None


def _first_time(fragment) -> float | None:
    """Smallest ``t`` of a file from its Parquet statistics, without reading data."""
    try:
        groups = fragment.row_groups
        stats = [g.statistics.get("t") for g in groups] if groups else []
        lows = [v["min"] if isinstance(v, dict) else v for v in stats if v is not None]
        lows = [v.timestamp() if hasattr(v, "timestamp") else v for v in lows]
        return float(min(lows)) if lows else None
    except (KeyError, TypeError, ValueError, OverflowError, pa.ArrowException):
        # OverflowError: a timestamp statistic beyond Python's datetime range (year 9999)
        return None


# What Arrow raises on data it cannot read: damaged pages (ArrowInvalid, OSError) and a
# directory's files that disagree on a column's type, which its scanner cannot cast to the
# first file's (ArrowNotImplementedError, ArrowTypeError).
READ_ERRORS = (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError, OSError)


def read_error(exc: BaseException, path) -> CorruptFileError | LogFormatError:
    """The gyrocal error, naming the log, for one of :data:`READ_ERRORS` met reading it."""
    if isinstance(exc, (pa.ArrowNotImplementedError, pa.ArrowTypeError)):
        return LogFormatError(
            f"a column cannot be read as one type ({first_line(exc)}); the "
            "files of a directory must agree on column types",
            source=path,
        )
    return CorruptFileError(f"cannot read Parquet data ({first_line(exc)})", source=path)


def declared_units(schema: pa.Schema, path: Path) -> dict[str, str]:
    """The ``gyrocal.units`` metadata entry, checked; empty when absent."""
    raw = (schema.metadata or {}).get(UNITS_KEY)
    if raw is None:
        return {}
    try:
        units = json.loads(raw)
    except ValueError:
        raise LogFormatError("metadata gyrocal.units is not valid JSON", source=path) from None
    if not isinstance(units, dict):
        raise LogFormatError("metadata gyrocal.units must be a JSON object", source=path)
    for quantity, unit in units.items():
        allowed = UNIT_FACTORS.get(quantity)
        if allowed is not None and (not isinstance(unit, str) or unit not in allowed):
            raise LogFormatError(
                f"metadata gyrocal.units gives {quantity} in {unit!r}; expected one of {', '.join(allowed)}",
                source=path,
            )
    return {k: v for k, v in units.items() if k in UNIT_FACTORS}


def check_float(schema: pa.Schema, name: str, path: Path) -> None:
    typ = schema.field(name).type
    if not (pa.types.is_float32(typ) or pa.types.is_float64(typ)):
        raise LogFormatError(f"column {name} has type {typ}, expected float32 or float64", source=path)


def time_seconds(col: pa.Array, path: Path, origin: list, units: dict | None = None) -> np.ndarray:
    """Seconds as float64. Timestamps count from the log's first one (kept in ``origin``),
    in integer arithmetic, so epoch times keep their sub-microsecond resolution; a float
    column in the unit ``units`` declares for ``t`` (default: seconds)."""
    typ = col.type
    unit = (units or {}).get("t", "s")
    if pa.types.is_timestamp(typ):
        if unit != "s":
            raise LogFormatError(
                f"metadata gyrocal.units gives t in {unit!r}, but column t is a "
                f"timestamp, which carries its own unit ({typ.unit})",
                source=path,
            )
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[typ.unit]
        ints = col.cast(pa.int64())
        missing = ints.is_null().to_numpy(zero_copy_only=False) if ints.null_count else None
        ints = ints.fill_null(0).to_numpy(zero_copy_only=False)
        if not origin and (missing is None or not missing.all()):
            origin.append((int(ints[0 if missing is None else np.argmin(missing)]), typ.unit))
        start = origin[0][0] if origin else 0
        seconds = (ints - start).astype(np.float64) * scale
        if missing is not None:  # a missing time makes the row non-finite: dropped
            seconds[missing] = np.nan
        return seconds
    if pa.types.is_float64(typ) or pa.types.is_float32(typ):
        seconds = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)
        return seconds * UNIT_FACTORS["t"][unit] if unit != "s" else seconds
    raise LogFormatError(f"column t has type {typ}, expected float64 seconds or a timestamp", source=path)


def _mount_codes(col: pa.Array, path: Path) -> np.ndarray:
    """Mount labels to int8 indices into MOUNTS (-1 where null), without decoding strings."""
    typ = col.type
    is_dict = pa.types.is_dictionary(typ)
    value_type = typ.value_type if is_dict else typ
    if not (pa.types.is_string(value_type) or pa.types.is_large_string(value_type)):
        raise LogFormatError(f"column mount has type {typ}, expected string or dictionary", source=path)
    allowed = pa.array(MOUNTS, type=value_type)
    if not is_dict:
        lookup = pc.index_in(col, value_set=allowed)
        _reject_unknown_mounts(col, lookup, None, path)
        return lookup.fill_null(-1).to_numpy(zero_copy_only=False).astype(np.int8)
    table = _dictionary_lookup(col.dictionary)
    if table is None:  # an entry outside MOUNTS: an error only if some row uses it
        lookup = pc.index_in(col.dictionary, value_set=allowed)
        _reject_unknown_mounts(col.dictionary, lookup, col.indices, path)
        table = np.append(lookup.fill_null(-1).to_numpy(zero_copy_only=False), -1).astype(np.int8)
    idx = col.indices
    has_null = idx.null_count > 0
    if has_null:
        idx = idx.fill_null(len(table) - 1)
    idx = idx.to_numpy(zero_copy_only=False)
    if not has_null and np.array_equal(table[:-1], np.arange(len(table) - 1)):
        return idx.astype(np.int8, copy=False)  # dictionary already in MOUNTS order
    return table[idx]


@functools.lru_cache(maxsize=64)
def _lookup_for(entries: tuple) -> np.ndarray | None:
    codes = [MOUNTS.index(e) if e in MOUNTS else (None if e is not None else -1) for e in entries]
    if any(c is None for c in codes):
        return None
    return np.array(codes + [-1], dtype=np.int8)


def _dictionary_lookup(dictionary: pa.Array) -> np.ndarray | None:
    """int8 code per dictionary entry (plus -1 for null rows); dictionaries repeat across
    batches, so the mapping is computed once per distinct dictionary."""
    return _lookup_for(tuple(dictionary.to_pylist()))


def _reject_unknown_mounts(values: pa.Array, lookup: pa.Array, used, path: Path) -> None:
    unknown = pc.and_(pc.is_null(lookup), pc.is_valid(values))
    if not pc.any(unknown).as_py():
        return
    bad_positions = np.flatnonzero(unknown.to_numpy(zero_copy_only=False))
    if used is not None:  # a dictionary entry only matters if some row uses it
        used_idx = np.unique(used.drop_null().to_numpy(zero_copy_only=False))
        bad_positions = np.intersect1d(bad_positions, used_idx)
        if bad_positions.size == 0:
            return
    bad = values[int(bad_positions[0])].as_py()
    raise LogFormatError(f"column mount holds {bad!r}; expected one of {' '.join(MOUNTS)}", source=path)


def _refuse_empty(rows: int, kept_rows: int, nonfinite: dict[str, int], path: Path) -> None:
    """A log without rows, or none kept (every row holds a non-finite value: the columns that
    hold none are named), is refused."""
    if rows == 0:
        raise EmptyLogError("the log has no rows", source=path)
    if not kept_rows:
        empty = [k for k, n in nonfinite.items() if n == rows]
        raise EmptyLogError(
            f"all {rows} rows hold a non-finite value"
            + (
                f": {'columns' if len(empty) > 1 else 'column'} {', '.join(empty)} "
                f"{'hold' if len(empty) > 1 else 'holds'} no finite value"
                if empty
                else ""
            ),
            source=path,
        )


def read_log(
    path: str | os.PathLike,
    *,
    optional: tuple[str, ...] = ("mount",),
    required: tuple[str, ...] = REQUIRED,
    sink=None,
    keep_bytes: float | None = None,
) -> RigLog:
    """Read and validate a rig log, returning only ``required`` plus present ``optional`` columns.

    Rows with a non-finite value in any numeric column read are dropped and counted. The
    log is read batch by batch; ``sink`` (a :class:`gyrocal.io.blocks.BlockSink`) sees each,
    and its block statistics are kept in ``blocks``. The batches are kept in memory while
    they take at most ``keep_bytes`` (None: always); past that none are, and stages read
    the file again (:meth:`RigLog.scan`).
    Raises a :class:`LogFormatError` (or subclass) naming the file and the problem.
    """
    path = Path(path)
    dataset, wanted, units = _open_checked(path, optional, required)
    if sink is not None:
        try:  # opens every file's footer: a directory's unreadable part shows here first
            rows_bound = dataset.count_rows()
        except READ_ERRORS as exc:
            raise read_error(exc, path) from None
        sink.open(tuple(wanted), rows_bound)
    batches: list[dict[str, np.ndarray]] | None = []
    kept_bytes, kept_rows, first, last = 0, 0, None, 0.0
    from .plausibility import InputStats

    stats = InputStats()
    stream = _batches(dataset, wanted, required, units, path, stats)
    for batch in stream:
        if sink is not None:
            sink.push(batch)
        kept_rows += len(batch["t"])
        first = float(batch["t"][0]) if first is None else first
        last = float(batch["t"][-1])
        if batches is not None:
            batches.append(batch)
            kept_bytes += sum(v.nbytes for v in batch.values())
            if keep_bytes is not None and kept_bytes > keep_bytes:
                batches = None
    rows, dropped, origin = stream.state
    _refuse_empty(rows, kept_rows, stats.nonfinite if stats is not None else {}, path)
    time_origin = None
    if origin:
        value, unit = origin[0]
        time_origin = str(np.datetime64(value, unit))

    def reread(names):
        columns = [c for c in wanted if c in names or c in required]
        for batch in _batches(open_dataset(path), columns, required, units, path):
            yield {k: batch[k] for k in names}

    return RigLog(
        str(path),
        tuple(batches) if batches is not None else None,
        rows,
        dropped,
        units,
        time_origin,
        columns=tuple(wanted),
        rows_kept=kept_rows,
        span=(first, last),
        reread=reread,
        blocks={sink.block_s: sink.result()} if sink is not None else {},
        input_stats=stats.summary() if stats is not None else None,
    )


def _open_checked(path: Path, optional, required):
    """The dataset, the columns to read and the declared units, with the schema checked."""
    dataset = open_dataset(path)
    schema = dataset.schema
    names = set(schema.names)
    missing = [c for c in required if c not in names]
    if missing:
        raise LogFormatError(
            f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(missing)}", source=path
        )
    wanted = [c for c in required] + [c for c in optional if c in names and c not in required]
    for name in wanted:
        if name not in ("t", "mount"):
            check_float(schema, name, path)
    return dataset, wanted, declared_units(schema, path)


READ_BATCH_ROWS = readahead.BATCH_ROWS
READ_BUFFER_BYTES = readahead.BUFFER_BYTES


def record_batches(dataset: ds.Dataset, columns, batch_rows: int | None = None) -> Iterator[pa.RecordBatch]:
    """The dataset's rows of ``columns``, batch by batch, in order, in memory that does not
    grow with the log: each column chunk is read through a buffer of ``READ_BUFFER_BYTES``
    (Arrow's default reads a row group's chunks whole, and pre-buffers the file's ahead;
    a 1 kHz log's row group can hold a few hundred MB)."""
    files = getattr(dataset, "files", None) or []
    batch_rows = batch_rows or READ_BATCH_ROWS
    if len(files) == 1:
        ahead = readahead.take(files[0], columns, batch_rows, READ_BUFFER_BYTES)
        if ahead is not None:  # decoded while the process started (gyrocal.io.readahead)
            yield from ahead
            return
        reader = pq.ParquetFile(files[0], pre_buffer=False, buffer_size=READ_BUFFER_BYTES)
        yield from reader.iter_batches(batch_size=batch_rows, columns=list(columns), use_threads=True)
        return
    scan = ds.ParquetFragmentScanOptions(
        pre_buffer=False, use_buffered_stream=True, buffer_size=READ_BUFFER_BYTES
    )
    yield from dataset.to_batches(
        columns=list(columns),
        use_threads=True,
        batch_size=batch_rows,
        fragment_scan_options=scan,
        batch_readahead=4,
        fragment_readahead=1,
    )


class _batches:
    """The log's batches converted and checked, non-finite rows dropped; ``state`` holds
    (rows read, rows dropped, time origin) once consumed."""

    def __init__(self, dataset, wanted, required, units, path, stats=None):
        self.args = dataset, wanted, required, units, path
        self.state = (0, 0, [])
        self.stats = stats  # a gyrocal.io.plausibility.InputStats, fed when given

    def __iter__(self):
        dataset, wanted, required, units, path = self.args
        rows, dropped, previous_t = 0, 0, -np.inf
        origin: list = []
        last_mount = np.int8(-1)
        try:
            for record_batch in record_batches(dataset, wanted):
                if record_batch.num_rows == 0:
                    continue
                batch = _convert_batch(record_batch, units, path, origin)
                if "mount" in batch:
                    batch["mount"], last_mount = _continue_labels(batch["mount"], last_mount)
                # Only the columns a stage requires decide which rows are usable: a missing
                # value in an optional column (a slower accelerometer, a file without it)
                # stays NaN.
                keep = _finite_rows({k: batch[k] for k in required})
                if self.stats is not None:
                    self.stats.push_raw(batch, keep is not None)
                positions = None
                if keep is not None:
                    dropped += len(keep) - int(np.count_nonzero(keep))
                    positions = np.flatnonzero(keep)
                    batch = {k: v[keep] for k, v in batch.items()}
                rows += record_batch.num_rows
                self.state = (rows, dropped, origin)
                if len(batch["t"]):
                    _check_time(batch["t"], previous_t, rows - record_batch.num_rows, positions, path)
                    previous_t = batch["t"][-1]
                    if self.stats is not None:
                        self.stats.push(batch)
                    yield batch
        except READ_ERRORS as exc:
            raise read_error(exc, path) from None


def _convert_batch(record_batch: pa.RecordBatch, units: dict[str, str], path: Path, origin: list) -> dict:
    batch = {}
    for name, col in zip(record_batch.schema.names, record_batch.columns, strict=False):
        if name == "t":
            batch[name] = _reading(time_seconds(col, path, origin, units), TIME_LIMIT)
        elif name == "mount":
            batch[name] = _mount_codes(col, path)
        else:
            batch[name] = _reading(to_internal_units(name, col.to_numpy(zero_copy_only=False), units))
    return batch


# The contract lets every reading column be float32, so a value beyond float32's range is no
# reading in any unit (the same log written as float32 would hold inf there): it counts as
# non-finite, its row dropped (an optional column's value: missing). No sum, mean or square
# of readings then overflows float64 downstream.
READING_LIMIT = float(np.finfo(np.float32).max)
# Likewise a float t beyond what a timestamp column can hold (int64 seconds) is no time; so
# no difference of two times overflows.
TIME_LIMIT = float(2**63)


def _reading(values: np.ndarray, limit: float = READING_LIMIT) -> np.ndarray:
    if values.dtype != np.float64 or not values.size:
        return values  # float32 holds nothing beyond it
    if values.min() >= -limit and values.max() <= limit:
        return values  # the common case; a NaN fails both tests and gets the exact one
    beyond = np.abs(values) > limit
    return np.where(beyond, np.copysign(np.inf, values), values) if beyond.any() else values


def to_internal_units(name: str, values: np.ndarray, units: dict[str, str]) -> np.ndarray:
    """A column's values in deg/s, °C or g, from the units the log declared."""
    quantity = _QUANTITY_OF.get(name)
    unit = units.get(quantity) if quantity else None
    if unit is None:
        return values
    # A value the conversion takes beyond the float range is inf: non-finite, like its
    # input should have been (see READING_LIMIT).
    with np.errstate(over="ignore"):
        if quantity == "temp":
            offset = UNIT_FACTORS["temp"][unit]
            return values + offset if offset else values
        factor = UNIT_FACTORS[quantity][unit]
        return values * factor if factor != 1.0 else values


def _finite_rows(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """Mask of rows finite in every column, or None when all are (the common, cheap case)."""
    # A NaN or inf anywhere makes the sum non-finite; an overflowing sum of finite values
    # only costs the exact check below.
    with np.errstate(over="ignore", invalid="ignore"):
        suspicious = [v for k, v in columns.items() if k != "mount" and not np.isfinite(v.sum())]
    if not suspicious:
        return None
    keep = np.ones(len(next(iter(columns.values()))), dtype=bool)
    for v in suspicious:
        keep &= np.isfinite(v)
    return keep


def _check_time(t: np.ndarray, previous: float, offset: int, positions, path: Path) -> None:
    """Strictly increasing within the batch and after the previous batch's last time.

    ``positions`` maps kept rows to their rows in the batch (None: none dropped), so the
    message names the row as it is in the file."""
    if t[0] <= previous:
        i, before = -1, previous
    else:
        bad = np.flatnonzero(t[1:] <= t[:-1])
        if not bad.size:
            return
        i, before = int(bad[0]), t[bad[0]]
    row = offset + (i + 1 if positions is None else int(positions[i + 1]))
    raise LogFormatError(
        f"column t is not strictly increasing: row {row} has t={float(t[i + 1])!r} after t={float(before)!r}",
        source=path,
    )


def _continue_labels(codes: np.ndarray, previous: np.int8) -> tuple[np.ndarray, np.int8]:
    """Null mount labels (-1) continue the last label, as a rig that logs the mount only
    when it changes would mean; labels before the first one stay unknown."""
    if codes.min(initial=0) >= 0:
        return codes, codes[-1] if len(codes) else previous
    index = np.where(codes >= 0, np.arange(len(codes)), -1)
    np.maximum.accumulate(index, out=index)
    filled = np.where(index >= 0, codes[np.maximum(index, 0)], previous).astype(np.int8)
    return filled, filled[-1]


# The input's hash in a calibration's provenance: BLAKE3, a cryptographic hash that SIMD
# makes fast on any CPU (SHA-256 costs as much as reading a log where the CPU has no SHA
# instructions). The record names its algorithm; files written before keep SHA-256.
HASH_ALGORITHM = "blake3"
HASH_ALGORITHMS = ("blake3", "sha256")


def _hasher(algorithm: str):
    if algorithm == "blake3":
        import blake3

        return blake3.blake3()
    if algorithm == "sha256":
        return hashlib.sha256()
    raise ValueError(f"unknown hash algorithm {algorithm!r}")


def file_digest(path: str | os.PathLike, algorithm: str = HASH_ALGORITHM, *, files: str = "*.parquet") -> str:
    """Hex digest of a file, or of a directory (its ``files``' relative names and digests,
    in name order: a dataset's Parquet files, by default). hashlib and blake3 release the
    GIL, so it runs beside a read."""
    path = Path(path)
    if path.is_dir():
        outer = _hasher(algorithm)
        for part in sorted(p for p in path.rglob(files) if p.is_file()):
            outer.update(part.relative_to(path).as_posix().encode() + b"\0")
            outer.update(bytes.fromhex(file_digest(part, algorithm)))
        return outer.hexdigest()
    digest = _hasher(algorithm)
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 22), b""):
                digest.update(block)
    except OSError as exc:
        raise CorruptFileError(f"cannot read file ({exc.strerror})", source=path) from None
    return digest.hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    return file_digest(path, "sha256")


def source_digest(record: dict) -> tuple[str, str] | None:
    """(algorithm, digest) of a provenance input record, whichever algorithm it names."""
    for algorithm in HASH_ALGORITHMS:
        if isinstance(record.get(algorithm), str):
            return algorithm, record[algorithm]
    return None


def verify_source(record: dict, path: str | os.PathLike) -> str:
    """The algorithm by which ``path`` is the input ``record`` describes; a
    :class:`LogFormatError` naming the file when it is not, or when the record holds no hash."""
    found = source_digest(record)
    if found is None:
        raise LogFormatError(
            f"the record names no input hash (one of {', '.join(HASH_ALGORITHMS)})", source=path
        )
    algorithm, expected = found
    if file_digest(path, algorithm) != expected:
        raise LogFormatError(
            f"is not the log the calibration was made from ({algorithm} {expected[:12]}…)", source=path
        )
    return algorithm
