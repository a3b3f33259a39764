"""The whole chain on simulated logs: recovered parameters and validation figures."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.calibration.file import save_calibration
from gyrocal.io.errors import IdentifiabilityError
from gyrocal.pipeline.chain import run

from .conftest import make_log, truth_coefficients


def test_fitted_K_and_B_within_three_reported_standard_errors(complete_run, truth):
    unit = truth["complete"]["unit"]
    grid = complete_run.calibration.grid
    assert len(grid.temperatures) == 6
    for p, T in enumerate(grid.temperatures):
        expected = truth_coefficients(unit, T)
        for j, name in enumerate(grid.names):
            z = (grid.values[p, j] - expected[name]) / grid.stderr[p, j]
            assert abs(z) < 3.0, f"{name} at {T:.1f} °C is {z:.2f} standard errors off"


def test_per_temperature_fits_explain_the_data(complete_run):
    # complete-model data: reduced chi-square within 3 sd of 1 (sd = sqrt(2/dof), 59 dof)
    for f in complete_run.fitted.fits:
        for axis in "xyz":
            assert abs(f.chi2_red(axis) - 1.0) < 3 * np.sqrt(2 / f.dof[axis])


def test_interpolated_leave_temperature_out_reaches_the_noise_floor(complete_run):
    s = complete_run.validation.summary
    assert (s["held_out"], s["scored"], s["holds_scored"]) == ("temperature", "interior", 4 * 63)
    assert s["validation_rms"] <= 1.2 * s["noise_floor"]
    # what remains above the floor is the calibration's own uncertainty
    assert s["noise_floor"] < s["expected_rms"] < 1.2 * s["noise_floor"]
    assert abs(s["excess_over_expected"] - 1.0) < 0.1
    assert s["uncompensated_rms"] > s["single_rms"] > s["validation_rms"]


def test_mean_rms_tables_have_the_seed_shape_and_consistent_gains(complete_run):
    for table in (complete_run.validation.table_holds, complete_run.validation.table_samples):
        assert list(zip(table.rotating, table.output, strict=False)) == [(r, o) for r in "xyz" for o in "xyz"]
        np.testing.assert_allclose(
            table.gain_vs_uncompensated_pct,
            100 * (1 - table.interpolated_rms / table.uncompensated_rms),
            rtol=1e-12,
        )
        assert (table.holds == 4 * 21).all()
    # on samples the floor is the per-sample noise: the error cannot go below it
    samples = complete_run.validation.table_samples
    assert (samples.interpolated_rms >= samples.noise_floor * 0.999).all()
    by_temp = complete_run.validation.by_temperature
    assert list(by_temp.clamped) == [True, False, False, False, False, True]


def test_single_temperature_reference_is_the_point_nearest_25_or_the_next(complete_run):
    s = complete_run.validation.summary
    temps = complete_run.calibration.grid.temperatures
    nearest, second = np.argsort(np.abs(temps - 25.0))[:2]
    assert s["reference_temperature"] == temps[nearest]
    holds = complete_run.validation.holds
    used = holds.groupby("point")["reference_temp"].unique()
    for point, refs in used.items():
        assert list(refs) == [temps[second] if point == nearest else temps[nearest]]


def test_one_temperature_point_is_validated_by_leaving_holds_out(tmp_path):
    path = make_log(tmp_path, "one", temperatures=(20.0,))
    result = run(path)
    s = result.validation.summary
    assert (s["held_out"], s["temperature_points"], s["holds_scored"]) == ("hold", 1, 63)
    assert s["single_rms"] == s["validation_rms"]
    # leaving a hold out costs a little: never below the in-sample residual
    in_sample = np.sqrt(np.mean(result.fitted.fits[0].residuals ** 2))
    assert s["validation_rms"] > in_sample
    assert s["validation_rms"] <= 1.2 * s["noise_floor"]


def test_two_temperature_points_are_validated_against_each_other(tmp_path):
    path = make_log(tmp_path, "two", temperatures=(0.0, 20.0))
    s = run(path).validation.summary
    # each point is compensated by the other's calibration, clamped: reported, and
    # counted because there is no interior point
    assert (s["held_out"], s["scored"], s["holds_scored"]) == ("temperature", "all", 126)
    assert s["validation_rms"] > 3 * s["noise_floor"]  # 20 °C of bias drift not modelled


def test_without_a_mount_column_the_result_is_as_good(logs):
    result = run(logs["no_mount"])
    s = result.validation.summary
    assert s["validation_rms"] <= 1.2 * s["noise_floor"]


def test_rerun_gives_byte_identical_calibration(logs, tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    save_calibration(run(logs["complete"]).calibration, a)
    save_calibration(run(logs["complete"]).calibration, b)
    assert a.read_bytes() == b.read_bytes()


def test_a_protocol_that_never_rotates_about_y_is_refused(tmp_path):
    path = make_log(tmp_path, "no_y", mounts=("+x", "+z"), temperatures=(0.0, 20.0))
    with pytest.raises(IdentifiabilityError) as info:
        run(path)
    assert {"scale.y", "misalignment.x.y", "misalignment.z.y"} <= set(info.value.parameters)
    assert str(path) in str(info.value)


def test_a_point_missing_a_mount_is_left_out_and_reported(tmp_path, logs):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from gyrocal.simulate import load_truth

    truth = load_truth(logs["complete"])
    doomed = [h for h in truth["holds"] if h["point"] == 2 and h["mount"] == "+y"]
    table = pq.read_table(logs["complete"])
    t = table.column("t").to_numpy()
    drop = np.zeros(len(t), bool)
    for h in doomed:
        drop |= (t >= h["t_start"] - 0.5) & (t <= h["t_end"] + 0.5)
    path = tmp_path / "hole.parquet"
    pq.write_table(table.filter(pa.array(~drop)), path)
    result = run(path)
    points = result.fitted.points
    assert list(points.used) == [True, True, False, True, True, True]
    assert "scale.y" in points.reason[2]
    # its holds are still validated, from the neighbours
    assert result.validation.by_temperature.loc[2, "holds"] == 42


def test_the_same_log_written_other_ways_gives_the_same_calibration(logs, tmp_path):
    """Timestamps, rad/s with units metadata, float64 columns and a directory of files are
    the same data to gyrocal: the calibration must not change."""
    import json

    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    table = pq.read_table(logs["complete"])
    reference = run(logs["complete"]).calibration.grid
    variants = {}
    t = table.column("t").to_numpy()
    stamps = pa.array(
        (t * 1e9).round().astype(np.int64) + 1_767_225_600_000_000_000, type=pa.timestamp("ns", tz="UTC")
    )
    variants["timestamp"] = table.set_column(0, "t", stamps)
    rad = table
    for c in ("gyro_x", "gyro_y", "gyro_z", "ref_rate"):
        i = rad.schema.get_field_index(c)
        rad = rad.set_column(i, c, pc.multiply(rad.column(c).cast(pa.float64()), np.pi / 180))
    variants["rad_s"] = rad.replace_schema_metadata(
        {b"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()}
    )
    f64 = table
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp"):
        f64 = f64.set_column(f64.schema.get_field_index(c), c, f64.column(c).cast(pa.float64()))
    variants["float64"] = f64
    for name, variant in variants.items():
        path = tmp_path / f"{name}.parquet"
        pq.write_table(variant, path)
        grid = run(path).calibration.grid
        # One-ulp differences (rad/s and back) can move a boundary block in or out of a
        # hold: allowed to shift a coefficient by a hundredth of its standard error.
        shift = np.abs(grid.values - reference.values) / reference.stderr
        assert shift.max() < 0.01, name
    folder = tmp_path / "dir"
    folder.mkdir()
    step = table.num_rows // 5 + 1
    for k in range(5):  # part-0 ... part-4 written in reverse order: order comes from t
        pq.write_table(table.slice(k * step, step), folder / f"part-{4 - k}.parquet")
    grid = run(folder).calibration.grid  # blocks assembled across files: summation order only
    np.testing.assert_allclose(grid.values, reference.values, rtol=1e-9, atol=0)


def test_a_log_read_again_batch_by_batch_segments_to_the_same_bits(logs, monkeypatch):
    """A log larger than the memory budget is reduced to block statistics as it is read and
    read again for the noise and the temperature record. With batches of a prime number of
    rows (so blocks, record bins and static stretches straddle them) and no budget, the
    observations, the noise, the record and the segmentation's info are the in-memory
    path's, bit for bit."""
    import pandas as pd

    from gyrocal.io import log
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings

    settings = Settings()
    path = logs["complete"]
    kept = segment_log(path, settings)
    monkeypatch.setattr(log, "READ_BATCH_ROWS", 4999)
    streamed = segment_log(path, settings, keep_bytes=0)
    pd.testing.assert_frame_equal(streamed.observations, kept.observations, check_exact=True)
    pd.testing.assert_frame_equal(streamed.segments, kept.segments, check_exact=True)
    from gyrocal.fit.floor import STATIC

    assert streamed.info == kept.info and streamed.info["noise"]["source"] == STATIC
    a, b = (s.observations.attrs["series"] for s in (kept, streamed))
    for name in ("t", "temp", "weight"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_history_of_pieces_is_the_history_of_the_whole():
    """Bin sums are made within one piece, so any cut of the record gives the same bits."""
    from gyrocal.terms.signals import HistoryBins, history

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.005, 0.015, 20_000))
    temp = 25 + np.cumsum(rng.normal(0, 0.01, t.size)).astype(np.float32)
    whole = history(t, temp, window_s=30.0)
    cuts = np.sort(rng.choice(np.arange(1, t.size), 40, replace=False))
    bins = HistoryBins(t[0], t[-1], window_s=30.0)
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, t.size], strict=False):
        bins.push(t[lo:hi], temp[lo:hi])
    pieces = bins.result()
    for name in ("t", "temp", "weight"):
        np.testing.assert_array_equal(getattr(pieces, name), getattr(whole, name))


