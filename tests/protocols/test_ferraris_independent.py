"""The hand-rotation protocol on sessions from an independent generator (tests/protocols/ferraris_gen:
written by a helper from the contract, the protocol's description, rigid-body physics and the
real session's statistics, without reading gyrocal; its NOTE.md says how).

A session that should calibrate must recover what a 360° reference allows (the truth's
``K_nominal``: K times each turn's true axis and angle) and the bias a still unit shows
(``b_expected``: Earth rate included), within 4 of the standard errors gyrocal reports with
the hand's assumed errors at zero, i.e. the noise's; one that should be refused must end in a
one-line error (or, where its author accepts a warning, in a recorded one)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.io.errors import GyrocalError
from gyrocal.pipeline.chain import run
from gyrocal.pipeline.config import Settings

from .ferraris_gen.generate import KINDS, session
from .test_ferraris import K_stderr

NOISE_ONLY = Settings.from_dict(
    {"protocols": {"ferraris": {"options": {"angle_uncertainty_deg": 0.0, "tilt_uncertainty_deg": 0.0}}}}
).for_protocol("ferraris")
SEEDS = (0, 1)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ferraris_gen")
    return {
        (kind, seed): (
            folder / f"{kind}_{seed}.parquet",
            session(kind, seed, folder / f"{kind}_{seed}.parquet"),
        )
        for kind in KINDS
        for seed in SEEDS
    }


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("kind", [k for k, v in KINDS.items() if v.expect == "calibrate"])
def test_good_sessions_recover_the_truth(sessions, kind, seed):
    path, truth = sessions[(kind, seed)]
    assert truth["expect"] == "calibrate"
    cal = run(path, NOISE_ONLY, protocol="ferraris").calibration
    K, B = cal.matrices()[0][0], cal.matrices()[1][0]
    B_se = np.array([dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))[f"bias.{a}"] for a in "xyz"])
    z_K = (K - np.asarray(truth["K_nominal"])) / K_stderr(cal)
    z_B = (B - np.asarray(truth["b_expected"])) / B_se
    assert np.abs(z_K).max() < 4, z_K
    assert np.abs(z_B).max() < 4, z_B
    codes = {w["code"] for w in cal.extra["warnings"]}
    assert codes <= {"temperature_not_logged"}, codes


@pytest.mark.parametrize("seed", SEEDS)
def test_bad_sessions_are_refused_or_warned_as_their_author_expects(sessions, seed):
    for (kind, s), (path, truth) in sessions.items():
        if s != seed or truth["expect"] == "calibrate":
            continue
        try:
            cal = run(path, NOISE_ONLY, protocol="ferraris").calibration
        except GyrocalError as exc:
            assert "refuse" in truth["acceptable"], (kind, str(exc))
            assert "\n" not in str(exc) and str(path) in str(exc), (kind, str(exc))
            continue
        assert "warn" in truth["acceptable"], kind
        assert "phases_doubtful" in {w["code"] for w in cal.extra["warnings"]}, kind


# -- recordings cut to their sections ------------------------------------------------------

CUT_KINDS = [k for k, v in KINDS.items() if v.expect == "calibrate" and v.accel]
WITH_G = Settings.from_dict(
    {
        "protocols": {
            "ferraris": {
                "options": {"angle_uncertainty_deg": 0.0, "tilt_uncertainty_deg": 0.0},
                "model": {"terms": ["bias", "scale", "misalignment", "g_sensitivity"]},
            }
        }
    }
).for_protocol("ferraris")


def cut_to_sections(path, truth, margin: float, rows_as_time: bool):
    """The generator's log trimmed to its sections, as a person's annotation would trim it:
    each face's still interval and each turn's motion with ``margin`` seconds of the rests
    on either side, by the truth's phase times; the handling moves, the lead, the tail and
    any annotation dropped. ``rows_as_time``: time counts the kept rows (no gap at a cut).
    Returns the cut log's path and, per kept row, its time in the original log."""
    table = pq.read_table(path)
    if "section" in table.column_names:
        table = table.drop_columns(["section"])
    t = table.column("t").to_numpy()
    keep = np.zeros(len(t), bool)
    for face in truth["faces"].values():
        keep[slice(*face["samples"])] = True
    for turn in truth["turns"].values():
        a, b = turn["t_motion"]
        keep |= (t >= a - margin) & (t <= b + margin)
    table = table.filter(pa.array(keep))
    if rows_as_time:
        dt = 1.0 / truth["sample_rate_hz"]
        table = table.set_column(0, "t", pa.array(t[0] + np.arange(table.num_rows) * dt))
    out = path.with_name(f"{path.stem}_cut_{margin}_{rows_as_time}.parquet")
    pq.write_table(table, out)
    return out, t[keep]


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("margin,rows_as_time", [(0.0, False), (0.3, True)])
@pytest.mark.parametrize("kind", CUT_KINDS)
def test_a_recording_cut_to_its_sections_segments_from_the_data(sessions, kind, seed, margin, rows_as_time):
    """No move between one section and the next: the faces are found where gravity turns
    from one to the next, each turn between the edges of its section. Every face must lie
    in its still interval, every turn must span its motion and stay in its section, and the
    calibration must be within the generator's own tolerance of its truth (8 noise sigmas
    plus the Earth-rate, bias-walk and g-sensitivity allowances; with g_sensitivity fitted
    where the generator put one in)."""
    path, truth = sessions[(kind, seed)]
    cut, t_orig = cut_to_sections(path, truth, margin, rows_as_time)
    result = run(cut, WITH_G if kind == "gsens" else NOISE_ONLY, protocol="ferraris")
    seg = result.segmentation
    assert seg.info["phases_from"] == "data"
    assert seg.info["cuts"] == 8 or rows_as_time  # a time gap at every cut
    log = pq.read_table(cut).to_pandas()
    t_cut = log["t"].to_numpy()
    obs = seg.observations.set_index("section")
    original = lambda s: t_orig[np.searchsorted(t_cut, s)]  # noqa: E731
    dt = 1.0 / truth["sample_rate_hz"]
    for label, face in truth["faces"].items():
        lo, hi = face["t"]
        assert lo <= original(obs.loc[label, "t_start"]) and original(obs.loc[label, "t_end"]) <= hi
    for label, turn in truth["turns"].items():
        lo, hi = turn["t_motion"]
        first, last = original(obs.loc[label, "t_start"]), original(obs.loc[label, "t_end"])
        assert first >= lo - margin - dt and last <= hi + margin + dt, (label, first, last, lo, hi)
        assert np.sign(obs.loc[label, "angle"]) == turn["sign"]
        # what of its section the turn leaves out turns the unit by nothing that counts
        # (a hand's slow start and finish, under the stillness threshold, may stay in a
        # rest): the rate about its axis less the truth's resting output, integrated
        axis = "xyz".index(label[0])
        section = (t_orig >= lo - margin - dt / 2) & (t_orig <= hi + margin + dt / 2)
        left = section & ((t_cut < obs.loc[label, "t_start"]) | (t_cut > obs.loc[label, "t_end"]))
        resting = np.asarray(truth["b_expected"])
        if truth["G"] is not None and left.any():  # the g-sensitivity at those samples' gravity
            accel = log.loc[left, ["accel_x", "accel_y", "accel_z"]].to_numpy().mean(axis=0)
            resting = resting + np.asarray(truth["G"]) @ accel
        angle_left = float(np.sum(log.loc[left, f"gyro_{label[0]}"] - resting[axis]) * dt)
        assert abs(angle_left) < 0.05, (label, angle_left)
    cal = result.calibration
    K, B = cal.matrices()[0][0], cal.matrices()[1][0]
    tolerance = truth["suggested_tolerance"]
    off_K = np.abs(K - np.asarray(truth["K_nominal"])) / np.asarray(tolerance["K_vs_K_nominal"])
    assert off_K.max() < 1, off_K
    if kind != "gsens":  # there B is at zero specific force; b_expected holds G f of the faces
        off_B = np.abs(B - np.asarray(truth["b_expected"])) / np.asarray(tolerance["b_vs_b_expected"])
        assert off_B.max() < 1, off_B
