"""End of line: spec limits, verdicts, yield, fleet outliers (calibrations made in memory)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from gyrocal.calibration.file import Calibration, save_calibration
from gyrocal.calibration.parameters import parameter_table, parameters_at
from gyrocal.fit.model import Model
from gyrocal.fit.thermal import ConstantCoefficients, TemperatureGrid
from gyrocal.fleet.eol import Verdict, batch_yield, judge, judge_folder
from gyrocal.fleet.limits import SpecLimits
from gyrocal.fleet.outliers import MAD_Z, fleet_outliers, plot_parameter_distributions
from gyrocal.io import failure
from gyrocal.io.errors import ConfigError, InputError
from gyrocal.io.tables import write_table
from gyrocal.simulate import GyroUnit

from .conftest import truth_coefficients

BIAS_SE, RATIO_SE = 3e-4, 3e-6  # deg/s; 1: typical of a quick turntable session

GOOD = GyroUnit(
    scale=(1.001, 0.999, 1.0005),
    scale_tc=(1e-5, -1e-5, 2e-5),
    misalignment=((0.0, 2e-3, -1e-3), (1.5e-3, 0.0, 5e-4), (-2e-3, 1e-3, 0.0)),
    bias_poly=((0.01, 1e-4, 2e-6, 0.0), (-0.02, -2e-4, -1e-6, 0.0), (0.005, 3e-4, 3e-6, 0.0)),
)

LIMITS = {
    "parameters": {"scale.*": 5000, "bias.*": 0.05, "misalignment.*": 5},
    "temperature_coefficients": {"scale.*": 50, "bias.*": 0.001},
    "validation_rms": 0.005,
    "excess": 1.5,
    "temperature_span": [0, 40],
    "temperature_span_tolerance": 1.0,
    "min_holds": 100,
    "min_hold_share": 0.9,
    "min_temperature_points": 3,
}
GOOD_SUMMARY = {"validation_rms": 0.0024, "excess": 1.05}
GOOD_INFO = {
    "holds_accepted": 189,
    "rejected_by_reason": {"handling_motion": 6, "not_steady": 3},
    "temperature_points": 3,
}


def grid_calibration(unit: GyroUnit, temps=(0.0, 20.0, 40.0), **meta) -> Calibration:
    """The seed-000 model's calibration of ``unit`` as an exact grid (no noise)."""
    model = Model.from_spec()
    names = tuple(model.names)
    values = np.array([[truth_coefficients(unit, t)[n] for n in names] for t in temps])
    stderr = np.tile([BIAS_SE if n.startswith("bias") else RATIO_SE for n in names], (len(temps), 1))
    grid = TemperatureGrid(np.asarray(temps, dtype=float), names, values, stderr)
    meta = {"device": "U1", "batch": "B1", "session": "2026-01-01", "protocol": "turntable", **meta}
    return Calibration(model, grid, 25.0, meta)


def test_parameters_in_engineering_units():
    p = parameters_at(grid_calibration(GOOD)).set_index("parameter")
    np.testing.assert_allclose(p.loc["scale.x", "value"], 1000.0, rtol=1e-9)  # ppm
    np.testing.assert_allclose(p.loc["misalignment.x.y", "value"], 1.001 * 2.0, rtol=1e-9)  # K_xy, mrad
    np.testing.assert_allclose(p.loc["bias.y", "value"], -0.02, rtol=1e-12)  # deg/s
    np.testing.assert_allclose(p.loc["scale.x", "stderr"], RATIO_SE * 1e6, rtol=0.2)  # interpolated


def test_continuous_model_reads_K_and_B_with_propagated_errors():
    """bias.x at T of bias + bias_temp_poly(degree=1) is b + c1 (T − 25) and its error the
    two errors in quadrature; d/dT is c1."""
    model = Model.from_spec(["bias", "scale", "bias_temp_poly(degree=1)"])
    names = tuple(model.names)
    values = {n: 0.0 for n in names} | {"bias.x": 0.02, "bias_temp_poly.x.c1": 3e-4, "scale.x": 1e-3}
    stderr = {n: 1e-6 for n in names} | {"bias.x": 2e-4, "bias_temp_poly.x.c1": 1e-5}
    grid = ConstantCoefficients(
        np.array([0.0, 40.0]),
        names,
        np.array([values[n] for n in names]),
        np.array([stderr[n] for n in names]),
    )
    cal = Calibration(model, grid, 25.0, {"device": "C1"})
    p = parameters_at(cal, 35.0).set_index("parameter")
    np.testing.assert_allclose(p.loc["bias.x", "value"], 0.02 + 3e-4 * 10, rtol=1e-12)
    np.testing.assert_allclose(p.loc["bias.x", "stderr"], np.hypot(2e-4, 10 * 1e-5), rtol=1e-9)
    np.testing.assert_allclose(p.loc["scale.x", "value"], 1000.0, rtol=1e-9)
    v = judge(cal, None, None, SpecLimits.from_dict({"temperature_coefficients": {"bias.x": 2e-4}}))
    assert v.reasons == ("d(bias.x)/dT = 0.0003 deg/s/°C exceeds ±0.0002 deg/s/°C over 0.0 to 40.0 °C",)


