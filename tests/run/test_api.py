"""The Python API (gyrocal.run.api, what ``import gyrocal`` offers): the same results as the
command line, byte for byte, whether the log comes as a path, a DataFrame or a Table."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import gyrocal
from gyrocal.io.errors import ConfigError, GyrocalError
from gyrocal.run import api
from gyrocal.run.cli import main

EFFECT = {"scale_quadratic": [2e-6, 0.0, 0.0]}  # 0.32 deg/s at 400 deg/s: 130 times the floor


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Two quick sessions of one unit with an effect beyond the 12 parameters."""
    folder = tmp_path_factory.mktemp("api")
    paths = []
    for session in ("2026-01-01", "2026-02-01"):
        path = folder / f"U7-{session}.parquet"
        gyrocal.simulate_log(path, device="U7", session=session, effects=EFFECT)
        paths.append(path)
    return paths


def test_import_gyrocal_stays_light_and_names_its_api():
    """``import gyrocal`` (as the command line does) loads neither numpy nor pandas; every
    name in ``__all__`` resolves, and ``dir`` lists them."""
    code = (
        "import sys, gyrocal; heavy = [m for m in ('numpy', 'pandas', 'pyarrow') if m in sys.modules]; "
        "print(heavy); [getattr(gyrocal, n) for n in gyrocal.__all__]"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    assert set(gyrocal.__all__) <= set(dir(gyrocal))
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        gyrocal.calibrat  # noqa: B018


def test_calibrate_saves_the_file_the_command_line_writes(sessions, tmp_path):
    cli, lib = tmp_path / "cli.json", tmp_path / "lib.json"
    assert main(["calibrate", str(sessions[0]), "-o", str(cli)]) == 0
    result = gyrocal.calibrate(sessions[0])
    result.save(lib)
    assert lib.read_bytes() == cli.read_bytes()
    # the Mean/RMS table the report shows, per temperature point
    table = result.by_temperature
    assert {"uncompensated_rms", "single_rms", "interpolated_rms"} <= set(table.columns)
    assert len(table) == result.summary["temperature_points"]
    assert "noise floor" in result._repr_html_()


def test_a_frame_or_a_table_calibrates_as_its_file_does(sessions):
    """The same coefficients from a path, a DataFrame and a pyarrow Table: a frame is read
    through the same reader, so its columns are checked and converted alike."""
    table = pq.read_table(sessions[0])
    made = [
        gyrocal.calibrate(log, device="U7").calibration for log in (sessions[0], table.to_pandas(), table)
    ]
    first = {k: v for k, v in made[0].to_dict().items() if k != "provenance"}
    for cal in made[1:]:
        assert {k: v for k, v in cal.to_dict().items() if k != "provenance"} == first
        assert cal.provenance["input"]["name"] == api.TABLE_NAME


@pytest.mark.slow
def test_the_named_fix_lowers_the_error_on_the_next_session(sessions, tmp_path):
    """The loop from Python: diagnose with the other session, add the fix it names, and the
    calibration meets the next session within what noise and its own uncertainty explain."""
    d = gyrocal.diagnose(pd.read_parquet(sessions[0]), other=sessions[1])
    assert d.add_term == "scale_quadratic"
    assert d.candidates.loc[0, "term"] == "scale_quadratic"
    before = gyrocal.calibrate(sessions[0]).check(sessions[1])
    after = gyrocal.calibrate(sessions[0], add_terms=[d.add_term]).check(sessions[1])
    assert not before["holds"] and after["holds"]
    assert after["excess"] < before["excess"] / 5
    html = d._repr_html_()
    assert "--add-term scale_quadratic" in html and "configured model" in html
    saved = d.save(tmp_path / "d.json")
    assert saved.read_text().startswith("{")


@pytest.mark.slow
def test_diagnose_saves_the_file_the_command_line_writes(sessions, tmp_path):
    cli, lib = tmp_path / "cli.json", tmp_path / "lib.json"
    assert main(["diagnose", str(sessions[0]), "--other-session", str(sessions[1]), "-o", str(cli)]) == 0
    gyrocal.diagnose(sessions[0], other=sessions[1]).save(lib)
    assert lib.read_bytes() == cli.read_bytes()


def test_apply_returns_what_the_command_line_writes(sessions, tmp_path):
    cal = tmp_path / "cal.json"
    out = tmp_path / "out.parquet"
    assert main(["calibrate", str(sessions[0]), "-o", str(cal)]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the range warning is tested with the command line
        assert main(["apply", str(cal), str(sessions[1]), "-o", str(out)]) == 0
        frame = gyrocal.apply(gyrocal.load_calibration(cal), pd.read_parquet(sessions[1]))
    pd.testing.assert_frame_equal(frame, pd.read_parquet(out))


def test_reports_and_tables_are_written(sessions, tmp_path):
    result = gyrocal.calibrate(sessions[0], device="U7<b>")
    page = result.report(tmp_path / "r.html").read_text()
    assert "U7&lt;b&gt;" in page and "U7<b>" not in page  # a name from the caller, escaped
    folder = result.save_tables(tmp_path / "tables")
    assert {p.name for p in folder.iterdir()} >= {"observations.parquet", "by_temperature.parquet"}


def test_noise_per_point_and_pooled(sessions):
    frame = gyrocal.noise(sessions[0]).to_frame()
    assert frame.loc[0, "data"] == "all" and np.isnan(frame.loc[0, "temp"])
    assert (frame["arw_x"] > 0).all()


def test_bad_input_is_one_error_naming_the_problem(sessions):
    with pytest.raises(ConfigError, match="a log is a path, a pandas DataFrame or a pyarrow Table"):
        gyrocal.calibrate([1, 2, 3])
    frame = pd.read_parquet(sessions[0]).drop(columns=["gyro_y"])
    with pytest.raises(GyrocalError, match="missing required column gyro_y"):
        gyrocal.calibrate(frame)
    with pytest.raises(ConfigError):
        gyrocal.load_settings(add_terms=["no_such_term"])


def test_blas_runs_on_one_thread_and_the_callers_setting_comes_back():
    threadpoolctl = pytest.importorskip("threadpoolctl")

    def blas_threads():
        return {i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"}

    np.dot(np.ones((4, 4)), np.ones((4, 4)))  # BLAS loaded
    if not blas_threads():
        pytest.skip("numpy links no BLAS threadpoolctl can see")
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        inside = api._one_blas_thread(blas_threads)()
        assert inside == {1}
        assert blas_threads() == {2}


def test_the_diagnosis_page_escapes_what_came_from_data():
    d = api.Diagnosis({"verdict": "<script>x</script>", "best": {"option": "--add-term '<i>'"}, "ladder": []})
    page = d._repr_html_()
    assert "<script>" not in page and "&lt;script&gt;" in page and "&lt;i&gt;" in page
    assert d.add_term == "<i>"


def test_a_path_is_read_as_it_is(tmp_path):
    """A path is never copied; only a frame or table is written to a temporary file."""
    with api._as_path(tmp_path / "x.parquet") as path:
        assert path == Path(tmp_path / "x.parquet")
    table = pa.table({"t": [0.0, 1.0]})
    with api._as_path(table) as path:
        assert pq.read_table(path).equals(table)
    assert not path.exists()


def rad_per_s(path, out):
    """``path``'s log with its rates in rad/s, declared as the contract says."""
    table = pq.read_table(path)
    for name in ("gyro_x", "gyro_y", "gyro_z", "ref_rate"):
        i = table.schema.get_field_index(name)
        table = table.set_column(i, name, pa.array(np.deg2rad(table[name].to_numpy())))
    units = b'{"gyro": "rad/s", "ref_rate": "rad/s"}'
    pq.write_table(table.replace_schema_metadata({b"gyrocal.units": units}), out)
    return out


def test_a_frame_keeps_its_units_as_declared(sessions, tmp_path):
    """pandas.read_parquet drops a file's key-value metadata: units= (or read_log, which keeps
    them in attrs) declares them, and the frame calibrates as its file does."""
    log = rad_per_s(sessions[0], tmp_path / "rad.parquet")
    expected = gyrocal.calibrate(log).summary["validation_rms"]
    units = {"gyro": "rad/s", "ref_rate": "rad/s"}
    assert gyrocal.calibrate(pd.read_parquet(log), units=units).summary["validation_rms"] == expected
    assert gyrocal.calibrate(gyrocal.read_log(log)).summary["validation_rms"] == expected
    # time as the index, as a time series often holds it
    frame = gyrocal.read_log(log).set_index("t")
    assert gyrocal.calibrate(frame).summary["validation_rms"] == expected


def test_a_frame_is_named_in_its_errors_and_its_name_is_a_name(sessions):
    frame = pd.read_parquet(sessions[0]).drop(columns=["temp"])
    with pytest.raises(
        GyrocalError, match=r"^the DataFrame given \(log.parquet\): missing required column temp"
    ):
        gyrocal.calibrate(frame)
    with pytest.raises(GyrocalError, match=r"^the Table given \(U9.parquet\): missing required column temp"):
        gyrocal.calibrate(pa.Table.from_pandas(frame), name="U9.parquet")
    for name in ("/tmp/elsewhere.parquet", "sub/x.parquet", ""):
        with pytest.raises(ConfigError, match="without a folder"):
            gyrocal.calibrate(frame, name=name)


def test_a_servo_calibration_refuses_terms_as_the_command_line_does(tmp_path):
    log = tmp_path / "servo.parquet"
    gyrocal.simulate_log(log, device="S7", protocol="servo")
    with pytest.raises(ConfigError, match="a servo calibration is the protocol's own model"):
        gyrocal.calibrate(log, protocol="servo", add_terms=["scale_quadratic"])


def test_blas_is_limited_in_a_fresh_process_from_the_first_call():
    """scipy's own BLAS loads inside the first call: the limit must reach it too."""
    pytest.importorskip("threadpoolctl")
    code = (
        "import numpy, threadpoolctl\n"
        "from gyrocal.run import api\n"
        "seen = api._one_blas_thread(lambda: sorted({i['num_threads'] for i in threadpoolctl.threadpool_info()"
        " if i['user_api'] == 'blas'}))()\n"
        "print(seen)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "[1]"
