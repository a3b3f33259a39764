"""The other session's part in proportion to the rates, fitted per mounting
(``sessions._turn_on_offsets`` with mountings): a fixture that seats the unit at a tilt of its
own each time, within what a unit's scale and a fixture repeat to, is the unit's normal
behaviour (``scale_allowance``); a change of the axes beyond it fails the calibration."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.diagnose.sessions import (
    SCALE_REPEATABILITY_PPM,
    TURN_ON_SIGMAS,
    _turn_on_offsets,
    fails_in_practice,
    rate_shaped,
    reseated,
    scale_allowance,
)
from gyrocal.diagnose.shapes import odd_in_own_rate
from gyrocal.fleet.drift import HoldErrors
from gyrocal.pipeline.config import DiagnosisSettings, Settings

FLOOR = 1e-3  # deg/s, a hold mean's white noise
MOUNTS = ("+x", "+y", "+z")
RATES = (-300.0, -100.0, -30.0, 30.0, 100.0, 300.0)


def held_errors(
    seed: int, tilt: float, mountings_per_mount: int = 3
) -> tuple[HoldErrors, np.ndarray, np.ndarray]:
    """Three mounts each mounted ``mountings_per_mount`` times, six rates a mounting, each
    mounting seated with its own small rotation (``tilt`` rad, 1 sigma per axis); white
    noise. The holds' errors, each hold's mounting, and each mounting's rotation."""
    rng = np.random.default_rng(seed)
    rows = [(g, MOUNTS[g % 3], r) for g in range(3 * mountings_per_mount) for r in RATES]
    mounting = np.array([g for g, _, _ in rows])
    rates = np.zeros((len(rows), 3))
    for i, (_, m, r) in enumerate(rows):
        rates[i, "xyz".index(m[1])] = r
    rotation = rng.normal(0.0, tilt, (3 * mountings_per_mount, 3))
    errors = np.array([np.cross(rotation[g], w) for g, w in zip(mounting, rates, strict=True)])
    errors += rng.normal(0.0, FLOOR, errors.shape)
    return (
        HoldErrors(errors, np.full(errors.shape, FLOOR), rates, np.ones(len(rows), bool)),
        mounting,
        rotation,
    )


def carry(held, mounting, allowance) -> dict:
    """A carry-over as ``carry_over`` writes it, from these holds alone."""
    found = _turn_on_offsets(held, None, mounting)
    v = float(np.sqrt(np.mean(held.errors**2)))
    expected = FLOOR * np.sqrt(1.0 + 12 / len(held.errors))
    return {
        "validation_rms": v,
        "expected_rms": expected,
        "wander_rms": expected,
        "holds": False,
        "bound": 1.1,
        "turn_on_allowance": None,
        "scale_allowance": allowance,
        **found,
    }


@pytest.mark.parametrize("seed", range(5))
def test_each_mountings_tilt_is_read_back(seed):
    """Per mounting, each output's coefficient on the turning rate is the rotation's
    cross-product entry: the RMS change of a row over the mountings matches the rotations'
    own, within what the noise (a floor over a 300 deg/s lever) allows."""
    held, mounting, rotation = held_errors(seed, tilt=50e-6)
    found = _turn_on_offsets(held, None, mounting)
    rows = []
    for g, r in enumerate(rotation):
        turning = np.eye(3)["xyz".index(MOUNTS[g % 3][1])]
        rows.extend(np.abs(np.cross(r, turning)))  # each output's change of the turning column
    truth = float(np.sqrt(np.mean(np.square(rows))))
    assert found["rate_shaped_change"] == pytest.approx(truth, abs=5 * FLOOR / 300.0)
    assert found["reseated_rms"] < 1.5 * FLOOR < found["rezeroed_rms"]


@pytest.mark.parametrize("seed", range(5))
def test_a_reseating_within_the_allowance_carries_and_one_beyond_it_fails(seed):
    """A 30 µrad seating (1 sigma per axis) makes about 0.004 deg/s over these rates, four
    floors: within the default allowance it is the unit's, and what is left carries; a 400
    µrad one is a change of the axes."""
    allowance = TURN_ON_SIGMAS * SCALE_REPEATABILITY_PPM * 1e-6
    small = carry(*held_errors(seed, tilt=30e-6)[:2], allowance)
    assert small["validation_rms"] > 2 * FLOOR  # there is something to allow
    assert reseated(small) and not rate_shaped(small) and not fails_in_practice(small)
    large = carry(*held_errors(seed, tilt=400e-6)[:2], allowance)
    assert not reseated(large) and rate_shaped(large) and fails_in_practice(large)


def test_the_allowance_is_three_sigma_of_the_repeatability_given():
    """Without the sensor's figure, 3 x 30 ppm; given it (ppm, 1 sigma), 3 x that."""
    default = Settings()
    assert scale_allowance(default) == pytest.approx(90e-6)
    given = Settings(diagnosis=DiagnosisSettings.from_dict({"scale_repeatability": 200}))
    assert scale_allowance(given) == pytest.approx(600e-6)
    assert given.diagnosis.to_dict()["scale_repeatability"] == 200
    assert "scale_repeatability" not in default.diagnosis.to_dict()  # the default digest unchanged


@pytest.mark.parametrize(
    ("term", "odd"),
    [
        ('expression(formula="tanh(rate_own / w)", parameters={"w": 267.0})', True),
        ('expression(formula="rate_own * abs(rate_own)")', True),
        ("scale_cubic", True),
        ('expression(formula="abs(rate_own)")', False),
        ('expression(formula="rate_own ** 2")', False),
        ('expression(formula="temp")', False),
        ('expression(formula="rate_x")', False),
        ("bias", False),
    ],
)
def test_an_odd_function_of_the_own_rate_is_a_scale_nonlinearity(term, odd):
    """f(ω) = ω·g(|ω|) is a scale that changes with |ω|, whatever the formula's form; an
    even one is a bias of |ω|; a term that reads another input, or one axis' rate on every
    output, is neither."""
    assert odd_in_own_rate(term) is odd
