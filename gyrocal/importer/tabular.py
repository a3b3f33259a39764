"""CSV and TSV sources, read a block at a time with Arrow's streaming CSV reader.

Only the mapped columns are parsed, each straight to float64 (mount, section: text); a block
becomes whole-column numpy arrays, converted to the contract's units in a few vector
operations. Memory is a few blocks, whatever the file's size, except where the map asks for
the rows to be ordered by time (``time.sort``): the mapped columns are then held whole.

The dialects rigs write are read as they are: any delimiter, a decimal comma
(``decimal: ","``), comment lines (``comment: "#"``: lines whose first character, after
blanks, is it; Arrow's reader has no such option, so the text reaches it through a filter
that drops them a block at a time) and a row of units under the header (``units_row``),
checked against the map's units where it names one gyrocal knows.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from ..io.errors import CorruptFileError, LogFormatError, first_line
from .mapping import TIME_UNITS, ImportMap
from .sink import ROW_GROUP_ROWS, LogSink

# Arrow parses this much text per batch (~17 000 rows of a rig log). Its reader keeps up to
# 32 blocks read ahead, so the block size sets the memory: 1 MiB blocks, about 32 MiB.
BLOCK_BYTES = 1 << 20
HEADER_LIMIT = 1 << 20  # a header line longer than this is no header
_CONVERSION = re.compile(r"In CSV column #(\d+): .*CSV conversion error to (\w+): invalid value '(.*)'")

# What a units row may call the map's units (lower case, brackets and blanks stripped).
UNIT_WORDS = {
    "deg/s": ("deg/s", "dps", "°/s", "deg/sec", "degree/s", "degrees/s", "degs-1", "°s-1"),
    "rad/s": ("rad/s", "rad/sec", "rads-1"),
    "mdps": ("mdps", "mdeg/s", "m°/s"),
    "g": ("g",),
    "m/s^2": ("m/s^2", "m/s2", "m/s²", "ms-2", "ms^-2", "m/s/s"),
    "mg": ("mg",),
    "s": ("s", "sec"),
    "ms": ("ms", "msec"),
    "us": ("us", "µs", "μs", "usec"),
    "ns": ("ns", "nsec"),
    "degC": ("°c", "degc", "c", "℃", "celsius"),
    "K": ("k", "kelvin"),
    "degF": ("°f", "degf", "f", "℉", "fahrenheit"),
}
_UNIT_OF = {word: unit for unit, words in UNIT_WORDS.items() for word in words}


def unit_named(cell: str) -> str | None:
    """The unit a units-row cell names, or None when it names none gyrocal knows."""
    word = re.sub(r"\s+", "", cell.strip().strip("[]()").lower())
    return _UNIT_OF.get(word)


class CommentLines:
    """Where a filtered table's comment lines stood: for each, how many lines were kept
    before it. Recorded as the filter reads (only appended, in order)."""

    def __init__(self):
        self.kept_before: list[int] = []

    def before(self, kept_line: int) -> int:
        """How many comment lines come before the kept line ``kept_line`` (from 0)."""
        return int(np.searchsorted(self.kept_before, kept_line, side="right"))


class _Uncommented:
    """A table's text without its comment lines, as a file Arrow's reader reads from: whole
    lines a block at a time, the comment lines cut out by one regular expression."""

    def __init__(self, path: Path, comment: str, record: CommentLines):
        self.stream = pa.input_stream(str(path), compression="detect")
        self.pattern = re.compile(rb"(?m)^[ \t]*" + re.escape(comment.encode()) + rb"[^\n]*(?:\n|\Z)")
        self.mark = comment.encode()
        self.record = record
        self.carry = b""
        self.out, self.at = b"", 0  # filtered text, and how much of it was read
        self.kept = 0
        self.eof = False
        self.closed = False

    def _filter(self, text: bytes) -> bytes:
        if self.mark not in text:
            self.kept += text.count(b"\n")
            return text
        pieces, at = [], 0
        for match in self.pattern.finditer(text):
            pieces.append(text[at : match.start()])
            self.kept += text.count(b"\n", at, match.start())
            self.record.kept_before.append(self.kept)
            at = match.end()
        pieces.append(text[at:])
        self.kept += text.count(b"\n", at)
        return b"".join(pieces)

    def read(self, size: int = -1) -> bytes:
        while (size < 0 or len(self.out) - self.at < size) and not self.eof:
            chunk = self.stream.read(BLOCK_BYTES)
            if not chunk:
                self.eof, text, self.carry = True, self.carry, b""
            else:
                text = self.carry + chunk
                end = text.rfind(b"\n") + 1
                text, self.carry = text[:end], text[end:]
            self.out, self.at = self.out[self.at :] + self._filter(text), 0
        end = len(self.out) if size < 0 else min(self.at + size, len(self.out))
        data, self.at = self.out[self.at : end], end
        return data

    def close(self) -> None:
        self.stream.close()
        self.closed = True


class Table:
    """A CSV/TSV source as its map reads it: the header, the units row, and where each data
    row stands in the file (for messages)."""

    def __init__(self, path: Path, spec: ImportMap):
        self.path, self.spec = path, spec
        self.names, self.units = read_header(path, spec)
        self.comments = CommentLines()

    def locate(self, row: int) -> str:
        """A data row as the line an editor shows (blank lines, which the reader skips, not
        counted)."""
        kept = row + 1 + int(self.spec.units_row)  # the header is kept line 0
        skipped = self.comments.before(kept) if self.spec.comment else 0
        return f"line {1 + kept + skipped}"

    def text(self, record: CommentLines | None = None):
        """The file as Arrow's reader takes it: its path, or the filter without comments."""
        if not self.spec.comment:
            return str(self.path)
        return _Uncommented(self.path, self.spec.comment, record or self.comments)


