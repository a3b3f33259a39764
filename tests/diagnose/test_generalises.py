"""The diagnosis on the kinds of unit it used to fail, from the independent zoo's fourth set
(benchmarks/zoo: written from the physics and a bug report, without reading gyrocal).

A shape's place and width between the protocol's levels, a floor that a slow pole must not
move, a calibration that fails on the other session where the temperature came from the
other side, and the grammar's screen that proposes the candidates: each judged against the
generator's own truth, or on a session the diagnosis never saw.
"""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.diagnosis import diagnose
from gyrocal.diagnosis.evaluation import evaluate
from gyrocal.diagnosis.grammar import screen
from gyrocal.diagnosis.sessions import turned_on
from gyrocal.diagnosis.stats import floor_uncertainty
from gyrocal.diagnosis.where import fit_quality
from gyrocal.fit.model import columns_of
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings

from .conftest import next_session, zoo_sessions

NEXT_SESSION_LIMIT = 1.2  # the target for a fix on the unseen session
SIGMAS = 3.0


@pytest.mark.slow
def test_a_bump_between_the_levels_is_placed_from_a_grid_not_a_guess(tmp_path):
    """A Gaussian bias bump centred between the rate levels (the zoo's rate_band_bias_wide at
    about 146 deg/s, 38 wide at half maximum, on a protocol with 125/150/175 deg/s): the bump
    offered is where the generator put it, its place and width within three of their reported
    errors of the truth (a Gaussian's exp(−((|ω| − m)/w)²) has w = FWHM / (2 sqrt(ln 2))), and
    it holds on the unseen session. Started from one guess (m = 40, w = 12.6), the place
    stopped at a neighbouring level with an error that claimed certainty."""
    rates = {"rates": [10, 50, 100, 125, 150, 175, 200, 400]}
    logs, (info, *_) = zoo_sessions(
        tmp_path, "rate_band_bias_wide", 1, sessions={s: rates for s in range(3)}, with_info=True
    )
    settings = Settings()
    d = diagnose(settings, segment_log(logs[0], settings).observations).to_dict()
    offer = d["best"]
    assert offer is not None and offer.get("family") == "bump", d["verdict"]
    found = {p["parameter"]: p for p in offer["profiled"]}
    truth = info["effect_params"]["rate_band_bias_wide"]
    width = truth["fwhm_dps"] / (2.0 * np.sqrt(np.log(2.0)))
    assert abs(found["m"]["value"] - truth["centre_dps"]) <= SIGMAS * found["m"]["stderr"] + 0.5, found
    assert abs(found["w"]["value"] - width) <= SIGMAS * found["w"]["stderr"] + 0.5, found
    assert next_session(logs, settings, offer) <= NEXT_SESSION_LIMIT


@pytest.mark.slow
def test_one_log_offers_the_fix_it_found_though_the_package_still_settles(tmp_path):
    """A quadratic cross-axis bias (the zoo's cross_axis_quadratic) on a rig whose package is
    still settling at the start of each temperature point (0.5 °C at the first hold): from one
    log the fix is offered, and what it leaves, where it follows time within the points, is
    named as a second question instead of withholding it (each hold fitted at its own
    temperature now carries most of the settling). On the unseen session the fix leaves no
    more than 1.2 times what the same settling leaves on a unit without the effect. It used
    to be offered only as "partial", the time pattern its reason."""
    settle = {s: {"settle_c": 0.5} for s in range(3)}
    settings = Settings()
    logs = zoo_sessions(tmp_path / "effect", "cross_axis_quadratic", 1, sessions=settle)
    d = diagnose(settings, segment_log(logs[0], settings).observations).to_dict()
    offer = d["best"]
    assert offer is not None and offer["term"].startswith("cross_rate"), d["verdict"]
    assert bool(offer.get("second_question")) == ("second question" in d["verdict"]), d["verdict"]
    settling_alone = next_session(zoo_sessions(tmp_path / "none", "none", 1, sessions=settle), settings, None)
    before, after = next_session(logs, settings, None), next_session(logs, settings, offer)
    assert before > 5 * settling_alone, (before, settling_alone)
    assert after <= NEXT_SESSION_LIMIT * settling_alone, (after, settling_alone)