def test_unit_inside_spec_passes_with_every_limit_checked():
    limits = SpecLimits.from_dict(LIMITS)
    v = judge(grid_calibration(GOOD), GOOD_SUMMARY, GOOD_INFO, limits)
    assert v.passed and v.reasons == () and v.calibrated
    assert all(c["passed"] for c in v.checked.values())
    # 12 parameters, 6 temperature coefficients (scale, bias), and the six other limits.
    assert len(v.checked) == 12 + 6 + 6
    # The bias curve is quadratic: its largest slope over 0-40 °C is at an end.
    dT = np.array([-25.0, 15.0])
    np.testing.assert_allclose(
        v.checked["d(bias.z)/dT"]["value"], np.max(np.abs(3e-4 + 2 * 3e-6 * dT)), rtol=1e-9
    )
    assert v.checked["min_hold_share"]["value"] == pytest.approx(189 / 192, rel=1e-12)  # not handling
    json.dumps(v.to_dict(), allow_nan=False)


def test_unit_outside_spec_fails_with_every_reason():
    bias = np.array(GOOD.bias_poly)
    bias[1, 0] = 0.08
    bad = replace(
        GOOD, scale=(1.00521, 0.999, 1.0005), scale_tc=(1e-5, -1e-5, 8e-5), bias_poly=tuple(map(tuple, bias))
    )
    cal = grid_calibration(bad, temps=(5.0, 20.0, 40.0))
    v = judge(
        cal,
        {"validation_rms": 0.0123, "excess": 1.2},
        {**GOOD_INFO, "holds_accepted": 80},
        SpecLimits.from_dict(LIMITS),
    )
    assert not v.passed
    assert v.reasons == (
        "bias.y = 0.08 deg/s exceeds ±0.05 deg/s at 25 °C",
        "scale.x = 5210 ppm exceeds ±5000 ppm at 25 °C",
        "d(scale.z)/dT = 80.04 ppm/°C exceeds ±50 ppm/°C over 5.0 to 40.0 °C",  # 1.0005 × 8e-5
        "validation RMS = 0.0123 deg/s exceeds 0.005 deg/s",
        "calibrated span 5.0 to 40.0 °C does not reach 0 °C (tolerance 1 °C)",
        "accepted holds = 80 below the minimum 100",
    )
    failed = sorted(k for k, c in v.checked.items() if not c["passed"])
    assert failed == ["bias.y", "d(scale.z)/dT", "min_holds", "scale.x", "temperature_span", "validation_rms"]


def test_range_limits_and_most_specific_pattern():
    """``scale.x`` has its own range, so ``scale.*``'s ±800 ppm does not apply to it."""
    limits = SpecLimits.from_dict(
        {"parameters": {"scale.*": 800, "scale.x": [900, 1100], "bias.y": [-0.01, 0.0]}}
    )
    v = judge(grid_calibration(GOOD), None, None, limits)
    assert v.checked["scale.x"] == {
        "value": pytest.approx(1000.0, rel=1e-9),
        "limit": [900.0, 1100.0],
        "unit": "ppm",
        "passed": True,
    }
    assert v.reasons == (
        "bias.y = -0.02 deg/s outside [-0.01, 0] deg/s at 25 °C",
        "scale.y = -1000 ppm exceeds ±800 ppm at 25 °C",
    )


