"""The diagnosis on units of a second independent generator (benchmarks/open2: written by a
helper from the log contract, the papers and the judge's interface, without reading gyrocal),
each judged against that generator's truth or on the session the diagnosis never saw.

Its nuisances are what every real unit carries and what the project's own simulator and the
first zoo did not: a turn-on bias of about one hold-mean floor at each power-on, bias
instability, door upsets at each remount. Its families include a table whose reference rate
reads a scale apart in one session, a bias bump in temperature between the points, a thermal
backlash, a fixture that tilts the unit anew at each mounting and a bias from the fixture's
thermal gradient under shorter soaks.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gyrocal.diagnosis import diagnose
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

from judge import _answer  # noqa: E402  (the benchmark's words for a diagnosis)
from open2.generator import generate_unit, make_units  # noqa: E402

PROTOCOL = "turntable"
NEXT_SESSION_LIMIT = 1.2  # the target for a fix on the unseen session


def open2_unit(tmp_path, name: str):
    """The runner's unit ``name`` (its default seed), its three logs and its truth."""
    family = name.rsplit("_", 1)[0].removeprefix("o2_")
    unit = next(u for u in make_units(families=[family]) if u["name"] == name)
    paths, truth, _ = generate_unit(unit, str(tmp_path))
    return [Path(p) for p in paths], truth


def next_session_rms(logs, offer: dict) -> float:
    """Session 0 calibrated with the offer's terms, judged on session 2: its hold-mean RMS
    (deg/s)."""
    from gyrocal.diagnosis import extended
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run

    settings = Settings().for_protocol(PROTOCOL)
    for term in (offer["term"], *offer.get("together", [])):
        settings = extended(settings, term)
    cal = run(logs[0], settings, protocol=PROTOCOL).calibration
    return revalidate(cal, segment_log(logs[2], settings, PROTOCOL).observations)["validation_rms"]


def diagnosed(logs, two_sessions: bool) -> dict:
    settings = Settings().for_protocol(PROTOCOL)
    obs = segment_log(logs[0], settings, PROTOCOL).observations
    other = segment_log(logs[1], settings, PROTOCOL).observations if two_sessions else None
    return diagnose(settings, obs, other).to_dict()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["o2_complete_0", "o2_complete_3"])
def test_a_complete_unit_with_a_turn_on_bias_is_quiet_in_both_modes(name, tmp_path):
    """A complete unit whose bias moves by about one hold-mean floor at each power-on, with
    bias instability besides: quiet from one log and from two sessions. The other session's
    error beyond the floor is an offset per axis, the power-on's bias, which no calibration
    carries; without it the calibration carries within the issue's bar."""
    logs, _ = open2_unit(tmp_path, name)
    for two in (False, True):
        d = diagnosed(logs, two)
        assert _answer(d)["verdict"] == "quiet", d["verdict"]
    nxt = d["next_session"]
    assert not nxt["fails_in_practice"], d["verdict"]
    assert nxt["rezeroed_rms"] <= NEXT_SESSION_LIMIT * nxt["expected_rms"] * 1.05, nxt


@pytest.mark.slow
def test_a_reference_rate_read_with_a_scale_error_is_told_as_the_labs(tmp_path):
    """The table's tachometer reads one session's rates a scale apart: the calibration of that
    session fails on the other by one scale every axis shares, which the verdict tells as the
    lab's (not "the unit changed"), with the scale the generator put in: the calibration's
    rates read 1 + ε times the true ones where the reference read 1 + ε, within the table's ripple (2e-5 of the
    rate) and its jitter."""
    logs, truth = open2_unit(tmp_path, "o2_table_tach_scale_2")
    d = diagnosed(logs, True)
    assert _answer(d)["reason"] == "lab", d["verdict"]
    from open2.generator import effect_params

    unit = next(u for u in make_units(families=["table_tach_scale"]) if u["name"] == "o2_table_tach_scale_2")
    eps = effect_params(unit["seed"], "table_tach_scale")["sign"] * 1e-3 * truth["amp"]
    assert abs(d["next_session"]["reference_scale"] - eps) <= 3e-5, (eps, d["next_session"])


