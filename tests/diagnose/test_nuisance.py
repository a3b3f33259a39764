"""The diagnosis on complete units of the open nuisance set (benchmarks/nuisance: written by
a helper from the log contract, the papers and the judge's interface, without reading
gyrocal): units that follow the standard model and carry every realistic nuisance of
turntable-in-chamber work, a new turn-on bias at each power-on among them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gyrocal.diagnosis import diagnose
from gyrocal.diagnosis.between import between_points, seating_variance
from gyrocal.diagnosis.evaluation import evaluate
from gyrocal.diagnosis.sessions import offset_alone, seating_sigma, turned_on, white_bar
from gyrocal.diagnosis.where import history_columns
from gyrocal.fit.model import columns_of
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "nuisance"))

from judge import _answer  # noqa: E402  (the benchmark's words for a diagnosis)
from nuisance import generator as nuisance  # noqa: E402

SEED = 20250611  # the set's own master seed (benchmarks/nuisance/run.py)


def sessions(tmp_path, index: int, settings: Settings):
    """Sessions 0 and 1 of the set's unit ``index``, segmented."""
    built = nuisance.build_unit(nuisance.draw_unit(SEED, index))
    paths = nuisance.write_unit(built, str(tmp_path))
    return [segment_log(p, settings, "turntable").observations for p in paths[:2]]


def diagnosed(tmp_path, index: int, settings: Settings | None = None) -> dict:
    """Session 0 diagnosed with session 1 as the other session, as the set's runner does."""
    settings = settings or Settings().for_protocol("turntable")
    obs, other = sessions(tmp_path, index, settings)
    return diagnose(settings, obs, other).to_dict()


def test_an_offset_new_in_the_other_session_is_its_power_ons_bias(tmp_path):
    """Unit N018: the other session visits points all between this one's, and its errors
    there are an offset per axis (z by 3.5 hold-mean floors), the same at every temperature.
    With no turn-on repeatability given the log bounds a power-on's bias nowhere (a MEMS
    gyroscope's is commonly tens of floors): the verdict reads the offset as that power-on's,
    names it and what would bound it, and the calibration carries over; it is no failure
    between the points."""
    d = diagnosed(tmp_path, 18)
    nxt = d["next_session"]
    assert nxt["repeat_p_value"] is None  # no point of the other session matches one of this
    assert nxt["turn_on_allowance"] is None and offset_alone(nxt) and not nxt["fails_in_practice"], nxt
    assert _answer(d)["verdict"] == "quiet", d["verdict"]
    assert "the bias the unit took at" in d["verdict"]
    assert "no turn-on bias repeatability given" in d["verdict"]


def test_a_datasheets_turn_on_repeatability_bounds_a_power_ons_bias(tmp_path):
    """The same unit with its sensor's turn-on bias repeatability given. As the set draws it
    (each power-on's bias per axis normal with ``rep_sigma``, 0.013 deg/s here), its offsets
    (up to 0.018 deg/s over the other session's stretches between gaps) are within 3 sigma:
    the power-ons' biases, and the calibration carries over. Given a quarter of that, 3 sigma
    (at least 3 hold-mean floors, 0.014 deg/s) is below them: they are no power-on's, and the
    verdict does not read them so (the other session's errors lie within the slow wander its
    static data cannot rule out, so the calibration still carries over)."""
    sigma = nuisance.draw_unit(SEED, 18)["noise"]["rep_sigma"]
    obs, other = sessions(tmp_path, 18, Settings().for_protocol("turntable"))
    for given, within in ((sigma, True), (sigma / 4, False)):
        settings = Settings.from_dict({"diagnosis": {"turn_on_repeatability": given}}).for_protocol(
            "turntable"
        )
        d = diagnose(settings, obs, other).to_dict()
        nxt = d["next_session"]
        allowance = 3 * max(given, nxt["noise_floor"])
        assert nxt["turn_on_allowance"] == pytest.approx(allowance), nxt
        assert (nxt["largest_turn_on"] <= allowance) is within and turned_on(nxt) is within, nxt
        assert ("the bias the unit took at" in d["verdict"]) is within, d["verdict"]
        assert _answer(d)["verdict"] == "quiet" and not nxt["fails_in_practice"], d["verdict"]