@pytest.mark.slow
def test_a_slow_pole_does_not_move_the_floor_it_is_judged_against(tmp_path):
    """A slow pole with a large share of the output (the zoo's slow_pole_strong: τ about 6 s,
    each hold settling by tens of floors): the floor the diagnosis reports is the same unit's
    without the effect, within three times the floor's own uncertainty; the pole is offered,
    and the unseen session, visited in a shuffled rate order, falls from hundreds of floors.
    Made of the holds' scatter and the stretches after each turn, the floor was 9 times it,
    and the excess "too small to attribute"."""
    settings = Settings()
    floors = {}
    for effect in ("none", "slow_pole_strong"):
        logs = zoo_sessions(tmp_path / effect, effect, 1, sessions={2: {"rate_order": "shuffled"}})
        obs = segment_log(logs[0], settings).observations
        d = diagnose(settings, obs).to_dict()
        floors[effect] = (d["noise_floor"], floor_uncertainty(obs))
    ratio = floors["slow_pole_strong"][0] / floors["none"][0]
    assert abs(ratio - 1.0) <= SIGMAS * max(u for _, u in floors.values()), floors
    assert d["best"] is not None and d["best"]["family"] == "slow pole", d["verdict"]
    before, after = next_session(logs, settings, None), next_session(logs, settings, d["best"])
    assert before > 100 and after < 0.02 * before, (before, after)


@pytest.mark.slow
def test_points_reached_from_the_other_side_are_told_as_hysteresis(tmp_path):
    """A bias that depends on the direction the temperature came from (the zoo's play
    operator), in a session visiting the points out of order (5, 55, −20, 30 °C) and another
    visiting them upward: the calibration fails on the other session only at the point
    reached from the other side there, and the verdict says so, with the step's size, instead
    of "the unit changed between sessions"."""
    orders = {0: {"temp_order": [5.0, 55.0, -20.0, 30.0]}, 1: {"temp_order": [-20.0, 5.0, 30.0, 55.0]}}
    logs, infos = zoo_sessions(tmp_path, "temp_hysteresis_play", 1, sessions=orders, with_info=True)
    settings = Settings()
    obs, other = (segment_log(log, settings).observations for log in logs[:2])
    d = diagnose(settings, obs, other).to_dict()
    approach = d["approach"]
    assert approach is not None and approach["explains"], d["verdict"]
    assert "direction the temperature came from" in d["verdict"]
    assert "unit changed between sessions" not in d["verdict"]
    # the generator's own record of each visit: the points whose side differs
    sides = [{round(v["setpoint_c"]): v["approached_from"] for v in i["setpoint_visits"]} for i in infos[:2]]
    differ = sorted(t for t in sides[0] if sides[0][t] != sides[1][t])
    assert sorted(round(t) for t in approach["points"]) == differ
    # the step is twice the hysteresis the generator drew: a point's mean error carries the
    # first session's calibration uncertainty there, about a floor, and the step is the
    # difference of two such means
    h = np.abs(infos[0]["effect_params"]["temp_hysteresis_play"]["h_dps"])
    step = np.abs([approach["shift"][a] for a in "xyz"])
    np.testing.assert_allclose(step, 2 * h, atol=SIGMAS * np.sqrt(2.0) * d["noise_floor"])


