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
from .io import GYRO, time_seconds, check_float, declared_units, open_dataset, to_internal_units

BATCH_ROWS = 1 << 20
DERIVED = ("rate_x", "rate_y", "rate_z", "temp_rate")  # solved for, or computed here
TEMP_RATE_WINDOW_S = 60.0  # a seed-000 hold, for calibration files that do not say


def temperature_rate(t: np.ndarray, temp: np.ndarray, window_s: float = TEMP_RATE_WINDOW_S
                     ) -> np.ndarray:
    """Temperature rate (°C/min) at every sample: the least-squares slope of the logged
    temperature over a centred window, computed on bin means (1 s, or a twentieth of the
    window if shorter) by one convolution and interpolated to the samples. Non-finite
    inputs give NaN.

    Bins without samples are filled linearly; the series is extended at both ends by odd
    reflection, which keeps a linear trend, so the slope near the ends is not biased to 0.
    """
    rate = np.full(len(t), np.nan)
    good = np.isfinite(t) & np.isfinite(temp)
    if good.sum() < 2:
        return rate
    tg, Tg = t[good], temp[good]
    width = min(1.0, window_s / 20.0)
    index = np.floor((tg - tg[0]) / width).astype(np.int64)
    counts = np.bincount(index)
    sums = np.bincount(index, weights=Tg)
    filled = counts > 0
    centres = (np.arange(len(counts)) + 0.5) * width
    means = np.interp(centres, centres[filled], sums[filled] / counts[filled])
    half = max(int(round(window_s / width / 2)), 1)
    if len(means) <= 2 * half:  # the whole log is shorter than the window: one slope
        lags = centres - centres.mean()
        rate[good] = 60.0 * np.sum(lags * means) / max(np.sum(lags ** 2), 1e-300)
        return rate
    padded = np.pad(means, half, mode="reflect", reflect_type="odd")
    lags = np.arange(-half, half + 1, dtype=float)
    slope = np.convolve(padded, lags[::-1] / (np.sum(lags ** 2) * width), mode="valid")  # °C/s
    rate[good] = 60.0 * np.interp(tg - tg[0], centres, slope)
    return rate


def apply_calibration(cal: Calibration, path, out) -> dict:
    """Write ``out`` from the log at ``path``; return counts (rows, non-finite, clamped).

    Rows whose gyro, temperature or other needed input is not finite get NaN compensated
    rates (counted); temperatures outside the calibrated range use the nearest end's
    calibration (counted).
    """
    path, out = Path(path), Path(out)
    dataset = open_dataset(path)
    schema = dataset.schema
    needed = [*GYRO, "temp"] + sorted(c for c in cal.model.needs if c not in (*DERIVED, "temp"))
    missing = [c for c in needed if c not in schema.names]
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

    temp_rate = None
    if "temp_rate" in cal.model.needs:  # needs the whole temperature record, not a batch
        if "t" not in schema.names:
            raise LogFormatError("cannot apply the calibration: its temp_rate term needs the t column",
                                 source=path)
        table = dataset.to_table(columns=["t", "temp"])
        check_float(schema, "temp", path)
        seconds = time_seconds(table.column("t").combine_chunks(), path, [])
        steps = np.diff(seconds[np.isfinite(seconds)])
        if steps.size and steps.min() <= 0:
            raise LogFormatError("column t does not increase strictly, so the temperature rate "
                                 "the calibration needs cannot be derived", source=path)
        window = cal.covariates.get("temp_rate", {}).get("window_s", TEMP_RATE_WINDOW_S)
        temp_rate = temperature_rate(seconds, to_internal_units(
            "temp", table.column("temp").to_numpy().astype(np.float64), units), window)
        del table

    counts = {"rows": 0, "nonfinite": 0, "clamped": 0}
    tmp = out.with_name(out.name + ".tmp")
    with pq.ParquetWriter(tmp, out_schema) as writer:
        for batch in dataset.to_batches(batch_size=BATCH_ROWS):
            cols = {c: to_internal_units(c, batch.column(c).to_numpy(zero_copy_only=False)
                                         .astype(np.float64), units) for c in needed}
            gyro = np.column_stack([cols[c] for c in GYRO])
            data = {c: cols[c] for c in needed if c not in GYRO}
            if temp_rate is not None:
                data["temp_rate"] = temp_rate[counts["rows"]:counts["rows"] + batch.num_rows]
            good = np.all(np.isfinite(gyro), axis=1)
            for v in data.values():
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
    tmp.replace(out)
    return counts
