"""Fuzzing ingest and the command line with mutated logs (docs/inputs.md, Fuzzing).

A few dozen derandomized examples run in every suite; ``benchmarks/fuzz.py`` runs thousands
with the same strategies and properties (``tests/io/fuzzing.py``). Below them, one regression
test per bug the fuzzing found, each with its reproducer.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
from hypothesis import event, example, given, reject, settings
from hypothesis import strategies as st

from gyrocal.io import log as gio
from gyrocal.io.errors import CorruptFileError, LogFormatError
from gyrocal.protocols.turntable.segment import LOG_COLUMNS
from gyrocal.run import cli

from . import fuzzing as fz
from .fuzzing import Case

# Arithmetic on NaN, inf or an overflow is an error here, numpy's own warnings too (numpy
# attributes the warnings of its reductions to itself, beyond pyproject's gyrocal.* filter).
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


@pytest.fixture(scope="session")
def base(tmp_path_factory):
    """The valid log every example mutates, and its calibration (for apply)."""
    folder = tmp_path_factory.mktemp("fuzz")
    path = fz.make_base_log(folder)
    calibration = folder / "base-cal.json"
    status, _, stderr, _ = fz.run_cli(["calibrate", str(path), "-o", str(calibration)])
    assert status == 0, stderr
    return SimpleNamespace(path=path, table=pq.read_table(path), calibration=calibration, scratch=folder)


def written(base, case, name):
    try:
        return fz.write_case(base.table, case, fz.fresh(base.scratch / name))
    except fz.Unwritable:
        reject()


# Reproducers the fuzzing found (each also has a plain regression test below).
DIRECTORY_WITH_EMPTY_PART = Case(parts=2, damage=(("empty",),))
UNITS_AS_A_LIST = Case(mutations=(("units", b'{"gyro": ["rad/s"]}'),))
TIMESTAMPS_BEYOND_YEAR_9999 = Case(
    mutations=(("cast", "t", "timestamp[ms]"), ("cast", "t", "timestamp[s]")), parts=1
)
PARTS_DISAGREE_ON_T = Case(parts=2, part_mutations=((0, ("cast", "t", "timestamp[s]")),))
HUGE_TEMPERATURES = Case(mutations=(("cast", "temp", "float64"), ("set", "temp", 0.3, 20, 1e308)))
HUGE_REFERENCE = Case(mutations=(("set", "ref_rate", 0.0, 20, 1e308),))
HALF_THE_LOG_STUCK = Case(parts=2, part_mutations=((0, ("scale", "gyro_x", 0.0)),))
TIME_BEFORE_THE_BIG_BANG = Case(mutations=(("set", "t", 0.0, 1, -1e308),))


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(case=fz.cases(), keep=st.sampled_from(fz.PIPELINE_KEEP))
@example(case=DIRECTORY_WITH_EMPTY_PART, keep=None)
@example(case=UNITS_AS_A_LIST, keep=None)
@example(case=TIMESTAMPS_BEYOND_YEAR_9999, keep=None)
@example(case=PARTS_DISAGREE_ON_T, keep=None)
@example(case=HUGE_REFERENCE, keep=None)
@example(case=TIME_BEFORE_THE_BIG_BANG, keep=0)
def test_ingest_gives_clean_columns_or_one_line_naming_the_file(base, case, keep):
    event(fz.check_ingest(written(base, case, "ingest"), keep, case.read_batch_rows))


@settings(max_examples=15, deadline=None, derandomize=True, database=None)
@given(
    case=st.one_of(fz.cases(soft=True), fz.cases()),
    command=st.sampled_from(("calibrate", "calibrate", "apply")),
    protocol=st.sampled_from(("turntable", "turntable", "turntable", "servo", "sweep")),
    ahead=st.booleans(),
)
@example(case=HUGE_TEMPERATURES, command="calibrate", protocol="turntable", ahead=False)
@example(
    case=Case(mutations=(("set", "gyro_x", 0.0, 1, 3.4028235e38),)),
    command="apply",
    protocol="turntable",
    ahead=False,
)
@example(case=DIRECTORY_WITH_EMPTY_PART, command="apply", protocol="turntable", ahead=False)
@example(case=HALF_THE_LOG_STUCK, command="calibrate", protocol="turntable", ahead=False)
def test_command_line_exits_0_or_2_with_gyrocal_messages_and_writes_no_nan(
    base, case, command, protocol, ahead
):
    folder = fz.fresh(base.scratch / "cli")
    path = written(base, case, "cli/in")
    outcome, _ = fz.check_cli(
        command,
        path,
        fz.fresh(folder / "out"),
        calibration=base.calibration,
        protocol=protocol,
        as_process_start=ahead,
    )
    event(f"{command}: {outcome}")


@pytest.mark.parametrize(
    "case",
    [
        Case(damage=(("flip_tail", 40, 0x55),)),  # footer damaged
        Case(damage=(("truncate", 0.6),)),  # data pages cut short
        Case(mutations=(("duplicate", "gyro_y"),)),
        Case(mutations=(("cast", "temp", "string"),)),
    ],
    ids=["footer", "truncated", "duplicate-column", "string-temp"],
)
def test_the_console_entry_point_refuses_bad_logs_in_one_line(base, tmp_path, case):
    """The real process: the log is decoded ahead on a thread, errors come back from it."""
    path = fz.write_case(base.table, case, tmp_path)
    out = tmp_path / "cal.json"
    run = subprocess.run(
        [sys.executable, "-m", "gyrocal.run.cli", "calibrate", str(path), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith(f"gyrocal: error: {path}: ") and run.stderr.count("\n") == 1
    assert not out.exists()


# ---------------------------------------------------------------------------------------
# The properties themselves: they pass on the valid log and catch what they are for.


def test_the_valid_log_passes_both_properties(base, tmp_path):
    assert fz.check_ingest(base.path) == "success"
    assert fz.check_ingest(base.path, 0, 61) == "success"  # re-read, small batches
    for command in ("calibrate", "apply"):
        outcome, _ = fz.check_cli(
            command, base.path, fz.fresh(tmp_path / command), calibration=base.calibration
        )
        assert outcome == "success"


def test_the_properties_flag_internal_errors_and_messages_without_the_file(base, monkeypatch, tmp_path):
    def crash(*args, **kwargs):
        raise ValueError("bug")

    monkeypatch.setattr(gio, "read_log", crash)
    with pytest.raises(fz.Violation, match="ValueError"):
        fz.check_ingest(base.path)

    def refuse(*args, **kwargs):
        raise LogFormatError("something is wrong")  # no source: names no file

    monkeypatch.setattr(gio, "read_log", refuse)
    with pytest.raises(fz.Violation, match="does not name the file"):
        fz.check_ingest(base.path)
    monkeypatch.undo()

    monkeypatch.setattr(cli, "cmd_calibrate", crash)
    with pytest.raises(fz.Violation, match="exit status 1"):
        fz.check_cli("calibrate", base.path, fz.fresh(tmp_path / "c"))
    with pytest.raises(fz.Violation, match="traceback"):
        fz.check_stderr(2, "Traceback (most recent call last):\n", base.path)
    with pytest.raises(fz.Violation, match="NaN written"):
        fz._strict_json('{"K": [NaN]}')


# ---------------------------------------------------------------------------------------
# Regression tests: one per bug found, with its reproducer.


def read_as_pipeline(path):
    from gyrocal.io.blocks import BlockSink

    return gio.read_log(path, optional=LOG_COLUMNS, sink=BlockSink(1.0))


def one_line_naming(exc_info, path):
    text = str(exc_info.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    return text


def test_a_directory_with_an_unreadable_part_is_a_corrupt_file(base, tmp_path):
    """Was: ArrowInvalid from counting the rows for the block sink (exit status 1)."""
    path = fz.write_case(base.table, DIRECTORY_WITH_EMPTY_PART, tmp_path)
    with pytest.raises(CorruptFileError) as info:
        read_as_pipeline(path)
    assert "Parquet file size is 0 bytes" in one_line_naming(info, path)


def test_units_that_are_not_strings_are_refused(base, tmp_path):
    """Was: TypeError (unhashable type: 'list') looking the unit up."""
    for payload in (b'{"gyro": ["rad/s"]}', b'{"temp": {"unit": "K"}}'):
        path = fz.write_case(base.table, Case(mutations=(("units", payload),)), fz.fresh(tmp_path / "u"))
        with pytest.raises(LogFormatError, match="metadata gyrocal.units gives"):
            read_as_pipeline(path)


def test_timestamps_beyond_pythons_datetime_range_are_read(base, tmp_path):
    """Was: OverflowError ordering a directory's files by their first time stamp (year
    55000 in a timestamp[s] column is valid Arrow, beyond Python's datetime)."""
    path = fz.write_case(base.table, TIMESTAMPS_BEYOND_YEAR_9999, tmp_path)
    log = read_as_pipeline(path)
    assert len(log) == base.table.num_rows and log.time_origin.startswith("55")