@pytest.mark.slow
def test_a_bump_between_the_points_is_told_where_the_other_session_visits_between_them(tmp_path):
    """A bias bump in temperature between the set points; the other session visits only the
    temperatures between this one's: no pattern can be compared, and the verdict says the
    calibration does not hold between its points (or the unit changed), not a bare change."""
    logs, _ = open2_unit(tmp_path, "o2_mode_crossing_1")
    d = diagnosed(logs, True)
    assert _answer(d)["reason"] == "between points", d["verdict"]
    # the other session's sentence claims no cause the why then hedges
    assert "the unit changed between sessions (" not in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_a_thermal_backlash_is_told_by_the_direction_each_point_was_reached_from(tmp_path):
    """A play operator of the temperature (5-8 °C wide) on the bias; the other session visits
    the points the other way round, so three of five are reached from the other side: the
    errors there step with the direction, within the bar a hold may err once the step and an
    offset are taken out."""
    logs, _ = open2_unit(tmp_path, "o2_thermal_play_1")
    d = diagnosed(logs, True)
    assert _answer(d)["reason"] == "direction of approach", d["verdict"]
    assert d["approach"]["explains"] and len(d["approach"]["points"]) == 3, d["approach"]


@pytest.mark.slow
def test_a_fixture_that_tilts_the_unit_at_each_mounting_is_the_mountings(tmp_path):
    """Six mounts, each mounting tilting the unit by a new angle: the turning rate leaks into
    the other outputs by a misalignment of each mounting's own, which a misalignment per
    mounting holds and per mount, per point's drift or per direction does not."""
    logs, _ = open2_unit(tmp_path, "o2_fixture_reseat_0")
    for two in (False, True):
        d = diagnosed(logs, two)
        assert _answer(d)["reason"] == "mounting", d["verdict"]


@pytest.mark.slow
def test_a_misalignment_growing_with_the_rate_keeps_its_sign(tmp_path):
    """A cross-axis term ω_b |ω_b| (odd in the turning rate): the grammar's square with its
    sign is offered from one log and brings the unseen session within the issue's bar of the
    generator's floor (what its complete unit leaves there, turn-on bias included)."""
    logs, truth = open2_unit(tmp_path, "o2_cross_rate_square_1")
    d = diagnosed(logs, False)
    assert d["best"] is not None and "signed_square" in d["best"]["term"], d["verdict"]
    assert next_session_rms(logs, d["best"]) <= NEXT_SESSION_LIMIT * truth["floor_ref"]


@pytest.mark.slow
def test_an_excess_the_other_session_does_not_repeat_is_searched_before_it_is_called_noise(tmp_path):
    """A bias from the fixture's thermal gradient, with a soak half as long in this session
    as in the other: the pattern differs between the sessions, but a term of the temperature's
    history explains this one and carries to the other, so it is offered, not called slow
    noise."""
    logs, _ = open2_unit(tmp_path, "o2_fixture_heat_flux_2")
    d = diagnosed(logs, True)
    answer = _answer(d)
    assert answer["verdict"] == "fix" and "thermal" in answer["reads"], d["verdict"]
    assert not d["unrepeated"]


@pytest.mark.slow
def test_a_charge_that_decays_after_turning_is_the_fix_not_the_floor(tmp_path):
    """A bias that the turns' magnitude charges and that decays over half a minute after
    them: it decays through the static stretches after each turn too, where it once passed
    for rate random walk and raised this session's floor by an order of magnitude. The
    stretches' drifts follow the turn before them, so the floor is the white noise's, the
    sessions' floors agree, and the lag of the rate's magnitude, offered from one log, brings
    the unseen session within the issue's bar of the generator's floor."""
    logs, truth = open2_unit(tmp_path, "o2_exposure_charging_0")
    settings = Settings().for_protocol(PROTOCOL)
    seg = segment_log(logs[0], settings, PROTOCOL)
    drift = seg.info["noise"]["session"]["motion_drift"]
    assert any(drift["follows"]), drift
    assert float(seg.observations["rrw_x"].max()) == 0.0
    d = diagnosed(logs, True)
    assert d["floors_differ"] is None, d["verdict"]
    d = diagnosed(logs, False)
    offer = d["best"] or d["partial"][0]
    assert "lag(" in offer["term"], d["verdict"]
    assert next_session_rms(logs, offer) <= NEXT_SESSION_LIMIT * truth["floor_ref"]


