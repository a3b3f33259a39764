"""Results tables: a pandas table as Parquet with gyrocal's JSON metadata beside it (the
stages' observations, segments, validation and diagnosis tables), and back.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from . import atomic
from .errors import CorruptFileError, LogFormatError, first_line

OBS_META_KEY = b"gyrocal.observations"


def write_table(frame, path, metadata: dict | None = None) -> None:
    """A pandas table as Parquet, with JSON metadata under ``gyrocal.observations``."""
    if frame.attrs:  # in-memory companions (the session's record) are not file metadata
        frame = frame.copy(deep=False)
        frame.attrs = {}
    table = pa.Table.from_pandas(frame, preserve_index=False)
    if metadata is not None:
        table = table.replace_schema_metadata(
            {**(table.schema.metadata or {}), OBS_META_KEY: json.dumps(metadata).encode()}
        )
    with atomic.replacing(path) as tmp:
        pq.write_table(table, tmp)


def read_table_with_metadata(path, data: bytes | None = None):
    """(pandas table, metadata dict) of a file written by :func:`write_table`; ``data``, its
    bytes where they come from elsewhere (a part of an archive, which ``path`` names)."""
    table, metadata = _read_arrow(path, data)
    return table.to_pandas(), metadata


def read_columns_with_metadata(path, data: bytes | None = None):
    """(:class:`gyrocal.io.columns.Columns`, metadata dict) of the same file, without pandas:
    what a report reads."""
    from .columns import Columns

    table, metadata = _read_arrow(path, data, whole_file=True)
    return Columns.from_arrow(table), metadata


def _read_arrow(path, data: bytes | None, whole_file: bool = False):
    """``whole_file``: one file read by ``ParquetFile``, which (unlike ``read_table`` and
    its dataset layer) imports neither pandas nor pyarrow.compute."""
    path = Path(path)
    source = path if data is None else pa.BufferReader(data)
    try:
        table = pq.ParquetFile(source).read() if whole_file else pq.read_table(source)
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except (pa.ArrowInvalid, OSError) as exc:
        raise CorruptFileError(f"not a readable Parquet file ({first_line(exc)})", source=path) from None
    raw = (table.schema.metadata or {}).get(OBS_META_KEY)
    if raw is None:
        raise LogFormatError("is not a table written by gyrocal", source=path)
    return table, json.loads(raw)