def test_limits_that_cannot_be_checked_fail():
    """A single-temperature calibration has no temperature coefficient, a unit without a
    validation summary no RMS, a servo session no rejection counts: each fails, saying so."""
    cal = grid_calibration(GOOD, temps=(22.0,), protocol="servo")
    limits = SpecLimits.from_dict(
        {"temperature_coefficients": {"bias.*": 0.001}, "validation_rms": 0.01, "min_hold_share": 0.5}
    )
    v = judge(cal, None, {"holds_accepted": 6}, limits)
    assert v.reasons == (
        "d(bias.*)/dT not available: calibrated at a single temperature (22.0 °C)",
        "validation RMS not available: no validation summary",
        "accepted hold share not available: the segmentation reports no rejected holds for this protocol",
    )


def test_failed_calibration_fails_and_yield_per_batch():
    limits = SpecLimits.from_dict(LIMITS)

    def ok(device, batch):
        return judge(
            grid_calibration(GOOD, device=device, batch=batch),
            GOOD_SUMMARY,
            GOOD_INFO,
            limits,
        )

    record = failure.record(
        "segment",
        InputError("no hold passed the checks"),
        {"device": "X9", "batch": "B2", "session": "2026-01-02"},
    )
    lost = judge(record, None, None, limits)
    assert not lost.passed and not lost.calibrated
    assert lost.reasons == ("calibration failed: the segment stage failed: no hold passed the checks",)
    bad = judge(
        grid_calibration(GOOD, device="U4"), {"validation_rms": 0.02, "excess": 1.0}, GOOD_INFO, limits
    )
    verdicts = {
        "U1": ok("U1", "B1"),
        "U2": ok("U2", "B1"),
        "U3": ok("U3", "B1"),
        "U4": bad,
        "U5": ok("U5", "B2"),
        "X9": lost,
    }
    y = batch_yield(verdicts)
    assert y.to_dict("records") == [
        {"batch": "B1", "units": 4, "passed": 3, "failed": 1, "no_calibration": 0, "yield_pct": 75.0},
        {"batch": "B2", "units": 2, "passed": 1, "failed": 1, "no_calibration": 1, "yield_pct": 50.0},
    ]


def test_judge_folder_reads_results_and_failure_records(tmp_path):
    limits = SpecLimits.from_dict(LIMITS)
    good = tmp_path / "good"
    good.mkdir()
    cal = grid_calibration(GOOD)
    save_calibration(cal, good / "calibration.json")
    (good / "validation.json").write_text(
        json.dumps({"format": "gyrocal.validation/1", "summary": GOOD_SUMMARY})
    )
    write_table(pd.DataFrame({"hold": [0]}), good / "observations.parquet", {"info": GOOD_INFO})
    assert judge_folder(good, limits).passed
    lost = tmp_path / "lost"
    rec = failure.record("fit", InputError("scale.y not excited"), {"device": "U9", "batch": "B1"})
    failure.write([lost / "calibration.json", lost / "observations.parquet"], rec)
    v = judge_folder(lost, limits)
    assert v.reasons == ("calibration failed: the fit stage failed: scale.y not excited",)
    assert v.meta["device"] == "U9"
    v = judge_folder(tmp_path / "absent", limits)
    assert not v.passed and "no such file" in v.reasons[0]


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"validation_rsm": 0.01}, "unknown setting spec.validation_rsm"),
        ({"parameters": {"sclae.*": 10}}, "'sclae.*' names no known term"),
        ({"parameters": {"scale x": 10}}, "is not a parameter name"),
        ({"parameters": {"scale.*": -1}}, "spec.parameters.scale.* must be positive"),
        ({"parameters": {"bias.x": [0.1, -0.1]}}, "low 0.1 exceeds high -0.1"),
        ({"temperature_coefficients": {"bias.*": [0, 1]}}, "must be a finite number"),
        ({"min_hold_share": 1.5}, "is a share"),
        ({"min_holds": 10.5}, "must be a whole number"),
        ({"temperature_span": [40]}, "must be [low, high]"),
        ({"excess": float("nan")}, "spec.excess must be a finite number"),
        ({"noise": {"white": 1.0}}, "spec.noise must map noise terms"),
        ({"noise": {"arw": -1.0}}, "spec.noise.arw must be positive"),
        (["validation_rms"], "spec must be a mapping"),
    ],
)
def test_spec_limits_refuse_bad_settings(spec, message):
    with pytest.raises(ConfigError, match=None) as err:
        SpecLimits.from_dict(spec)
    assert message in str(err.value)


