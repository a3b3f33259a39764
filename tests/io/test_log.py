"""Ingest: the log contract (section 1), units, directory datasets and every refusal."""

from __future__ import annotations

import json
import math

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gyrocal.io.errors import CorruptFileError, EmptyLogError, GyrocalError, LogFormatError
from gyrocal.io.log import MOUNTS, file_digest, file_sha256, read_log


def table(n=100, **overrides):
    t = np.arange(n) * 0.01
    cols = {
        "t": t,
        "gyro_x": np.full(n, 1.0, np.float32),
        "gyro_y": np.zeros(n, np.float32),
        "gyro_z": np.zeros(n, np.float32),
        "temp": np.full(n, 20.0, np.float32),
        "ref_rate": np.ones(n),
    }
    cols.update(overrides)
    return pa.table({k: v for k, v in cols.items() if v is not None})


def write(tmp_path, tbl, name="log.parquet", metadata=None):
    path = tmp_path / name
    if metadata:
        tbl = tbl.replace_schema_metadata({**(tbl.schema.metadata or {}), **metadata})
    pq.write_table(tbl, path)
    return path


def one_line_naming(exc, path):
    text = str(exc)
    assert "\n" not in text
    assert str(path) in text
    return text


def test_reads_only_what_it_needs_in_internal_units(tmp_path):
    path = write(tmp_path, table(extra=np.arange(100.0)))
    log = read_log(path)
    assert set(log.names) == {"t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"}
    assert len(log) == 100 and log.rows_read == 100 and log.rows_dropped == 0
    np.testing.assert_array_equal(log.column("gyro_x"), np.ones(100))


