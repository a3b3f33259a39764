"""The diagnosis on units of the seventh sealed set (benchmarks/sealed7: written by a helper
from the log contract, the papers and the judge's interface, without reading gyrocal; run once
sealed at 9044ae9, a training set since). Each test builds one unit from the set's own
generator and seed and scores the answer against the generator's truth: its reference floor
(the standard calibration's error on the unseen session 2) and the words it expects."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gyrocal.diagnosis.sessions import SHARED_SCALE_DOMINANT, changed_alone, reference_scaled, wanders_most

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

from judge import judge_unit  # noqa: E402  (the benchmark's words for a diagnosis, and session 2)
from sealed7 import generator as sealed7  # noqa: E402


def judged(tmp_path, uid: str, one_session: bool = False) -> tuple[dict, dict, dict]:
    """The unit's truth, the answer (session 2 unseen) and session 0's diagnosis, with
    session 1 as the other session unless ``one_session``."""
    spec = next(s for s in sealed7.plan() if s["uid"] == uid)
    unit = sealed7.build_unit(spec)
    paths = sealed7.write_unit(unit, str(tmp_path))
    answer = judge_unit(paths, "turntable", one_session=one_session, peer=False, keep_diagnosis=True)
    return unit["truth"], answer, answer.pop("diagnosis")


@pytest.mark.slow
def test_an_acceleration_sensitivity_read_from_the_mounts_of_a_log_without_accelerometer(tmp_path):
    """U726: a bias in proportion to the specific force (a full 3 x 3 matrix, changing with
    temperature), six mounts, no accelerometer logged. The turntable's axis points up, so each
    mount says which way gravity lies along the sensor's axes; the g-sensitivity read from it
    is the fix (the grid fits it at each temperature point), and it carries to the unseen
    session within 1.2 times the generator's reference floor. Without the mounts' force it
    was told "the mounting"."""
    truth, answer, d = judged(tmp_path, "U726")
    assert "accel" in truth["reads"] and truth["acts"] == {"bias"}, truth
    assert answer["verdict"] == "fix" and answer["reads"] == ["accel"] and answer["acts_on"] == "bias", answer
    assert "the specific force is the one each mount implies" in d["verdict"], d["verdict"]
    assert answer["next_after_rms"] <= truth["threshold"], (answer, truth)


@pytest.mark.slow
def test_one_scale_every_axis_shares_is_the_reference_though_the_axes_move_a_little(tmp_path):
    """U713: the table's rate read 0.2 % off in session 0 alone. The other session errs 44
    times the floor, nearly all of it one scale the three axes share; the fixture's re-seating
    leaves a little in proportion to the rates beside it (over the white-noise bar, far under
    the shared part). One change of the whole unit fits too, with eleven more parameters: the
    shared scale is the reading, the reference's, fixed in the lab."""
    truth, answer, d = judged(tmp_path, "U713")
    assert truth["reasons"] == ["lab"], truth
    nxt = d["next_session"]
    assert reference_scaled(nxt) and changed_alone(nxt), nxt
    assert nxt["rescaled_shaped_rms"] ** 2 <= (1 - SHARED_SCALE_DOMINANT) * nxt["rate_shaped_rms"] ** 2, nxt
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "lab", answer


@pytest.mark.slow
def test_a_change_one_change_of_the_unit_takes_whole_is_no_slow_noise(tmp_path):
    """U701: the package's axes relaxed after session 0 (a cross-axis change). Session 0's
    residuals do not come back in session 1, which errs 248 times the floor; one change of
    bias, scale and axes takes that failure whole, which hold-by-hold wander would not: the
    unit changed, not slow noise."""
    truth, answer, d = judged(tmp_path, "U701")
    assert truth["reasons"] == ["unit changed"], truth
    assert changed_alone(d["next_session"]), d["next_session"]
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "unit changed", answer


@pytest.mark.slow
def test_a_scale_that_depends_on_the_direction_of_approach(tmp_path):
    """U704: a scale factor with thermal hysteresis (a play of a few °C in the temperature),
    points visited out of order. The grammar's direction of travel, acting on the scale, is
    the fix, offered in a model continuous in temperature (a grid absorbs a state that is one
    value per point). It takes most of the effect's error on the unseen session (29 times the
    reference floor) but not all: 2.8 times the floor is left (the logged temperature lags
    the die's, whose play the generator applies), a gap issue 52 keeps open; the test asks
    for the right story and nine tenths of the excess over the reference floor gone."""
    truth, answer, d = judged(tmp_path, "U704")
    assert truth["reasons"] == ["direction of approach"] and truth["acts"] == {"scale"}, truth
    assert answer["verdict"] == "fix" and "thermal" in answer["reads"] and answer["acts_on"] == "scale", (
        answer
    )
    assert "scale factor that depends on the temperature's direction" in d["verdict"], d["verdict"]
    before, after = answer["next_before_rms"], answer["next_after_rms"]
    assert before - after >= 0.9 * (before - truth["floor"]), (answer, truth)


@pytest.mark.slow
def test_one_log_offers_the_sensor_term_the_mountings_offsets_would_mimic(tmp_path):
    """U726 from one log: offsets per mounting fit the excess whole (each mounting holds
    gravity one way), but the g-sensitivity read from the mounts takes most of the held-out
    error (83 %), which a fixture's seating would not: the mounting is not the answer, the
    term is offered in part, and it carries to the unseen session within 1.2 times the
    generator's reference floor."""
    truth, answer, d = judged(tmp_path, "U726", one_session=True)
    assert "accel" in truth["reads"], truth
    assert d["mounting"]["explains"], d["mounting"]
    assert answer["verdict"] == "fix" and answer["reads"] == ["accel"] and answer["acts_on"] == "bias", answer
    assert "the specific force is the one each mount implies" in d["verdict"], d["verdict"]
    assert answer["next_after_rms"] <= truth["threshold"], (answer, truth)


@pytest.mark.slow
def test_a_failure_that_moves_within_the_other_sessions_points_is_slow_noise(tmp_path):
    """U702: a bias that switches between two levels at random (dwells of tens of minutes).
    The other session's points all lie between session 0's, so no pattern can be compared;
    its errors, 14 times the floor, move within each of its points once the point's own bias
    and rates are out (nearly all of the failure), which no shape in temperature and no
    change of the unit does: slow noise, not a failure between the points."""
    truth, answer, d = judged(tmp_path, "U702")
    assert truth["reasons"] == ["slow noise"], truth
    nxt = d["next_session"]
    assert wanders_most(nxt) and nxt["between_share"] == 1.0, nxt
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "slow noise", answer


@pytest.mark.slow
def test_a_complete_unit_whose_excess_the_user_never_meets_is_quiet(tmp_path):
    """U738, no effect: the in-sample residuals are 3.3 times a floor from within the holds,
    but the points left out err 1.12 times what a correct model leaves and the calibration
    carries to the other session: within the bar a calibration meets on its next session, an
    excess nobody will meet. Quiet, not an unexplained effect."""
    truth, answer, d = judged(tmp_path, "U738")
    assert truth["complete"], truth
    assert d["factor"] > 1.2 and not d["next_session"]["fails_in_practice"], d["next_session"]
    assert answer["verdict"] == "quiet", answer
