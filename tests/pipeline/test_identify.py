"""A term beyond the protocol's own model is kept for a unit only where the unit's data tell
it from that model (gyrocal.pipeline.identify), on units of the independent generator
(benchmarks/zoo): a warm-up added to a unit that has none, to one that has one, and to one
whose bias drifts over the session."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.zoo.generator import make_unit, write_session  # noqa: E402
from gyrocal.calibration.parameters import parameters_at  # noqa: E402
from gyrocal.diagnosis import extended  # noqa: E402
from gyrocal.pipeline.chain import calibrate_observations, segment_log  # noqa: E402
from gyrocal.pipeline.config import Settings  # noqa: E402
from gyrocal.pipeline.identify import MAX_INFLATION  # noqa: E402

# A warm-up as the diagnosis offers it for a unit: time constant searched over 10 s to 4 h.
DECAY = 'expression(label="decay_t", formula="exp(-t / tau)", parameters={"tau": 900.0}, profile={"tau": [10.0, 14400.0]})'
META = {"device": "Z", "protocol": "turntable"}


@pytest.fixture(scope="module")
def units(tmp_path_factory):
    folder = tmp_path_factory.mktemp("identify")
    out = {}
    for effect in ("none", "warmup", "bias_ramp"):
        log = folder / f"{effect}.parquet"
        write_session(
            make_unit(effect=effect, protocol="turntable3", noise="white", seed=3),
            log,
            session=0,
            seed=30,
            rate_hz=25.0,
        )
        out[effect] = segment_log(log, Settings())
    return out


def calibrations(seg, spec):
    """The unit calibrated with the default model and with ``spec`` added."""
    info = dict(noise=seg.info.get("noise"), info=seg.info)
    plain, _ = calibrate_observations(seg.observations, Settings(), meta=META, **info)
    added, _ = calibrate_observations(seg.observations, extended(Settings(), spec), meta=META, **info)
    return plain, added


def test_a_warmup_on_a_unit_without_one_is_dropped_and_its_calibration_is_the_twelve_parameters(units):
    plain, added = calibrations(units["none"], DECAY)
    (record,) = added.extra["added_terms"]
    assert not record["kept"]
    # not identified: its time constant at a bound of the search, or the bias's error exploding
    assert "bound of its search" in record["reason"] or record["inflation"] > MAX_INFLATION
    assert "does not lower the held-out error" in record["reason"]
    assert [t.name for t in added.model.terms] == ["bias", "scale", "misalignment"]
    assert added.grid.values.tolist() == plain.grid.values.tolist()  # the parameters end of line judges
    (warning,) = [w for w in added.extra["warnings"] if w["code"] == "term_dropped"]
    assert "decay_t" in warning["message"]
    # the held-out figure with the term is no better than without it beyond its own spread
    assert record["with"]["excess"] >= 0.9 * record["without"]["excess"]


def test_a_warmup_on_a_unit_with_one_is_kept_and_lowers_the_held_out_error(units):
    plain, added = calibrations(units["warmup"], DECAY)
    (record,) = added.extra["added_terms"]
    assert record["kept"] and "not_identified" not in record, record
    assert record["inflation"] <= MAX_INFLATION
    assert record["with"]["excess"] < 0.5 * record["without"]["excess"]
    assert any(t.name == "expression" for t in added.model.terms)
    assert not [w for w in added.extra["warnings"] if w["code"].startswith("term_")]


def test_a_term_that_helps_though_the_data_cannot_fix_it_is_kept_with_a_warning(units):
    """A bias ramp over the session reads as a decay slower than any the search allows: the
    time constant ends at its bound, but the unit's compensation needs the ramp."""
    plain, added = calibrations(units["bias_ramp"], DECAY)
    (record,) = added.extra["added_terms"]
    assert "bound of its search" in record["not_identified"], record
    assert record["kept"] and record["with"]["excess"] < record["without"]["excess"]
    (warning,) = [w for w in added.extra["warnings"] if w["code"] == "term_not_identified"]
    assert "session" in warning["message"]
    # End of line judges the bias as the session measured it, not the fit's extrapolation:
    # within the errors of the calibration without the term, where the extrapolation is not.
    before, after = (parameters_at(c).set_index("parameter") for c in (plain, added))
    assert "bias_in_session" in added.extra
    bias = [f"bias.{a}" for a in "xyz"]
    shift = (after.loc[bias, "value"] - before.loc[bias, "value"]).abs()
    combined = np.hypot(after.loc[bias, "stderr"], before.loc[bias, "stderr"])
    assert (shift < 3 * combined).all(), (shift, combined)
    fitted = added.coefficients([added.reference_temperature], warn=False)
    assert any(abs(float(fitted[n][0]) - before.loc[n, "value"]) > 3 * combined[n] for n in bias)


