"""Seed 001's servo six-observation calibration: simulator, rotations, Algorithm 1, LM, study."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gyrocal.io.errors import GyrocalError, SegmentationError
from gyrocal.io.log import RigLog, read_log
from gyrocal.protocols.servo import (
    ServoFitError,
    find_rotations,
    fit_iterative,
    fit_lm,
    fit_observations,
    g_optimal_warnings,
)
from gyrocal.protocols.servo.fit import PARAMETERS
from gyrocal.protocols.servo.montecarlo import box_stats, fit_batch, simulate_observations, speed_sweep, study
from gyrocal.simulate.servo import DIRECTIONS, ServoProtocol, ServoUnit, render_servo

DEG = 180.0 / math.pi
IDEAL = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def servo_log(tmp_path, *, seed=1, unit=None, name="servo", **protocol):
    """A simulated servo log (normal-condition unit unless given) and its truth."""
    rng = np.random.default_rng(seed)
    unit = unit or ServoUnit.random(rng)
    path = tmp_path / f"{name}.parquet"
    truth = render_servo(ServoProtocol(**protocol), unit, rng, path)
    return path, unit, truth


# --- the simulated calibration, end to end --------------------------------------------------


@pytest.mark.parametrize("noise", [0.035, 0.2])
@pytest.mark.parametrize("seed,mount_column", [(11, False), (12, True), (13, False)])
def test_rotations_found_and_unit_recovered(tmp_path, noise, seed, mount_column):
    # Hand mounting up to 6° off, 5 % ripple, handling motion between mounts (ref_rate 0).
    path, unit, truth = servo_log(
        tmp_path, seed=seed, noise=noise, mount_column=mount_column, mount_error_deg=6.0, ripple=0.05
    )
    assert max(r["tilt_deg"] for r in truth["rotations"]) > 2.0 and truth["handling"]
    rot = find_rotations(read_log(path))
    obs = rot.observations()
    # The six rotations, in order, each inside the servo's constant-speed phase.
    assert rot.directions == DIRECTIONS
    assert rot.warnings == ()
    starts = np.array([r["t_start"] for r in truth["rotations"]])
    ends = np.array([r["t_end"] for r in truth["rotations"]])
    np.testing.assert_allclose(obs["t_start"], starts, atol=1e-9)
    np.testing.assert_allclose(obs["t_end"], ends, atol=1e-9)
    np.testing.assert_allclose(obs["ref_rate"], 60.0, rtol=1e-12)

    fit = fit_observations(obs)
    lm = fit_observations(obs, method="lm")
    # Paper's counting (Table I): estimates settle in the fourth decimal by the third.
    assert fit.converged and fit.settled_at() <= 3
    # Six equations, six unknowns: both methods solve them exactly. Algorithm 1 stops at
    # Σ|Δβ| <= 1e-6 with an error shrinking ~β0/ω² < 0.05 per step, so ~1e-8 is left.
    np.testing.assert_allclose(fit.k, lm.k, rtol=1e-8)
    np.testing.assert_allclose(fit.b, lm.b, rtol=1e-8, atol=1e-12)
    tight = fit_observations(obs, tol=1e-12)
    np.testing.assert_allclose(tight.k, lm.k, rtol=1e-9)
    np.testing.assert_allclose(tight.b, lm.b, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(lm.residuals, 0.0, atol=1e-12)

    # The fit's own standard error, from the white-noise level of each revolution, is the
    # paper's σ/√(2N) for biases (N = 1200 samples per revolution at 60 deg/s, 200 Hz) ...
    np.testing.assert_allclose(fit.b_se, noise / math.sqrt(2 * 1200), rtol=0.15)
    # ... and the errors lie within four of them (two-sided 6e-5 false alarm per parameter).
    assert np.all(np.abs(fit.k - unit.k) <= 4 * fit.k_se)
    assert np.all(np.abs(fit.b - unit.b) <= 4 * fit.b_se)


def test_two_revolutions_give_per_revolution_rows(tmp_path):
    order = ("+z", "-z", "+x", "-x", "+y", "-y")
    path, unit, truth = servo_log(
        tmp_path, seed=21, revolutions=2, order=order, remount_every_rotation=True, mount_error_deg=8.0
    )
    assert len(truth["handling"]) == 5 and len({r["tilt_deg"] for r in truth["rotations"]}) == 6
    rot = find_rotations(read_log(path))
    assert len(rot.revolutions) == 12 and rot.directions == order
    assert (rot.observations()["revolutions"] == 2).all()
    # Twelve observations: both methods still estimate the unit, and differ within the noise.
    fit = fit_observations(rot.revolutions)
    lm = fit_observations(rot.revolutions, method="lm")
    assert np.all(np.abs(fit.k - unit.k) <= 4 * fit.k_se)
    assert np.all(np.abs(fit.b - lm.b) <= 0.1 * fit.b_se)


def test_ripple_cancels_over_whole_revolutions(tmp_path):
    # Noise off: the revolution mean is exact although the speed wobbles by 20 %.
    path, unit, truth = servo_log(tmp_path, seed=5, noise=0.0, ripple=0.2)
    obs = find_rotations(read_log(path)).observations()
    g = np.array([r["axis"] for r in truth["rotations"]]) * truth["rotations"][0]["speed_rad_s"]
    expected = unit.measure(g) * DEG
    np.testing.assert_allclose(obs[["gyro_x", "gyro_y", "gyro_z"]], expected, atol=2e-4)
    fit = fit_observations(obs, tol=1e-12)
    np.testing.assert_allclose(fit.k, unit.k, rtol=1e-5)
    np.testing.assert_allclose(fit.b, unit.b, atol=1e-5)


# --- conventions: paper (k, b) and the calibration file's (K, B) -----------------------------


def test_file_convention_compensates_to_the_true_rate(tmp_path):
    path, unit, truth = servo_log(tmp_path, seed=8, noise=0.035, ripple=0.0)
    log = read_log(path)
    w = np.column_stack([log.column(c) for c in ("gyro_x", "gyro_y", "gyro_z")]).astype(float)
    t = log.column("t")
    # w = K w_true + B  =>  w_true = K^-1 (w - B), with K = diag(1/k), B = -b (deg/s).
    np.testing.assert_allclose(unit.K, np.diag(1 / np.asarray(unit.k)), rtol=1e-15)
    np.testing.assert_allclose(unit.B, -np.asarray(unit.b) * DEG, rtol=1e-15)
    w_true = np.linalg.solve(unit.K, (w - unit.B).T).T
    sigma = 0.035 * DEG * np.asarray(unit.k)  # noise of the compensated rate, deg/s
    for r in truth["rotations"]:
        inside = (t >= r["t_start"]) & (t <= r["t_end"])
        err = w_true[inside] - np.asarray(r["axis"]) * r["speed_rad_s"] * DEG
        n = int(inside.sum())
        assert np.all(np.abs(err.mean(axis=0)) <= 4 * sigma / math.sqrt(n))
        np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.1)
    still = log.column("ref_rate") == 0
    quiet = still & ~np.any([(t >= h["t_start"]) & (t <= h["t_end"]) for h in truth["handling"]], axis=0)
    assert np.all(np.abs(w_true[quiet].mean(axis=0)) <= 4 * sigma / math.sqrt(quiet.sum()))
    # The fit's K, B mean the same: its compensation agrees with the true unit's.
    fit = fit_observations(find_rotations(log))
    np.testing.assert_allclose(fit.K, np.diag(1 / fit.k), rtol=1e-15)
    np.testing.assert_allclose(fit.B, -fit.b * DEG, rtol=1e-15)
    np.testing.assert_allclose(fit.compensate(w[:5]), w_true[:5], atol=6 * 0.035 * DEG * 0.03)
    # ... and so do its coefficients in gyrocal's term names (scale = K_aa - 1, bias = B_a).
    coef, err = fit.coefficients(), fit.coefficient_errors()
    np.testing.assert_allclose([coef[f"scale.{a}"] for a in "xyz"], np.diag(fit.K) - 1, rtol=1e-12)
    np.testing.assert_allclose([coef[f"bias.{a}"] for a in "xyz"], fit.B, rtol=1e-12)
    for i, a in enumerate("xyz"):
        assert abs(coef[f"scale.{a}"] - (unit.K[i, i] - 1)) <= 4 * err[f"scale.{a}"]
        assert abs(coef[f"bias.{a}"] - unit.B[i]) <= 4 * err[f"bias.{a}"]


# --- the G-optimal design and refusing what cannot be calibrated ------------------------------


def test_g_optimal_warnings():
    assert g_optimal_warnings(DIRECTIONS, IDEAL * 60.0 + 0.5, speeds=[60.0] * 6) == []
    missing = g_optimal_warnings(("+x", "-x", "+y", "+z", "-z"), np.delete(IDEAL, 3, axis=0))
    assert any("5 rotations" in w for w in missing) and any("no -y rotation" in w for w in missing)
    no_axis = g_optimal_warnings(("+x", "-x", "+y", "-y", "+x", "-x"), IDEAL[[0, 1, 2, 3, 0, 1]])
    assert any("sensor z axis" in w for w in no_axis) and any("+x appears 2 times" in w for w in no_axis)
    tilted = IDEAL.copy()
    tilted[2] = [0.5, 0.8, 0.0]  # 32° off +y
    assert any("rotation 2 (+y)" in w for w in g_optimal_warnings(DIRECTIONS, tilted))
    assert any("speeds differ" in w for w in g_optimal_warnings(DIRECTIONS, IDEAL, speeds=[60] * 5 + [50]))


def test_five_rotations_refused_with_one_line(tmp_path):
    path, _, _ = servo_log(tmp_path, seed=3, order=("+x", "-x", "+y", "+z", "-z"))
    with pytest.raises(SegmentationError) as info:
        find_rotations(read_log(path))
    message = str(info.value)
    assert "\n" not in message and "found 5 rotations" in message and "needs six" in message
    assert message.startswith(str(path))


def test_no_whole_revolution_refused(tmp_path):
    t = np.arange(0, 8.0, 0.005)
    ref = np.where((t > 1) & (t < 3.5), 60.0, 0.0)  # 150° of rotation
    gyro = (ref + np.random.default_rng(0).normal(0, 1, t.size)).astype(np.float32)
    path = tmp_path / "short.parquet"
    pq.write_table(
        pa.table(
            {
                "t": t,
                "gyro_x": gyro,
                "gyro_y": gyro * 0,
                "gyro_z": gyro * 0,
                "temp": np.full(t.size, 22.0),
                "ref_rate": ref,
            }
        ),
        path,
    )
    with pytest.raises(SegmentationError, match="covers a whole revolution"):
        find_rotations(read_log(path))


@given(
    st.lists(
        st.tuples(st.integers(1, 400), st.sampled_from([0.0, 0.0, 30.0, 180.0, 360.0, -360.0, 1e-3])),
        min_size=1,
        max_size=20,
    ),
    st.integers(0, 2**32 - 1),
)
def test_any_log_gives_rotations_or_a_gyrocal_error(segments, seed):
    # Piecewise-constant servo speeds at 100 Hz with random gyro output, in memory.
    ref = np.concatenate([np.full(n, rate) for n, rate in segments])
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.choice([0.01, 0.2], ref.size, p=[0.998, 0.002]))  # rare logging gaps
    gyro = rng.normal(0, 50, (ref.size, 3))
    batch = {
        "t": t,
        "gyro_x": gyro[:, 0],
        "gyro_y": gyro[:, 1],
        "gyro_z": gyro[:, 2],
        "temp": np.full(ref.size, 22.0),
        "ref_rate": ref,
    }
    try:
        rot = find_rotations(RigLog("mem.parquet", (batch,), ref.size, 0))
    except GyrocalError as exc:
        assert "\n" not in str(exc)
        return
    obs = rot.observations()
    assert len(obs) >= 6 and np.isfinite(obs.select_dtypes("number").to_numpy()).all()
    assert (
        rot.revolutions["ref_rate"] * (rot.revolutions["t_end"] - rot.revolutions["t_start"]) <= 360.0 + 1e-6
    ).all()


def test_fit_refuses_instead_of_nan():
    k, b = np.array([2.0, 2.0, 2.0]), np.array([0.2, 0.2, 0.2])
    with pytest.raises(ServoFitError, match="did not converge"):  # β0/ω² ≈ 0.5: too slow
        fit_iterative(IDEAL / k - b, np.ones(6))
    loose = fit_iterative(IDEAL / k - b, np.ones(6), strict=False)
    assert not loose.converged and np.isfinite(loose.k).all()
    with pytest.raises(ServoFitError, match="β1..β3 <= 0"):  # diverges to k² < 0
        fit_iterative(0.3 * IDEAL / k - b, np.full(6, 0.3))
    with pytest.raises(ServoFitError, match="do not determine"):  # no rotation about z
        fit_iterative(IDEAL[[0, 1, 2, 3, 0, 1]], np.ones(6))
    with pytest.raises(ServoFitError, match="at least 6"):
        fit_lm(IDEAL[:5], np.ones(5))


@given(st.lists(st.floats(-5, 5, allow_nan=False), min_size=18, max_size=18), st.floats(0.05, 5.0))
def test_any_observations_give_a_finite_fit_or_a_gyrocal_error(values, omega):
    m = np.asarray(values).reshape(6, 3)
    for fit in (fit_iterative, fit_lm):
        try:
            result = fit(m, np.full(6, omega))
        except GyrocalError:
            continue
        summary = result.summary()
        assert all(
            np.isfinite(np.asarray(summary[key], dtype=float)).all()
            for key in ("k", "b", "K", "B_deg_s", "beta", "residuals")
        )
        assert np.all(result.k > 0)


# --- the Monte-Carlo study --------------------------------------------------------------------


def test_batched_algorithm_equals_per_run_calls():
    rng = np.random.default_rng(4)
    k, b = np.array([[0.9, 1.1, 1.05], [1.7, 1.3, 1.9]]), np.array([[0.05, -0.08, 0.01], [0.15, -0.2, 0.12]])
    m = simulate_observations(k, b, 4, rng, speed=1.0, noise=0.2, samples=419).reshape(-1, 6, 3)
    batch = fit_batch(m, 1.0)
    assert batch.converged.all()
    for r in range(len(m)):
        single = fit_iterative(m[r], np.ones(6))
        np.testing.assert_allclose(batch.k[r], single.k, rtol=1e-12)
        np.testing.assert_allclose(batch.b[r], single.b, rtol=1e-12)
        assert batch.iterations[r] == single.iterations


def test_study_is_deterministic_and_methods_agree():
    a = study(n_sets=2, n_runs=6, seed=7)
    b = study(n_sets=2, n_runs=6, seed=7)
    pd.testing.assert_frame_equal(a, b)
    assert not a.equals(study(n_sets=2, n_runs=6, seed=8))
    assert len(a) == 2 * 2 * 2 * 6 * 2 and a["converged"].all()
    it, lm = a[a["method"] == "iterative"].reset_index(), a[a["method"] == "lm"].reset_index()
    for p in PARAMETERS:  # identical up to Algorithm 1's stopping rule (paper Section III-A)
        np.testing.assert_allclose(it[f"{p}_err"], lm[f"{p}_err"], atol=1e-8)


def test_study_spread_matches_the_noise_model():
    # Bias error of the ± pair: σ/√(2N) with N = 419; whiskers of a normal sample at ±2.698 sd.
    df = study(n_sets=4, n_runs=150, noise=(0.035, 0.2), conditions="normal", method="iterative")
    stats = box_stats(df).set_index(["noise", "parameter"])
    for sigma in (0.035, 0.2):
        sd = sigma / math.sqrt(2 * 419)
        row = stats.loc[(sigma, "b")]
        np.testing.assert_allclose((row["q3"] - row["q1"]) / 1.349, sd, rtol=0.1)
        np.testing.assert_allclose(0.5 * (row["whisker_hi"] - row["whisker_lo"]), 2.698 * sd, rtol=0.15)
        assert abs(row["median"]) <= 4 * 1.2533 * sd / math.sqrt(row["count"])  # unbiased


def test_speed_sweep_shape():
    sweep = speed_sweep((0.3, 1.0, 3.0), n_sets=3, n_runs=60, noise=0.035)
    assert (sweep["failed"] == 0).all()
    mse_k, mse_b = sweep["mse_k"].to_numpy(), sweep["mse_b"].to_numpy()
    # Scale error ∝ 1/ω at fixed N (common random numbers): MSE ratio ≈ (3/0.3)² = 100.
    np.testing.assert_allclose(mse_k[0] / mse_k[2], 100.0, rtol=0.05)
    np.testing.assert_allclose(mse_b / mse_b[0], 1.0, rtol=0.01)


def test_render_is_deterministic(tmp_path):
    a, _, _ = servo_log(tmp_path, seed=9, name="a", mount_column=True)
    b, _, _ = servo_log(tmp_path, seed=9, name="b", mount_column=True)
    c, _, _ = servo_log(tmp_path, seed=10, name="c", mount_column=True)
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()
    _, _, truth = servo_log(tmp_path, seed=9, name="d")
    assert json.loads(json.dumps(truth)) == truth
    assert ServoUnit.from_dict(ServoUnit((1.1, 0.9, 1.0), (0.01, -0.02, 0.03)).to_dict()) == ServoUnit(
        (1.1, 0.9, 1.0), (0.01, -0.02, 0.03)
    )


# --- the paper's tables and figures -----------------------------------------------------------


def test_paper_tables_and_figures(tmp_path):
    from gyrocal.paper import seed001

    tables = {t.name: t for t in seed001.tables(quick=True)}
    assert set(tables) == {
        "Table I",
        "Fig. 2 statistics",
        "Fig. 4 statistics",
        "Fig. 5 statistics",
        "Table II",
        "Table III",
    }
    for table in tables.values():
        assert table.seed == "001" and table.rows and table.notes
        assert all(math.isfinite(r.regenerated) for r in table.rows)
    settled = {r.label: r for r in tables["Table I"].rows if "settled" in r.label}
    assert [r.regenerated for r in settled.values()] == [r.published for r in settled.values()] == [2, 3, 3]
    # Tables II-III: the units are set to the paper's turntable values; both simulated
    # calibrations recover them within four servo standard errors (about 1e-3 each).
    for name, _, truth in seed001.TABLE_II_III.values():
        rows = [r for r in tables[name].rows if "−" not in r.label]
        assert len(rows) == 12
        for r in rows:
            assert abs(r.regenerated - truth[PARAMETERS.index(r.label.split(" / ")[0])]) <= 4e-3, r.label
    paths = seed001.figures(tmp_path / "a", quick=True)
    again = seed001.figures(tmp_path / "b", quick=True)
    assert [p.name for p in paths] == ["001-fig-2.svg", "001-fig-4.svg", "001-fig-5.svg"]
    for p, q in zip(paths, again, strict=False):
        text = p.read_text()
        assert text.startswith("<?xml") and "<dc:date>" not in text and p.read_bytes() == q.read_bytes()


# --- cross-axis terms: what a servo log can tell of them ----------------------------------------
# The independent generator (benchmarks/zoo) turns its unit about three mounts, each both
# ways; a hand mount is 2-6° off the axis in a random direction, new every session.


def zoo_servo(tmp_path, seed, sessions=(0,), **overrides):
    """Revolutions of zoo servo sessions of unit ``seed`` (one table, the sessions in turn),
    the unit's true K and B at 25 °C and the sessions' truth records."""
    from benchmarks.zoo.generator import B_of_T, K_of_T, make_unit, write_session

    unit = make_unit(effect="none", protocol="servo", seed=seed)
    tables, infos = [], []
    for s in sessions:
        path = tmp_path / f"zoo-{seed}-{s}.parquet"
        infos.append(write_session(unit, path, session=s, seed=100 + s, **overrides))
        tables.append(find_rotations(read_log(path)).revolutions)
    return pd.concat(tables, ignore_index=True), K_of_T(unit, 25.0), B_of_T(unit, 25.0), infos


def stderr_matrix(fit) -> tuple[np.ndarray, np.ndarray]:
    se = fit.coefficient_errors()
    K = np.array([[se[f"scale.{a}" if a == b else f"misalignment.{a}.{b}"] for b in "xyz"] for a in "xyz"])
    return K, np.array([se[f"bias.{a}"] for a in "xyz"])


def test_a_fixture_gives_every_term_from_the_off_axis_outputs(tmp_path):
    from gyrocal.protocols.servo.fit import fit_model

    revs, K, B, _ = zoo_servo(tmp_path, 3, misalign_deg=[0.0, 0.0])
    fit, used, _ = fit_model(revs, "fixture")
    K_se, B_se = stderr_matrix(fit)
    assert used == "fixture" and np.all(K_se < 2e-4) and np.all(B_se < 1e-2)
    assert np.all(np.abs(fit.K - K) <= 4 * K_se) and np.all(np.abs(fit.B - B) <= 4 * B_se)
    assert np.abs(K - np.diag(np.diag(K))).max() > 20 * K_se.max()  # the terms were there to find


def test_a_hand_mount_puts_its_tilt_into_the_off_axis_outputs(tmp_path):
    # What the fixture model fits on hand mounts is K U, U the mounts' true rotation axes:
    # the tilt, a property of the session, many standard errors beside the unit's own terms.
    from gyrocal.protocols.servo.fit import fit_model

    revs, K, B, (info,) = zoo_servo(tmp_path, 3)
    fit, _, _ = fit_model(revs, "fixture")
    K_se, _ = stderr_matrix(fit)
    U = np.column_stack([np.asarray(m["R_body_to_rig"])[2] for m in info["mounts"]])  # +x, +y, +z
    assert np.all(np.abs(fit.K - K @ U) <= 4 * K_se)
    assert np.abs(fit.K - K).max() > 100 * K_se.max()


def test_cross_terms_from_magnitudes_need_six_axes(tmp_path):
    from gyrocal.protocols.servo.fit import fit_model

    one, K, B, _ = zoo_servo(tmp_path, 2)
    with pytest.raises(ServoFitError, match="do not determine the symmetric cross terms"):
        fit_model(one, "symmetric")
    fit, used, why = fit_model(one, "auto")
    assert used == "seed001" and "six or more axes" in why and fit.K.shape == (3, 3)
    # Two sessions' mounts: six hand-placed axes, each turned both ways.
    two, _, _, _ = zoo_servo(tmp_path, 2, sessions=(0, 1))
    fit, used, why = fit_model(two, "auto")
    assert used == "symmetric" and "χ²" in why
    # Magnitudes see K only up to a rotation: the symmetric factor P of K = P Q.
    w, V = np.linalg.eigh(K @ K.T)
    P = (V * np.sqrt(w)) @ V.T
    K_se, B_se = stderr_matrix(fit)
    assert np.allclose(fit.K, fit.K.T, atol=1e-12)
    assert np.all(np.abs(fit.K - P) <= 4 * K_se) and np.all(np.abs(fit.B - B) <= 4 * B_se)


def test_symmetric_algorithm1_solves_nine_rotations_exactly():
    from gyrocal.protocols.servo.fit import algorithm1_symmetric, fit_symmetric, symmetric_parameters

    rng = np.random.default_rng(5)
    A = np.eye(3) + 0.02 * rng.standard_normal((3, 3))
    K = (A + A.T) / 2
    B = np.array([0.05, -0.08, 0.03])
    axes = rng.standard_normal((9, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    m = 3.0 * axes @ K.T + B
    fit = fit_symmetric(m, np.full(9, 3.0), tol=1e-14)
    np.testing.assert_allclose(fit.K, K, atol=1e-10)
    np.testing.assert_allclose(fit.B, np.degrees(B), atol=1e-8)
    np.testing.assert_allclose(fit.residuals, 0.0, atol=1e-10)
    batch = algorithm1_symmetric(np.stack([m, m]), np.full((2, 9), 3.0), tol=1e-14)
    C, b = symmetric_parameters(batch.beta)
    np.testing.assert_allclose(np.linalg.inv(C[1]), fit.K, atol=1e-12)
    with pytest.raises(ServoFitError, match="at least 9"):
        fit_symmetric(m[:8], np.full(8, 3.0))


def test_the_servo_calibration_setting_reaches_the_file_and_the_validation(tmp_path):
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.io.errors import ConfigError
    from gyrocal.pipeline.chain import run
    from gyrocal.pipeline.config import Settings

    path = tmp_path / "fixture.parquet"
    write_session(
        make_unit(effect="none", protocol="servo", seed=4), path, session=0, seed=1, misalign_deg=[0.0, 0.0]
    )
    result = run(
        path,
        Settings.from_dict({"protocols": {"servo": {"options": {"calibration": "fixture"}}}}),
        protocol="servo",
    )
    cal, summary = result.calibration, result.validation.summary
    assert cal.extra["servo"]["model"]["used"] == "fixture"
    assert {"misalignment.x.y", "misalignment.z.x"} <= set(cal.grid.names)
    assert summary["servo_model"] == "fixture" and "commanded rate vector" in summary["quantity"]
    # 18 held-out revolutions: the RMS scatters by about 1/√36 of itself; three times that.
    assert summary["validation_rms"] <= 1.5 * summary["expected_rms"]
    assert summary["uncompensated_rms"] > 100 * summary["validation_rms"]
    default = run(path, protocol="servo")
    assert default.calibration.extra["servo"]["model"] == {
        "configured": "auto",
        "used": "seed001",
        "why": default.calibration.extra["servo"]["model"]["why"],
    }
    assert set(default.calibration.grid.names) == {f"{t}.{a}" for t in ("bias", "scale") for a in "xyz"}
    with pytest.raises(ConfigError, match="calibration"):
        Settings.from_dict({"protocols": {"servo": {"options": {"calibration": "full"}}}})


def test_cross_axis_study_says_what_the_terms_cost_and_gain():
    from gyrocal.protocols.servo.montecarlo import cross_axis_study, cross_axis_summary

    df = cross_axis_study(n_sets=4, n_runs=40, noise=0.001)
    pd.testing.assert_frame_equal(df, cross_axis_study(n_sets=4, n_runs=40, noise=0.001))
    s = cross_axis_summary(df).set_index(["mounting", "design", "model"])
    # Three axes never determine the symmetric terms; with six (a 45° wedge) they bring a
    # hand-mounted unit's magnitude to its noise floor, where seed 001's model misses by
    # its cross terms times the diagonal.
    assert s.loc[("hand", "three axes", "symmetric"), "estimated"] == 0
    assert s.loc[("hand", "six axes", "symmetric"), "magnitude_floor"] < 1.5
    assert s.loc[("hand", "six axes", "seed001"), "magnitude_floor"] > 20
    assert s.loc[("hand", "six axes", "auto"), "magnitude_floor"] < 1.5
    # On hand mounts the fixture model takes the tilt for cross terms: worse than none.
    assert (
        s.loc[("hand", "three axes", "fixture"), "magnitude_floor"]
        > 5 * s.loc[("hand", "three axes", "seed001"), "magnitude_floor"]
    )
    # With a fixture every term comes from the off-axis outputs: the vector to its floor
    # (√3 for the three axes' noise), seed 001's model left with the cross terms.
    assert s.loc[("fixture", "three axes", "fixture"), "nominal_floor"] < 2.5
    assert s.loc[("fixture", "three axes", "seed001"), "nominal_floor"] > 50
    # No calibration knows the next hand mount's tilt: against the commanded axis every
    # model stays thousands of times the floor at this noise.
    assert (s.xs("hand")["nominal_floor"].dropna() > 1000).all()