@pytest.mark.parametrize(
    "effect, reads",
    [
        ("none", None),
        ("rate_band_bias", "|rate|"),
        ("cross_axis_quadratic", "other axes' rate"),
        ("warmup", "time since power-on"),
        ("slow_pole", "the output's slow pole"),
    ],
)
def test_the_grammar_screen_puts_the_effects_input_first(effect, reads, tmp_path):
    """The screen of every candidate the grammar makes, on one session of a zoo unit: the
    input the generator's effect reads comes first; on a complete unit nothing passes."""
    logs = zoo_sessions(tmp_path, effect, 1)
    settings = Settings()
    obs = segment_log(logs[0], settings).observations
    base = evaluate(settings, obs, "configured model")
    screened = screen(obs, columns_of(obs), fit_quality(base, len(obs)), settings.diagnosis.significance)
    if reads is None:
        assert screened == []
    else:
        assert screened and screened[0].input.label == reads, [s.input.label for s in screened]


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["scale_range_switch", "slow_pole"])
def test_a_fixed_rate_order_is_named_and_another_order_tells(effect, tmp_path):
    """Two readings a fixed rate order moves together, each simulated (the zoo's range switch,
    an effect of the hold's own rate; its slow pole, one of the rate before it) in the default
    order and in the order the verdict advises (shuffled). In the default order the range
    switch's fix reads the own rate and the verdict says the rate before the hold groups the
    holds alike and which order would tell; in the shuffled order each is named by its own
    reading, with no such sentence. The slow pole's output settles within its holds, which
    tells the readings apart in either order."""
    settings = Settings()
    verdicts = {}
    for order in ("default", "shuffled"):
        logs = zoo_sessions(tmp_path / order, effect, 1, sessions={0: {"rate_order": order}})
        verdicts[order] = diagnose(settings, segment_log(logs[0], settings).observations).to_dict()
    history = effect == "slow_pole"
    for order, d in verdicts.items():
        assert d["best"] is not None, d["verdict"]
        assert ("lag(" in d["best"]["term"]) == history, d["best"]["term"]
        named = d["confound"] is not None
        assert named == (order == "default" and not history), d["verdict"]
        assert ("another rate order (shuffled" in d["verdict"]) == named


@pytest.mark.slow
def test_a_temperature_dependent_g_sensitivity_is_the_orientations_not_the_mountings(tmp_path):
    """The zoo's g_sensitivity_temp on six mounts with the accelerometer logged (a bias of
    the orientation of gravity whose coefficients change with temperature): a term of the
    specific force is named, not offsets per mounting, and it holds on the unseen session and
    on each mount left out of its fit, which offsets of the fixture would not."""
    from benchmarks.zoo.generator import make_unit, write_session

    unit = make_unit(effect="g_sensitivity_temp", protocol="turntable6", noise="white", seed=1)
    logs = [tmp_path / f"s{s}.parquet" for s in range(3)]
    for s, log in enumerate(logs):
        write_session(unit, log, session=s, seed=1000 + s, rate_hz=10.0)
    settings = Settings()
    obs, other = (segment_log(log, settings).observations for log in logs[:2])
    d = diagnose(settings, obs, other).to_dict()
    from gyrocal.diagnosis.verdict import term_reads

    assert d["best"] is not None and "accel" in term_reads(d["best"]["term"]), d["verdict"]
    assert d["mounting"] is None or not d["mounting"]["explains"], d["verdict"]
    assert next_session(logs, settings, d["best"]) <= NEXT_SESSION_LIMIT
    by_mount = {g["by"]: g for g in d["grain"]}["mount"]
    assert by_mount["groups"] == 6 and by_mount["carries"], d["grain"]
    assert by_mount["fix"] <= NEXT_SESSION_LIMIT < by_mount["base"], d["grain"]


