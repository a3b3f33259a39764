"""Each mounting's own rotation in the other session's errors (``sessions._seating``): a
fixture that seats the unit anew at each mounting, within its seating repeatability up to
chance, is the rig's normal behaviour (``reseated``); a change of the axes beyond it, a bias
that differs per mounting, and a mounting too short to tell are not."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.diagnosis.sessions import (
    SEATING_REPEATABILITY_URAD,
    _rms_bound,
    _seating,
    _turn_on_offsets,
    fails_in_practice,
    rate_shaped,
    reseated,
    seating_sigma,
)
from gyrocal.diagnosis.shapes import odd_in_own_rate
from gyrocal.fleet.drift import HoldErrors
from gyrocal.pipeline.config import DiagnosisSettings, Settings

FLOOR = 1e-3  # deg/s, a hold mean's white noise
MOUNTS = ("+x", "+y", "+z")
RATES = (-300.0, -100.0, -30.0, 30.0, 100.0, 300.0)
ALPHA = 0.01


def held_errors(
    seed: int, tilt: float, rates=RATES, mountings_per_mount: int = 3, bias_per_mounting: float = 0.0
) -> tuple[HoldErrors, np.ndarray, np.ndarray]:
    """Three mounts each mounted ``mountings_per_mount`` times, ``rates`` on each mounting,
    each mounting seated with its own small rotation (``tilt`` rad, 1 sigma per component)
    and, if given, its own bias (1 sigma per axis); white noise. The holds' errors, each
    hold's mounting, and each mounting's rotation."""
    rng = np.random.default_rng(seed)
    rows = [(g, MOUNTS[g % 3], r) for g in range(3 * mountings_per_mount) for r in rates]
    mounting = np.array([g for g, _, _ in rows])
    turning = np.zeros((len(rows), 3))
    for i, (_, m, r) in enumerate(rows):
        turning[i, "xyz".index(m[1])] = r
    rotation = rng.normal(0.0, tilt, (3 * mountings_per_mount, 3))
    bias = rng.normal(0.0, bias_per_mounting, (3 * mountings_per_mount, 3))
    errors = np.array([np.cross(rotation[g], w) for g, w in zip(mounting, turning, strict=True)])
    errors += bias[mounting] + rng.normal(0.0, FLOOR, errors.shape)
    held = HoldErrors(errors, np.full(errors.shape, FLOOR), turning, np.ones(len(rows), bool))
    return held, mounting, rotation


def carry(held, mounting, sigma: float = SEATING_REPEATABILITY_URAD * 1e-6) -> dict:
    """A carry-over as ``carry_over`` writes it, from these holds alone."""
    found = _turn_on_offsets(held, None, mounting)
    expected = FLOOR * np.sqrt(1.0 + 12 / len(held.errors))
    out = {
        "validation_rms": float(np.sqrt(np.mean(held.errors**2))),
        "expected_rms": expected,
        "wander_rms": expected,
        "holds": False,
        "bound": 1.1,
        "turn_on_allowance": None,
        **found,
    }
    if found["seating_change"] is not None:
        out["seating_allowance"] = sigma * _rms_bound(found["seating_coefficients"], ALPHA)
    return out


def true_coefficients(rotation) -> np.ndarray:
    """Each mounting's rotation as the errors see it: on each other output, the component
    of the rotation's cross product with the turning axis."""
    out = []
    for g, r in enumerate(rotation):
        turning = "xyz".index(MOUNTS[g % 3][1])
        crossed = np.cross(r, np.eye(3)[turning])
        out.extend(np.delete(crossed, turning))
    return np.asarray(out)


@pytest.mark.parametrize("rates", [RATES, (30.0, 100.0, 300.0)], ids=["both signs", "one sign"])
@pytest.mark.parametrize("seed", range(4))
def test_each_mountings_rotation_is_read_back_with_a_bias_per_mounting_beside_it(seed, rates):
    """The RMS of the fitted coefficients matches the rotations' own within what the noise
    allows (a floor over a 100-300 deg/s lever), rates of one sign included: the offset per
    mounting beside the tilt keeps a bias from reading as one. The bias per mounting is not
    taken out: what is left holds it."""
    held, mounting, rotation = held_errors(seed, tilt=50e-6, rates=rates, bias_per_mounting=5 * FLOOR)
    seated = _seating(held.errors, 1.0 / held.floor**2, held.rates, mounting, 0)
    truth = float(np.sqrt(np.mean(true_coefficients(rotation) ** 2)))
    assert seated.change == pytest.approx(truth, abs=3 * FLOOR / 100.0)
    assert seated.left_rms > 3 * FLOOR  # the biases per mounting stay


