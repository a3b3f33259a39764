"""Failure records: how one unit's failure travels through a fleet run without stopping it.

When a workflow stage cannot process a unit (corrupt log, unidentifiable model, ...) it
still writes every output it promised, as a *failure record* that names the unit, the stage
that failed and the one-line error. Later stages that receive a failure record pass it on;
the fleet summary lists the unit as failed. A failure record can never be mistaken for a
result: a JSON record has format ``gyrocal.failure/1`` (the calibration loader refuses it),
a Parquet record is an empty table carrying the record in its metadata, and an HTML record
is a page saying what failed (:func:`gyrocal.report.pages.write_failure`, which writes a
record to every output of a stage).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypedDict

import pyarrow as pa
import pyarrow.parquet as pq

from . import atomic, formats
from .errors import CorruptFileError, GyrocalError

FORMAT = formats.FAILURE
META_KEY = b"gyrocal.failure"


class FailureRecord(TypedDict):
    """A failure record, as every JSON or Parquet output of the failed stage holds it."""

    format: str  # FORMAT
    device: str | None
    batch: str | None
    session: str | None
    protocol: str | None
    stage: str
    error: str  # one line
    internal: bool  # a bug of gyrocal rather than a fault of the input or the machine


class UpstreamFailure(GyrocalError):
    """An input is a failure record: this stage has nothing to work on."""

    def __init__(self, record: FailureRecord):
        super().__init__(f"{record['stage']} failed: {record['error']}")
        self.record = record


def record(stage: str, error: BaseException | str, meta: Mapping[str, Any] | None = None) -> FailureRecord:
    """The failure record of ``stage`` failing with ``error`` (an exception, or the reason
    as text: a job the workflow's limits ended, :mod:`gyrocal.run.guard`)."""
    internal = not isinstance(error, (GyrocalError, str, MemoryError))
    text = " ".join(str(error).split())
    if isinstance(error, MemoryError):  # the machine's memory, not a bug of the stage
        text = "ran out of memory" + (f" ({text})" if text else "")
    elif internal:
        text = f"internal error: {type(error).__name__}: {text}"
    meta = meta or {}
    return {
        "format": FORMAT,
        "device": meta.get("device"),
        "batch": meta.get("batch"),
        "session": meta.get("session"),
        "protocol": meta.get("protocol"),
        "stage": stage,
        "error": text,
        "internal": internal,
    }


def read(path, data=None) -> FailureRecord | None:
    """The failure record stored at ``path`` (or in ``data``, the bytes of a file of that
    name or a seekable binary file of them: a Parquet file's footer alone is read), or None
    if it holds a real result."""
    path = Path(path)
    if data is None and not path.exists():
        return None
    if path.suffix == ".parquet":
        source = path if data is None else data if hasattr(data, "read") else pa.BufferReader(data)
        try:
            meta = pq.read_schema(source).metadata or {}
        except (pa.ArrowInvalid, OSError):
            return None
        raw = meta.get(META_KEY)
        return json.loads(raw) if raw else None
    if path.suffix == ".json":
        if hasattr(data, "read"):
            data = data.read()
        try:
            doc = json.loads(path.read_text() if data is None else data)
        except (ValueError, OSError):
            return None
        return doc if isinstance(doc, dict) and doc.get("format") == FORMAT else None
    return None


def check_inputs(*paths) -> None:
    """Raise :class:`UpstreamFailure` if any input is a failure record."""
    for path in paths:
        found = read(path) if path else None
        if found is not None:
            raise UpstreamFailure(found)


def write(outputs, rec: FailureRecord) -> None:
    """Write ``rec`` into every Parquet or JSON output, in the form its suffix calls for (an
    HTML output's page is the report's: :func:`gyrocal.report.pages.write_failure`)."""
    for out in map(Path, outputs):
        if out.suffix == ".html":
            raise ValueError(f"{out}: a failure page is written by gyrocal.report.pages.write_failure")
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.suffix == ".parquet":
            table = pa.table({"failed": pa.array([], type=pa.bool_())})
            with atomic.replacing(out) as tmp:
                pq.write_table(table.replace_schema_metadata({META_KEY: json.dumps(rec).encode()}), tmp)
        else:
            atomic.write_text(out, json.dumps(rec, indent=2) + "\n")


def load_json(path, data: bytes | None = None, refuse_records: bool = True) -> dict[str, Any]:
    """A JSON result file (or ``data``, the bytes of one that ``path`` names), refusing
    failure records with their own message (``refuse_records``; else returned as read)."""
    path = Path(path)
    try:
        if data is None:
            data = path.read_bytes()
        doc = json.loads(data)
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except ValueError as exc:
        raise CorruptFileError(f"not valid JSON ({exc})", source=path) from None
    if refuse_records and isinstance(doc, dict) and doc.get("format") == FORMAT:
        raise UpstreamFailure(doc)
    return doc
