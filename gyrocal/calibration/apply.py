"""Applying a calibration to a log (contract section 5), batch by batch.

The output keeps every row and column of the input; ``gyro_x/y/z`` become compensated
rates in deg/s (float64). Only the columns the model needs are converted; the rest are
passed through as Arrow arrays. Three batches are under way at a time: the next decoded
on a thread, this one compensated, the last one written on another thread (Arrow decodes,
encodes and compresses without the GIL), so memory stays flat and the compensation runs
beside the reading and writing rather than between them.
"""

from __future__ import annotations

import json
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..io import atomic
from ..io.errors import LogFormatError
from ..io.log import (
    GYRO,
    READ_ERRORS,
    REQUIRED,
    check_float,
    declared_units,
    open_dataset,
    read_error,
    read_log,
    record_batches,
    time_seconds,
    to_internal_units,
)
from ..terms.signals import (
    RECORD_COLUMNS,
    SERIES_INPUTS,
    TEMP_RATE_WINDOW_S,
    HistoryBins,
    SampleRecord,
    Series,
)
from .file import Calibration

BATCH_ROWS = 1 << 18  # rows compensated and written at a time, a row group of the output
DERIVED = ("rate_x", "rate_y", "rate_z")  # solved for


class ApplyCounts(TypedDict):
    """What ``gyrocal apply`` did to a log: its rows, those written NaN (an input not finite,
    or a compensation that overflows), those at temperatures clamped to the calibrated
    range, and of those the ones beyond it by more than the end points' own temperature
    spread (:meth:`gyrocal.calibration.file.Calibration.range_tolerance`: the ones to warn of)."""

    rows: int
    nonfinite: int
    clamped: int
    beyond: int


def apply_calibration(cal: Calibration, path, out) -> ApplyCounts:
    """Write ``out`` from the log at ``path``; return counts (rows, non-finite, clamped,
    beyond the clamping's tolerance).

    Rows whose gyro, temperature or other needed input is not finite get NaN compensated
    rates (counted); temperatures outside the calibrated range use the nearest end's
    calibration (counted).
    """
    path, out = Path(path), Path(out)
    dataset = open_dataset(path)
    schema = dataset.schema
    needs = cal.model.inputs
    # A log with no temperature (a hand-rotation session may have none) takes a
    # calibration made at one temperature as it is: there is nothing to interpolate.
    constant_temp = None
    grid_temps = cal.grid.temperatures
    if "temp" not in schema.names and len(grid_temps) == 1 and not needs & SERIES_INPUTS:
        constant_temp = float(grid_temps[0])
    needed = [*GYRO, *(["temp"] if constant_temp is None else [])] + sorted(
        c for c in needs if c not in (*DERIVED, "temp", *SERIES_INPUTS)
    )
    missing = [c for c in ([*needed, "t"] if needs & SERIES_INPUTS else needed) if c not in schema.names]
    if missing:
        raise LogFormatError(f"cannot apply the calibration: the log lacks {', '.join(missing)}", source=path)
    for c in needed:
        check_float(schema, c, path)
    units = declared_units(schema, path)

    out_schema = schema
    for c in GYRO:
        out_schema = out_schema.set(out_schema.get_field_index(c), pa.field(c, pa.float64()))
    metadata = dict(schema.metadata or {})
    if "gyro" in units:  # compensated rates are deg/s whatever the input was
        metadata[b"gyrocal.units"] = json.dumps({k: v for k, v in units.items() if k != "gyro"}).encode()
    out_schema = out_schema.with_metadata(metadata)

    # Series signals (time since the first sample, the temperature rate, lags) are defined
    # on the whole record, as in the fit (gyrocal.pipeline.chain.segment_log): time counts from
    # the first row the fit would keep, and the record is the same bin means, gathered in
    # a first pass over the file.
    origin: list = []
    t0, series = None, None
    if needs & SERIES_INPUTS:
        t0, series = _record(
            cal,
            path,
            schema.names,
            bool(needs & {"temp_rate", "temp_lag"}),
            [
                c
                for c in RECORD_COLUMNS
                if {"gyro": "rate_history", "accel": "accel_history"}[c.split("_")[0]] in needs
            ],
        )
    counts: ApplyCounts = {"rows": 0, "nonfinite": 0, "clamped": 0, "beyond": 0}
    transforms = cal.model.sample_transforms()  # a die temperature: filters with state
    with atomic.replacing(out) as tmp:  # never leave half a file behind
        _write(
            dataset,
            tmp,
            out_schema,
            cal,
            needed,
            units,
            path,
            origin,
            t0,
            series,
            counts,
            constant_temp,
            transforms,
        )
    return counts


def _record(cal: Calibration, path: Path, names, whole: bool, columns=()) -> tuple[float, Series | None]:
    """The first kept row's time (the rule of :func:`gyrocal.io.log.read_log`: finite time,
    gyro, temperature and, when logged, reference rate) and, when ``whole`` or ``columns``
    (the record's further columns a history reads), the record as the fit makes it
    (:class:`gyrocal.terms.signals.HistoryBins`), in memory that does not grow with the log."""
    required = tuple(c for c in REQUIRED if c != "ref_rate" or c in names)
    log = read_log(
        path, optional=tuple(c for c in columns if c not in REQUIRED), required=required, keep_bytes=0
    )
    first, last = log.time_span
    if not whole and not columns:
        return first, None
    window = cal.covariates.get("temp_rate", {}).get("window_s", TEMP_RATE_WINDOW_S)
    record = HistoryBins(first, last, window_s=window)
    for batch in log.scan(("t", "temp", *columns)):
        record.push(batch["t"], batch["temp"], {c: batch[c] for c in columns})
    return first, record.result()


