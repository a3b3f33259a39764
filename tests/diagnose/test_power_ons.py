"""The other session's errors read per power-on: offsets per stretch between the log's gaps
(:func:`gyrocal.diagnosis.sessions._turn_on_offsets`), on hold errors made up here."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.diagnosis.sessions import _turn_on_offsets
from gyrocal.fit.validate import MIN_STRETCH_HOLDS, stretches_between_gaps
from gyrocal.fleet.drift import HoldErrors


def held(errors, rates, floor=1e-3):
    n = len(errors)
    return HoldErrors(
        np.asarray(errors, float), np.full((n, 3), floor), np.asarray(rates, float), np.ones(n, bool)
    )


def test_stretches_too_short_to_judge_join_the_one_before():
    """Stretches of 8, 2 and 7 holds: the two holds after the second gap join the first
    stretch (a logger pausing between holds gives no power-on of its own); a log that never
    resumes is one stretch."""
    resumed = np.repeat([0.0, 100.0, 200.0], [8, 2, 7])
    assert MIN_STRETCH_HOLDS > 2
    np.testing.assert_array_equal(stretches_between_gaps(resumed, 17), np.repeat([0, 0, 1], [8, 2, 7]))
    np.testing.assert_array_equal(stretches_between_gaps(None, 5), np.zeros(5, int))
    np.testing.assert_array_equal(
        stretches_between_gaps(np.repeat([0.0, 1.0], [2, 8]), 10), np.zeros(10, int)
    )


def test_offsets_per_power_on_are_taken_out_and_counted():
    """Two stretches of 12 holds whose errors are white noise about their own offsets (x
    +0.02 then −0.01 deg/s): each stretch's offsets are found, the largest is 0.02, and what
    is left, scaled for the six means taken out, is the noise's RMS within its sampling
    error. No part follows the rates."""
    rng = np.random.default_rng(3)
    n, sigma = 24, 1e-3
    rates = np.zeros((n, 3))
    rates[:, 2] = np.tile([-100.0, -10.0, 10.0, 100.0], 6)
    offsets = np.repeat([[0.02, 0.0, 0.005], [-0.01, 0.003, 0.005]], 12, axis=0)
    noise = rng.normal(0.0, sigma, (n, 3))
    out = _turn_on_offsets(held(offsets + noise, rates), np.repeat([0.0, 500.0], 12))
    assert out["power_ons"] == 2
    assert abs(out["largest_turn_on"] - 0.02) < 4 * sigma / np.sqrt(12)
    left = noise - np.repeat([noise[:12].mean(0), noise[12:].mean(0)], 12, axis=0)
    assert out["rezeroed_rms"] == pytest.approx(np.sqrt(np.mean(left**2) * n / (n - 2)), rel=1e-12)
    assert abs(out["rezeroed_rms"] / sigma - 1.0) < 3 / np.sqrt(3 * (n - 2))
    assert out["rate_shaped_rms"] < 3 * sigma * np.sqrt(3 / (3 * n))


def test_a_scale_change_is_the_part_that_follows_the_rates():
    """The same holds with the z output reading 100 ppm more of the z rate: the part of the
    errors in proportion to the rates is that change's RMS over the holds."""
    rng = np.random.default_rng(4)
    n = 24
    rates = np.zeros((n, 3))
    rates[:, 2] = np.tile([-100.0, -10.0, 10.0, 100.0], 6)
    errors = rng.normal(0.0, 1e-4, (n, 3))
    errors[:, 2] += 1e-4 * rates[:, 2]
    out = _turn_on_offsets(held(errors, rates), None)
    expected = np.sqrt(np.mean((1e-4 * rates[:, 2]) ** 2) / 3)
    assert abs(out["rate_shaped_rms"] / expected - 1.0) < 0.05, out


def test_the_other_sessions_holds_between_this_ones_points_are_counted():
    """Points at 0, 20 and 40 °C (each point's holds scattered by a few tenths): of the other
    session's holds at 10, 20.5, 30, 45 and -5 °C, those at 10 and 30 lie where only the
    interpolation reaches; 20.5 is at a point (within POINT_MATCH), 45 and -5 outside the span."""
    import pandas as pd

    from gyrocal.diagnosis.sessions import POINT_MATCH, between_share

    temps = np.array([0.0, 0.3, -0.2, 20.0, 20.4, 40.0, 39.8])
    obs = pd.DataFrame({"point": [0, 0, 0, 1, 1, 2, 2], "temp": temps})
    assert POINT_MATCH > 0.5
    assert between_share(obs, np.array([10.0, 20.5, 30.0, 45.0, -5.0])) == pytest.approx(2 / 5)
    assert between_share(obs.drop(columns="point"), np.array([10.0])) == 0.0


def test_a_point_logged_on_its_own_is_scored_with_its_turn_on_bias_taken_out():
    """Three points of 8 holds: the first logged on its own (a gap in the log after it), the
    second and third in one stretch. The first point's offsets (its own stretch, which may
    hold a power-on) are taken out; the other two, one stretch over two points, keep theirs.
    What is left is the noise, scaled for the one mean per axis taken out."""
    import pandas as pd

    from gyrocal.fit.validate import own_power_ons

    rng = np.random.default_rng(7)
    n = 24
    obs = pd.DataFrame({"point": np.repeat([0, 1, 2], 8), "resumed_at": np.repeat([0.0, 500.0, 500.0], 8)})
    noise = rng.normal(0.0, 1e-3, (n, 3))
    offsets = np.zeros((n, 3))
    offsets[:8] = [0.02, -0.01, 0.03]  # the first point's power-on
    floor = np.full((n, 3), 1e-3)
    use = np.ones(n, bool)
    rms, stretches = own_power_ons(obs, noise + offsets, floor, use)
    left = noise.copy()
    left[:8] -= noise[:8].mean(axis=0)
    assert stretches == 1
    assert rms == pytest.approx(np.sqrt(np.mean(left**2)) * np.sqrt(n / (n - 1)))
    # one stretch for every point: no point is logged on its own
    assert own_power_ons(obs.assign(resumed_at=0.0), noise + offsets, floor, use) is None
