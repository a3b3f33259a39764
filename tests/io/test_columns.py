"""Tables read as numpy columns without pandas (gyrocal.io.columns): the same values pandas
reads, and a unit report drawn from them without importing pandas."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from gyrocal.io.columns import Columns
from gyrocal.io.tables import read_columns_with_metadata, read_table_with_metadata, write_table


def same(a: list, b: list) -> bool:
    """Equal lists of plain values, NaN equal to NaN."""
    return len(a) == len(b) and all(
        x == y or (isinstance(x, float) and isinstance(y, float) and x != x and y != y)
        for x, y in zip(a, b, strict=False)
    )


def frame() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "f": [1.5, np.nan, -2.0, 0.0, 3.25],
            "i": [1, 2, 3, 4, 5],
            "b": [True, False, True, True, False],
            "s": ["+x", None, "-z", "+x", "text & <tag>"],
            "c": pd.Categorical(["hold", "soak", None, "hold", "rejected"]),
            "o": pd.array([True, None, False, True, None], dtype=object),
            "n": pd.array([1, None, 3, None, 5], dtype="Int64"),
            "z": [None] * 5,  # a column that held nothing: Arrow's null type
        }
    )


def as_pandas_reads(series) -> list:
    """A column's values as pandas reads them, a missing one as NaN in a numeric column
    (whose values are then floats) and None in any other."""
    numeric = series.dtype.kind in "iuf"
    missing = series.isna().to_numpy()
    values = series.astype(object).tolist()
    return [
        (float("nan") if numeric else None) if gap else (float(v) if numeric and missing.any() else v)
        for v, gap in zip(values, missing, strict=False)
    ]


def test_a_table_reads_as_pandas_reads_it(tmp_path):
    path = tmp_path / "t.parquet"
    write_table(frame(), path, {"k": 1})
    columns, meta = read_columns_with_metadata(path)
    pandas_frame, pandas_meta = read_table_with_metadata(path)
    assert meta == pandas_meta == {"k": 1}
    assert columns.columns == list(pandas_frame.columns) and len(columns) == len(pandas_frame)
    for name in columns.columns:
        assert same(columns[name].tolist(), as_pandas_reads(pandas_frame[name])), name
        assert same(Columns.from_frame(pandas_frame)[name].tolist(), columns[name].tolist()), name
    assert columns["n"].dtype == np.float64 and np.isnan(columns["n"][1])  # integers with gaps
    assert columns["i"].dtype == np.int64 and columns["b"].dtype == bool
    assert columns["s"][1] is None and columns["c"][2] is None and columns["o"][1] is None
    assert columns["z"].tolist() == [None] * 5
    assert same([r["f"] for r in columns.records()], [1.5, float("nan"), -2.0, 0.0, 3.25])


def test_chunks_and_slices_read_whole():
    """A column in several chunks, and arrays that are views into larger ones (an offset
    into their buffers, validity bits not starting at a byte)."""
    data = pa.table(
        {
            "f": pa.array([0.5, None, 2.0, 3.0, None, 5.0, 6.0, 7.0, 8.0, 9.0]),
            "i": pa.array(list(range(10)), pa.int32()),
            "b": pa.array([True, False] * 5),
            "s": pa.array(["a", "b", None, "d", "e", "f", "g", "h", "i", "j"], pa.large_string()),
            "d": pa.array(["p", "q", None, "p", "q", "p", "q", "p", "q", "p"]).dictionary_encode(),
        }
    )
    chunked = pa.concat_tables([data.slice(3, 4), data.slice(0, 3), data.slice(7)])
    columns = Columns.from_arrow(chunked)
    expected = chunked.to_pandas()
    for name in chunked.column_names:
        assert same(columns[name].tolist(), Columns.from_frame(expected)[name].tolist()), name
    assert len(columns) == 10


def test_rows_by_mask_names_and_records():
    table = Columns.from_frame(frame())
    hold = table[table["c"] == "hold"]
    assert len(hold) == 2 and hold["i"].tolist() == [1, 4]
    assert table[["i", "s"]].records()[0] == {"i": 1, "s": "+x"}
    assert "f" in table and "x" not in table and not table.empty and table[table["i"] > 9].empty
    with pytest.raises(ValueError, match="different lengths"):
        Columns({"a": [1, 2], "b": [1]})


@pytest.mark.slow
def test_a_unit_report_draws_from_columns_alone(logs, tmp_path):
    """The report of a unit folder, in a fresh process, imports neither pandas nor the
    other libraries the fit needs; and the tables and figures it draws from the folder are
    the ones the run in memory gives (only the folder's own metadata told apart)."""
    from gyrocal.pipeline.chain import run
    from gyrocal.protocols import registry
    from gyrocal.report.unit import UnitResults, write_unit_report
    from gyrocal.run import cli

    unit = tmp_path / "unit"
    assert cli.main(["segment", str(logs["complete"]), "--out", str(unit)]) == 0
    assert cli.main(["analyse", str(unit)]) == 0
    script = (
        "import sys, json\nfrom gyrocal.run.cli import main\n"
        f"status = main(['report', {str(unit)!r}, '-o', {str(tmp_path / 'r.html')!r}])\n"
        "print(json.dumps([status, sorted(m for m in ('pandas', 'pyarrow.compute', 'pyarrow.dataset',"
        " 'jsonschema', 'scipy', 'matplotlib') if m in sys.modules)]))"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.splitlines()[-1]) == [0, []]

    folder = UnitResults.from_folder(unit)
    memory = UnitResults.from_run(run(logs["complete"]))
    folder = dataclasses.replace(folder, diagnosis=None, residuals=None, heatmaps={}, command="c")
    memory = dataclasses.replace(
        memory,
        command="c",
        calibration=folder.calibration,
        meta=folder.meta,
        protocol=folder.protocol,
        protocol_figures=folder.protocol_figures,
    )
    protocol = registry.get("turntable")
    write_unit_report(folder, tmp_path / "folder.html", protocol)
    write_unit_report(memory, tmp_path / "memory.html", protocol)
    assert (tmp_path / "folder.html").read_bytes() == (tmp_path / "memory.html").read_bytes()


def test_what_a_report_of_any_protocol_imports():
    """The modules a unit report loads, whatever the unit's protocol (its sections and
    figure are read from the protocol's module), leave pandas and the fit's libraries out."""
    from gyrocal.protocols import registry

    script = (
        "import sys, json\nfrom gyrocal.protocols import registry\n"
        "import gyrocal.run.cli, gyrocal.run.stages, gyrocal.report.unit\n"
        f"for name in {list(registry.BUILTIN)!r}:\n    registry.get(name)\n"
        "print(json.dumps(sorted(m for m in ('pandas', 'pyarrow.compute', 'pyarrow.dataset',"
        " 'jsonschema', 'scipy', 'matplotlib') if m in sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.splitlines()[-1]) == []
    assert {"turntable", "servo", "sweep", "ferraris", "static"} <= set(registry.BUILTIN)