def read_header(path: Path, spec: ImportMap) -> tuple[list[str], list[str] | None]:
    """The column names and the units row's cells (or None), from the file's first lines
    that are no comment (compressed files too, as Arrow reads them)."""
    wanted = 2 if spec.units_row else 1
    mark = (spec.comment or "").encode()
    lines: list[bytes] = []
    try:
        with pa.input_stream(str(path), compression="detect") as stream:
            head = b""
            while len(head) < HEADER_LIMIT:
                chunk = stream.read(1 << 16)
                head += chunk
                whole = head.split(b"\n")[:-1] if chunk else head.split(b"\n")
                lines = [line for line in whole if not (mark and line.lstrip(b" \t").startswith(mark))]
                if len(lines) >= wanted or not chunk:
                    break
    except (OSError, pa.ArrowInvalid) as exc:
        raise CorruptFileError(f"cannot read ({first_line(exc)})", source=path) from None
    try:
        text = [line.rstrip(b"\r").decode("utf-8-sig") for line in lines[:wanted]]
    except UnicodeDecodeError:
        raise CorruptFileError(
            "not a UTF-8 text file: its first line cannot be read as column names", source=path
        ) from None
    if not text or not text[0].strip():
        raise CorruptFileError("empty: no header line with column names", source=path)
    names = [name.strip() for name in next(csv.reader([text[0]], delimiter=spec.delimiter))]
    units = None
    if spec.units_row:
        if len(text) < 2:
            raise LogFormatError(
                "the map says a units row follows the header, but the file ends there", source=path
            )
        units = [cell.strip() for cell in next(csv.reader([text[1]], delimiter=spec.delimiter))]
    return names, units


def resolve_columns(table: Table, spec: ImportMap, map_name: str) -> ImportMap:
    """The map checked against the file's columns (and its units row); without a map, the
    optional contract columns the file lacks are left out."""
    names, path = table.names, table.path
    if spec.optional_defaults:
        absent = [
            q
            for q, cols in (
                ("accel", spec.accel),
                ("temp", (spec.temp,)),
                ("ref_rate", (spec.ref_rate,)),
                ("mount", (spec.mount,)),
            )
            if not all(c in names for c in cols)
        ]
        spec = spec.without(absent)
    for column, role in spec.columns().items():
        if column not in names:
            shown = ", ".join(names[:40]) + (", ..." if len(names) > 40 else "")
            why = (
                f"{role} in {map_name}"
                if not spec.optional_defaults
                else "without --map the contract's names t, gyro_x, gyro_y, gyro_z are expected"
            )
            raise LogFormatError(
                f"column {column!r} ({why}) is not in the file; its columns: {shown}", source=path
            )
        if names.count(column) > 1:
            raise LogFormatError(
                f"column {column!r} ({role} in {map_name}) appears {names.count(column)} times in the header",
                source=path,
            )
    if table.units is not None:
        _check_units(table, spec, map_name)
    table.spec = spec
    return spec