@pytest.mark.slow
def test_a_unit_switched_off_between_points_takes_a_bias_per_power_on(tmp_path):
    """Unit N002 is switched off at every change of set point, and its log stops there: each
    stretch of the other session between its log's gaps has its own turn-on bias. Its errors
    there are offsets per axis for each stretch; with them out what is left is white noise
    (offsets per stretch already take every slower wander out), the calibration carries over,
    and the verdict says the log cannot tell where the unit was switched off."""
    d = diagnosed(tmp_path, 2)
    nxt = d["next_session"]
    assert nxt["power_ons"] > 1 and nxt["largest_turn_on"] > max(abs(v) for v in nxt["turn_on_bias"].values())
    assert nxt["rezeroed_rms"] <= white_bar(nxt) < nxt["validation_rms"], nxt
    assert not nxt["fails_in_practice"] and _answer(d)["verdict"] == "quiet", d["verdict"]
    assert f"each of the {nxt['power_ons']} stretches between gaps in its log" in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_offsets_per_stretch_that_leave_more_than_white_noise_are_not_read_as_power_ons(tmp_path):
    """Unit N038, switched off at every change of set point too: with its offsets per stretch
    out the other session still errs beyond the bar for white noise, so the offsets are not
    what sets it apart; its errors, with the slow wander its static data cannot rule out,
    are within the bar, and the calibration carries over without reading power-ons."""
    d = diagnosed(tmp_path, 38)
    nxt = d["next_session"]
    assert nxt["power_ons"] > 1 and nxt["rezeroed_rms"] > white_bar(nxt) and not offset_alone(nxt), nxt
    assert not nxt["fails_in_practice"] and _answer(d)["verdict"] == "quiet", d["verdict"]
    assert "stretches between gaps" not in d["verdict"] and "it carries over" in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_the_other_sessions_slow_noise_counts_in_its_bar_as_this_ones_does(tmp_path):
    """Unit N009 wanders slowly (bias instability about twice the hold-mean floor, one
    Gauss-Markov process of hours): the other session errs beyond 1.2 times what white noise
    leaves, within what a correct model leaves with the slow noise that session's own static
    data cannot rule out; the calibration carries over (it was told a failure between the
    temperature points)."""
    d = diagnosed(tmp_path, 9)
    nxt = d["next_session"]
    white_bar = 1.2 * nxt["expected_rms"] * nxt["bound"]
    assert nxt["wander_rms"] > nxt["expected_rms"] and nxt["rezeroed_rms"] > white_bar, nxt
    assert not nxt["fails_in_practice"] and _answer(d)["verdict"] == "quiet", d["verdict"]


@pytest.mark.slow
def test_offsets_per_mounting_within_the_slow_wander_are_no_finding(tmp_path):
    """Unit N003 from one log: its in-sample residuals, 1.85 times the floor, are offsets per
    mounting beyond chance, and within the slow wander that the session's 22 minutes of static
    data cannot rule out. Wander leaves such offsets too: the mounting is not told, and the
    verdict leaves the reading to another session."""
    settings = Settings().for_protocol("turntable")
    obs, _ = sessions(tmp_path, 3, settings)
    d = diagnose(settings, obs).to_dict()
    assert d["mounting"] is None and d["within_noise_uncertainty"]["explains"], d["verdict"]
    assert _answer(d)["verdict"] == "quiet" and "as far as one session can tell" in d["verdict"]


def _with_seating(settings: Settings, index: int) -> tuple[Settings, float]:
    """``settings`` with the rig's seating repeatability given as the set draws it for unit
    ``index`` (µrad, 1 sigma per axis), and that figure."""
    urad = float(nuisance.draw_unit(SEED, index)["handling"]["seat_urad"])
    data = settings.to_dict()
    diagnosis = {**data.get("diagnosis", {}), "seating_repeatability": urad}
    return Settings.from_dict({**data, "diagnosis": diagnosis}), urad


@pytest.mark.parametrize("index", [5, pytest.param(45, marks=pytest.mark.slow)])
def test_a_point_left_out_that_misses_by_the_fixtures_seating_is_no_failure(tmp_path, index):
    """Units N005 and N045: each mounting seats the unit at a rotation of its own (the set
    draws σ = 5.95 and 7.28 µrad per axis), and every temperature point mounts the unit anew.
    Leaving a point out, the misalignment interpolated from the other points misses the one
    fitted there beyond the fits' own uncertainty (told "between points", then "the mounting"),
    but within what the seating gives each point's fit, with the rig's repeatability given as
    the set's own σ: no failure between the points, and from one log the model explains the
    data."""
    settings, _ = _with_seating(Settings().for_protocol("turntable"), index)
    obs, _ = sessions(tmp_path, index, settings)
    base = evaluate(settings, obs, "configured model")
    mounting = history_columns(obs, columns_of(obs))["mounting"]
    alone = between_points(base.fitted, 0.01)
    assert alone.fails and alone.worst["coefficient"].startswith("misalignment"), alone
    seated = between_points(base.fitted, 0.01, seating_variance(obs, mounting, seating_sigma(settings)))
    assert not seated.fails, seated
    d = diagnose(settings, obs).to_dict()
    assert not d["between_points"]["fails"] and _answer(d)["verdict"] == "quiet", d["verdict"]