def test_noise_limits_judge_the_largest_axis_and_fail_without_a_noise_model():
    limits = SpecLimits.from_dict({"noise": {"arw": 0.4, "bias_instability": 10.0}})
    terms = {"arw": [0.30, 0.31, 0.45], "bias_instability": [6.0, 5.5, 7.0]}
    cal = grid_calibration(GOOD)
    cal.extra["noise"] = {"floor": "noise model of the static stretches", "session": terms}
    v = judge(cal, None, None, limits)
    assert not v.passed and v.reasons == (
        "angle random walk = 0.45 deg/√h exceeds 0.4 deg/√h (largest axis)",
    )
    assert v.checked["noise.bias_instability"] == {
        "value": 7.0,
        "limit": 10.0,
        "unit": "deg/h",
        "passed": True,
    }
    bare = judge(grid_calibration(GOOD), None, None, limits)
    assert not bare.passed and len(bare.reasons) == 2
    assert "no noise characterisation" in bare.reasons[0]


def test_spec_limits_round_trip():
    limits = SpecLimits.from_dict({**LIMITS, "noise": {"arw": 0.5}})
    assert SpecLimits.from_dict(limits.to_dict()) == limits
    assert SpecLimits.from_dict(None) == SpecLimits()
    assert judge(grid_calibration(GOOD), None, None, SpecLimits()) == Verdict(
        True, (), {}, {"device": "U1", "batch": "B1", "session": "2026-01-01", "protocol": "turntable"}
    )


# -- outliers -------------------------------------------------------------------------------
def fleet_table(seed=5) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for batch, n in (("B1", 8), ("B2", 8), ("B3", 4)):
        for i in range(n):
            rows.append(
                {
                    "device": f"{batch}-{i}",
                    "batch": batch,
                    "session": "2026-01-01",
                    "scale.x": rng.normal(500, 30),
                    "scale.y": rng.normal(-200, 30),
                    "bias.x": rng.normal(0.0, 0.01),
                }
            )
    table = pd.DataFrame(rows)
    table.loc[table["device"] == "B1-5", "scale.y"] += 400  # > 10 σ from its batch
    table.loc[table["device"] == "B3-1", "bias.x"] = 1.0  # a small batch is not judged
    return table


def reference_z(table: pd.DataFrame) -> pd.DataFrame:
    """The modified z-score computed directly, batch by batch, parameter by parameter."""
    rows = []
    for batch, part in table.groupby("batch"):
        for p in ("scale.x", "scale.y", "bias.x"):
            x = part[p].to_numpy()
            med = np.median(x)
            mad = np.median(np.abs(x - med))
            for device, xi in zip(part["device"], x, strict=False):
                rows.append((batch, device, p, MAD_Z * (xi - med) / mad, len(x)))
    return pd.DataFrame(rows, columns=["batch", "device", "parameter", "z", "count"])


def test_outlier_in_a_batch_of_eight_is_flagged_with_its_parameter():
    table = fleet_table()
    flagged = fleet_outliers(table)
    assert flagged[["device", "parameter"]].values.tolist() == [["B1-5", "scale.y"]]
    ref = reference_z(table)
    expected = ref[(ref["count"] >= 5) & (ref["z"].abs() > 3.5)]
    assert expected[["device", "parameter"]].values.tolist() == [["B1-5", "scale.y"]]
    np.testing.assert_allclose(flagged["z"], expected["z"], rtol=1e-12)
    row = flagged.iloc[0]
    b1 = table.loc[table["batch"] == "B1", "scale.y"]
    np.testing.assert_allclose(
        [row["median"], row["mad"]], [b1.median(), (b1 - b1.median()).abs().median()], rtol=1e-12
    )
    assert list(flagged.columns) == [
        "device",
        "batch",
        "session",
        "parameter",
        "value",
        "median",
        "mad",
        "z",
        "note",
    ]
    # The far larger bias of B3-1 is not flagged: its batch has four units, and says so.
    assert flagged.attrs["small_batches"] == {"B3": 4}
    assert flagged.attrs["notes"] == ["batch B3: 4 units, fewer than 5: no outlier flags"]
    assert fleet_outliers(table, threshold=50.0).empty


