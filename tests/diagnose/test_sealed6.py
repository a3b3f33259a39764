"""The diagnosis on units of the sixth sealed set (benchmarks/sealed6: written by a helper from
the log contract, the papers and the judge's interface, without reading gyrocal; run once
sealed at 9f271a5, a training set since). Each test builds one unit from the set's own
generator and seed and scores the answer against the generator's truth: its reference floor
(the standard calibration's error on the unseen session 2) and the words it expects."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gyrocal.diagnosis.lab import MOUNTING_DOMINANT, RIVAL_HALF
from gyrocal.diagnosis.naming import MOST
from gyrocal.diagnosis.sessions import changed_alone, fails_between_only, offset_alone, white_bar

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

from judge import judge_unit  # noqa: E402  (the benchmark's words for a diagnosis, and session 2)
from sealed6 import generator as sealed6  # noqa: E402


def built(uid: str) -> dict:
    """The set's unit ``uid`` as its runner builds it (master seed, three units a family)."""
    spec = next(s for s in sealed6.plan() if s["uid"] == uid)
    return sealed6.build_unit(spec)


def judged(tmp_path, uid: str, one_session: bool = False) -> tuple[dict, dict, dict]:
    """The unit's truth, the answer (session 2 unseen) and session 0's diagnosis, with
    session 1 as the other session unless ``one_session``."""
    unit = built(uid)
    paths = sealed6.write_unit(unit, str(tmp_path))
    answer = judge_unit(paths, "turntable", one_session=one_session, peer=False, keep_diagnosis=True)
    return unit["truth"], answer, answer.pop("diagnosis")


@pytest.mark.slow
def test_a_warm_up_is_no_power_on_at_every_gap_of_the_log(tmp_path):
    """S6U17: a bias decaying with time since the session's one power-on (time constants of
    tens of minutes to hours), logged in stretches between unlogged soaks. Each stretch of the
    other session misses by its own offset (up to 1.4 deg/s, 70 times the floor) and still
    drifts within it; offsets per stretch would read as power-ons only if what they leave
    were white noise, and it is not, so the failure stays open however faint the held-out
    error of this session. A shape of time since power-on takes it: the fix carries to the
    unseen session within 1.2 times the generator's reference floor."""
    truth, answer, d = judged(tmp_path, "S6U17")
    assert truth["family"] == "warmup" and truth["reads"] == {"time"}, truth
    nxt = d["next_session"]
    assert nxt["power_ons"] > 1 and nxt["rezeroed_rms"] > white_bar(nxt) and not offset_alone(nxt), nxt
    assert nxt["fails_in_practice"], nxt
    assert answer["verdict"] == "fix" and "time" in answer["reads"] and answer["acts_on"] == "bias", answer
    assert answer["next_after_rms"] <= truth["threshold"], (answer, truth)


@pytest.mark.slow
def test_a_failure_between_the_points_where_the_points_carry(tmp_path):
    """S6U32: a bias bump centred between two of session 0's temperature points. The other
    session visits two of those points and three between: at the shared points its
    calibration carries over, between them it errs up to 0.2 deg/s. The unit did not change
    and no offset per stretch reads it (two stretches at one point share their offset): the
    calibration does not hold between its points."""
    truth, answer, d = judged(tmp_path, "S6U32")
    assert truth["family"] == "between" and truth["reasons"] == {"between points"}, truth
    nxt = d["next_session"]
    assert fails_between_only(nxt), nxt
    assert "carries over at this session's temperature points" in d["verdict"], d["verdict"]
    assert answer["next_before_rms"] > truth["threshold"], (answer, truth)  # a failure the user meets
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "between points", answer