@pytest.mark.slow
@pytest.mark.parametrize("index", [4, 44])
def test_offsets_per_mounting_within_the_seating_and_the_slow_wander_are_no_finding(tmp_path, index):
    """Units N004 and N044 from one log, six mounts revisited at every point: the in-sample
    residuals (1.56 and 2.01 times the floor) are offsets and tilts per mounting beyond chance
    and beyond the slow wander the static data cannot rule out (told "the mounting"). With each
    mounting's rotation a random effect of the rig's repeatability (the set's own σ), both
    together explain them, and the rotations fitted are no larger than that σ: quiet, the
    verdict names the seating."""
    settings, urad = _with_seating(Settings().for_protocol("turntable"), index)
    obs, _ = sessions(tmp_path, index, settings)
    d = diagnose(settings, obs).to_dict()
    within = d["within_noise_uncertainty"]
    assert d["mounting"] is None and within["explains"], d["verdict"]
    assert 0 < within["seating_change"] <= 1e-6 * urad, within
    assert _answer(d)["verdict"] == "quiet" and "the fixture's seating" in d["verdict"], d["verdict"]


@pytest.mark.slow
def test_a_unit_switched_off_at_each_set_point_is_validated_with_its_power_ons_out(tmp_path):
    """Unit N013 is switched off at every change of set point and its log stops there: each
    of its three points is logged on its own, with a turn-on bias no interpolation from the
    other points knows. Left out, the points' holds erred 63 times what a correct model leaves,
    read as an effect; with each point's offsets per axis taken out, the error is what slow
    noise leaves, and from one log the model explains the data. With the other session, whose
    offsets per stretch its power-ons explain, the calibration carries over: slow noise and
    power-ons, not a unit that changed."""
    settings = Settings().for_protocol("turntable")
    obs, other = sessions(tmp_path, 13, settings)
    one = diagnose(settings, obs).to_dict()
    assert one["rezeroed_stretches"] == 1, one  # the middle point, the one interpolated
    assert one["validation_rms_as_scored"] > 10 * one["validation_rms"], one
    assert _answer(one)["verdict"] == "quiet", one["verdict"]
    two = diagnose(settings, obs, other).to_dict()
    assert not two["next_session"]["fails_in_practice"], two["verdict"]
    assert _answer(two)["verdict"] == "quiet", two["verdict"]
    assert "the calibration carries over" in two["verdict"], two["verdict"]


def test_holds_still_moving_after_a_door_serve_the_calibration(tmp_path):
    """Unit N046: after each remount the chamber's door lets the air go and the unit's
    temperature recovers at tenths of a degree a minute through the holds. Each hold is fitted
    at its own temperature, so they serve; rejected at the static stretches' 0.1 °C/min, they
    took whole mounts from points and the calibration erred 49 times the set's reference
    floor on the unseen session. The default calibration of session 0 meets the issue's bar,
    1.2 times that floor, on session 2."""
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run

    built = nuisance.build_unit(nuisance.draw_unit(SEED, 46))
    paths = nuisance.write_unit(built, str(tmp_path))
    floor = nuisance.reference_floor(built)["floor"]
    settings = Settings().for_protocol("turntable")
    unseen = revalidate(
        run(paths[0], settings).calibration, segment_log(paths[2], settings, "turntable").observations
    )
    assert unseen["validation_rms"] <= 1.2 * floor, (unseen["validation_rms"], floor)


@pytest.mark.slow
@pytest.mark.parametrize("index", [20, 40])
def test_three_points_left_out_count_the_curvature_a_line_misses(tmp_path, index):
    """Units N020 and N040: complete, on three temperature points, their bias curving with
    temperature by several floors between the points. Left out, the middle point is read by
    the line through the other two where the calibration runs a parabola through all three,
    and erred 8 (N040) to 26 (N020) times what a correct model leaves: from one log,
    "unexplained". That error is the curvature: the drift chord (the smooth drift of the
    calibration's own order interpolated from the other points) matches it within three
    noise bars of the held-out figure; counted in what a correct model leaves, the model
    explains the data and the verdict says that only another temperature point would test
    the curvature."""
    settings = Settings().for_protocol("turntable")
    obs, _ = sessions(tmp_path, index, settings)
    d = diagnose(settings, obs).to_dict()
    chord, held_out = d["drift_chord_rms"], d["validation_rms"]
    noise = (d["expected_rms"] ** 2 - chord**2) ** 0.5  # the floor and the calibration's uncertainty
    assert held_out > 5 * noise and abs(held_out - chord) <= 3 * noise, d
    assert _answer(d)["verdict"] == "quiet", d["verdict"]
    assert "another temperature point would" in d["verdict"], d["verdict"]