def _check_units(table: Table, spec: ImportMap, map_name: str) -> None:
    """Refuse a map whose unit for a column is not the one the file's units row names (a
    rad/s column mapped as deg/s, a column mapped to the wrong quantity)."""
    declared = {}
    if spec.sample_rate is None and spec.time_column:  # an index column has no unit
        declared[spec.time_column] = ("time", next(u for u, f in TIME_UNITS.items() if f == spec.time_factor))
    for name, cols, scale in (("gyro", spec.gyro, spec.gyro_scale), ("accel", spec.accel, spec.accel_scale)):
        for axis, col in zip("xyz", cols or (), strict=False):
            declared.setdefault(col, (f"{name}.{axis}", scale.unit))
    for name, scale in (("temp", spec.temp_scale), ("ref_rate", spec.ref_scale)):
        if getattr(spec, name):
            declared.setdefault(getattr(spec, name), (name, scale.unit))
    for column, (role, unit) in declared.items():
        index = table.names.index(column)
        cell = table.units[index] if index < len(table.units) else ""
        named = unit_named(cell)
        if named is not None and named != unit:
            raise LogFormatError(
                f"the units row gives {cell!r} for column {column!r}, which {map_name} maps as "
                f"{role} in {unit}: correct the map's unit (or the column)",
                source=table.path,
            )


def convert(table: Table, sink: LogSink) -> int:
    """Stream the table into ``sink`` (ordered by time first where the map asks); returns
    the number of data rows read."""
    spec = table.spec
    numeric = [c for c in spec.columns() if c not in spec.text_columns()]
    reader = _open(table, numeric, spec.text_columns())
    if spec.sort:
        return _convert_sorted(table, reader, numeric, sink)
    row = 0
    while True:
        batch = _next(reader, table, numeric)
        if batch is None:
            break
        n = batch.num_rows
        if n:
            rows = np.arange(row, row + n, dtype=np.int64)
            sink.write(_columns(batch, spec, rows), rows)
            row += n
    return row


def _next(reader, table: Table, numeric: list[str]) -> pa.RecordBatch | None:
    try:
        return reader.read_next_batch()
    except StopIteration:
        return None
    except (pa.ArrowInvalid, OSError) as exc:
        raise _read_error(exc, table, numeric) from None


def _convert_sorted(table: Table, reader, numeric: list[str], sink: LogSink) -> int:
    """The rows ordered by the time column (a stable sort: equal times keep their order and
    are then refused as the contract refuses them), written a row group at a time. The
    mapped columns are held whole: a file grouped by label is ordered only once read."""
    batches = []
    while (batch := _next(reader, table, numeric)) is not None:
        batches.append(batch)
    if not batches:
        return 0
    whole = pa.Table.from_batches(batches).combine_chunks()
    order = np.argsort(whole.column(table.spec.time_column).to_numpy(zero_copy_only=False), kind="stable")
    for at in range(0, len(order), ROW_GROUP_ROWS):
        rows = order[at : at + ROW_GROUP_ROWS]
        part = whole.take(pa.array(rows)).to_batches()[0]
        sink.write(_columns(part, table.spec, rows), rows)
    return whole.num_rows