def test_outliers_when_mad_is_zero():
    n = 7
    table = pd.DataFrame(
        {
            "device": [f"U{i}" for i in range(n)],
            "batch": "B1",
            "misalignment.x.y": [0.0] * (n - 1) + [0.4],  # one differs
            "fixed": [2.5] * n,  # all identical
            "rounding": [1.0] * (n - 1) + [1.0 * (1 + 1e-13)],
        }
    )  # a rounding step
    flagged = fleet_outliers(table)
    assert flagged[["device", "parameter", "note"]].values.tolist() == [
        ["U6", "misalignment.x.y", "differs from identical others"]
    ]
    assert flagged["z"].iloc[0] == np.inf and flagged["mad"].iloc[0] == 0.0


def test_outliers_skip_missing_values_and_need_the_batch_column():
    table = fleet_table()
    table.loc[table["batch"] == "B2", "bias.x"] = np.nan  # e.g. a model without the term
    table.loc[table["device"] == "B2-0", "bias.x"] = 5.0
    flagged = fleet_outliers(table)
    assert flagged["device"].tolist() == ["B1-5"]
    assert "batch B2: bias.x known for fewer than 5 units: not checked" in flagged.attrs["notes"]
    with pytest.raises(InputError, match="no column 'lot'"):
        fleet_outliers(table, by="lot")


def test_parameter_table_and_distribution_plot(tmp_path):
    cals = [grid_calibration(GOOD, device=f"U{i}") for i in range(5)]
    cals.append(grid_calibration(replace(GOOD, scale=(1.004, 0.999, 1.0005)), device="U5"))
    table = parameter_table(cals)
    assert table.shape == (6, 3 + 12)
    flagged = fleet_outliers(table)
    # K = diag(s)(I + M): a scale factor carries its row's cross-axis terms along.
    assert flagged[["device", "parameter"]].values.tolist() == [
        ["U5", "scale.x"],
        ["U5", "misalignment.x.y"],
        ["U5", "misalignment.x.z"],
    ]
    assert set(flagged["note"]) == {"differs from identical others"}
    path = tmp_path / "dist.svg"
    table = table[["device", "batch", "session", "bias.x", "scale.x", "misalignment.x.y", "misalignment.x.z"]]
    svg = plot_parameter_distributions(table, flagged, path)
    assert svg.startswith("<svg") and path.read_text() == svg
    assert plot_parameter_distributions(table, flagged, None) == svg  # deterministic
    assert svg.count(">U5<") == 3  # labelled in each panel that flags it, and only it


def test_end_of_line_can_fail_a_unit_on_its_plausibility_warnings():
    cal = grid_calibration(GOOD)
    warning = {
        "code": "temperature_dropout",
        "message": "temp is missing in 17% of the rows",
        "evidence": {"share": 0.17},
    }
    cal.extra["warnings"] = [warning]
    assert judge(cal, GOOD_SUMMARY, GOOD_INFO, SpecLimits()).passed  # not asked: not judged
    verdict = judge(cal, GOOD_SUMMARY, GOOD_INFO, SpecLimits.from_dict({"fail_on_warnings": True}))
    assert not verdict.passed
    assert verdict.reasons == (
        "plausibility warning temperature_dropout: temp is missing in 17% of the rows",
    )
    assert verdict.checked["warnings"] == {
        "value": ["temperature_dropout"],
        "limit": True,
        "unit": None,
        "passed": False,
    }
    other = SpecLimits.from_dict({"fail_on_warnings": ["accel_units", "sample_jitter"]})
    assert judge(cal, GOOD_SUMMARY, GOOD_INFO, other).passed
    assert SpecLimits.from_dict(other.to_dict()) == other
    with pytest.raises(ConfigError, match="'accel_unit' is no warning code"):
        SpecLimits.from_dict({"fail_on_warnings": ["accel_unit"]})


