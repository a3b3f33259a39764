"""Drift audit: parameter changes between sessions and re-validation of an old calibration,
on simulated sessions of one unit (quick turntable protocol, three temperatures)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from gyrocal.fleet.drift import parameter_changes, plot_drift, revalidate
from gyrocal.io import failure
from gyrocal.io.errors import ConfigError, InputError
from gyrocal.io.tables import write_table
from gyrocal.pipeline.chain import calibrate_observations, segment_log
from gyrocal.pipeline.config import Settings
from gyrocal.simulate import GyroUnit, TurntableProtocol, simulate_unit

TEMPS = (0.0, 20.0, 40.0)
SHIFT = np.array([0.01, 0.0, -0.02])  # deg/s added to the bias at every temperature
TOLERANCE = {"bias.*": 0.005, "scale.*": 30.0, "misalignment.*": 0.03}  # deg/s, ppm, mrad
STABLE_SEEDS = tuple(range(11, 19))  # 8 units, 96 changes: the χ² check below tells a √2 error in se


def session(directory, unit: GyroUnit, seed: int, date: str, device="D1"):
    """(calibration, observations) of one simulated session."""
    path = directory / f"{device}_{date}_{seed}.parquet"
    simulate_unit(
        path,
        rig=TurntableProtocol.quick(temperatures=TEMPS),
        unit=unit,
        rng=np.random.default_rng(seed),
        device=device,
        session=date,
    )
    settings = Settings()
    seg = segment_log(path, settings)
    meta = {"device": device, "batch": "B1", "session": date, "protocol": "turntable"}
    cal, _ = calibrate_observations(seg.observations, settings, meta=meta)
    return cal, seg.observations


def shifted(unit: GyroUnit) -> GyroUnit:
    bias = np.array(unit.bias_poly)
    bias[:, 0] += SHIFT
    return replace(unit, bias_poly=tuple(map(tuple, bias)))


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("drift")
    unit = GyroUnit.seed000()
    return {
        "first": session(d, unit, 1, "2026-01-10"),
        "second": session(d, unit, 2, "2026-03-10"),
        "shifted": session(d, shifted(unit), 3, "2026-06-10"),
        "stable": [
            (session(d, u, 2 * s, "2026-01-01", f"S{s}"), session(d, u, 2 * s + 1, "2026-02-01", f"S{s}"))
            for s in STABLE_SEEDS
            for u in [GyroUnit.random(np.random.default_rng(s))]
        ],
    }


def test_bias_shift_is_flagged_with_its_size(sessions):
    cals = [sessions[k][0] for k in ("shifted", "first", "second")]  # out of order on purpose
    ch = parameter_changes(cals, tolerance=TOLERANCE)
    assert list(dict.fromkeys(ch["session"])) == ["2026-01-10", "2026-03-10", "2026-06-10"]
    last = ch[ch["session"] == "2026-06-10"].set_index("parameter")
    assert sorted(last.index[last["flagged"]]) == ["bias.x", "bias.z"]
    assert not ch.loc[ch["session"] != "2026-06-10", "flagged"].any()
    for i, a in enumerate("xyz"):
        row = last.loc[f"bias.{a}"]
        # The simulated shift, recovered within three of its standard errors, both ways.
        assert abs(row["change_prev"] - SHIFT[i]) < 3 * row["se_prev"]
        assert abs(row["change_first"] - SHIFT[i]) < 3 * row["se_first"]
        np.testing.assert_allclose(
            row["se_prev"],
            np.hypot(
                row["stderr"],
                ch.set_index(["session", "parameter"]).loc[("2026-03-10", f"bias.{a}"), "stderr"],
            ),
            rtol=1e-12,
        )
    assert last.loc["bias.x", "z_prev"] > 10 and last.loc["bias.z", "z_prev"] < -10
    assert (last["unit"].loc[["bias.x", "scale.x", "misalignment.x.y"]] == ["deg/s", "ppm", "mrad"]).all()
    first = ch[ch["baseline"]]
    assert (first[["change_prev", "z_prev", "se_first"]].to_numpy() == 0).all() and not first["flagged"].any()


def test_tolerance_decides_what_matters(sessions):
    cals = [sessions["first"][0], sessions["shifted"][0]]
    # A specific tolerance wins over the wildcard: 0.02 deg/s on z is within 0.05.
    ch = parameter_changes(cals, tolerance={**TOLERANCE, "bias.z": 0.05})
    assert ch.loc[ch["flagged"], "parameter"].tolist() == ["bias.x"]
    # Without a tolerance any significant change flags (|z| > 3); an insignificant one never.
    ch = parameter_changes(cals, tolerance={})
    assert {"bias.x", "bias.z"} <= set(ch.loc[ch["flagged"], "parameter"])
    assert (ch.loc[ch["flagged"], "z_prev"].abs() > 3).all()


def test_stable_units_are_not_flagged_and_z_is_unit_normal(sessions):
    z = []
    for (a, _), (b, _) in sessions["stable"]:
        ch = parameter_changes([a, b], tolerance=TOLERANCE)
        assert not ch["flagged"].any(), ch.loc[
            ch["flagged"], ["device", "parameter", "change_prev", "z_prev"]
        ]
        z.append(ch.loc[~ch["baseline"], "z_prev"].to_numpy())
    z = np.concatenate(z)
    # If the standard errors are right, Σz² is χ² with one degree per change (99 % bounds;
    # errors of one session instead of both would double it, far beyond the upper bound).
    lo, hi = chi2.ppf([5e-3, 1 - 5e-3], len(z))
    assert lo < np.sum(z**2) < hi


def test_revalidation_holds_for_the_same_unit_and_not_after_a_shift(sessions):
    old = sessions["first"][0]
    same = revalidate(old, sessions["second"][1])
    assert same["holds"] and same["verdict"].startswith("the old calibration still holds (")
    # RMS over N hold-mean errors scatters by about 1/sqrt(2N) around what is expected.
    N = 3 * same["holds_scored"]
    assert abs(same["excess_over_expected"] - 1) < 4 / np.sqrt(2 * N)
    assert same["holds_scored"] == len(sessions["second"][1])
    assert same["table"].shape[0] == 9 and set(same["table"]["rotating"]) == {"x", "y", "z"}

    moved = revalidate(old, sessions["shifted"][1])
    assert not moved["holds"] and moved["verdict"].startswith("the old calibration no longer holds (")
    # The error is the shift on top of the expected: sqrt(expected² + mean(shift²)).
    np.testing.assert_allclose(
        moved["validation_rms"], np.sqrt(moved["expected_rms"] ** 2 + np.mean(SHIFT**2)), rtol=0.1
    )
    table = moved["table"].groupby("output")["interpolated_mean"].mean()
    np.testing.assert_allclose(table[["x", "y", "z"]], SHIFT, atol=1.5e-3)  # ~4σ of a mean of ~60 holds
    assert revalidate(old, sessions["shifted"][1], max_excess=10.0)["holds"]


def test_revalidation_reads_files_and_refuses_servo_and_bad_settings(sessions, tmp_path):
    old, obs = sessions["first"]
    path = tmp_path / "observations.parquet"
    write_table(sessions["second"][1], path, {"info": {}})
    assert revalidate(old, path)["validation_rms"] == revalidate(old, sessions["second"][1])["validation_rms"]
    failure.write([path], failure.record("segment", InputError("no hold passed the checks")))
    with pytest.raises(failure.UpstreamFailure, match="segment failed: no hold passed the checks"):
        revalidate(old, path)
    with pytest.raises(InputError, match="servo"):
        revalidate(replace(old, meta={**old.meta, "protocol": "servo"}), obs)
    with pytest.raises(ConfigError, match="max_excess must be positive"):
        revalidate(old, obs, max_excess=0)
    with pytest.raises(InputError, match="no holds"):
        revalidate(old, obs.iloc[0:0])


def test_changes_refuse_mixed_devices_and_bad_tolerances(sessions):
    a = sessions["first"][0]
    other = sessions["stable"][0][0][0]
    with pytest.raises(InputError, match="one device's sessions, got devices D1, S11"):
        parameter_changes([a, other], tolerance={})
    with pytest.raises(ConfigError, match="'bais.*' names no known term"):
        parameter_changes([a], tolerance={"bais.*": 0.01})
    with pytest.raises(ConfigError, match="must be at least 0"):
        parameter_changes([a], tolerance={"bias.*": -1})


def test_drift_plot_is_deterministic(sessions, tmp_path):
    ch = parameter_changes([sessions[k][0] for k in ("first", "second", "shifted")], tolerance=TOLERANCE)
    ch = ch[ch["parameter"].isin(["bias.x", "bias.z", "misalignment.z.y"])]  # four panels: quick
    path = tmp_path / "drift.svg"
    svg = plot_drift(ch, path)
    assert svg.startswith("<svg") and path.read_text() == svg
    assert plot_drift(ch, None) == svg
    assert svg.count("bias.x, deg/s") == 1 and svg.count("misalignment.z.y, mrad") == 1
