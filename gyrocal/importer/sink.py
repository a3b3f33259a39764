"""Writing converted batches as a contract log.

Every source (CSV, bag, MCAP) hands the sink whole-column arrays already in the contract's
units, with the source row each came from; the sink checks what the contract asks of every
log (time strictly increasing), labels the annotated sections and writes. It holds at most
one row group's worth of rows, so the output's size never bounds what can be imported.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ..io.errors import ConfigError, EmptyLogError, LogFormatError
from ..io.log import ACCEL, GYRO, MOUNTS, SECTIONS

ORDER = ("t", *GYRO, "temp", "ref_rate", *ACCEL, "mount", "section")
METADATA_KEY = b"gyrocal.import"
# Batches are gathered into row groups of about this many rows: sources hand over small
# batches (bounded memory), readers prefer fewer, larger row groups.
ROW_GROUP_ROWS = 1 << 17
MOUNT_TYPE = pa.dictionary(pa.int8(), pa.string())
_MOUNTS = pa.array(MOUNTS, pa.string())
_LABELS = pa.array(SECTIONS, pa.string())


@dataclass
class Summary:
    """What an import wrote, for the one line the command prints."""

    rows: int = 0
    span: tuple[float, float] = (0.0, 0.0)
    columns: tuple[str, ...] = ()
    mapped: list[str] = field(default_factory=list)  # "gyro from gyr_x.. (deg/s)", ...
    notes: list[str] = field(default_factory=list)  # rows dropped, and why
    labels: tuple[str, ...] = ()  # a label column's sections, in order


class LogSink:
    """The output log, written to ``path`` batch by batch.

    ``locate(row)`` describes a source row for messages ("line 12", "message 7 on /imu");
    ``sections`` maps labels to (start, end) source rows, end exclusive; a batch may carry
    the labels instead, as a ``section`` text column (the map's label column), checked as a
    section list is; ``hint(t, before)`` ends a time-order error (what to change in the map).
    """

    def __init__(
        self,
        path: Path,
        source: Path,
        locate: Callable[[int], str],
        sections: dict[str, tuple[int, int]] | None = None,
        sections_file=None,
        hint: Callable[[float, float], str] | str = "",
    ):
        self.path, self.source, self.locate = path, source, locate
        self.hint = hint if callable(hint) else (lambda t, before: hint)
        self.sections = sections or {}
        self.sections_file = sections_file
        self.labels = pa.array(list(self.sections), pa.string())
        # a label column: each label's (first, last) source row as written, the one open
        self.stretches: dict[str, list[int]] = {}
        self.open_label: str | None = None
        self.writer: pq.ParquetWriter | None = None
        self.schema: pa.Schema | None = None
        self.rows, self.first, self.last, self.last_row = 0, None, -np.inf, None
        self.pending: list[pa.RecordBatch] = []
        self.pending_rows = 0

    def write(self, batch: dict, rows: np.ndarray) -> None:
        """Write one batch: ``batch`` maps log columns to float64 arrays (``mount``: an Arrow
        string array), ``rows`` the source row of each sample."""
        n = len(rows)
        if n == 0:
            return
        t = batch["t"]
        self._check_time(t, rows)
        arrays = {name: batch[name] for name in ORDER if name in batch}
        if "mount" in arrays:
            arrays["mount"] = self._mounts(arrays["mount"], rows)
        if "section" in arrays:
            arrays["section"] = self._labels(arrays["section"], rows)
        elif self.sections:
            arrays["section"] = self._section_column(rows)
        table = pa.record_batch(
            [pa.array(v) if isinstance(v, np.ndarray) else v for v in arrays.values()], names=list(arrays)
        )
        if self.writer is None:
            self.schema = table.schema
            # Dictionary encoding only for the labels: tried on float columns it costs
            # memory and time and falls back to plain anyway (readings rarely repeat).
            labels = [name for name in ("mount", "section") if name in arrays]
            self.writer = pq.ParquetWriter(
                self.path, self.schema, compression="zstd", use_dictionary=labels or False
            )
        self.pending.append(table)
        self.pending_rows += n
        if self.pending_rows >= ROW_GROUP_ROWS:
            self._flush()
        if self.first is None:
            self.first = float(t[0])
        self.last, self.last_row = float(t[-1]), int(rows[-1])
        self.rows += n

    def _flush(self) -> None:
        if self.pending:
            self.writer.write_table(pa.Table.from_batches(self.pending), row_group_size=self.pending_rows)
            self.pending, self.pending_rows = [], 0

    def _check_time(self, t: np.ndarray, rows: np.ndarray) -> None:
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise LogFormatError(
                f"{self.locate(int(rows[bad[0]]))} has no valid time ({float(t[bad[0]])!r})",
                source=self.source,
            )
        if t[0] <= self.last:
            i, before = 0, self.last
        else:
            steps = np.flatnonzero(t[1:] <= t[:-1])
            if not steps.size:
                return
            i, before = int(steps[0]) + 1, float(t[steps[0]])
        raise LogFormatError(
            f"time is not strictly increasing: {self.locate(int(rows[i]))} has "
            f"t={float(t[i])!r} s after t={before!r} s"
            f"{self.hint(float(t[i]), before)}",
            source=self.source,
        )

    def _mounts(self, values: pa.Array, rows: np.ndarray) -> pa.Array:
        """Mount labels as a dictionary in the order of gyrocal.io.log.MOUNTS (its fast path)."""
        index = pc.index_in(values, value_set=_MOUNTS)
        unknown = pc.and_(pc.is_null(index), pc.is_valid(values))
        if pc.any(unknown).as_py():
            i = int(np.flatnonzero(unknown.to_numpy(zero_copy_only=False))[0])
            raise LogFormatError(
                f"{self.locate(int(rows[i]))}: mount {values[i].as_py()!r} is not one of {' '.join(MOUNTS)}",
                source=self.source,
            )
        return pa.DictionaryArray.from_arrays(index.cast(pa.int8()), _MOUNTS)

    def _labels(self, values: pa.Array, rows: np.ndarray) -> pa.Array:
        """A label column's text as the section column, checked as a section list is: known
        labels only (an empty cell is outside every section), each label one stretch of
        samples in time order (a section list gives each one start and one end)."""
        values = pc.if_else(pc.equal(values, ""), pa.scalar(None, pa.string()), values)
        index = pc.index_in(values, value_set=_LABELS)
        unknown = pc.and_(pc.is_null(index), pc.is_valid(values))
        if pc.any(unknown).as_py():
            i = int(np.flatnonzero(unknown.to_numpy(zero_copy_only=False))[0])
            raise LogFormatError(
                f"{self.locate(int(rows[i]))}: section {values[i].as_py()!r} is "
                f"not one of {' '.join(SECTIONS)} (or an empty cell)",
                source=self.source,
            )
        codes = index.fill_null(-1).to_numpy(zero_copy_only=False).astype(np.int8)
        # the runs of one label (or none) in this batch: a loop per run, not per sample
        starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
        ends = np.r_[starts[1:], len(codes)]
        for a, b in zip(starts, ends, strict=False):
            label = SECTIONS[codes[a]] if codes[a] >= 0 else None
            if label is not None and label != self.open_label and label in self.stretches:
                first, last = self.stretches[label]
                raise LogFormatError(
                    f"{self.locate(int(rows[a]))}: section {label} starts again after other "
                    f"rows (it ran from {self.locate(first)} to {self.locate(last)}); a section "
                    "is one stretch of samples in time order",
                    source=self.source,
                )
            if label is not None:
                self.stretches.setdefault(label, [int(rows[a]), 0])[1] = int(rows[b - 1])
            self.open_label = label
        return pa.DictionaryArray.from_arrays(pa.array(codes, mask=codes < 0), _LABELS)

    def _section_column(self, rows: np.ndarray) -> pa.Array:
        codes = np.full(len(rows), -1, dtype=np.int8)
        for k, (start, end) in enumerate(self.sections.values()):
            lo, hi = np.searchsorted(rows, (start, end))
            codes[lo:hi] = k
        return pa.DictionaryArray.from_arrays(pa.array(codes, mask=codes < 0), self.labels)

    def finish(self, metadata: dict, source_rows: int) -> Summary:
        """Close the file with the provenance entry; ``source_rows`` is how many rows (IMU
        samples) the source held, which the section list must not run past."""
        if self.writer is None:
            raise EmptyLogError("no samples to import", source=self.source)
        late = [(label, end) for label, (_, end) in self.sections.items() if end > source_rows]
        if late:
            label, end = late[0]
            raise ConfigError(
                f"section {label} ends at sample {end}, past the source's {source_rows} samples",
                source=self.sections_file or self.source,
            )
        self._flush()
        self.writer.add_key_value_metadata(
            {METADATA_KEY: json.dumps(metadata, sort_keys=True, separators=(",", ":"))}
        )
        self.writer.close()
        self.writer = None
        return Summary(
            rows=self.rows,
            span=(self.first, self.last),
            columns=tuple(self.schema.names),
            labels=tuple(self.stretches),
        )

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
