"""Units that stand out from their batch: robust z-scores (median/MAD) per parameter."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..io.errors import InputError
from .limits import finite_number

MIN_BATCH = 5  # fewer units than this: a median/MAD says nothing, no outlier flags
MAD_Z = 0.6745  # Φ⁻¹(0.75): MAD / 0.6745 estimates σ for normal data (Iglewicz & Hoaglin)
ID_COLUMNS = ("device", "batch", "session", "protocol", "unit")


def parameter_columns(table: pd.DataFrame, by: str) -> list[str]:
    """The parameters of a table of units: its numeric columns but ``by`` and identifiers."""
    return [
        c
        for c in table.columns
        if c != by
        and c not in ID_COLUMNS
        and pd.api.types.is_numeric_dtype(table[c])
        and not pd.api.types.is_bool_dtype(table[c])
    ]


def fleet_outliers(table: pd.DataFrame, *, by: str = "batch", threshold: float = 3.5) -> pd.DataFrame:
    """Units whose parameter lies far from the rest of their batch.

    ``table`` has one row per unit: the ``by`` column, identifying columns (any of
    ``ID_COLUMNS`` or non-numeric ones) and one numeric column per parameter (e.g.
    :func:`gyrocal.calibration.parameters.parameter_table`). Within each batch and parameter the robust
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
        raise InputError(
            f"outlier table has no column {by!r} (columns: {', '.join(map(str, table.columns))})"
        )
    threshold = finite_number(threshold, "threshold", positive=True)
    params = parameter_columns(table, by)
    ids = [c for c in table.columns if c not in params]
    long = (
        table.reset_index(drop=True)
        .rename_axis("_row")
        .reset_index()
        .melt(id_vars=["_row", *ids], value_vars=params, var_name="parameter", value_name="value")
    )
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
        ["batch_key", "_p", "_row"], kind="stable"
    )
    out = flagged[[*ids, "parameter", "value", "median", "mad", "z", "note"]].reset_index(drop=True)

    notes, small = [], {}
    units = table.groupby(table[by].astype(str).where(table[by].notna(), ""), sort=True).size()
    for batch, n in units.items():
        if n < MIN_BATCH:
            small[batch] = int(n)
            notes.append(
                f"batch {batch}: {n} unit{'s' if n != 1 else ''}, fewer than {MIN_BATCH}: no outlier flags"
            )
    few = long[~big.to_numpy()].drop_duplicates(["batch_key", "parameter"])
    few = few[~few["batch_key"].isin(small)]
    for batch, part in few.groupby("batch_key", sort=True):
        names = sorted(part["parameter"], key=order.get)
        notes.append(f"batch {batch}: {', '.join(names)} known for fewer than {MIN_BATCH} units: not checked")
    out.attrs["notes"] = notes
    out.attrs["small_batches"] = small
    return out


def plot_parameter_distributions(
    table: pd.DataFrame, flagged: pd.DataFrame, path_or_none=None, *, by: str = "batch", label: str = "device"
) -> str:
    """Each parameter's values per batch (one panel per parameter, units as points, the
    batch median as a bar, batches too small to judge in grey, unit counts in the axis
    labels), flagged units ringed in red and labelled by ``label``.
    Deterministic SVG; written to ``path_or_none`` when given."""
    from ..report.plots import figure_style, panels, to_svg, write_svg

    params = parameter_columns(table, by)
    batches = sorted(table[by].astype(str).where(table[by].notna(), "").unique())
    position = {b: i for i, b in enumerate(batches)}
    frame = table.reset_index(drop=True)
    bkey = frame[by].astype(str).where(frame[by].notna(), "")
    # Deterministic spread of a batch's points across ±0.3 of its slot, by row order.
    rank = bkey.groupby(bkey).cumcount().to_numpy()
    size = bkey.map(bkey.value_counts()).to_numpy()
    x = bkey.map(position).to_numpy(dtype=float) + np.where(
        size > 1, (rank / np.maximum(size - 1, 1) - 0.5) * 0.6, 0
    )
    ids = [c for c in flagged.columns if c in frame.columns and c not in params]
    hit = (
        frame.reset_index().merge(flagged[ids + ["parameter"]], on=ids, how="inner") if len(flagged) else None
    )
    counts = bkey.value_counts()
    ticks = [f"{b} ({counts[b]})" for b in batches]  # unit count; grey points: too few to judge
    with figure_style():
        fig, grid = panels(params, 2.3)
        for axis, p in grid:
            v = frame[p].to_numpy(dtype=float)
            ok = np.isfinite(v)
            small = size < MIN_BATCH
            axis.plot(x[ok & ~small], v[ok & ~small], "o", ms=3, color="#1f77b4", alpha=0.8)
            axis.plot(x[ok & small], v[ok & small], "o", ms=3, color="#999999", alpha=0.8)
            medians = frame[ok].groupby(bkey[ok])[p].median()
            for b, m in medians.items():
                axis.plot([position[b] - 0.35, position[b] + 0.35], [m, m], color="#444", lw=1.2)
            if hit is not None:
                mine = hit[hit["parameter"] == p]
                idx = mine["index"].to_numpy()
                axis.plot(x[idx], v[idx], "o", ms=8, mfc="none", mec="#d62728", mew=1.5)
                if label in frame.columns:
                    for i in idx:
                        axis.annotate(
                            str(frame[label].iloc[i]),
                            (x[i], v[i]),
                            xytext=(4, 3),
                            textcoords="offset points",
                            fontsize=7,
                            color="#d62728",
                            parse_math=False,
                        )
            axis.set_title(p, fontsize=9, parse_math=False)
            axis.set_xticks(
                range(len(batches)),
                ticks,
                rotation=30 if len(batches) > 4 else 0,
                fontsize=7,
                parse_math=False,
            )
            axis.set_xlim(-0.6, len(batches) - 0.4)
        return write_svg(to_svg(fig), path_or_none)