def test_a_library_term_on_a_unit_without_its_effect_moves_no_parameter_beyond_its_error(units):
    """scale_quadratic is identified on any turntable session: kept, and the twelve
    parameters stay within their standard errors of the calibration without it."""
    plain, added = calibrations(units["none"], "scale_quadratic")
    (record,) = added.extra["added_terms"]
    assert record["kept"]
    before, after = (parameters_at(c).set_index("parameter") for c in (plain, added))
    shift = np.abs(after["value"] - before["value"]) / after["stderr"]
    assert shift.max() < 3.0, shift.sort_values().tail(3)


def test_two_terms_that_share_one_collinearity_do_not_hide_each_other(units):
    """A decay and a ramp of time added together to a unit with neither: each alone is
    dropped, and neither may stay because the other carries the blame."""
    from gyrocal.pipeline.identify import identify

    ramp = 'expression(label="ramp_t", formula="t / 3600")'
    settings = extended(extended(Settings(), DECAY), ramp)
    found = identify(settings, units["none"].observations, "turntable")
    assert [a.kept for a in found.added] == [False, False], [a.reason for a in found.added]
    assert [t for t in found.settings.model.term_specs()] == ["bias", "scale", "misalignment"]


def test_a_term_whose_input_the_log_lacks_is_dropped_for_that_unit_alone(units):
    obs = units["none"].observations
    bare = obs.drop(columns=[c for c in obs.columns if c.startswith("accel_")])
    bare.attrs.update(obs.attrs)
    cal, _ = calibrate_observations(
        bare,
        extended(Settings(), "g_sensitivity"),
        meta=META,
        noise=units["none"].info.get("noise"),
        checks=False,
    )
    (record,) = cal.extra["added_terms"]
    assert not record["kept"] and "the log lacks what it reads" in record["reason"]


def test_a_continuous_models_terms_of_temperature_are_its_own_not_added(units):
    from gyrocal.pipeline.identify import added_terms

    settings = Settings.from_dict(
        {
            "model": {
                "kind": "continuous",
                "terms": [
                    "bias",
                    "scale",
                    "misalignment",
                    "bias_temp_poly(degree=2)",
                    "scale_temp_poly",
                    "misalignment_temp",
                    "scale_quadratic",
                ],
            }
        }
    )
    assert added_terms(settings, "turntable") == ["scale_quadratic"]


def test_a_term_that_leaves_the_calibration_unvalidated_is_dropped(tmp_path):
    """A step of the bias in temperature, fitted to a sweep without one: the fit takes it,
    but then no one-point calibration can be compared with the sweep's (the point holds too
    little of the step to fit it), so the calibration would reach end of line unvalidated."""
    from gyrocal.diagnosis import extended as extend

    log = tmp_path / "sweep.parquet"
    write_session(
        make_unit(effect="none", protocol="sweep", noise="white", seed=101),
        log,
        session=0,
        seed=101000,
        rate_hz=5.0,
        ramp_c_per_h=30.0,
    )
    settings = extend(Settings().for_protocol("sweep"), "bias_temp_poly")
    seg = segment_log(log, settings, "sweep")
    # its place and width held: profiled, the sharpest width would fit best and the term be
    # dropped at the bound of its search, before its validation is asked
    step = 'expression(label="step_temp", formula="tanh((temp + 20.81 - m) / w)", parameters={"m": 5.69, "w": 4.0})'

    cal, _ = calibrate_observations(
        seg.observations,
        extend(settings, step),
        noise=seg.info.get("noise"),
        meta={"device": "S", "protocol": "sweep"},
        checks=False,
    )
    (record,) = cal.extra["added_terms"]
    assert not record["kept"] and "no temperature point can be left out" in record["reason"], record
    assert record["with"] is None and record["without"]["excess"] is not None


def test_a_term_that_raises_a_units_held_out_error_is_dropped_though_identified(tmp_path):
    """The demo's U004 (a warm-up) given the quadratic scale another unit needs: the fit
    determines it well, but the interpolation between temperature points pays for it, and
    the held-out error rises beyond chance: the term is dropped for this unit."""
    from gyrocal.run.cli import main

    log = tmp_path / "u004.parquet"
    assert (
        main(
            [
                "simulate",
                "--log",
                str(log),
                "--device",
                "U004",
                "--batch",
                "B1",
                "--session",
                "2026-01-07",
                "--preset",
                "quick",
                "--protocol",
                "turntable",
                "--temperatures=-40,-30,-20,-10,0,10,20,30,40,50",
                "--rates=0.1,1,10,50,100,150,200,250,300,400",
                "--effects",
                '{"warmup": [0.3, -0.25, 0.2]}',
            ]
        )
        == 0
    )
    seg = segment_log(log, Settings())
    plain, added = calibrations(seg, "scale_quadratic")
    (record,) = added.extra["added_terms"]
    assert not record["kept"] and "raises the held-out error" in record["reason"]
    assert record["with"]["excess"] > record["without"]["excess"]
    assert added.grid.values.tolist() == plain.grid.values.tolist()
