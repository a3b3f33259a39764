"""Temperature-sweep drift models of seed 003: simulator, windows, models, stability, design."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gyrocal.io.errors import (
    CalibrationFileError,
    ConfigError,
    GyrocalError,
    IdentifiabilityError,
    SegmentationError,
)
from gyrocal.io.log import MOUNTS, RigLog, read_log
from gyrocal.protocols.sweep import (
    DriftModel,
    SweepDesign,
    bias_stability,
    conduction_time,
    fit_drift,
    improvements,
    jump_interval,
    ramp_rate,
    split_sweeps,
    stability_table,
    sweep_windows,
)
from gyrocal.simulate.sweep import SweepProtocol, SweepUnit, render_sweep, sweep_log, sweep_samples

SIGMA = 0.05  # deg/s per sample
CURVED = SweepUnit(
    bias=(1.0, -2.0, 0.5),
    drift_dT=(0.03, -0.02, 0.01),
    drift_dT2=(2e-4, -1.5e-4, 1e-4),
    noise=(SIGMA,) * 3,
    temp_noise=0.02,
)
FLAT = SweepUnit(bias=(1.0, -2.0, 0.5), drift_dT=(0.03, -0.02, 0.01), noise=(SIGMA,) * 3, temp_noise=0.02)
QUICK = SweepProtocol.quick()
WINDOW = 10.0


def log_of(unit, seed, protocol=QUICK):
    return sweep_log(protocol, unit, np.random.default_rng(seed))[0]


@pytest.fixture(scope="module")
def curved():
    logs = [log_of(CURVED, s) for s in (1, 2)]
    return logs, [sweep_windows(g, window_s=WINDOW) for g in logs]


@pytest.fixture(scope="module")
def flat():
    logs = [log_of(FLAT, s) for s in (3, 4)]
    return logs, [sweep_windows(g, window_s=WINDOW) for g in logs]


def within(actual, expected, atol):
    """Per-axis |actual − expected| <= atol, for tolerances that differ by axis."""
    diff = np.abs(np.asarray(actual, dtype=float) - np.asarray(expected, dtype=float))
    assert (diff <= np.asarray(atol)).all(), f"|diff| {diff} exceeds atol {np.asarray(atol)}"


def line_misfit(protocol, unit):
    """Mean square of what a line in ΔT leaves of c2·ΔT², per axis, over the protocol's
    noise-free die temperatures (an independent least-squares fit)."""
    cols, _ = sweep_samples(protocol, SweepUnit(noise=(0.0,) * 3, temp_noise=0.0), np.random.default_rng(0))
    dT = cols["temp"].astype(float) - unit.t_ref
    X = np.column_stack([np.ones_like(dT), dT])
    q = np.outer(dT**2, unit.drift_dT2)
    r = q - X @ np.linalg.lstsq(X, q, rcond=None)[0]
    return np.mean(r * r, axis=0)


# -- the modified model against the conventional one -----------------------------------------


@pytest.mark.parametrize("modified_kind", ["poly", "rbf"])
def test_modified_model_removes_the_dT2_drift_the_conventional_one_leaves(curved, modified_kind):
    (train_log, verify_log), (train, _) = curved
    conv = fit_drift(train, kind="poly", inputs="dT")
    mod = fit_drift(train, kind=modified_kind, inputs="dT,dT2")
    table = stability_table(verify_log, (conv, mod))
    N = len(verify_log)
    s2 = SIGMA**2
    misfit = line_misfit(QUICK, CURVED)
    # BS over N samples of noise σ: sd of BS3 is σ² √(2/N); a fit from m training windows
    # adds about p σ²/N_train on average. BS2 adds the misfit and its cross term with the noise.
    p = len(mod.coef[0])
    bs3_sd = s2 * math.sqrt(2 / N) + p * s2 / len(train_log)
    bs2_sd = np.sqrt(2 * s2**2 / N + 4 * s2 * misfit / N) + 2 * s2 / N
    np.testing.assert_allclose(table["BS3"], s2, rtol=0, atol=5 * bs3_sd)
    within(table["BS2"], s2 + misfit, atol=5 * bs2_sd)
    # The paper's P3 (≈ 10 % there); here the simulated sizes put it near 3-10 %.
    expected_p3 = s2 / (s2 + misfit)
    assert (table["P3"] < 0.2).all()
    within(
        table["P3"], expected_p3, atol=5 * bs3_sd / (s2 + misfit) + 5 * expected_p3 * bs2_sd / (s2 + misfit)
    )


def test_without_dT2_the_two_models_agree_within_noise(flat):
    (train_log, verify_log), (train, _) = flat
    conv = fit_drift(train, kind="poly", inputs="dT")
    s2 = SIGMA**2
    N, N_train = len(verify_log), len(train_log)
    for kind in ("poly", "rbf"):
        mod = fit_drift(train, kind=kind, inputs="dT,dT2")
        table = stability_table(verify_log, (conv, mod))
        np.testing.assert_allclose(table["BS2"], s2, rtol=0, atol=5 * s2 * math.sqrt(2 / N))
        # Both leave the same noise; they differ by their estimation errors δ only: a mean
        # square of about p σ²/N_train each (a χ² with p degrees of freedom: 8 times its mean
        # is beyond its 99.9 % point) and a cross term with the noise of sd 2σ·rms(δ)/√N.
        p = len(mod.coef[0])
        est = p * s2 / N_train
        atol = 8 * est + 5 * 2 * SIGMA * math.sqrt(2 * est) / math.sqrt(N)
        within(table["BS3"], table["BS2"], atol=atol)
        within(table["P3"], 1.0, atol=atol / table["BS2"].min())


def test_poly_fit_recovers_the_drift_coefficients_within_their_standard_errors(curved):
    _, (train, _) = curved
    model = fit_drift(train, kind="poly", inputs="dT,dT2")
    assert model.t_ref == pytest.approx(train.attrs["t_ref"], abs=1e-9)
    # The unit's ΔT counts from −40 °C; the windows' from the first window's temperature.
    shift = model.t_ref - CURVED.t_ref
    c = np.asarray(model.coef)
    truth = np.column_stack(
        [
            CURVED.drift(model.t_ref),
            np.asarray(CURVED.drift_dT) + 2 * np.asarray(CURVED.drift_dT2) * shift,
            CURVED.drift_dT2,
        ]
    )
    se = np.asarray(model.stderr)
    assert (np.abs(c - truth) < 5 * se).all(), (c - truth) / se
    # Independent reference: numpy least squares on the same weighted rows.
    X = np.column_stack([np.ones(len(train)), train["dT"], train["dT"] ** 2])
    w = np.sqrt(train["n"].to_numpy(float))[:, None]
    ref = np.linalg.lstsq(X * w, train[["err_x", "err_y", "err_z"]].to_numpy() * w, rcond=None)[0]
    np.testing.assert_allclose(c, ref.T, rtol=1e-9, atol=1e-12)


def test_models_refuse_data_without_a_temperature_change(curved):
    _, (train, _) = curved
    still = train.assign(temp=-40.0, dT=0.0, dT2=0.0)
    for kind in ("poly", "rbf"):
        with pytest.raises(IdentifiabilityError, match="spans"):
            fit_drift(still, kind=kind, inputs="dT")
    with pytest.raises(ConfigError, match="kind"):
        fit_drift(train, kind="spline", inputs="dT")
    with pytest.raises(GyrocalError, match="non-finite"):
        fit_drift(train.assign(err_x=np.r_[np.nan, train["err_x"].to_numpy()[1:]]), kind="poly", inputs="dT")


# -- train / verify ----------------------------------------------------------------------------


def test_verification_windows_never_enter_the_fit():
    protocol = SweepProtocol.quick(segments=((85.0, 250.0, 300.0), (-40.0, 250.0, 300.0)))
    log = log_of(CURVED, 7, protocol)
    windows = sweep_windows(log, window_s=WINDOW)
    up, down = split_sweeps(windows)
    assert up["t_end"].max() < down["t_start"].min()
    grid = np.linspace(0.0, 120.0, 50)
    for kind in ("poly", "rbf"):
        model = fit_drift(up, kind=kind, inputs="dT,dT2")
        # Corrupt everything after the up sweep: same split, same fit, same predictions.
        altered = windows.copy()
        later = altered["t_start"] >= down["t_start"].min()
        altered.loc[later, ["err_x", "err_y", "err_z"]] *= 10.0
        altered.loc[later, "err_y"] += 3.0
        up2, down2 = split_sweeps(altered)
        again = fit_drift(up2, kind=kind, inputs="dT,dT2")
        assert again.to_dict() == model.to_dict()
        np.testing.assert_array_equal(again.predict(grid), model.predict(grid))
        assert not np.array_equal(down2["err_x"].to_numpy(), down["err_x"].to_numpy())


def test_split_finds_the_up_and_the_down_ramp_each_with_its_own_reference():
    protocol = SweepProtocol.quick(segments=((85.0, 250.0, 300.0), (-40.0, 250.0, 300.0)))
    windows = sweep_windows(log_of(FLAT, 8, protocol), window_s=WINDOW)
    sweeps = split_sweeps(windows)
    assert [s.attrs["direction"] for s in sweeps] == [1, -1]
    assert sweeps[0].attrs["t_ref"] == pytest.approx(-40.0, abs=0.05)  # the stable start
    assert sweeps[1].attrs["t_ref"] > 80.0  # the top of the ramp
    assert sum(len(s) for s in sweeps) == len(windows)
    for s in sweeps:
        np.testing.assert_allclose(s["dT"], s["temp"] - s.attrs["t_ref"], rtol=0, atol=1e-12)
    # A model trained on the up ramp compensates the down ramp through its own t_ref.
    model = fit_drift(sweeps[0], kind="poly", inputs="dT,dT2")
    table = stability_table(sweeps[1], model)
    m = len(sweeps[1])
    s2_window = SIGMA**2 / sweeps[1]["n"].mean()
    # Window means carry σ²/n; m of them scatter by √(2/m) relative; the fit adds p/m_train.
    bound = s2_window * (1 + 5 * math.sqrt(2 / m) + 3 / len(sweeps[0]))
    assert (table["BS2"] < bound).all(), (table["BS2"].to_numpy(), bound)


# -- RBF -----------------------------------------------------------------------------------


def test_rbf_is_deterministic_and_fits_the_drift_to_the_noise_level(curved):
    _, (train, _) = curved
    for inputs in ("dT", "dT,dT2"):
        a = fit_drift(train, kind="rbf", inputs=inputs)
        b = fit_drift(train.copy(), kind="rbf", inputs=inputs)
        assert a.to_dict() == b.to_dict()
        m, p = a.n_train, len(a.coef[0])
        # Residual RMS of a good fit: the window noise, less the p fitted degrees of freedom;
        # the RMS of m residuals scatters by about 1/√(2m) relative.
        expected = np.asarray(a.noise) * math.sqrt(1 - p / m)
        np.testing.assert_allclose(a.residual_rms, expected, rtol=4 / math.sqrt(2 * m))
        # And it follows the true drift: the error at the windows is within the noise a fit
        # of p parameters to m windows leaves (√(p/m) of the window noise), with margin.
        true = CURVED.drift(train["temp"].to_numpy())
        err = a.predict(train) - true
        assert (np.sqrt(np.mean(err**2, axis=0)) < 3 * np.asarray(a.noise) * math.sqrt(p / m)).all()


def test_rbf_layout_follows_the_documented_rule(curved):
    _, (train, _) = curved
    model = fit_drift(train, kind="rbf", inputs="dT", centres=5, width=1.5)
    C = np.asarray(model.centres)[:, 0]
    np.testing.assert_allclose(C, np.linspace(0, 1, 5), rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.widths, [1.5 * 0.25] * 5, rtol=1e-12)
    two = fit_drift(train, kind="rbf", inputs="dT,dT2", centres=4)
    U = np.asarray(two.centres)
    dT = train["dT"].to_numpy()
    g = np.linspace(dT.min(), dT.max(), 4)
    np.testing.assert_allclose(U[:, 0], (g - dT.min()) / np.ptp(dT), rtol=0, atol=1e-12)
    np.testing.assert_allclose(U[:, 1], (g**2 - (dT**2).min()) / np.ptp(dT**2), rtol=0, atol=1e-12)


# -- storage -------------------------------------------------------------------------------


def test_drift_model_round_trips_exactly_through_json(curved):
    _, (train, _) = curved
    grid = np.linspace(-5.0, 130.0, 77)
    for kind in ("poly", "rbf"):
        for inputs in ("dT", "dT,dT2"):
            model = fit_drift(train, kind=kind, inputs=inputs)
            back = DriftModel.from_dict(json.loads(json.dumps(model.to_dict())))
            assert back == model
            np.testing.assert_array_equal(back.predict(grid), model.predict(grid))
            summary = model.summary()
            json.dumps(summary)
            assert len(summary["parameters"]) == 3 * len(model.coef[0])
    broken = fit_drift(train, kind="poly", inputs="dT").to_dict()
    broken["coef"] = broken["coef"][:2]
    with pytest.raises(CalibrationFileError, match="coef"):
        DriftModel.from_dict(broken)
    with pytest.raises(CalibrationFileError, match="format"):
        DriftModel.from_dict({"kind": "poly"})


def test_sweep_unit_and_protocol_round_trip():
    unit = SweepUnit.random(np.random.default_rng(5))
    assert SweepUnit.from_dict(json.loads(json.dumps(unit.to_dict()))) == unit
    p = SweepProtocol.seed003(disturbances=((100.0, 20.0),))
    assert SweepProtocol.from_dict(json.loads(json.dumps(p.to_dict()))) == p
    with pytest.raises(ConfigError):
        SweepUnit(bias=(1.0, 2.0))
    with pytest.raises(ConfigError):
        SweepProtocol(mount="+w")


# -- windows ---------------------------------------------------------------------------------


def tiny_log() -> RigLog:
    """60 s at 2 Hz, rig at 5 deg/s about −y; a gap in window 3, motion in window 5."""
    t = np.arange(120) / 2.0
    keep = ~((t >= 31.0) & (t < 34.0))  # 3-s gap inside window 3 (30-40 s)
    t = t[keep]
    rng = np.random.default_rng(11)
    n = len(t)
    temp = -10.0 + 0.05 * t + rng.normal(0, 0.01, n)
    gyro = np.column_stack([0.2 + 0.01 * (temp + 10), -5.0 + 0.3 + 0.02 * (temp + 10), -0.1 + 0 * t])
    gyro += rng.normal(0, 0.02, (n, 3))
    gyro[(t >= 50) & (t < 53), 0] += 40.0  # a knock in window 5
    batch = {
        "t": t,
        "gyro_x": gyro[:, 0].astype(np.float32),
        "gyro_y": gyro[:, 1].astype(np.float32),
        "gyro_z": gyro[:, 2].astype(np.float32),
        "temp": temp.astype(np.float32),
        "ref_rate": np.full(n, 5.0),
        "mount": np.full(n, MOUNTS.index("-y"), dtype=np.int8),
    }
    return RigLog("tiny", (batch,), n, 0)


def test_windows_match_a_hand_computation_on_a_tiny_log():
    log = tiny_log()
    w = sweep_windows(log, window_s=10.0, min_windows=2, min_span=1.0, settle_windows=0)
    assert w.attrs["dropped"] == {"incomplete": 1, "reference": 0, "mount": 0, "motion": 1}
    assert w["window"].tolist() == [0, 1, 2, 4]
    assert w.attrs["mount"] == "-y" and w.attrs["mount_source"] == "column"
    t = log.column("t")
    for _, row in w.iterrows():
        sel = (t >= 10.0 * row["window"]) & (t < 10.0 * (row["window"] + 1))
        g = np.column_stack([log.column(c)[sel].astype(float) for c in ("gyro_x", "gyro_y", "gyro_z")])
        T = log.column("temp")[sel].astype(float)
        assert row["n"] == sel.sum() == 20
        assert row["t_start"] == t[sel][0] and row["t_end"] == t[sel][-1]
        np.testing.assert_allclose(
            row[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(float), g.mean(axis=0), rtol=0, atol=1e-12
        )
        np.testing.assert_allclose(
            row[["std_x", "std_y", "std_z"]].to_numpy(float), g.std(axis=0, ddof=1), rtol=1e-9, atol=1e-12
        )
        np.testing.assert_allclose(row["temp"], T.mean(), rtol=0, atol=1e-12)
        slope = np.polyfit(t[sel], T, 1)[0] * 60.0
        np.testing.assert_allclose(row["temp_rate"], slope, rtol=1e-8, atol=1e-10)
        expected = g.mean(axis=0) - np.array([0.0, -5.0, 0.0])  # −y mount: gyro_y sees −5
        np.testing.assert_allclose(
            row[["err_x", "err_y", "err_z"]].to_numpy(float), expected, rtol=0, atol=1e-12
        )
    np.testing.assert_allclose(w["dT"], w["temp"] - w["temp"].iloc[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(w["dT2"], w["dT"] ** 2, rtol=0, atol=1e-12)


def test_windows_drop_and_count_motion_gaps_and_reference_changes(tmp_path):
    protocol = SweepProtocol.quick(
        disturbances=((600.0, 30.0),), gaps=((1200.0, 45.0),), rig_rate=10.0, mount="+x"
    )
    path = tmp_path / "sweep.parquet"
    truth = render_sweep(protocol, CURVED, np.random.default_rng(3), path)
    json.dumps(truth)
    log = read_log(path)
    w = sweep_windows(log, window_s=WINDOW)
    dropped = w.attrs["dropped"]
    assert dropped["motion"] >= 3 + 2  # 30 s of handling plus a settling window either side
    for ev in truth["disturbances"] + truth["gaps"]:
        overlap = (w["t_end"] >= ev["t_start"]) & (w["t_start"] < ev["t_end"])
        assert not overlap.any()
    # Windows restart after the logger's pause: the window the pause cuts short is dropped,
    # and the first after it starts at the first sample after it, complete.
    t = log.column("t")
    gap = truth["gaps"][0]
    resumed = t[np.searchsorted(t, gap["t_end"])]
    assert dropped["incomplete"] >= 1
    after = w[w["t_start"] >= resumed]
    assert len(after) > 10
    assert np.all(
        np.isclose(
            (after["t_start"] - resumed) / WINDOW, np.round((after["t_start"] - resumed) / WINDOW), atol=0.02
        )
    )
    # The file and the in-memory log give the same windows.
    mem = sweep_windows(sweep_log(protocol, CURVED, np.random.default_rng(3))[0], window_s=WINDOW)
    pd.testing.assert_frame_equal(w, mem)
    # A reference change mid-log is dropped as such.
    batch = dict(log.batches[0])
    ref = batch["ref_rate"].copy()
    ref[(batch["t"] >= 300) & (batch["t"] < 400)] = 20.0
    batch["ref_rate"] = ref
    w2 = sweep_windows(RigLog("ref", (batch,), len(ref), 0), window_s=WINDOW)
    assert w2.attrs["dropped"]["reference"] == 10


def test_a_log_without_a_sweep_is_refused():
    still = SweepProtocol.quick(segments=((-39.0, 250.0, 600.0),))
    with pytest.raises(SegmentationError, match="temperature spans"):
        sweep_windows(log_of(FLAT, 1, still), window_s=WINDOW)
    with pytest.raises(SegmentationError, match="usable"):
        sweep_windows(log_of(FLAT, 1), window_s=WINDOW, min_windows=10_000)


@given(
    st.lists(
        st.tuples(
            st.floats(0.01, 30.0), st.floats(-50, 100), st.floats(-1e3, 1e3), st.sampled_from([0.0, 0.0, 1.0])
        ),
        min_size=0,
        max_size=60,
    )
)
def test_windows_give_a_table_or_a_gyrocal_error(rows):
    if rows:
        dt, temp, g, ref = (np.asarray(c, dtype=float) for c in zip(*rows, strict=False))
    else:
        dt = temp = g = ref = np.zeros(0)
    batch = {"t": np.cumsum(dt), "gyro_x": g, "gyro_y": -g, "gyro_z": g * 0.5, "temp": temp, "ref_rate": ref}
    try:
        out = sweep_windows(RigLog("h", (batch,), len(dt), 0), window_s=5.0, min_windows=1, min_span=0.5)
    except GyrocalError:
        return
    assert len(out) >= 1 and np.isfinite(out.select_dtypes("number").to_numpy()).all()


# -- stability and design ---------------------------------------------------------------------


def test_bias_stability_and_improvements_follow_eq30_and_the_tables():
    x = np.array([[1.0, 2.0], [3.0, -2.0]])
    np.testing.assert_allclose(bias_stability(x, 1.0), [2.0, 5.0], rtol=1e-15)
    # Table 3, x axis: P1 = BS2/BS1, P2 = BS3/BS1, P3 = P2/P1; BS2 is printed to 4 decimals
    # (±0.9 %), BS3 and the P columns to 4 digits.
    p = improvements(15.3711, 0.0055, 3.885e-4)
    np.testing.assert_allclose(p["P1"], 3.594e-4, rtol=0.01)
    np.testing.assert_allclose(p["P2"], 2.528e-5, rtol=5e-4)
    np.testing.assert_allclose(p["P3"], 0.0703, rtol=0.01)
    with pytest.raises(GyrocalError):
        bias_stability(np.array([[np.nan, 1.0]]))


def test_stability_table_on_windows_and_on_samples(curved):
    (_, verify_log), (train, verify) = curved
    model = fit_drift(train, kind="poly", inputs="dT,dT2")
    on_windows = stability_table(
        verify, {"conventional": fit_drift(train, kind="poly", inputs="dT"), "modified": model}
    )
    assert list(on_windows.columns) == ["BS1", "BS2", "BS3", "P1", "P2", "P3"]
    assert on_windows.attrs["level"] == "windows"
    # Window means carry σ²/n of noise: the modified model's BS on windows is that size.
    n, m = verify["n"].mean(), len(verify)
    np.testing.assert_allclose(on_windows["BS3"], SIGMA**2 / n, rtol=5 * math.sqrt(2 / m) + 3 / len(train))
    single = stability_table(verify_log, model)
    assert list(single.columns) == ["BS1", "BS2", "P1"] and single.attrs["level"] == "samples"
    raw = np.column_stack([verify_log.column(c) for c in ("gyro_x", "gyro_y", "gyro_z")]).astype(float)
    np.testing.assert_allclose(single["BS1"], np.mean(raw**2, axis=0), rtol=1e-12)
    # At rest the reference is 0: BS2 is Eq 30 of the compensated output (Section 3.2 step 4).
    np.testing.assert_allclose(single["BS2"], np.mean(model.compensate(verify_log) ** 2, axis=0), rtol=1e-12)


def test_design_reproduces_the_papers_l3gd20_numbers():
    d = SweepDesign.l3gd20()
    assert d.sensitivity_tc == pytest.approx(0.04, rel=1e-12)
    assert d.jump_interval() == pytest.approx(0.125, rel=1e-12)
    assert jump_interval(8.75e-3, -0.03, 0.04) == pytest.approx(0.125, rel=1e-12)
    # The paper prints 17.5209 s: Eq 24 with C = 1.005 taken in kJ/(kg·K).
    assert d.conduction_time_as_printed() == pytest.approx(17.5209, abs=5e-5)
    assert conduction_time(1005.0, 1.293, 0.6, 0.0267) == pytest.approx(17520.876, abs=1e-3)
    assert ramp_rate(0.1, 20.0) == pytest.approx(18.0, rel=1e-12)
    with pytest.raises(ConfigError):
        SweepDesign.l3gd20().__class__(**{**d.summary()["inputs"], "length": 0.0})


# -- the regenerated paper tables ----------------------------------------------------------------


@pytest.mark.slow
def test_seed003_tables_and_figures(tmp_path):
    from gyrocal.paper import seed003

    tables = seed003.tables(seed=0, quick=True)
    assert [t.name for t in tables] == [
        "Section 3.1 design",
        "Table 2",
        "Table 3",
        "Table 4",
        "Table 5",
        "Table 6",
        "Table 7",
    ]
    for t in tables:
        assert all(math.isfinite(r.regenerated) for r in t.rows) and t.notes
    # Experiments 2-5 (Tables 4-7, rows 2-5 of Table 2): the set-up is solved from their
    # means, so each regenerated BS is as far from the published one as that experiment is
    # from the mean, plus the BS's own scatter over N samples (quick: 1 Hz).
    published = {}
    for t in tables[3:]:
        for r in t.rows:
            if r.published is not None and r.label.split(" / ")[1] in ("BS1", "BS2", "BS3"):
                published.setdefault(r.label, []).append(r.published)
    spread = max(np.max(np.abs(np.asarray(v) / np.mean(v) - 1)) for v in published.values())
    N = 30400
    tol = spread + 5 * math.sqrt(2 / N)
    checked = 0
    for t in tables[1:2] + tables[3:]:
        for r in t.rows:
            if r.published is None or "1st" in r.label or "improvement" in r.label:
                continue
            if t.name != "Table 2" and r.label.split(" / ")[1] not in ("BS1", "BS2", "BS3"):
                continue
            assert abs(r.ratio - 1) <= tol, (t.name, r.label, r.ratio, tol)
            checked += 1
    assert checked == 4 * 2 + 4 * 9
    seed003._study.cache_clear()
    first = [p.read_bytes() for p in seed003.figures(tmp_path / "a", quick=True)]
    seed003._study.cache_clear()
    second = [p.read_bytes() for p in seed003.figures(tmp_path / "b", quick=True)]
    assert first == second and all(b.startswith(b"<svg") for b in first)