@pytest.mark.slow
def test_a_bias_that_jumps_in_one_sessions_static_data_makes_the_floors_differ(tmp_path):
    """A bias that jumps between two levels every few minutes (popcorn): this session's
    static data caught jumps, the other's did not, so the other's floor is a tenth of this
    one's. The verdict states that finding and names no change of the unit. (Its errors fail
    against the other session's white floor and lie within the slow wander its static data
    cannot rule out, so the calibration carries and the benchmark's judge reads the verdict as
    quiet, not "slow noise": complete units on a rig with slow wander make the floors differ
    by as much, the nuisance set's N031 by 0.15.)"""
    logs, _ = open2_unit(tmp_path, "o2_popcorn_bias_2")
    d = diagnosed(logs, True)
    assert d["floors_differ"]["ratio"] < 0.2, d["floors_differ"]
    assert "The other session's noise floor, from its own static data, is" in d["verdict"]
    assert "the unit changed" not in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_a_tilt_at_each_mounting_with_every_point_mounted_anew_is_the_mountings(tmp_path):
    """A fixture that tilts the unit anew at each mounting, on a rig whose every temperature
    point mounts the unit afresh and with no accelerometer logged: each point's calibration
    absorbs its own tilt, so what fails is the misalignment interpolated between points
    while the scale meets its interpolation. Read with the mountings, it is the mounting's,
    from one log and from two sessions."""
    logs, _ = open2_unit(tmp_path, "o2_fixture_reseat_2")
    for two in (False, True):
        d = diagnosed(logs, two)
        assert _answer(d)["reason"] == "mounting", d["verdict"]
        assert "unit changed" not in d["verdict"]


@pytest.mark.slow
def test_a_clamp_that_relaxes_after_each_mounting_is_read_by_the_time_since_it(tmp_path):
    """A bias that relaxes over one to two minutes after each mounting (the clamp settling):
    the grammar's decay of the time since the mounting takes most of the excess, from one
    log and from two sessions (where the pattern, in another mounting order, does not repeat
    by hold and so once read as slow noise), and takes most of the unseen session's error
    (more than the half a partial offer must take)."""
    logs, truth = open2_unit(tmp_path, "o2_clamp_relaxation_2")
    settings = Settings().for_protocol(PROTOCOL)
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run

    before = revalidate(
        run(logs[0], settings, protocol=PROTOCOL).calibration,
        segment_log(logs[2], settings, PROTOCOL).observations,
    )["validation_rms"]
    for two in (False, True):
        d = diagnosed(logs, two)
        offer = d["best"] or d["partial"][0]
        assert offer.get("offered", True) and "t_mount" in offer["term"], d["verdict"]
        assert not d["unrepeated"]
        after = next_session_rms(logs, offer)
        assert before - after > 0.5 * (before - truth["floor_ref"]), (before, after)


@pytest.mark.slow
def test_a_clamp_relaxation_the_decay_explains_is_named_by_its_input(tmp_path):
    """Where the decay of the time since the mounting explains the excess (with the library's
    g-sensitivity beside it), the fix is named, its shape told against the time since the
    mounting, and it takes most of the unseen session's error beyond the generator's floor
    (on this unit 4.5 → 1.26 times that floor: the issue's bar of 1.2 is not met)."""
    logs, truth = open2_unit(tmp_path, "o2_clamp_relaxation_0")
    d = diagnosed(logs, False)
    assert d["best"] is not None and "t_mount" in d["best"]["term"], d["verdict"]
    assert "time since the mounting" in d["verdict"]
    settings = Settings().for_protocol(PROTOCOL)
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run

    unseen = segment_log(logs[2], settings, PROTOCOL).observations
    before = revalidate(run(logs[0], settings, protocol=PROTOCOL).calibration, unseen)["validation_rms"]
    after = next_session_rms(logs, d["best"])
    assert before - after > 0.5 * (before - truth["floor_ref"]), (before, after)
