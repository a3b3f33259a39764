"""The hand-rotation protocol on sessions from an independent generator (tests/ferraris_gen:
written by a helper from the contract, the protocol's description, rigid-body physics and the
real session's statistics, without reading gyrocal; its NOTE.md says how).

A session that should calibrate must recover what a 360° reference allows (the truth's
``K_nominal``: K times each turn's true axis and angle) and the bias a still unit shows
(``b_expected``: Earth rate included), within 4 of the standard errors gyrocal reports with
the hand's assumed errors at zero, i.e. the noise's; one that should be refused must end in a
one-line error (or, where its author accepts a warning, in a recorded one)."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.config import Settings
from gyrocal.errors import GyrocalError
from gyrocal.pipeline import run

from .ferraris_gen.generate import KINDS, session
from .test_ferraris import K_stderr

NOISE_ONLY = Settings.from_dict({"protocols": {"ferraris": {"options": {
    "angle_uncertainty_deg": 0.0, "tilt_uncertainty_deg": 0.0}}}}).for_protocol("ferraris")
SEEDS = (0, 1)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ferraris_gen")
    return {(kind, seed): (folder / f"{kind}_{seed}.parquet",
                           session(kind, seed, folder / f"{kind}_{seed}.parquet"))
            for kind in KINDS for seed in SEEDS}


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("kind", [k for k, v in KINDS.items() if v.expect == "calibrate"])
def test_good_sessions_recover_the_truth(sessions, kind, seed):
    path, truth = sessions[(kind, seed)]
    assert truth["expect"] == "calibrate"
    cal = run(path, NOISE_ONLY, protocol="ferraris").calibration
    K, B = cal.matrices()[0][0], cal.matrices()[1][0]
    B_se = np.array([dict(zip(cal.grid.names, cal.grid.stderr[0]))[f"bias.{a}"] for a in "xyz"])
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
