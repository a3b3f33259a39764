"""The calibration file (contract section 4) and applying it (section 5)."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.calibration.apply import apply_calibration
from gyrocal.calibration.file import Calibration, load_calibration, save_calibration
from gyrocal.fit.model import Model
from gyrocal.fit.thermal import TemperatureGrid
from gyrocal.io.errors import CalibrationFileError, GyrocalError, LogFormatError
from gyrocal.io.log import read_log
from gyrocal.simulate import load_truth


def identity_calibration(temps=(0.0, 20.0, 40.0)) -> Calibration:
    model = Model.from_spec()
    P, C = len(temps), len(model.names)
    grid = TemperatureGrid(np.array(temps), tuple(model.names), np.zeros((P, C)), np.full((P, C), 1e-6))
    return Calibration(model, grid, meta={"device": "X"})


def test_file_round_trips_byte_for_byte(complete_run, tmp_path):
    cal = complete_run.calibration
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    save_calibration(cal, first)
    loaded = load_calibration(first)
    save_calibration(loaded, second)
    assert first.read_bytes() == second.read_bytes()
    np.testing.assert_array_equal(loaded.grid.values, cal.grid.values)
    np.testing.assert_array_equal(loaded.grid.temperatures, cal.grid.temperatures)
    doc = json.loads(first.read_text())
    assert doc["format"] == "gyrocal.calibration/1"
    assert doc["units"]["B"] == "deg/s" and doc["model"]["interpolation"]["method"] == "lagrange3"
    assert len(doc["provenance"]["input"]["blake3"]) == 64
    assert len(doc["provenance"]["config_sha256"]) == 64
    K = np.array(doc["grid"]["K"])
    assert K.shape == (len(doc["grid"]["temperature"]), 3, 3)


def test_K_and_B_in_the_file_are_the_units_true_K_and_B(complete_run, truth):
    """w = K w_true + B (contract section 4): the file's K and B against the simulated unit,
    entry by entry, within 4 standard errors of the coefficient each entry comes from."""
    cal = complete_run.calibration
    unit = truth["complete"]["unit"]
    K, B = cal.matrices()
    se = dict(zip(cal.grid.names, cal.grid.stderr.T, strict=False))
    for p, T in enumerate(cal.grid.temperatures):
        for i, a in enumerate("xyz"):
            assert abs(B[p, i] - unit.B(T)[i]) < 4 * se[f"bias.{a}"][p]
            for j, b in enumerate("xyz"):
                name = f"scale.{a}" if a == b else f"misalignment.{a}.{b}"
                assert abs(K[p, i, j] - unit.K(T)[i, j]) < 4 * se[name][p]


@pytest.mark.parametrize(
    "method, degree, reference", [("poly", 0, 25.0), ("spline", 3, 30.0), ("linear", 3, -5.0)]
)
def test_round_trip_keeps_non_default_settings(complete_run, tmp_path, method, degree, reference):
    g = complete_run.calibration.grid
    grid = TemperatureGrid(g.temperatures, g.names, g.values, g.stderr, method, degree)
    cal = Calibration(complete_run.calibration.model, grid, reference)
    loaded = load_calibration_roundtrip(cal, tmp_path)
    assert (loaded.grid.method, loaded.grid.degree, loaded.reference_temperature) == (
        method,
        degree,
        reference,
    )
    temps = np.linspace(-8, 42, 11)  # inside the calibrated range
    for name in g.names:
        np.testing.assert_array_equal(loaded.coefficients(temps)[name], cal.coefficients(temps)[name])


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d.update(format="gyrocal.calibration/2"),
            "format version 2 is not one this gyrocal reads",
        ),
        (lambda d: d.update(format="imucal"), "format is 'imucal'"),
        (lambda d: d.pop("grid"), "missing key 'grid'"),
        (lambda d: d["grid"]["coefficients"].pop("bias.y"), "missing key 'bias.y'"),
        (lambda d: d["grid"]["coefficients"]["bias.x"].__setitem__(0, None), "coefficient bias.x must be"),
        (lambda d: d["grid"]["K"][0][0].__setitem__(0, 1.5), "K and B do not match"),
        (lambda d: d["model"]["terms"].append({"name": "warp_drive"}), "unknown model term 'warp_drive'"),
        (lambda d: d["model"]["interpolation"].update(method="cosine"), "interpolation method 'cosine'"),
        (lambda d: d["model"]["interpolation"].update(degree="two"), "degree must be a non-negative integer"),
        (lambda d: d["model"].update(reference_temperature="room"), "reference_temperature must be a number"),
        (lambda d: d["units"].update(rate="rad/s"), "units {'rate': 'rad/s'}"),
        (
            lambda d: d["grid"]["covariance"][0][0].__setitem__(1, 1.0),
            "(point 1 of 6) is not symmetric: |C[bias.x,bias.y] − C[bias.y,bias.x]|",
        ),
        (
            lambda d: d["grid"]["covariance"][0][0].__setitem__(0, 1.0),
            "C[bias.x,bias.x] = 1 is not the squared stderr",
        ),
        (
            lambda d: d["grid"]["covariance"].pop(),
            "grid.covariance must hold a finite 12 x 12 matrix per point",
        ),
        (lambda d: d["grid"].update(covariance="none"), "grid.covariance must"),
    ],
)
def test_bad_files_are_refused_with_one_line(complete_run, tmp_path, edit, message):
    doc = complete_run.calibration.to_dict()
    edit(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(CalibrationFileError) as info:
        load_calibration(path)
    text = str(info.value)
    assert message in text and str(path) in text and "\n" not in text
    assert info.value.exit_status == 2


def test_not_json_and_nan_are_refused(complete_run, tmp_path):
    path = tmp_path / "x.json"
    path.write_text("{not json")
    with pytest.raises(CalibrationFileError, match="not valid JSON"):
        load_calibration(path)
    for where in ("coefficients", "B"):
        doc = complete_run.calibration.to_dict()
        if where == "B":
            doc["grid"]["B"][1][2] = float("nan")
        else:
            doc["grid"]["coefficients"]["bias.x"][0] = float("nan")
        path.write_text(json.dumps(doc))  # Python's json writes NaN
        with pytest.raises(CalibrationFileError, match="finite numbers"):
            load_calibration(path)
    values = complete_run.calibration.grid.values.copy()
    values[0, 0] = np.nan
    g = complete_run.calibration.grid
    broken = Calibration(
        complete_run.calibration.model, TemperatureGrid(g.temperatures, g.names, values, g.stderr)
    )
    with pytest.raises(GyrocalError, match="non-finite"):
        save_calibration(broken, tmp_path / "nan.json")
    assert not (tmp_path / "nan.json").exists()


def test_identity_calibration_leaves_the_data_unchanged(logs, tmp_path):
    cal = identity_calibration()
    out = tmp_path / "same.parquet"
    counts = apply_calibration(cal, logs["complete"], out)
    original, applied = pq.read_table(logs["complete"]), pq.read_table(out)
    assert applied.num_rows == original.num_rows == counts["rows"]
    assert applied.schema.names == original.schema.names
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        np.testing.assert_array_equal(
            applied.column(c).to_numpy(), original.column(c).to_numpy().astype(np.float64)
        )
    for c in ("t", "temp", "ref_rate", "mount"):
        assert applied.column(c).equals(original.column(c))


def test_applied_log_recovers_the_true_rate_within_the_noise(complete_run, logs, tmp_path):
    out = tmp_path / "applied.parquet"
    cal = load_calibration_roundtrip(complete_run.calibration, tmp_path)
    apply_calibration(cal, logs["complete"], out)
    truth = load_truth(logs["complete"])
    applied = read_log(out)
    t = applied.column("t")
    noise = truth["unit"].noise_std(truth["rig"]["sample_rate"])
    for hold in truth["holds"][::7]:
        inside = (t > hold["t_start"] + 1.0) & (t < hold["t_end"] - 1.0)
        axis = "xyz".index(hold["mount"][1])
        sign = 1.0 if hold["mount"][0] == "+" else -1.0
        for i, c in enumerate(("gyro_x", "gyro_y", "gyro_z")):
            mean = applied.column(c)[inside].mean()
            expected = sign * hold["rate"] if i == axis else 0.0
            # hold mean of n samples: noise / sqrt(n), plus the calibration's own error
            assert abs(mean - expected) < 6 * noise / np.sqrt(inside.sum()) + 2e-3


def load_calibration_roundtrip(cal, tmp_path):
    path = tmp_path / "cal.json"
    save_calibration(cal, path)
    return load_calibration(path)


def test_apply_converts_rad_per_second_and_keeps_bad_rows_as_nan(tmp_path):
    n = 50
    t = np.arange(n) * 0.01
    g = np.full(n, np.deg2rad(10.0))
    g[5] = np.nan
    table = pa.table(
        {
            "t": t,
            "gyro_x": g,
            "gyro_y": np.zeros(n),
            "gyro_z": np.zeros(n),
            "temp": np.full(n, 20.0),
            "ref_rate": np.zeros(n),
            "note": ["a"] * n,
        }
    )
    table = table.replace_schema_metadata({b"gyrocal.units": b'{"gyro": "rad/s", "ref_rate": "rad/s"}'})
    src, out = tmp_path / "in.parquet", tmp_path / "out.parquet"
    pq.write_table(table, src)
    counts = apply_calibration(identity_calibration(), src, out)
    result = pq.read_table(out)
    gx = result.column("gyro_x").to_numpy()
    assert counts["nonfinite"] == 1 and np.isnan(gx[5])
    np.testing.assert_allclose(np.delete(gx, 5), 10.0, rtol=1e-12)
    units = json.loads(result.schema.metadata[b"gyrocal.units"])
    assert units == {"ref_rate": "rad/s"}  # gyro is now deg/s; ref_rate untouched
    assert result.column("note").to_pylist() == ["a"] * n


def test_apply_refuses_a_log_without_temperature(tmp_path):
    n = 10
    src = tmp_path / "notemp.parquet"
    pq.write_table(
        pa.table(
            {"t": np.arange(n) * 1.0, "gyro_x": np.zeros(n), "gyro_y": np.zeros(n), "gyro_z": np.zeros(n)}
        ),
        src,
    )
    with pytest.raises(LogFormatError, match="lacks temp"):
        apply_calibration(identity_calibration(), src, tmp_path / "o.parquet")


def test_each_point_keeps_its_coefficient_covariance(complete_run, tmp_path):
    """The file carries each point's covariance as the fit made it, read back to the bit;
    a file of an earlier version without it still loads (standard errors as uncorrelated)."""
    cal = complete_run.calibration
    fitted = complete_run.fitted  # one joint fit: each point's block of its covariance
    points = np.array([fitted.point_fit(p).covariance for p in fitted.point_ids])
    np.testing.assert_array_equal(cal.grid.covariance, points)
    path = tmp_path / "cal.json"
    save_calibration(cal, path)
    again = load_calibration(path)
    np.testing.assert_array_equal(again.grid.covariance, cal.grid.covariance)
    doc = json.loads(path.read_text())
    doc["grid"].pop("covariance")
    older = Calibration.from_dict(doc)
    assert older.grid.covariance is None
    np.testing.assert_allclose(
        np.diagonal(older.grid.covariance_at([5.0])[0]),
        np.diagonal(again.grid.covariance_at([5.0])[0]),
        rtol=1e-12,
    )


def test_what_another_session_should_leave_counts_correlated_coefficients():
    """A bias and a scale known only together (their errors anticorrelated, as from holds
    at one speed): at that speed the calibration's own error nearly cancels, and what
    revalidation expects of another session says so; taken as uncorrelated it would not."""
    import pandas as pd

    from gyrocal.fit.thermal import ConstantCoefficients
    from gyrocal.fleet.drift import revalidate

    sb, ss, rho, w = 0.01, 1e-4, -0.99, 100.0  # deg/s, 1, -, deg/s: sb = w·ss
    model = Model.from_spec(["bias", "scale"])
    names = tuple(model.names)
    cov = np.diag([sb**2] * 3 + [ss**2] * 3)
    for i in range(3):
        cov[i, i + 3] = cov[i + 3, i] = rho * sb * ss
    values = np.zeros(6)
    stderr = np.sqrt(np.diag(cov))
    meta = {"device": "D", "protocol": "turntable"}
    correlated = Calibration(
        model, ConstantCoefficients(np.array([25.0]), names, values, stderr, covariance=cov), meta=meta
    )
    plain = Calibration(model, ConstantCoefficients(np.array([25.0]), names, values, stderr), meta=meta)
    n, floor = 40, 0.001
    rng = np.random.default_rng(0)
    obs = pd.DataFrame(
        {
            "axis": "x",
            "mount": "+x",
            "temp": 25.0,
            "ref_rate": w,
            "n": 100.0,
            "rate_x": w,
            "rate_y": 0.0,
            "rate_z": 0.0,
            **{f"gyro_{a}": (w if a == "x" else 0.0) + floor * rng.standard_normal(n) for a in "xyz"},
            **{f"std_{a}": floor * 10.0 for a in "xyz"},
        },
        index=range(n),
    )
    calibration_var = sb**2 + (w * ss) ** 2 + 2 * w * rho * sb * ss  # on x, per hold
    with_cov = revalidate(correlated, obs)["expected_rms"] ** 2
    without = revalidate(plain, obs)["expected_rms"] ** 2
    # expected² = floor² + (calibration variance on x + bias variance on y and z) / 3
    # (to 1e-4: the terms are evaluated at the compensated rates, which carry the noise)
    np.testing.assert_allclose(with_cov, floor**2 + (calibration_var + 2 * sb**2) / 3, rtol=1e-4)
    np.testing.assert_allclose(without, floor**2 + (sb**2 + (w * ss) ** 2 + 2 * sb**2) / 3, rtol=1e-4)


def test_distinct_rows_are_bit_for_bit():
    from gyrocal.calibration.file import distinct_rows

    temp = np.array([20.0, 20.5, 20.0, -0.0, 0.0, 20.5, np.nan, np.nan])
    accel = np.array([1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    first, index = distinct_rows([temp, accel])
    assert len(first) == 6  # (20, 1) (20.5, 1) (20, 2) (-0, 1) (0, 1) (nan, 1)
    for column in (temp, accel):
        np.testing.assert_array_equal(column[first][index].view(np.int64), column.view(np.int64))


def check_compensation_per_distinct_row(cal: Calibration, n=20_000, seed=3, step=1 / 16, **extra):
    """The shared first step gives what the per-sample solve gives, to the rounding of
    each row's largest output (the check of every sample is the same)."""
    from gyrocal.calibration import file

    rng = np.random.default_rng(seed)
    temp = np.round(rng.uniform(-15.0, 55.0, n) / step) * step  # a sensor's steps
    gyro = rng.normal(0.0, 200.0, (n, 3))
    data = {"temp": temp, **{k: f(rng, n) for k, f in extra.items()}}
    shared = []
    distinct = file.distinct_rows
    file.distinct_rows = lambda cols: shared.append(len((found := distinct(cols))[0])) or found
    try:
        grouped = cal.compensate(gyro, data, warn=False)
    finally:
        file.distinct_rows = distinct
    assert shared and shared[0] <= n // 2  # the shared path was taken
    covariates = {**data, "temp": cal.clamp(temp)}
    direct, _ = cal.model.compensate(cal.coefficients(temp, warn=False), gyro, covariates)
    scale = np.abs(gyro).max(axis=1, keepdims=True)
    assert np.all(np.abs(grouped - direct) <= 1e-12 * scale), np.max(np.abs(grouped - direct) / scale)
    return grouped