@pytest.mark.parametrize("seed", range(4))
def test_a_seating_within_the_repeatability_carries_and_one_beyond_it_fails(seed):
    """A 30 µrad seating (1 sigma per component) makes about 0.004 deg/s over these rates,
    four floors: within the default repeatability up to chance it is the rig's, and what is
    left carries; a 300 µrad one is a change of the axes."""
    small = carry(*held_errors(seed, tilt=30e-6)[:2])
    assert small["validation_rms"] > 2 * FLOOR  # there is something to allow
    assert reseated(small) and not rate_shaped(small) and not fails_in_practice(small)
    large = carry(*held_errors(seed, tilt=300e-6)[:2])
    assert not reseated(large) and rate_shaped(large) and fails_in_practice(large)


def test_a_change_of_scale_is_no_seating():
    """Every output's scale 400 ppm apart in the other session and the fixture seated
    exactly: a seating fits other outputs' rates only, so the scale's part stays and fails
    the calibration."""
    held, mounting, _ = held_errors(0, tilt=0.0)
    errors = held.errors + 400e-6 * held.rates
    nxt = carry(held._replace(errors=errors), mounting)
    assert reseated(nxt)  # no rotation to speak of
    assert rate_shaped(nxt) and fails_in_practice(nxt)


def test_mountings_too_short_to_tell_keep_their_errors():
    """One hold per mounting: its rotation cannot be told from its offset, nothing is
    fitted, and a bias of eight floors per mounting fails the calibration as before."""
    held, mounting, _ = held_errors(
        1, tilt=0.0, rates=(300.0,), mountings_per_mount=4, bias_per_mounting=8 * FLOOR
    )
    nxt = carry(held, mounting)
    assert nxt["seating_change"] is None and not reseated(nxt)
    assert fails_in_practice(nxt)


def test_the_allowance_is_the_repeatability_given_up_to_chance():
    """Without the rig's figure 30 µrad, given it (µrad, 1 sigma) that; the RMS of many
    coefficients may lie above it by the chi-square bound only."""
    default = Settings()
    assert seating_sigma(default) == pytest.approx(30e-6)
    given = Settings(diagnosis=DiagnosisSettings.from_dict({"seating_repeatability": 200}))
    assert seating_sigma(given) == pytest.approx(200e-6)
    assert given.diagnosis.to_dict()["seating_repeatability"] == 200
    assert "seating_repeatability" not in default.diagnosis.to_dict()  # the default digest unchanged
    assert 1.0 < _rms_bound(1000, ALPHA) < _rms_bound(18, ALPHA) < _rms_bound(2, ALPHA)


@pytest.mark.parametrize(
    ("term", "odd"),
    [
        ('expression(formula="tanh(rate_own / w)", parameters={"w": 267.0})', True),
        ('expression(formula="rate_own * abs(rate_own)")', True),
        ("scale_cubic", True),
        ('expression(formula="abs(rate_own)")', False),
        ('expression(formula="sign(rate_own)")', False),
        ('expression(formula="tanh(rate_own / w)", parameters={"w": 10.0})', False),
        ('expression(formula="rate_own ** 2")', False),
        ('expression(formula="temp")', False),
        ('expression(formula="rate_x")', False),
        ("bias", False),
    ],
)
def test_an_odd_function_of_the_own_rate_is_a_scale_nonlinearity(term, odd):
    """f(ω) = ω·g(|ω|) is a scale that changes with |ω|, whatever the formula's form; an
    even one is a bias of |ω|, one that keeps its size down to small rates (a sign, a
    saturation at 10 deg/s) a bias that flips with the direction; a term that reads another
    input, or one axis' rate on every output, is neither."""
    assert odd_in_own_rate(term) is odd


def test_a_mounting_is_a_stretch_of_consecutive_holds_on_one_mount_in_time():
    """The holds, listed out of time order: a mount left and mounted again is a new
    mounting."""
    import pandas as pd

    from gyrocal.diagnosis.where import mountings

    other = pd.DataFrame({"t_start": [5.0, 1.0, 2.0, 3.0, 4.0], "mount": ["+x", "+x", "+x", "+y", "+x"]})
    assert mountings(other).tolist() == [2, 0, 0, 1, 2]