@pytest.mark.slow
def test_one_log_offers_a_term_of_the_rate_beside_the_curvature_three_points_miss(tmp_path):
    """S6U18, one log: a scale that compresses smoothly with the rate (a cubic), under a die
    warming with each hold's turning, on three temperature points. Left out, the middle point
    is read by the line through the others where the calibration runs a parabola: most of its
    error is the temperature curvature a correct model has (the drift chord, counted in what
    a correct model leaves). Beyond it, the library's cubic scale takes all of the excess and
    is offered first; it carries to the unseen session within 1.2 times the generator's
    reference floor."""
    truth, answer, d = judged(tmp_path, "S6U18", one_session=True)
    assert truth["family"] == "rate_knee" and truth["acts"] == {"scale"}, truth
    assert d["drift_chord_rms"] > 0.5 * d["validation_rms"], d
    first = d["partial"][0]
    assert first["offered"] and first["excess_taken"] >= MOST, first
    assert "a line where it runs a parabola" in d["verdict"], d["verdict"]
    assert answer["verdict"] == "fix" and answer["acts_on"] == "scale" and "rate" in answer["reads"], answer
    assert answer["next_after_rms"] <= truth["threshold"], (answer, truth)


@pytest.mark.slow
def test_the_fixtures_seating_takes_nearly_all_where_no_rival_takes_half(tmp_path):
    """S6U26: each placement of the unit on its fixture seats it at its own tilt (28
    placements), 51 times the floor in sample. One offset and one misalignment per placement
    take nearly all of the excess, while the best rival (one per mount for the session, a
    drift within each point, the temperature's direction, a power-on in each gap of the log)
    takes about a third: the mounting
    is the answer though what it leaves is not within chance (the rig's other scatter)."""
    truth, answer, d = judged(tmp_path, "S6U26")
    assert truth["family"] == "seat" and truth["reasons"] == {"mounting"}, truth
    m = d["mounting"]
    assert m["left_p_value"] < 1e-3 and m["share_of_excess"] >= MOUNTING_DOMINANT, m
    assert m["rival_share"] < RIVAL_HALF, m
    assert m["explains"], m
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "mounting", answer


@pytest.mark.slow
def test_one_change_for_the_whole_other_session_is_the_unit_changing(tmp_path):
    """S6U21: between sessions the unit's scales and biases changed (tens of ppm, a few
    mdeg/s), and the other session visits only temperatures between this one's points. Its
    calibration errs there over a hundred times the floor, and no term fitted to this
    session takes a practical part of that; one change of bias, scale and axes, the same at
    each of its temperatures, brings it within the bar, which a shape of the sensor between
    the points would not: the unit changed between the sessions."""
    truth, answer, d = judged(tmp_path, "S6U21")
    assert truth["family"] == "changed" and truth["reasons"] == {"unit changed"}, truth
    nxt = d["next_session"]
    assert nxt["fails_in_practice"] and changed_alone(nxt), nxt
    assert d["unexplained"]["reason"] == "does not carry over", d["verdict"]
    assert "one change of bias, scale and axes" in d["verdict"], d["verdict"]
    assert answer["verdict"] == "no_sensor_term" and answer["reason"] == "unit changed", answer


@pytest.mark.slow
def test_one_log_names_a_rate_term_every_axis_shares_as_the_references_or_the_sensors(tmp_path):
    """S6U29 from one log: the table droops at its highest rates during this session only,
    which every axis reads in turn as one cubic scale error of the same sign and size. The
    cubic scale takes a practical part of the excess, but a term the same on every axis is
    what the reference rate's error gives: it is not offered at its grain, and the verdict
    says one log cannot tell the table's from the sensor's (offered, it made the unseen
    session, on a true table, worse)."""
    truth, answer, d = judged(tmp_path, "S6U29", one_session=True)
    assert truth["family"] == "table" and truth["reasons"] == {"lab"}, truth
    first = d["partial"][0]
    assert first["term"] == "scale_cubic" and not first["offered"], first
    assert "the same on every axis" in d["verdict"] and "cannot tell the two apart" in d["verdict"]
    assert answer["verdict"] != "fix", answer