def test_compensation_shares_the_first_step_between_equal_rows(complete_run):
    cal = complete_run.calibration
    check_compensation_per_distinct_row(cal)
    # a model that is not affine in the rate: the per-sample check takes further steps
    K = np.array(cal.grid.values)
    model = Model.from_spec(["bias", "scale", "misalignment", "scale_quadratic"])
    values = np.concatenate([K, np.full((len(K), 3), 3e-6)], axis=1)
    quad = Calibration(
        model, TemperatureGrid(cal.grid.temperatures, tuple(model.names), values, np.full(values.shape, 1e-6))
    )
    out = check_compensation_per_distinct_row(quad)
    assert np.all(np.isfinite(out))
    # an input beside the temperature: rows are distinct by both
    g = Model.from_spec(["bias", "scale", "misalignment", "g_sensitivity"])
    values = np.concatenate([K, np.full((len(K), len(g.names) - K.shape[1]), 0.01)], axis=1)
    gcal = Calibration(
        g, TemperatureGrid(cal.grid.temperatures, tuple(g.names), values, np.full(values.shape, 1e-6))
    )
    steps = {f"accel_{a}": (lambda rng, n: rng.choice([-1.0, 0.0, 1.0], n)) for a in "xyz"}
    check_compensation_per_distinct_row(gcal, step=1.0, **steps)


