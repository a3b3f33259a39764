"""CSV and TSV sources, read a block at a time with Arrow's streaming CSV reader.

Only the mapped columns are parsed, each straight to float64 (mount: text); a block becomes
whole-column numpy arrays, converted to the contract's units in a few vector operations.
Memory is a few blocks, whatever the file's size.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from ..errors import CorruptFileError, LogFormatError
from ..io import first_line
from .mapping import ImportMap
from .sink import LogSink

# Arrow parses this much text per batch (~17 000 rows of a rig log). Its reader keeps up to
# 32 blocks read ahead, so the block size sets the memory: 1 MiB blocks, about 32 MiB.
BLOCK_BYTES = 1 << 20
HEADER_LIMIT = 1 << 20    # a header line longer than this is no header
_CONVERSION = re.compile(r"In CSV column #(\d+): .*CSV conversion error to (\w+): invalid value '(.*)'")


def locate(row: int) -> str:
    """A data row as the line an editor shows (the header is line 1)."""
    return f"line {row + 2}"


def read_header(path: Path, delimiter: str) -> list[str]:
    """The column names, from the first line (compressed files too, as Arrow reads them)."""
    try:
        with pa.input_stream(str(path), compression="detect") as stream:
            head = b""
            while b"\n" not in head and len(head) < HEADER_LIMIT:
                chunk = stream.read(1 << 16)
                if not chunk:
                    break
                head += chunk
    except (OSError, pa.ArrowInvalid) as exc:
        raise CorruptFileError(f"cannot read ({first_line(exc)})", source=path) from None
    line = head.split(b"\n", 1)[0].rstrip(b"\r")
    try:
        text = line.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CorruptFileError("not a UTF-8 text file: its first line cannot be read as column "
                               "names", source=path) from None
    if not text.strip():
        raise CorruptFileError("empty: no header line with column names", source=path)
    return [name.strip() for name in next(csv.reader([text], delimiter=delimiter))]


def resolve_columns(path: Path, spec: ImportMap, names: list[str], map_name: str) -> ImportMap:
    """The map checked against the file's columns; without a map, the optional contract
    columns the file lacks are left out."""
    if spec.optional_defaults:
        absent = [q for q, cols in (("accel", spec.accel), ("temp", (spec.temp,)),
                                    ("ref_rate", (spec.ref_rate,)), ("mount", (spec.mount,)))
                  if not all(c in names for c in cols)]
        spec = spec.without(absent)
    for column, role in spec.columns().items():
        if column not in names:
            shown = ", ".join(names[:40]) + (", ..." if len(names) > 40 else "")
            why = (f"{role} in {map_name}" if not spec.optional_defaults else
                   "without --map the contract's names t, gyro_x, gyro_y, gyro_z are expected")
            raise LogFormatError(f"column {column!r} ({why}) is not in the file; its columns: "
                                 f"{shown}", source=path)
        if names.count(column) > 1:
            raise LogFormatError(f"column {column!r} ({role} in {map_name}) appears "
                                 f"{names.count(column)} times in the header", source=path)
    return spec


def convert(path: Path, spec: ImportMap, sink: LogSink) -> int:
    """Stream the table into ``sink``; returns the number of data rows read."""
    names = read_header(path, spec.delimiter)
    numeric = [c for c in spec.columns() if c != spec.mount]
    text = [spec.mount] if spec.mount else []
    reader = _open(path, spec, numeric, text)
    row = 0
    while True:
        try:
            batch = reader.read_next_batch()
        except StopIteration:
            break
        except (pa.ArrowInvalid, OSError) as exc:
            raise _read_error(exc, path, spec, names, numeric) from None
        n = batch.num_rows
        if n:
            rows = np.arange(row, row + n, dtype=np.int64)
            sink.write(_columns(batch, spec, rows), rows)
            row += n
    return row


def _open(path, spec, numeric, text, types=pa.float64()):
    convert = pacsv.ConvertOptions(
        include_columns=numeric + text, strings_can_be_null=True,
        column_types={**{c: types for c in numeric}, **{c: pa.string() for c in text}})
    try:
        return pacsv.open_csv(path, read_options=pacsv.ReadOptions(block_size=BLOCK_BYTES),
                              parse_options=pacsv.ParseOptions(delimiter=spec.delimiter),
                              convert_options=convert)
    except (pa.ArrowInvalid, OSError) as exc:  # the first block is parsed on opening
        if types == pa.string():
            raise
        raise _read_error(exc, path, spec, read_header(path, spec.delimiter), numeric) from None


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
    for axis, column in enumerate(spec.accel or ()):
        out[f"accel_{'xyz'[axis]}"] = spec.accel_scale.apply(values(column), axis)
    if spec.mount:
        out["mount"] = pc.utf8_trim_whitespace(batch.column(spec.mount))
    return out


def _read_error(exc, path: Path, spec: ImportMap, names: list[str], numeric: list[str]):
    """The one-line error for what Arrow met: a value that is no number (found again, with
    its line), or text that is no CSV at all."""
    text = str(exc)
    match = _CONVERSION.search(text)
    if match is None:
        return CorruptFileError(f"not a readable {spec.format.upper()} file ({first_line(exc)})",
                                source=path)
    index, value = int(match.group(1)), match.group(3)
    if match.group(2) != "double":
        return LogFormatError(f"column {names[index] if index < len(names) else '?'}: "
                              f"{value!r} cannot be read as {match.group(2)}", source=path)
    named = names[index] if index < len(names) and names[index] in numeric else None
    for column in ([named] if named else []) + [c for c in numeric if c != named]:
        row = _first_non_number(path, spec, column)
        if row is not None:
            return LogFormatError(f"{locate(row[0])}, column {column}: {row[1]!r} is not a number",
                                  source=path)
    column = named or "?"
    return LogFormatError(f"column {column}: {value!r} is not a number", source=path)


def _first_non_number(path: Path, spec: ImportMap, column: str):
    """(row, text) of the first value of ``column`` that is no number, or None. The column
    is read again as text, a block at a time; a block that fails is halved until one value
    is left (error path only)."""
    try:
        reader = _open(path, spec, [column], [], types=pa.string())
        row = 0
        for batch in reader:
            values = pc.utf8_trim_whitespace(batch.column(0))
            bad = _bisect(values)
            if bad is not None:
                return row + bad, values[bad].as_py()
            row += batch.num_rows
    except (pa.ArrowInvalid, OSError):
        return None
    return None


def _bisect(values: pa.Array) -> int | None:
    def parses(part):
        try:
            pc.cast(part, pa.float64())
            return True
        except pa.ArrowInvalid:
            return False

    if parses(values):
        return None
    lo, hi = 0, len(values)   # the first bad value is in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if parses(values.slice(lo, mid - lo)):
            lo = mid
        else:
            hi = mid
    return lo
