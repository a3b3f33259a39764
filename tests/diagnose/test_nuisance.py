"""The diagnosis on complete units of the open nuisance set (benchmarks/nuisance: written by
a helper from the log contract, the papers and the judge's interface, without reading
gyrocal): units that follow the standard model and carry every realistic nuisance of
turntable-in-chamber work, a new turn-on bias at each power-on among them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gyrocal.diagnose import diagnose
from gyrocal.diagnose.sessions import offset_alone
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


def test_an_offset_new_in_the_other_session_is_not_a_failure_between_the_points(tmp_path):
    """Unit N018: the other session visits points all between this one's, and its errors
    there are an offset per axis (z by 3.5 hold-mean floors: the bias of its power-on), the
    same at every temperature. A calibration failing between its points would err by
    temperature; the verdict names the offset and how far it moved, not the points."""
    d = diagnosed(tmp_path, 18)
    nxt = d["next_session"]
    assert nxt["repeat_p_value"] is None  # no point of the other session matches one of this
    assert nxt["fails_in_practice"] and offset_alone(nxt), nxt
    # beyond the 3 floors a power-on's bias is granted: the bias moved between the sessions
    assert _answer(d)["reason"] == "unit changed", d["verdict"]
    assert (
        "an offset per axis" in d["verdict"]
        and "the unit changed between sessions, its bias by" in d["verdict"]
    )


def test_a_datasheets_turn_on_repeatability_is_the_allowance_for_a_power_ons_bias(tmp_path):
    """The same unit with its sensor's turn-on bias repeatability given, as the set draws it
    (each power-on's bias per axis normal with ``rep_sigma``, 0.013 deg/s here): its offset,
    3.5 floors (0.016 deg/s), is within 3 sigma, a power-on's bias, and the calibration
    carries over; the default allowance, 3 floors, stands for a specification the log does
    not give."""
    sigma = nuisance.draw_unit(SEED, 18)["noise"]["rep_sigma"]
    settings = Settings.from_dict({"diagnosis": {"turn_on_repeatability": sigma}}).for_protocol("turntable")
    d = diagnosed(tmp_path, 18, settings)
    nxt = d["next_session"]
    largest = max(abs(v) for v in nxt["turn_on_bias"].values())
    assert largest <= nxt["turn_on_allowance"] == pytest.approx(3 * sigma), nxt
    assert not nxt["fails_in_practice"] and _answer(d)["verdict"] == "quiet", d["verdict"]
    assert "the bias the unit took at that power-on" in d["verdict"]


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
