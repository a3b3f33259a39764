"""A results table as named numpy columns, read from Arrow without pandas.

The unit report reads a dozen small tables and draws them; importing pandas (and the
pyarrow.compute it loads) would take 0.4 s of a standalone report's 1.2 s. pyarrow's own
``to_numpy`` imports pandas too, so the Arrow buffers are read here directly: the types
gyrocal's tables hold (numbers, booleans, strings, dictionary-encoded strings, and the null
type of a column that held nothing). A missing value is NaN in a float column and in an
integer column with gaps (a float column then), None in any other; pandas' own readings of
missing strings (NaN) and of nullable integers (its Int64) are brought to the same by
:meth:`Columns.from_frame`, so a table in memory and the same table read back agree.
"""

from __future__ import annotations

from typing import Any

import numpy as np

# Arrow type ids (pyarrow.lib.Type_*) of the layouts read here.
_NUMERIC = {
    "int8": np.int8,
    "int16": np.int16,
    "int32": np.int32,
    "int64": np.int64,
    "uint8": np.uint8,
    "uint16": np.uint16,
    "uint32": np.uint32,
    "uint64": np.uint64,
    "halffloat": np.float16,
    "float": np.float32,
    "double": np.float64,
}


class Columns:
    """Equal-length named columns: ``table[name]`` is a numpy array, ``table[mask]`` the
    rows where a boolean array is true, ``len(table)`` the row count."""

    __slots__ = ("_data", "_rows")

    def __init__(self, data: dict, rows: int | None = None):
        self._data = {name: np.asarray(values) for name, values in data.items()}
        lengths = {len(v) for v in self._data.values()}
        if len(lengths) > 1:
            raise ValueError(f"columns of different lengths: {sorted(lengths)}")
        self._rows = lengths.pop() if lengths else (rows or 0)

    @classmethod
    def from_frame(cls, frame) -> Columns:
        """A pandas table's columns (categories and strings as object arrays)."""
        if frame is None:
            return None
        if isinstance(frame, Columns):
            return frame
        return cls({str(name): _from_series(frame[name]) for name in frame.columns}, len(frame))

    @classmethod
    def from_arrow(cls, table) -> Columns:
        """A pyarrow Table's columns."""
        return cls({name: _from_chunked(table.column(name)) for name in table.column_names}, table.num_rows)

    def __len__(self) -> int:
        return self._rows

    def __contains__(self, name) -> bool:
        return name in self._data

    def __getitem__(self, key):
        if isinstance(key, str):
            return self._data[key]
        if isinstance(key, list):
            return Columns({name: self._data[name] for name in key}, self._rows)
        mask = np.asarray(key)
        return Columns(
            {name: v[mask] for name, v in self._data.items()},
            int(np.count_nonzero(mask)) if mask.dtype == bool else len(mask),
        )

    @property
    def columns(self) -> list[str]:
        return list(self._data)

    @property
    def empty(self) -> bool:
        return self._rows == 0 or not self._data

    def assign(self, **columns) -> Columns:
        return Columns({**self._data, **columns}, self._rows)

    def records(self) -> list[dict[str, Any]]:
        """A dict of plain Python values per row (as pandas' ``to_dict("records")``)."""
        names = list(self._data)
        lists = [self._data[n].tolist() for n in names]
        return [dict(zip(names, row, strict=False)) for row in zip(*lists, strict=False)] if names else []


def present(values: np.ndarray) -> np.ndarray:
    """Where a column holds a value: neither None nor NaN."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        return ~np.isnan(values)
    if values.dtype == object:
        return np.not_equal(values, None) & (values == values)
    return np.ones(values.shape, bool)


def _from_series(series) -> np.ndarray:
    if series.dtype.kind in "biufc" and not series.hasnans:
        return series.to_numpy()
    if series.dtype.kind in "iuf":  # nullable integers with gaps: floats, NaN where missing
        return series.to_numpy(dtype=np.float64, na_value=np.nan)
    return series.to_numpy(dtype=object, na_value=None)


def _from_chunked(column) -> np.ndarray:
    parts = [_from_array(chunk) for chunk in column.chunks]
    if not parts:
        return np.empty(0, _NUMERIC.get(str(column.type), object))
    if len(parts) == 1:
        return parts[0]
    if any(p.dtype == object for p in parts):
        return np.concatenate([p.astype(object) for p in parts])
    return np.concatenate(parts)


def _valid(array) -> np.ndarray | None:
    """Where ``array`` holds a value (None: everywhere)."""
    if array.null_count == 0:
        return None
    bits = np.frombuffer(array.buffers()[0], np.uint8)
    return np.unpackbits(bits, bitorder="little")[array.offset : array.offset + len(array)].astype(bool)


def _from_array(array) -> np.ndarray:
    kind = str(array.type)
    n, offset = len(array), array.offset
    if kind == "null":  # no buffers at all
        return np.full(n, None, object)
    valid = _valid(array)
    if kind in _NUMERIC:
        values = np.frombuffer(array.buffers()[1], _NUMERIC[kind], count=offset + n)[offset:]
        if valid is None:
            return values.copy()
        out = values.astype(np.float64)  # a missing value in an integer column: NaN, as pandas
        out[~valid] = np.nan
        return out
    if kind == "bool":
        bits = np.frombuffer(array.buffers()[1], np.uint8)
        values = np.unpackbits(bits, bitorder="little")[offset : offset + n].astype(bool)
        if valid is None:
            return values
        out = values.astype(object)
        out[~valid] = None
        return out
    if kind.startswith("dictionary<"):
        labels = _from_array(array.dictionary)
        codes = _from_array(array.indices)
        out = np.empty(n, object)
        present = np.isfinite(codes) if codes.dtype.kind == "f" else np.ones(n, bool)
        out[present] = labels[codes[present].astype(np.int64)]
        out[~present] = None
        return out
    if kind in ("string", "large_string", "utf8", "large_utf8"):
        return np.array(array.to_pylist(), dtype=object)
    raise TypeError(f"a column of Arrow type {kind} is not read as numpy here")
