"""Applying a calibration to a log (contract section 5), batch by batch.

The output keeps every row and column of the input; ``gyro_x/y/z`` become compensated
rates in deg/s (float64). Only the columns the model needs are converted; the rest are
passed through as Arrow arrays.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .calibration import Calibration
from .errors import LogFormatError
from .io import (GYRO, check_float, declared_units, open_dataset, record_batches, time_seconds,
                 to_internal_units)
from .signals import SERIES_INPUTS, TEMP_RATE_WINDOW_S, Series, temperature_rate  # noqa: F401

BATCH_ROWS = 1 << 20
DERIVED = ("rate_x", "rate_y", "rate_z")  # solved for


def apply_calibration(cal: Calibration, path, out) -> dict:
    """Write ``out`` from the log at ``path``; return counts (rows, non-finite, clamped).

    Rows whose gyro, temperature or other needed input is not finite get NaN compensated
    rates (counted); temperatures outside the calibrated range use the nearest end's
    calibration (counted).
    """
    path, out = Path(path), Path(out)
    dataset = open_dataset(path)
    schema = dataset.schema
    needs = cal.model.inputs
    needed = [*GYRO, "temp"] + sorted(c for c in needs if c not in (*DERIVED, "temp", *SERIES_INPUTS))
    missing = [c for c in ([*needed, "t"] if needs & SERIES_INPUTS else needed) if c not in schema.names]
    if missing:
        raise LogFormatError(f"cannot apply the calibration: the log lacks {', '.join(missing)}",
                             source=path)
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
    # on the whole record, as in the fit (gyrocal.signals): the time of the first sample is
    # read first, and the temperature record whole when a term reads more than t.
    origin: list = []
    reads_time = bool(needs & SERIES_INPUTS)
    t0 = _first_time(dataset, path, units, origin) if reads_time else 0.0
    series = None
    if needs & {"temp_rate", "temp_lag"}:
        table = dataset.to_table(columns=["t", "temp"])
        seconds = time_seconds(table.column("t").combine_chunks(), path, origin)
        steps = np.diff(seconds[np.isfinite(seconds)])
        if steps.size and steps.min() <= 0:
            raise LogFormatError("column t does not increase strictly, so the temperature record "
                                 "the calibration's terms read cannot be derived", source=path)
        temp = to_internal_units("temp", table.column("temp").to_numpy().astype(np.float64), units)
        del table
        good = np.isfinite(seconds) & np.isfinite(temp)
        window = cal.covariates.get("temp_rate", {}).get("window_s", TEMP_RATE_WINDOW_S)
        series = Series(seconds[good] - t0, temp[good], t0, window)

    counts = {"rows": 0, "nonfinite": 0, "clamped": 0}
    tmp = out.with_name(out.name + ".tmp")
    try:
        _write(dataset, tmp, out_schema, cal, needed, units, path, origin,
               t0 if reads_time else None, series, counts)
    except BaseException:
        tmp.unlink(missing_ok=True)  # never leave half a file behind
        raise
    tmp.replace(out)
    return counts


def _first_time(dataset, path, units, origin) -> float:
    """The time of the first row the fit kept (``read_log``: finite time, gyro, temperature
    and reference rate): series signals count ``t`` from it on both sides."""
    names = [c for c in ("t", *GYRO, "temp", "ref_rate") if c in dataset.schema.names]
    for batch in dataset.to_batches(columns=names):
        t = time_seconds(batch.column("t"), path, origin)
        good = np.isfinite(t)
        for c in names[1:]:
            good &= np.isfinite(batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64))
        if good.any():
            return float(t[np.argmax(good)])
    raise LogFormatError("no row has a finite time, gyro and temperature", source=path)


def _write(dataset, tmp, out_schema, cal, needed, units, path, origin, t0, series, counts) -> None:
    with pq.ParquetWriter(tmp, out_schema) as writer:
        for batch in record_batches(dataset, dataset.schema.names, BATCH_ROWS):
            cols = {c: to_internal_units(c, batch.column(c).to_numpy(zero_copy_only=False)
                                         .astype(np.float64), units) for c in needed}
            gyro = np.column_stack([cols[c] for c in GYRO])
            data = {c: cols[c] for c in needed if c not in GYRO}
            if t0 is not None:  # the model reads series signals: time since the first row
                data["t"] = time_seconds(batch.column("t"), path, origin) - t0
            if series is not None:
                data["series"] = series
                data["temp_rate"] = series.at("temp_rate", data["t"])
            good = np.all(np.isfinite(gyro), axis=1)
            for k, v in data.items():
                if k != "series":
                    good &= np.isfinite(v)
            result = np.full_like(gyro, np.nan)
            if good.any():
                sub = {k: v[good] for k, v in data.items()}
                result[good] = cal.compensate(gyro[good], sub, warn=False)
                counts["clamped"] += int(cal.grid.outside(sub["temp"]).sum())
            arrays = [pa.array(result[:, GYRO.index(name)]) if name in GYRO else batch.column(name)
                      for name in out_schema.names]
            writer.write_table(pa.Table.from_arrays(arrays, schema=out_schema))
            counts["rows"] += batch.num_rows
            counts["nonfinite"] += int((~good).sum())