def test_parts_that_disagree_on_a_column_type_are_a_format_error(base, tmp_path):
    """Was: ArrowNotImplementedError from the dataset scanner (cast timestamp to double)."""
    path = fz.write_case(base.table, PARTS_DISAGREE_ON_T, tmp_path)
    with pytest.raises(LogFormatError, match="files of a directory must agree") as info:
        read_as_pipeline(path)
    one_line_naming(info, path)


def test_a_column_name_that_is_not_utf8_is_a_corrupt_file(base, tmp_path):
    """Was: UnicodeDecodeError from the schema's names (a flipped byte in the footer)."""
    path = tmp_path / "log.parquet"
    table = base.table.append_column("zqzqzq", pa.array(np.zeros(base.table.num_rows)))
    pq.write_table(table, path)
    data = path.read_bytes()
    assert data.count(b"zqzqzq") == 2  # the footer's schema and column chunk (ARROW:schema is base64)
    path.write_bytes(data.replace(b"zqzqzq", b"\xffqzqzq"))
    with pytest.raises(UnicodeDecodeError):
        _ = ds.dataset(path).schema.names  # what gyrocal met
    with pytest.raises(CorruptFileError, match="not UTF-8") as info:
        read_as_pipeline(path)
    one_line_naming(info, path)


@pytest.mark.parametrize(
    "mutations",
    [
        (("cast", "temp", "float64"), ("set", "temp", 0.3, 20, 1e308)),  # was: exit 1, NaN point
        (("set", "ref_rate", 0.0, 20, 1e308),),  # was: overflow in blocks
        (("cast", "gyro_y", "float64"), ("set", "gyro_y", 0.5, 20, -1e160)),
        (("units", b'{"gyro": "rad/s", "ref_rate": "rad/s"}'), ("set", "gyro_x", 0.5, 3, 3e38)),
    ],
)
def test_readings_beyond_float32_range_count_as_non_finite(base, tmp_path, mutations):
    """A float64 reading beyond ±3.4e38 (float32's range, which the contract allows for
    every reading) is dropped and counted like inf: was a NaN temperature point (exit 1,
    "refusing to write a non-finite value") or overflow in block statistics."""
    path = fz.write_case(base.table, Case(mutations=mutations), tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        log = read_as_pipeline(path)
    n = min(20, mutations[-1][3]) if mutations[-1][0] == "set" else 0
    assert log.rows_dropped == n and len(log) == base.table.num_rows - n
    assert all(np.abs(log.column(c)).max() <= gio.READING_LIMIT for c in gio.REQUIRED[1:])
    out = tmp_path / "cal.json"
    status, _, stderr, _ = fz.run_cli(["calibrate", str(path), "-o", str(out)])
    assert status in (0, 2) and "internal error" not in stderr, stderr
    if status == 0:
        assert np.isfinite(json.loads(out.read_text())["grid"]["temperature"]).all()


def test_a_time_beyond_what_a_timestamp_can_hold_counts_as_non_finite(base, tmp_path):
    """Was: overflow in the sample-interval statistics and the hold timing (t = -1e308 s in
    the first row: finite and increasing, but no difference of times survives it)."""
    path = fz.write_case(base.table, TIME_BEFORE_THE_BIG_BANG, tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy's own too
        log = read_as_pipeline(path)
        assert log.rows_dropped == 1 and log.time_span[0] == base.table["t"][1].as_py()
        status, _, stderr, _ = fz.run_cli(["calibrate", str(path), "-o", str(tmp_path / "c.json")])
    assert status == 0 and "encountered" not in stderr, stderr


def test_a_float32_temperature_at_its_largest_does_not_overflow_a_stretch_mean(base, tmp_path):
    """Was: overflow (numpy's RuntimeWarning, an inf intermediate) in a static stretch's
    mean temperature, accumulated in float32 like the column (3.4e38 °C is kept: float32
    holds it)."""
    path = fz.write_case(base.table, Case(mutations=(("set_all", "temp", 3.4028235e38),)), tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        status, _, stderr, _ = fz.run_cli(["calibrate", str(path), "-o", str(tmp_path / "c.json")])
    assert status == 0 and "encountered" not in stderr, stderr
    assert "temperature_out_of_range" in stderr  # what the log deserves instead


@pytest.mark.parametrize("terms", [(), ("scale_quadratic",)])
@pytest.mark.parametrize("value", [3.4028235e38, 1e20])
def test_apply_compensates_huge_rates_without_a_singular_matrix(base, tmp_path, terms, value):
    """Was: LinAlgError (singular matrix), exit 1: with one axis at 3.4e38 the others'
    residuals carry its rounding, so the solve iterated and re-linearised where a 1 deg/s
    step is lost. Now it stops at the row's rounding, and steps scale with the rate."""
    calibration = base.calibration
    if terms:
        calibration = tmp_path / "cal-nonlinear.json"
        add = [a for t in terms for a in ("--add-term", t)]
        assert fz.run_cli(["calibrate", str(base.path), "-o", str(calibration), *add])[0] == 0
    path = fz.write_case(
        base.table, Case(mutations=(("set", "gyro_x", 0.0, 1, value),)), fz.fresh(tmp_path / "in")
    )
    outcome, _ = fz.check_cli("apply", path, fz.fresh(tmp_path / "out"), calibration=calibration)
    assert outcome == "success"  # and check_cli found no NaN the command did not count


def test_apply_refuses_damaged_data_pages_in_one_line(base, tmp_path):
    """Was: OSError (corrupt snappy data) or ArrowInvalid from apply's own reader, exit 1."""
    path = fz.write_case(base.table, Case(parts=2, damage=(("empty",),)), fz.fresh(tmp_path / "d"))
    out = fz.fresh(tmp_path / "out")
    outcome, line = fz.check_cli("apply", path, out, calibration=base.calibration)
    assert outcome == "CorruptFileError" and "Parquet file size is 0 bytes" in line
    single = tmp_path / "log.parquet"
    pq.write_table(base.table, single, compression="snappy")
    data = bytearray(single.read_bytes())
    middle = len(data) // 8  # inside the first column's data pages
    data[middle : middle + 32] = bytes(b ^ 0xA5 for b in data[middle : middle + 32])
    single.write_bytes(bytes(data))
    outcome, line = fz.check_cli("apply", single, fz.fresh(tmp_path / "out2"), calibration=base.calibration)
    assert outcome in ("CorruptFileError", "LogFormatError") and str(single) in line


def test_a_servo_run_too_fast_to_cut_into_revolutions_is_refused(base, tmp_path):
    """Was: RuntimeWarning (invalid value in cast) counting 5e37 revolutions in int64, exit 1
    (a reference of 1e38 deg/s: within float32's range, so a reading)."""
    path = fz.write_case(base.table, Case(mutations=(("set_all", "ref_rate", 1e38),)), tmp_path)
    outcome, line = fz.check_cli("calibrate", path, fz.fresh(tmp_path / "out"), protocol="servo")
    assert outcome == "SegmentationError" and "no revolution can be cut" in line


def test_an_axis_stuck_for_part_of_the_log_is_left_out_not_a_singular_fit(base, tmp_path):
    """Was: divide by zero weighting the fit, then LinAlgError (SVD did not converge), exit
    1: gyro_x reads 0.0 through the first half, so every hold of the first temperature point
    has zero scatter on x and the typical floor the weights are capped by was zero too.
    Then a refusal (scale.x not excited at the first point). Now the holds where an axis
    reads one value are rejected as stuck, and the calibration rests on the healthy part,
    saying so: the points left without holds are excluded, each in a warning."""
    path = fz.write_case(base.table, HALF_THE_LOG_STUCK, tmp_path)
    out = fz.fresh(tmp_path / "out")
    outcome, line = fz.check_cli("calibrate", path, out)
    assert outcome == "success", line
    cal = json.loads((Path(out) / "cal.json").read_text())
    codes = {w["code"]: w["message"] for w in cal["warnings"]}
    assert "point_excluded" in codes and "stuck_axis" in codes["holds_rejected"]
    assert len(cal["grid"]["temperature"]) < 3