def _read(dataset, path):
    """The log's batches; data Arrow cannot read is an error naming the log (the output's
    own errors, raised by the writer, are not caught here)."""
    try:
        yield from record_batches(dataset, dataset.schema.names, BATCH_ROWS)
    except READ_ERRORS as exc:
        raise read_error(exc, path) from None


_DONE = object()


def _ahead(batches, depth: int = 2):
    """``batches`` (an iterator), produced on a thread up to ``depth`` ahead of the
    consumer; an error is raised where the batch would have been."""
    waiting: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                waiting.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce():
        try:
            for batch in batches:
                if not put(batch):
                    return
            put(_DONE)
        except BaseException as exc:  # noqa: BLE001 - raised in the consumer
            put(exc)

    threading.Thread(target=produce, name="apply-read", daemon=True).start()
    try:
        while (item := waiting.get()) is not _DONE:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()  # the consumer stopped: let the thread end and free its batches


class WriterOptions(TypedDict):
    """Keyword arguments of :class:`pyarrow.parquet.ParquetWriter` (:func:`writer_options`)."""

    use_dictionary: list[str]  # the columns Arrow dictionary-encodes


def writer_options(schema: pa.Schema) -> WriterOptions:
    """How apply writes Parquet: Arrow's defaults, but no dictionary for the compensated
    rates, whose float64 values never repeat (Arrow would build a dictionary of each
    column chunk's first megabyte before falling back to plain: half the writing time)."""
    return {"use_dictionary": [name for name in schema.names if name not in GYRO]}


def _write(
    dataset,
    tmp,
    out_schema,
    cal,
    needed,
    units,
    path,
    origin,
    t0,
    series,
    counts,
    constant_temp=None,
    transforms=(),
) -> None:
    with (
        pq.ParquetWriter(tmp, out_schema, **writer_options(out_schema)) as writer,
        ThreadPoolExecutor(1) as pool,
    ):
        writing = None
        histories: dict = {}  # each history's filter, its state carried from batch to batch
        for batch in _ahead(_read(dataset, path)):
            cols = {
                c: to_internal_units(
                    c, batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64), units
                )
                for c in needed
            }
            gyro = np.column_stack([cols[c] for c in GYRO])
            data = {c: cols[c] for c in needed if c not in GYRO}
            if constant_temp is not None:
                data["temp"] = np.full(len(gyro), constant_temp)
            if t0 is not None:  # the model reads series signals: time since the first row
                data["t"] = time_seconds(batch.column("t"), path, origin, units) - t0
            inputs = _with_record(data, cols, series, histories)
            for transform in transforms:  # a die temperature: a filter with state
                inputs = transform(inputs)
            result, good = _compensated(cal, gyro, cols, inputs, counts)
            arrays = [
                pa.array(result[:, GYRO.index(name)]) if name in GYRO else batch.column(name)
                for name in out_schema.names
            ]
            if writing is not None:
                writing.result()  # in order, one batch written at a time
            writing = pool.submit(writer.write_table, pa.Table.from_arrays(arrays, schema=out_schema))
            counts["rows"] += batch.num_rows
            counts["nonfinite"] += int((~good).sum())
        if writing is not None:
            writing.result()


def _with_record(
    data: dict[str, np.ndarray], cols: dict, series: Series | None, histories: dict
) -> dict[str, Any]:
    """A batch's inputs with, where the model reads series signals, the temperature rate
    from the fit's record and the batch's samples as the record its histories run over,
    from the state the batch before left."""
    if series is None:
        return data
    temp_rate = series.at("temp_rate", data["t"])
    record = SampleRecord(
        series, {**cols, "t": data["t"], "temp": data["temp"], "temp_rate": temp_rate}, histories
    )
    return {**data, "temp_rate": temp_rate, "series": record}


def _compensated(
    cal, gyro: np.ndarray, cols: dict, data: dict[str, Any], counts: ApplyCounts
) -> tuple[np.ndarray, np.ndarray]:
    """One batch's compensated rates and which rows are finite: a row whose gyro or any input
    is not finite, or whose compensation overflows, is NaN; temperatures clamped to the
    calibrated range are counted."""
    good = np.isfinite(cols[GYRO[0]])
    for c in GYRO[1:]:
        good &= np.isfinite(cols[c])
    for k, v in data.items():
        if k != "series":
            good &= np.isfinite(v)
    every = bool(good.all())
    result = np.full_like(gyro, np.nan)
    if every or good.any():
        sub = data if every else {k: v[good] for k, v in data.items()}
        with np.errstate(over="ignore", invalid="ignore"):  # counted just below
            found = cal.compensate(gyro if every else gyro[good], sub, warn=False)
        if every:
            result = found
        else:
            result[good] = found
        counts["clamped"] += int(cal.grid.outside(sub["temp"]).sum())
        counts["beyond"] += int(cal.beyond_tolerance(sub["temp"]).sum())
    elif "series" in data:
        # No row to compensate (the gyro dropped out, the temperature still logged):
        # the histories' filters still move on over the batch, as firmware's do.
        with np.errstate(over="ignore", invalid="ignore"):
            cal.compensate(gyro, data, warn=False)
    # A finite output too large to compensate (its terms overflow) is written as
    # NaN too, and counted with the non-finite rows: no NaN or inf goes unsaid.
    for i in range(3):
        good &= np.isfinite(result[:, i])
    result[~good] = np.nan
    return result, good