def test_apply_writes_the_compensated_rates_without_a_dictionary(complete_run, logs, tmp_path):
    out = tmp_path / "applied.parquet"
    apply_calibration(complete_run.calibration, logs["complete"], out)
    meta = pq.ParquetFile(out).metadata
    chunks = {
        meta.row_group(0).column(i).path_in_schema: meta.row_group(0).column(i)
        for i in range(meta.num_columns)
    }
    for c in ("gyro_x", "gyro_y", "gyro_z"):
        assert not chunks[c].has_dictionary_page
    assert chunks["mount"].has_dictionary_page


def test_an_error_while_applying_leaves_no_output_and_no_thread(complete_run, logs, tmp_path, monkeypatch):
    import threading

    from gyrocal.calibration import apply as apply_module

    cal = complete_run.calibration
    calls = []
    real = Calibration.compensate

    def failing(self, gyro, data, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("compensation failed")
        return real(self, gyro, data, **kw)

    monkeypatch.setattr(Calibration, "compensate", failing)
    monkeypatch.setattr(apply_module, "BATCH_ROWS", 4096)  # several batches
    out = tmp_path / "applied.parquet"
    with pytest.raises(RuntimeError, match="compensation failed"):
        apply_calibration(cal, logs["complete"], out)
    assert not out.exists() and not list(tmp_path.glob(".applied*"))
    for thread in threading.enumerate():
        if thread.name == "apply-read":
            thread.join(timeout=5)
            assert not thread.is_alive()


@pytest.mark.parametrize("name", ["complete", "random_unit"])
def test_a_term_only_one_point_excites_is_calibrated_that_point_not_scored(logs, name):
    """A session-wide step in time inside one temperature point's soak: only that point's
    holds see both of its sides, so leaving it out leaves the step undetermined. The
    calibration is still made, validated on the other points, and the point is counted
    and never scored (on three points, the end points left out are what is scored)."""
    from gyrocal.diagnosis import extended
    from gyrocal.fit.validate import CannotLeaveOut, validate
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings
    from gyrocal.pipeline.identify import fit_of

    settings = Settings()
    obs = segment_log(logs[name], settings).observations
    middle = obs[obs["point"] == sorted(obs["point"].unique())[1]]
    t0 = float(obs.attrs["series"].t0)
    at = float(middle["t_start"].median()) - t0
    step = f"expression(label='step', formula='tanh((t - {at:.1f}) / 1)')"
    # the model with the step, as fitted (a unit's calibration keeps it only where its data
    # ask for it: gyrocal.pipeline.identify; here the validation of such a model is tested)
    fitted = fit_of(extended(settings, step), obs)
    summary = validate(fitted.model, obs, fitted, every_point=False).summary
    assert summary["points_not_left_out"] == 1
    assert summary["held_out"] == "temperature"
    # Scored: the interior points' holds (the end points, left out, are outside what
    # remains) but the one that could not be left out.
    points = sorted(obs["point"].unique())
    interior = ~obs["point"].isin([points[0], points[1], points[-1]])
    left_out = ~obs["point"].isin([points[1]])
    assert summary["holds_scored"] == int((interior if interior.any() else left_out).sum())
    assert summary["scored"] == ("interior" if interior.any() else "left-out")
    assert np.isfinite(summary["validation_rms"])
    with pytest.raises(CannotLeaveOut, match="leaves nothing to calibrate from"):
        validate(fitted.model, obs, fitted)
