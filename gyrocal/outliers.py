"""Units that stand out from their batch: robust z-scores (median/MAD) per parameter."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import InputError
from .limits import finite_number

MIN_BATCH = 5            # fewer units than this: a median/MAD says nothing, no outlier flags
MAD_Z = 0.6745           # Φ⁻¹(0.75): MAD / 0.6745 estimates σ for normal data (Iglewicz & Hoaglin)
ID_COLUMNS = ("device", "batch", "session", "protocol", "unit")


def parameter_columns(table: pd.DataFrame, by: str) -> list[str]:
    """The parameters of a table of units: its numeric columns but ``by`` and identifiers."""
    return [c for c in table.columns if c != by and c not in ID_COLUMNS
            and pd.api.types.is_numeric_dtype(table[c]) and not pd.api.types.is_bool_dtype(table[c])]


def fleet_outliers(table: pd.DataFrame, *, by: str = "batch", threshold: float = 3.5) -> pd.DataFrame:
    """Units whose parameter lies far from the rest of their batch.

    ``table`` has one row per unit: the ``by`` column, identifying columns (any of
    ``ID_COLUMNS`` or non-numeric ones) and one numeric column per parameter (e.g.
    :func:`gyrocal.parameters.parameter_table`). Within each batch and parameter the robust
    z-score is

        z = 0.6745 (x − median) / MAD,        MAD = median |x − median|

    (Iglewicz & Hoaglin's modified z-score: 0.6745 = Φ⁻¹(0.75) makes MAD/0.6745 estimate σ
    for normal data, so z is in standard deviations and one outlying unit cannot inflate
    the yardstick); |z| > ``threshold`` flags. When MAD is 0 (most units share one value),
    a value that differs from the median beyond 1e-9 relative is flagged with z = ±inf,
    note "differs from identical others". A batch with fewer than 5 units (per parameter:
    units with a value) gets no flags; ``result.attrs["notes"]`` says so, and
    ``result.attrs["small_batches"]`` maps such batches to their unit counts.

    Returns one row per flag: the row's identifying columns, parameter, value, median, mad,
    z, note; sorted by batch, parameter (table order) and row.
    """
    if by not in table.columns:
        raise InputError(f"outlier table has no column {by!r} (columns: {', '.join(map(str, table.columns))})")
    threshold = finite_number(threshold, "threshold", positive=True)
    params = parameter_columns(table, by)
    ids = [c for c in table.columns if c not in params]
    long = table.reset_index(drop=True).rename_axis("_row").reset_index().melt(
        id_vars=["_row", *ids], value_vars=params, var_name="parameter", value_name="value")
    long = long[np.isfinite(long["value"].to_numpy(dtype=float))]
    long["batch_key"] = long[by].astype(str).where(long[by].notna(), "")
    keys = [long["batch_key"], long["parameter"]]
    grouped = long.groupby(keys, sort=False)["value"]
    long["median"] = grouped.transform("median")
    long["dev"] = (long["value"] - long["median"]).abs()
    long["mad"] = long.groupby(keys, sort=False)["dev"].transform("median")
    long["count"] = grouped.transform("size")
    big = long["count"] >= MIN_BATCH
    mad, dev = long["mad"].to_numpy(), long["dev"].to_numpy()
    diff = long["value"].to_numpy() - long["median"].to_numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(mad > 0, MAD_Z * diff / np.where(mad > 0, mad, 1.0), 0.0)
    tiny = 1e-9 * np.maximum(np.abs(long["value"].to_numpy()), np.abs(long["median"].to_numpy()))
    distinct = (mad == 0) & (dev > tiny)
    z = np.where(distinct, np.copysign(np.inf, diff), z)
    long["z"] = z
    long["note"] = np.where(distinct, "differs from identical others", "")
    flagged = long[big.to_numpy() & (np.abs(z) > threshold)]
    order = {p: i for i, p in enumerate(params)}
    flagged = flagged.assign(_p=flagged["parameter"].map(order)).sort_values(
        ["batch_key", "_p", "_row"], kind="stable")
    out = flagged[[*ids, "parameter", "value", "median", "mad", "z", "note"]].reset_index(drop=True)

    notes, small = [], {}
    units = table.groupby(table[by].astype(str).where(table[by].notna(), ""), sort=True).size()
    for batch, n in units.items():
        if n < MIN_BATCH:
            small[batch] = int(n)
            notes.append(f"batch {batch}: {n} unit{'s' if n != 1 else ''}, fewer than {MIN_BATCH}: "
                         "no outlier flags")
    few = long[~big.to_numpy()].drop_duplicates(["batch_key", "parameter"])
    few = few[~few["batch_key"].isin(small)]
    for batch, part in few.groupby("batch_key", sort=True):
        names = sorted(part["parameter"], key=order.get)
        notes.append(f"batch {batch}: {', '.join(names)} known for fewer than {MIN_BATCH} units: "
                     "not checked")
    out.attrs["notes"] = notes
    out.attrs["small_batches"] = small
    return out

