"""Servo (seed 001) and sweep (seed 003) logs through the common chain: segmentation into
observations, calibration, validation, diagnosis, the report and apply."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from gyrocal.calibration.apply import apply_calibration
from gyrocal.calibration.file import load_calibration, save_calibration
from gyrocal.diagnosis import diagnose
from gyrocal.io import schema
from gyrocal.io.errors import ConfigError
from gyrocal.pipeline.chain import run
from gyrocal.pipeline.config import Settings
from gyrocal.protocols import registry
from gyrocal.protocols.sweep.protocol import sweep_analysis
from gyrocal.report.unit import UnitResults, write_unit_report
from gyrocal.simulate import simulate_unit
from gyrocal.simulate.servo import ServoProtocol, ServoUnit
from gyrocal.simulate.sweep import SweepProtocol, SweepUnit

from ..run.test_cli import gyrocal


@pytest.fixture(scope="module")
def servo_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("servo") / "S1.parquet"
    unit = ServoUnit.random(np.random.default_rng(11))
    truth = simulate_unit(
        path,
        protocol="servo",
        rig=ServoProtocol(revolutions=3),
        unit=unit,
        rng=np.random.default_rng(12),
        device="S1",
    )
    return path, truth


@pytest.fixture(scope="module")
def sweep_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "W1.parquet"
    unit = SweepUnit.random(np.random.default_rng(21), drift_dT2=(1.5e-4, -1.0e-4, 8.0e-5))
    truth = simulate_unit(
        path,
        protocol="sweep",
        rig=SweepProtocol.demo(),
        unit=unit,
        rng=np.random.default_rng(22),
        device="W1",
    )
    return path, truth


def test_servo_calibration_is_algorithm_1_and_recovers_the_unit(servo_log):
    path, truth = servo_log
    result = run(path, protocol="servo")
    cal = result.calibration
    servo = cal.extra["servo"]
    k, b = np.array(servo["iterative"]["k"]), np.array(servo["iterative"]["b"])
    k_se, b_se = np.array(servo["iterative"]["k_se"]), np.array(servo["iterative"]["b_se"])
    unit = truth["unit"]  # as simulated (paper convention, rad/s)
    # within 4 of the fit's own standard errors (seed 001's error ranges are wider)
    np.testing.assert_allclose(k, unit["k"], atol=4 * k_se.max())
    np.testing.assert_allclose(b, unit["b"], atol=4 * b_se.max())
    # the file form: K = diag(1/k), B = −b in deg/s (contract: w = K w_true + B)
    K, B = cal.matrices_at(np.array([22.0]))
    np.testing.assert_allclose(np.diag(K[0]), 1 / k, rtol=1e-12)
    np.testing.assert_allclose(B[0], -np.degrees(b), rtol=1e-12)
    # 18 revolutions, more than the six unknowns: the two methods' optima differ by far
    # less than the noise (the six-observation case agrees to 1e-9, tests/protocols/test_servo.py)
    np.testing.assert_allclose(servo["lm"]["k"], k, atol=0.01 * k_se.min())
    np.testing.assert_allclose(servo["lm"]["b"], b, atol=0.01 * b_se.min())
    assert servo["iterative"]["converged"] and servo["settled_at"] <= 3


def test_servo_validation_holds_each_revolution_out_and_sits_at_the_noise_floor(servo_log):
    path, _ = servo_log
    s = run(path, protocol="servo").validation.summary
    assert s["held_out"] == "revolution" and s["holds_scored"] == 18
    # 18 revolution errors: the RMS scatters by 1/sqrt(2·18) ≈ 17 %; 3 of that either way
    # (a floor inflated by the servo's ripple would put it far below)
    assert abs(s["excess_over_expected"] - 1) < 3 / np.sqrt(36)
    assert s["uncompensated_rms"] > 20 * s["validation_rms"]


def test_servo_file_round_trips_and_apply_returns_the_servo_speed(servo_log, tmp_path):
    path, _ = servo_log
    cal = run(path, protocol="servo").calibration
    save_calibration(cal, tmp_path / "cal.json")
    again = load_calibration(tmp_path / "cal.json")
    np.testing.assert_array_equal(again.grid.values, cal.grid.values)
    assert again.extra["servo"]["iterative"]["k"] == cal.extra["servo"]["iterative"]["k"]
    counts = apply_calibration(again, path, tmp_path / "out.parquet")
    assert counts["nonfinite"] == 0
    raw = pd.read_parquet(path)
    out = pd.read_parquet(tmp_path / "out.parquet")
    obs = run(path, protocol="servo").segmentation.observations
    errors = []
    for r in obs.itertuples():  # one check per revolution, not per sample
        inside = (out["t"] >= r.t_start) & (out["t"] <= r.t_end)
        mean = out.loc[inside, ["gyro_x", "gyro_y", "gyro_z"]].mean().to_numpy()
        errors.append(np.linalg.norm(mean) - raw.loc[inside, "ref_rate"].abs().mean())
    # each revolution mean: noise ≈ 2 deg/s per sample over √1200 samples → 0.06 deg/s
    assert np.sqrt(np.mean(np.square(errors))) < 3 * 0.06


def test_servo_diagnosis_runs_on_revolution_means(servo_log):
    path, _ = servo_log
    settings = Settings().for_protocol("servo")
    diag = diagnose(settings, run(path, protocol="servo").segmentation.observations)
    assert diag.explains and diag.best is None
    assert {c["status"] for c in diag.to_dict()["candidates"]} >= {"ranked"}


def test_sweep_diagnosis_finds_the_square_of_the_temperature_change(sweep_log):
    path, truth = sweep_log
    settings = Settings().for_protocol("sweep")
    result = run(path, settings, protocol="sweep")
    assert result.calibration.kind == "continuous"
    assert result.validation.summary["held_out"] == "temperature"
    diag = diagnose(settings, result.segmentation.observations)
    assert not diag.explains and diag.best is not None
    assert diag.best.term == "bias_temp_poly"
    # the fitted ΔT² coefficients match the simulated ones within 5 standard errors
    size = {z["coefficient"]: z for z in diag.best.size}
    for axis, true in zip("xyz", truth["unit"]["drift_dT2"], strict=False):
        z = size[f"bias_temp_poly.{axis}.c2"]
        assert abs(z["value"] - true) < 5 * z["stderr"]
    fixed = run(
        path, replace(settings, model=settings.model.with_terms(("bias_temp_poly",))), protocol="sweep"
    ).validation.summary
    assert fixed["excess"] <= 1.2


def test_sweep_analysis_trains_on_one_sweep_and_verifies_on_the_other(sweep_log):
    path, _ = sweep_log
    obs = run(path, protocol="sweep").segmentation.observations
    a = sweep_analysis(obs)
    assert a["sweeps"] == 2 and not a["verified_on_training"]
    assert a["train"]["t_end"] < a["verify"]["t_start"]
    poly = {row["axis"]: row for row in a["stability"]["polynomial"]["rows"]}
    # curvature of 1e-4 deg/s/°C² over 125 °C: far above the windows' noise
    assert all(poly[axis]["P3"] < 0.2 for axis in "xyz")


@pytest.mark.slow
def test_sweep_report_shows_the_seed_003_tables(sweep_log, tmp_path):
    path, _ = sweep_log
    settings = Settings().for_protocol("sweep")
    result = run(path, settings, protocol="sweep")
    out = tmp_path / "r.html"
    obs = result.segmentation.observations
    write_unit_report(
        UnitResults.from_run(result, "", diagnose(settings, obs), registry.analysis("sweep", obs)),
        out,
        registry.get("sweep"),
    )
    html = out.read_text()
    assert "Drift models and bias stability (seed 003)" in html
    assert "verified on sweep 2" in html


def test_protocol_settings_are_checked_and_resolved_once():
    with pytest.raises(ConfigError, match="protocols.sweep.options.width"):
        Settings.from_dict({"protocols": {"sweep": {"options": {"width": 3}}}})
    with pytest.raises(ConfigError, match="unknown protocol protocols.gimbal"):
        Settings.from_dict({"protocols": {"gimbal": {}}})
    s = Settings.from_dict({"protocols": {"sweep": {"options": {"window_s": 30}}}})
    sweep = s.for_protocol("sweep")
    assert sweep.model.kind == "continuous" and s.protocol_options("sweep")["window_s"] == 30
    added = replace(sweep, model=sweep.model.with_terms(("temp_rate",)))
    assert added.for_protocol("sweep") is added  # resolved once: --add-term survives
    assert s.for_protocol("turntable") is s


@pytest.mark.parametrize("name", ["servo", "sweep", "ferraris", "static"])
def test_a_protocols_options_come_from_the_config_schema(name):
    """The schema holds each protocol's options with their defaults and bounds; the settings
    complete an override with them, while the config keeps the override as given."""
    defaults = registry.option_defaults(name)
    properties = registry.options_schema(name)["properties"]
    assert set(defaults) == set(properties)  # every option has its default there
    assert Settings().protocol_options(name) == defaults
    key, value = next(iter(defaults.items()))
    config = schema.check({"devices": "d.tsv", "model": {}, "protocols": {name: {"options": {key: value}}}})
    assert config["protocols"][name] == {"options": {key: value}}
    assert Settings.from_dict({"protocols": config["protocols"]}).protocol_options(name) == defaults


@pytest.mark.slow
def test_cli_diagnose_and_add_term_on_a_sweep(sweep_log, tmp_path):
    path, _ = sweep_log
    out = gyrocal("diagnose", str(path), "--protocol", "sweep", "-o", str(tmp_path / "d.json"))
    assert out.returncode == 0, out.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["candidates"][0]["term"] == "bias_temp_poly" and d["excess"] > 2
    out = gyrocal(
        "calibrate",
        str(path),
        "--protocol",
        "sweep",
        "-o",
        str(tmp_path / "c.json"),
        "--add-term",
        d["candidates"][0]["term"],
    )
    assert out.returncode == 0, out.stderr
    cal = json.loads((tmp_path / "c.json").read_text())
    poly = [t for t in cal["model"]["terms"] if t["name"] == "bias_temp_poly"]
    assert [t.get("degree", 2) for t in poly] == [2]  # degree 1 replaced, not kept
    assert "bias_temp_poly.x.c2" in cal["grid"]["coefficients"]
    out = gyrocal(
        "calibrate",
        str(path),
        "--protocol",
        "servo",
        "-o",
        str(tmp_path / "s.json"),
        "--add-term",
        "scale_quadratic",
    )
    assert out.returncode == 2 and "use them with gyrocal diagnose" in out.stderr


def test_simulate_cli_writes_servo_sweep_and_ferraris_logs_and_refuses_turntable_knobs(tmp_path):
    out = gyrocal(
        "simulate", "--protocol", "servo", "--log", str(tmp_path / "s.parquet"), "--preset", "quick"
    )
    assert out.returncode == 0, out.stderr
    out = gyrocal(
        "simulate",
        "--protocol",
        "sweep",
        "--log",
        str(tmp_path / "w.parquet"),
        "--preset",
        "quick",
        "--rates",
        "1,2",
    )
    assert out.returncode == 2 and "--rates do not apply to the sweep rig" in out.stderr
    # one hand-rotation log of a device (its unit as in its turntable sessions)
    out = gyrocal("simulate", "--protocol", "ferraris", "--log", str(tmp_path / "f.parquet"))
    assert out.returncode == 0, out.stderr
    out = gyrocal(
        "calibrate", str(tmp_path / "f.parquet"), "--protocol", "ferraris", "-o", str(tmp_path / "f.json")
    )
    assert out.returncode == 0, out.stderr


def test_a_single_revolution_per_direction_is_scored_in_sample_without_inventing_a_ratio(tmp_path):
    path = tmp_path / "one.parquet"
    simulate_unit(
        path,
        protocol="servo",
        rig=ServoProtocol(revolutions=1),
        unit=ServoUnit.random(np.random.default_rng(5)),
        rng=np.random.default_rng(6),
    )
    s = run(path, protocol="servo").validation.summary
    assert s["held_out"].startswith("nothing") and s["holds_scored"] == 6
    assert s["expected_rms"] is None and s["excess_over_expected"] is None  # no residual dof
    json.dumps(s, allow_nan=False)


def test_servo_and_turntable_sessions_of_one_unit_agree_within_their_errors(tmp_path):
    from gyrocal.fleet.summary import servo_versus_turntable
    from gyrocal.simulate import TurntableProtocol
    from gyrocal.simulate.fleet import unit_for

    rows = []
    for protocol, session, rig in (
        ("turntable", "2026-01-01", TurntableProtocol.quick(temperatures=(10.0, 20.0, 30.0))),
        ("servo", "2026-01-02", ServoProtocol(revolutions=3)),
    ):
        unit, seed = unit_for("U9", session, protocol=protocol)
        path = tmp_path / f"{protocol}.parquet"
        simulate_unit(path, protocol=protocol, rig=rig, unit=unit, rng=np.random.default_rng(seed))
        cal = run(path, protocol=protocol).calibration
        rows.append(
            {"device": "U9", "protocol": protocol, "session": session, "report": "r.html", "calibration": cal}
        )
    (unit,) = servo_versus_turntable(rows)
    servo_cal, table_cal = rows[1]["calibration"], rows[0]["calibration"]
    (K,), (B,) = table_cal.matrices_at([unit["temperature"]])
    table = {p["parameter"]: p for p in unit["rows"]}
    np.testing.assert_allclose(table["scale y, ppm"]["turntable"], (K[1, 1] - 1) * 1e6, rtol=1e-12)
    np.testing.assert_allclose(table["bias z, deg/s"]["turntable"], B[2], rtol=1e-12)
    assert servo_cal.meta["protocol"] == "servo"
    # one simulated unit on both rigs: the methods differ by noise alone (4 standard errors)
    assert all(abs(p["sigmas"]) < 4 for p in unit["rows"]), unit["rows"]