def _open(table: Table, numeric, text, types=None, record: CommentLines | None = None):
    types = pa.float64() if types is None else types
    spec = table.spec
    convert = pacsv.ConvertOptions(
        include_columns=numeric + text,
        strings_can_be_null=True,
        decimal_point=spec.decimal,
        column_types={**{c: types for c in numeric}, **{c: pa.string() for c in text}},
    )
    try:
        return pacsv.open_csv(
            table.text(record),
            read_options=pacsv.ReadOptions(block_size=BLOCK_BYTES, skip_rows_after_names=int(spec.units_row)),
            parse_options=pacsv.ParseOptions(delimiter=spec.delimiter),
            convert_options=convert,
        )
    except (pa.ArrowInvalid, OSError) as exc:  # the first block is parsed on opening
        if types == pa.string():
            raise
        raise _read_error(exc, table, numeric) from None


def _columns(batch: pa.RecordBatch, spec: ImportMap, rows: np.ndarray) -> dict:
    """One block in the contract's columns and units."""

    def values(name):
        return batch.column(name).to_numpy(zero_copy_only=False)

    out = {}
    if spec.sample_rate is not None:
        index = values(spec.time_column) if spec.time_column else rows.astype(np.float64)
        out["t"] = index / spec.sample_rate
    else:
        t = values(spec.time_column)
        out["t"] = t * spec.time_factor if spec.time_factor != 1.0 else t
    for axis, column in enumerate(spec.gyro):
        out[f"gyro_{'xyz'[axis]}"] = spec.gyro_scale.apply(values(column), axis)
    if spec.temp:
        out["temp"] = spec.temp_scale.apply(values(spec.temp))
    if spec.ref_rate:
        out["ref_rate"] = spec.ref_scale.apply(values(spec.ref_rate))
    elif spec.ref_value is not None:
        out["ref_rate"] = np.full(len(out["t"]), spec.ref_value)
    for axis, column in enumerate(spec.accel or ()):
        out[f"accel_{'xyz'[axis]}"] = spec.accel_scale.apply(values(column), axis)
    if spec.mount:
        out["mount"] = pc.utf8_trim_whitespace(batch.column(spec.mount))
    if spec.section_column:
        out["section"] = pc.utf8_trim_whitespace(batch.column(spec.section_column))
    return out


def _read_error(exc, table: Table, numeric: list[str]):
    """The one-line error for what Arrow met: a value that is no number (found again, with
    its line), or text that is no CSV at all."""
    text, names, path = str(exc), table.names, table.path
    match = _CONVERSION.search(text)
    if match is None:
        return CorruptFileError(
            f"not a readable {table.spec.format.upper()} file ({first_line(exc)})", source=path
        )
    index, value = int(match.group(1)), match.group(3)
    if match.group(2) != "double":
        return LogFormatError(
            f"column {names[index] if index < len(names) else '?'}: "
            f"{value!r} cannot be read as {match.group(2)}",
            source=path,
        )
    named = names[index] if index < len(names) and names[index] in numeric else None
    for column in ([named] if named else []) + [c for c in numeric if c != named]:
        row = _first_non_number(table, column)
        if row is not None:
            return LogFormatError(
                f"{table.locate(row[0])}, column {column}: {row[1]!r} is not a number", source=path
            )
    column = named or "?"
    return LogFormatError(f"column {column}: {value!r} is not a number", source=path)


def _first_non_number(table: Table, column: str):
    """(row, text) of the first value of ``column`` that is no number, or None. The column
    is read again as text, a block at a time; a block that fails is halved until one value
    is left (error path only)."""
    try:
        reader = _open(table, [column], [], types=pa.string(), record=CommentLines())
        row = 0
        for batch in reader:
            values = pc.utf8_trim_whitespace(batch.column(0))
            bad = _bisect(values, table.spec.decimal)
            if bad is not None:
                return row + bad, values[bad].as_py()
            row += batch.num_rows
    except (pa.ArrowInvalid, OSError):
        return None
    return None


def _bisect(values: pa.Array, decimal: str) -> int | None:
    if decimal != ".":  # as the reader parses them
        values = pc.replace_substring(pc.replace_substring(values, ".", "\x00"), decimal, ".")

    def parses(part):
        try:
            pc.cast(part, pa.float64())
            return True
        except pa.ArrowInvalid:
            return False

    if parses(values):
        return None
    lo, hi = 0, len(values)  # the first bad value is in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if parses(values.slice(lo, mid - lo)):
            lo = mid
        else:
            hi = mid
    return lo