def test_apply_reads_the_temperature_record_the_fit_read(logs, monkeypatch):
    """A model with a temperature-rate term is applied with the record the fit saw: the
    same bin means of the same kept rows, gathered in a pass that keeps no batch."""
    import pyarrow.parquet as pq

    from gyrocal.calibration import apply
    from gyrocal.diagnosis import extended
    from gyrocal.io import log
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings

    path = logs["complete"]
    settings = extended(Settings(), "temp_rate")
    cal = run(path, settings).calibration
    fitted = segment_log(path, settings).observations.attrs["series"]
    assert cal.covariates["temp_rate"]["window_s"] == fitted.temp_rate_window_s
    monkeypatch.setattr(log, "READ_BATCH_ROWS", 4999)
    t0, record = apply._record(cal, path, pq.read_schema(path).names, True)
    assert t0 == fitted.t0
    for name in ("t", "temp", "weight"):
        np.testing.assert_array_equal(getattr(record, name), getattr(fitted, name))


def test_a_log_read_ahead_segments_to_the_same_bits(logs):
    """The command line decodes the log on a thread while it imports (gyrocal.io.readahead);
    the reader takes those batches instead of reading the file, and nothing changes. A
    read-ahead the reader cannot use (other columns) is dropped and the file read."""
    import pandas as pd

    from gyrocal.io import log, readahead
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings
    from gyrocal.protocols.turntable.segment import LOG_COLUMNS

    assert set(log.REQUIRED + LOG_COLUMNS) <= set(readahead.COLUMNS)
    path = logs["complete"]
    direct = segment_log(path, Settings())
    readahead.start(path)
    (reading,) = readahead._pending.values()
    ahead = segment_log(path, Settings())
    reading.thread.join(timeout=10)
    # Taken by the reader and read to the end: not dropped, nothing left waiting.
    assert not readahead._pending and not reading.stopped.is_set() and reading.batches.empty()
    pd.testing.assert_frame_equal(ahead.observations, direct.observations, check_exact=True)
    assert ahead.info == direct.info
    readahead.start(path)
    assert readahead.take(path, ("t", "not_a_column"), log.READ_BATCH_ROWS, log.READ_BUFFER_BYTES) is None
    assert not readahead._pending