def test_the_fleet_summary_reads_each_unit_once_and_a_broken_unit_fails_alone(tmp_path):
    """A calibrated unit (its parts packed), a unit whose fit failed, one whose validation
    is not JSON and one whose diagnosis is not: the summary lists all four, the unreadable
    validation as that unit's failure naming the part, the unreadable diagnosis as its
    calibrated unit's note."""
    from gyrocal.fleet.summary import fleet_summary
    from gyrocal.io.unit_folder import pack_stage

    def unit(name, validation=None, diagnosis=None, cal=None):
        folder = tmp_path / name
        folder.mkdir()
        save_calibration(cal or grid_calibration(GOOD, device=name), folder / "calibration.json")
        (folder / "validation.json").write_text(
            validation or json.dumps({"format": "gyrocal.validation/1", "summary": GOOD_SUMMARY})
        )
        if diagnosis is not None:
            (folder / "diagnosis.json").write_text(diagnosis)
        write_table(pd.DataFrame({"hold": [0]}), folder / "observations.parquet", {"info": GOOD_INFO})
        pack_stage(folder, "segment")
        pack_stage(folder, "analyse")
        return {
            "row": {"batch": "B1", "device": name, "session": "2026-01-01", "protocol": "turntable"},
            "folder": folder,
            "report": f"{name}.html",
        }

    units = [
        unit(
            "OK",
            diagnosis=json.dumps({"format": "gyrocal.diagnosis/1", "best": None, "explains_the_data": True}),
        ),
        unit("BADVAL", validation="{not json"),
        unit("BADDIAG", diagnosis="[1, 2"),
    ]
    lost = tmp_path / "LOST"
    rec = failure.record("fit", InputError("scale.y not excited"), {"device": "LOST"})
    failure.write([lost / "calibration.json", lost / "validation.json", lost / "observations.parquet"], rec)
    pack_stage(lost, "segment")
    pack_stage(lost, "analyse")
    units.append(
        {
            "row": {"batch": "B1", "device": "LOST", "session": "2026-01-01", "protocol": "turntable"},
            "folder": lost,
            "report": "LOST.html",
        }
    )
    rows = {r["device"]: r for r in fleet_summary(units)["rows"]}
    assert rows["OK"]["status"] == "ok" and rows["OK"]["missing"] == "nothing"
    assert rows["OK"]["summary"] == GOOD_SUMMARY
    assert (rows["LOST"]["status"], rows["LOST"]["stage"]) == ("failed", "fit")
    assert rows["BADVAL"]["status"] == "failed" and "analysis.zip/validation.json" in rows["BADVAL"]["error"]
    assert "not valid JSON" in rows["BADVAL"]["error"]
    assert rows["BADDIAG"]["status"] == "ok"
    assert rows["BADDIAG"]["missing"].startswith("diagnosis unreadable:")


def test_every_planned_drift_page_is_made_with_what_it_could_not_compare(tmp_path):
    """The drift pages are planned before the run, from the manifest and the registry's
    earlier sessions (drift_devices): a device whose second session fails, or whose earlier
    session's file changed since it was registered, still gets its audit, which names them."""
    from gyrocal.fleet.summary import FleetSettings, drift_devices, fleet_summary

    def unit(device, session, ok=True):
        folder = tmp_path / device / session
        row = {"batch": "B1", "device": device, "session": session, "protocol": "turntable"}
        if ok:
            folder.mkdir(parents=True)
            save_calibration(
                grid_calibration(GOOD, device=device, session=session), folder / "calibration.json"
            )
            (folder / "validation.json").write_text(
                json.dumps({"format": "gyrocal.validation/1", "summary": GOOD_SUMMARY})
            )
            write_table(pd.DataFrame({"hold": [0]}), folder / "observations.parquet", {"info": GOOD_INFO})
        else:
            rec = failure.record("fit", InputError("scale.y not excited"), {"device": device})
            failure.write([folder / "calibration.json", folder / "validation.json"], rec)
        return {"row": row, "folder": folder, "report": f"{device}/{session}.html"}

    units = [unit("A1", "2026-01-01"), unit("A1", "2026-03-01", ok=False), unit("C1", "2026-03-01")]
    changed = {
        "device": "C1",
        "batch": "B0",
        "session": "2025-12-01",
        "protocol": "turntable",
        "path": "B0/C1/2025-12-01/calibration.json",
        "file_hash": "0" * 64,
        "problem": "changed since it was registered (its hash differs)",
    }
    foreign = {**changed, "device": "Z9"}  # a device this run does not hold: no page
    planned = drift_devices([u["row"] for u in units], [changed, foreign])
    assert planned == ["A1", "C1"]
    audits = fleet_summary(units, FleetSettings(), [changed, foreign])["fleet"]["drift"]
    assert [a["device"] for a in audits] == planned
    a1, c1 = audits
    assert a1["sessions"] == ["2026-01-01"]
    assert a1["error"] == "fewer than two calibrated sessions to compare: 2026-03-01 did not calibrate"
    assert c1["sessions"] == ["2026-03-01"] and "2025-12-01 (an earlier run's): changed since" in c1["error"]
    assert c1["earlier"] == [{k: changed[k] for k in ("session", "batch", "path", "file_hash")}]