@pytest.mark.slow
def test_a_bias_new_in_the_other_session_is_a_change_between_sessions(tmp_path):
    """The zoo's session_bias_step: a constant offset present in session 1 only. The model
    explains session 0 and no term is offered (a warm-up would not carry it). With no turn-on
    repeatability given, the offset is what a power-on may give: the verdict reads it so.
    Given the sensor's (0.1 mdeg/s, well below the step), it is beyond 3 sigma of it: the
    unit changed between sessions."""
    logs = zoo_sessions(tmp_path, "session_bias_step", 1)
    settings = Settings()
    obs, other = (segment_log(log, settings).observations for log in logs[:2])
    d = diagnose(settings, obs, other).to_dict()
    assert d["best"] is None and not d["partial"], d["verdict"]
    assert "the bias the unit took at that power-on" in d["verdict"], d["verdict"]
    assert d["approach"] is None or not d["approach"]["explains"]
    spec = Settings.from_dict({"diagnosis": {"turn_on_repeatability": 0.0001}})
    d = diagnose(spec, obs, other).to_dict()
    assert d["best"] is None and "the unit changed between sessions" in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_two_sessions_floors_that_differ_are_a_finding(tmp_path):
    """The same complete unit, its other session with twice the white noise (the zoo's
    arw override): each session's floor is made from its own static data the same way, and
    the verdict says the other's is about twice this one's, beyond their uncertainty."""
    from benchmarks.zoo.generator import make_unit, write_session

    quiet = make_unit(effect="none", protocol="turntable3", noise="white", seed=1)
    arw = 2.0 * np.asarray(quiet.params["noise"]["arw_dps_rthz"])
    noisy = make_unit(effect="none", protocol="turntable3", noise="white", seed=1, arw_dps_rthz=list(arw))
    logs = [tmp_path / "s0.parquet", tmp_path / "s1.parquet"]
    write_session(quiet, logs[0], session=0, seed=1000, rate_hz=10.0)
    write_session(noisy, logs[1], session=1, seed=1001, rate_hz=10.0)
    settings = Settings()
    obs, other = (segment_log(log, settings).observations for log in logs)
    d = diagnose(settings, obs, other).to_dict()
    found = d["floors_differ"]
    assert found is not None, d["verdict"]
    assert abs(found["ratio"] - 2.0) <= found["tolerance"] * 2.0
    assert "noise floor, from its own static data" in d["verdict"]


@pytest.mark.slow
def test_a_fix_is_judged_leaving_each_rate_level_out(tmp_path):
    """At the grain of the rate: a quadratic cross-axis bias (a shape of the rate) carries to
    each interior rate level left out of its fit, near the floor; a range switch's table of
    the levels cannot be fitted without its level, and the verdict says so. Three mounts
    leave no mount out (each excites an axis no other does)."""
    settings = Settings()
    for effect, carries in (("cross_axis_quadratic", True), ("scale_range_switch", None)):
        logs = zoo_sessions(tmp_path / effect, effect, 1)
        d = diagnose(settings, segment_log(logs[0], settings).observations).to_dict()
        assert d["best"] is not None, d["verdict"]
        grain = {g["by"]: g for g in d["grain"]}
        assert set(grain) == {"rate level"}, d["grain"]  # three mounts: none can be left out
        level = grain["rate level"]
        if carries:
            assert level["carries"] and level["fix"] <= NEXT_SESSION_LIMIT < level["base"], level
        else:  # a table over the levels: nothing to say of a level it never saw
            assert d["best"]["term"].startswith("levels("), d["best"]["term"]
            assert level["fix"] is None and "cannot be fitted" in d["verdict"], level


@pytest.mark.slow
def test_time_and_temperature_visited_together_are_named_and_another_order_tells(tmp_path):
    """A bias drifting with time since power-on (the zoo's bias_ramp). Visited rising, the
    temperature points follow time (rank correlation near 1): the fix reads time, the
    temperature groups the holds alike, and the verdict names the confound and the order
    that would tell. Visited out of order (zigzag), the same effect is no longer tied to the
    temperature: nothing is named, and the fix of time still holds on the unseen session."""
    settings = Settings()
    rising = zoo_sessions(tmp_path / "rising", "bias_ramp", 1)
    d = diagnose(settings, segment_log(rising[0], settings).observations).to_dict()
    from gyrocal.diagnosis.verdict import term_reads

    assert d["best"] is not None and term_reads(d["best"]["term"]) == {"time"}, d["verdict"]
    confound = d["confound"]
    assert confound is not None and confound["reading"] == "time since power-on", d["verdict"]
    assert confound["tied"] >= 0.9 and "another order" in d["verdict"], confound
    zigzag = zoo_sessions(
        tmp_path / "zigzag", "bias_ramp", 1, sessions={s: {"temp_order": "zigzag"} for s in range(3)}
    )
    d = diagnose(settings, segment_log(zigzag[0], settings).observations).to_dict()
    assert d["best"] is not None and term_reads(d["best"]["term"]) == {"time"}, d["verdict"]
    assert d["confound"] is None, d["confound"]
    assert next_session(zigzag, settings, d["best"]) <= NEXT_SESSION_LIMIT