def test_rad_per_second_metadata_converts_to_degrees(tmp_path):
    units = {b"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()}
    path = write(tmp_path, table(), metadata=units)
    log = read_log(path)
    np.testing.assert_allclose(log.column("gyro_x"), 180.0 / math.pi, rtol=1e-6)
    np.testing.assert_allclose(log.column("ref_rate"), 180.0 / math.pi, rtol=1e-12)


def test_timestamp_time_column_becomes_seconds(tmp_path):
    stamps = pa.array(np.arange(100) * 10_000_000 + 1_700_000_000_000_000_000, type=pa.timestamp("ns"))
    path = write(tmp_path, table(t=stamps))
    t = read_log(path).column("t")
    np.testing.assert_allclose(np.diff(t), 0.01, rtol=1e-9)


def test_non_finite_rows_are_dropped_and_counted(tmp_path):
    gx = np.ones(100, np.float32)
    gx[[3, 50]] = np.nan
    temp = np.full(100, 20.0, np.float32)
    temp[7] = np.inf
    log = read_log(write(tmp_path, table(gyro_x=gx, temp=temp)))
    assert log.rows_dropped == 3 and len(log) == 97
    assert np.all(np.isfinite(log.column("gyro_x")))


def test_directory_dataset_is_ordered_by_time_not_by_name(tmp_path):
    folder = tmp_path / "log"
    folder.mkdir()
    full = table(1200)
    for i in range(12):  # part-10 sorts before part-2 by name
        pq.write_table(full.slice(i * 100, 100), folder / f"part-{i}.parquet")
    log = read_log(folder)
    assert len(log) == 1200
    assert np.all(np.diff(log.column("t")) > 0)
    assert len(file_sha256(folder)) == 64
    assert len(file_digest(folder)) == 64 and file_digest(folder) != file_sha256(folder)


def test_mount_labels_become_codes_and_nulls_continue_the_last_label(tmp_path):
    labels = pa.array([None, "+x", None, "-z"] * 25)
    codes = read_log(write(tmp_path, table(mount=labels))).column("mount")
    x, z = MOUNTS.index("+x"), MOUNTS.index("-z")
    assert list(codes[:6]) == [-1, x, x, z, z, x]  # a leading null stays unknown
    dict_labels = labels.dictionary_encode()
    np.testing.assert_array_equal(
        read_log(write(tmp_path, table(mount=dict_labels), "d.parquet")).column("mount"), codes
    )


def test_a_missing_optional_value_does_not_drop_the_row(tmp_path):
    accel = np.full(100, 1.0, np.float32)
    accel[::2] = np.nan  # an accelerometer logged at half the rate
    path = write(tmp_path, table(accel_x=accel, accel_y=accel, accel_z=accel))
    log = read_log(path, optional=("accel_x", "accel_y", "accel_z"))
    assert len(log) == 100 and log.rows_dropped == 0
    assert np.isnan(log.column("accel_x")).sum() == 50


@pytest.mark.parametrize(
    "case, expected",
    [
        ("missing", "missing required column ref_rate"),
        ("int_gyro", "column gyro_y has type int32, expected float32 or float64"),
        ("backwards", "column t is not strictly increasing"),
        ("duplicate", "column t is not strictly increasing"),
        ("empty", "the log has no rows"),
        ("all_nan", "all 100 rows hold a non-finite value"),
        ("bad_mount", "column mount holds 'x+'"),
        ("bad_units", "gives gyro in 'dps'"),
        ("string_t", "column t has type string"),
    ],
)
def test_bad_logs_get_one_line_errors_naming_the_file(tmp_path, case, expected):
    t = np.arange(100) * 0.01
    metadata = None
    if case == "missing":
        tbl = table(ref_rate=None)
    elif case == "int_gyro":
        tbl = table(gyro_y=np.zeros(100, np.int32))
    elif case == "backwards":
        t[60] = t[10]
        tbl = table(t=t)
    elif case == "duplicate":
        t[61] = t[60]
        tbl = table(t=t)
    elif case == "empty":
        tbl = table(0)
    elif case == "all_nan":
        tbl = table(temp=np.full(100, np.nan, np.float32))
    elif case == "bad_mount":
        tbl = table(mount=pa.array(["+x"] * 99 + ["x+"]))
    elif case == "bad_units":
        tbl, metadata = table(), {b"gyrocal.units": b'{"gyro": "dps"}'}
    else:
        tbl = table(t=pa.array([str(x) for x in t]))
    path = write(tmp_path, tbl, metadata=metadata)
    with pytest.raises(LogFormatError) as info:
        read_log(path)
    assert expected in one_line_naming(info.value, path)
    assert info.value.exit_status == 2


def test_corrupt_and_absent_files(tmp_path):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 this is not parquet at all")
    with pytest.raises(CorruptFileError) as info:
        read_log(bad)
    one_line_naming(info.value, bad)
    truncated = write(tmp_path, table(5000), "trunc.parquet")
    truncated.write_bytes(truncated.read_bytes()[: truncated.stat().st_size // 2])
    with pytest.raises(CorruptFileError):
        read_log(truncated)
    with pytest.raises(CorruptFileError, match="no such file"):
        read_log(tmp_path / "absent.parquet")


def test_empty_directory_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(CorruptFileError, match="no .parquet files"):
        read_log(tmp_path / "empty")


column_types = st.sampled_from([pa.float32(), pa.float64(), pa.int32(), pa.string()])


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), n=st.integers(0, 40))
def test_any_table_gives_a_log_or_a_gyrocal_error(tmp_path, data, n):
    names = data.draw(
        st.lists(
            st.sampled_from(["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "mount", "other"]),
            unique=True,
            min_size=1,
            max_size=8,
        )
    )
    cols = {}
    for name in names:
        typ = data.draw(column_types)
        values = data.draw(
            st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=n, max_size=n)
        )
        if pa.types.is_string(typ):
            cols[name] = pa.array([data.draw(st.sampled_from(MOUNTS + ("?",))) for _ in values])
        elif pa.types.is_integer(typ):
            cols[name] = pa.array(
                [int(v) if math.isfinite(v) and abs(v) < 2**31 else 0 for v in values], type=typ
            )
        else:
            cols[name] = pa.array(values, type=typ)
    path = write(tmp_path, pa.table(cols), "h.parquet")
    try:
        log = read_log(path)
    except GyrocalError as exc:
        assert "\n" not in str(exc)
    else:
        assert len(log) >= 1
        assert np.all(np.diff(log.column("t")) > 0)


def test_hashes_are_of_the_bytes(tmp_path):
    import hashlib

    import blake3

    path = write(tmp_path, table())
    assert file_sha256(path) == hashlib.sha256(path.read_bytes()).hexdigest()
    assert file_digest(path) == blake3.blake3(path.read_bytes()).hexdigest()


def test_empty_error_is_a_format_error(tmp_path):
    with pytest.raises(EmptyLogError):
        read_log(write(tmp_path, table(0)))