@pytest.mark.slow
def test_a_turn_on_bias_is_the_power_ons_unless_a_datasheet_bounds_it(tmp_path):
    """A bias new at every power-on (the zoo's run_to_run_bias) drawn small (0.4 mdeg/s per
    axis, about a third of a hold mean's floor) and large (4 mdeg/s). The small one leaves the
    other session within 1.2 times what a correct model would leave there, and the unseen
    session by the same bar. The large one misses both; with no turn-on repeatability given,
    the verdict reads its offset as the power-on's bias, which no calibration carries, and
    names it; given the small unit's figure as the datasheet's, 3 sigma of it (3 hold-mean
    floors) is below the offset, and the verdict does not read it as a power-on's (whether it
    fails is then the slow wander's to say: the other session's static data, a few minutes,
    cannot rule out wander of its size)."""
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run

    settings = Settings()
    spec = Settings.from_dict({"diagnosis": {"turn_on_repeatability": 0.0004}})
    for sigma, missed in ((0.0004, False), (0.004, True)):
        logs = zoo_sessions(tmp_path / f"{sigma}", "run_to_run_bias", 1, run_to_run_bias__sigma_dps=sigma)
        obs, other = (segment_log(log, settings).observations for log in logs[:2])
        d = diagnose(settings, obs, other).to_dict()
        nxt = d["next_session"]
        assert d["best"] is None and d["explains_the_data"] and not nxt["fails_in_practice"], d["verdict"]
        assert (nxt["validation_rms"] > 1.2 * nxt["expected_rms"] * nxt["bound"]) is missed, nxt
        assert not missed or "the bias the unit took at" in d["verdict"], d["verdict"]
        unseen = revalidate(run(logs[0], settings).calibration, segment_log(logs[2], settings).observations)
        assert (unseen["validation_rms"] > 1.2 * unseen["expected_rms"]) is missed, unseen["validation_rms"]
        bounded = diagnose(spec, obs, other).to_dict()
        assert turned_on(bounded["next_session"]) is not missed, bounded["next_session"]
        assert not missed or "the bias the unit took at" not in bounded["verdict"], bounded["verdict"]


@pytest.mark.slow
def test_three_mounts_mounted_once_tie_the_specific_force_to_the_mounting(tmp_path):
    """A g-sensitivity (the zoo's) on a session that mounts each of three mounts once (one
    temperature point): the fix reads the specific force, which takes one value per mounting,
    so an offset the fixture gave each mounting fits as well and the verdict names it with
    what would tell. Where each mount is mounted again at every point (the zoo's default,
    twelve mountings) the two part and nothing is named."""
    settings = Settings()
    once = zoo_sessions(
        tmp_path / "once", "g_sensitivity", 3, sessions={s: {"temps": [30.0]} for s in range(3)}
    )
    d = diagnose(settings, segment_log(once[0], settings).observations).to_dict()
    assert d["best"] is not None and "g_sensitivity" in d["best"]["term"], d["verdict"]
    assert d["confound"] is not None and d["confound"]["rival"] == "the mounting", d["verdict"]
    again = zoo_sessions(tmp_path / "again", "g_sensitivity", 3)
    d = diagnose(settings, segment_log(again[0], settings).observations).to_dict()
    assert d["best"] is not None and d["confound"] is None, d["verdict"]


def test_every_kind_of_input_a_candidate_reads_has_the_protocol_that_separates_it():
    """The advice for a candidate the protocol cannot fit names, for each kind of input it
    reads, the protocol that would separate it: no kind is left without its sentence (a
    term of the fixture's faces, blocked on three mounts, once had none)."""
    from gyrocal.diagnosis.verdict import SEPARATES, input_kinds
    from gyrocal.terms.effects import CANDIDATES

    specs = [*CANDIDATES, "expression(formula='exp(-t_mount / 100)')", "expression(formula='t')"]
    for spec in specs:
        assert input_kinds(spec) <= SEPARATES.keys(), spec
    assert "mount" in input_kinds("misalignment_faces")
