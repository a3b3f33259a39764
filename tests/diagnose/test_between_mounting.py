"""A misalignment that fails between temperature points is told as the mounting's only where
the scale meets its interpolation and every point has mountings of its own."""

from __future__ import annotations

import numpy as np

from gyrocal.diagnosis.between import tilted_per_point
from gyrocal.diagnosis.findings import BetweenPoints

ALPHA = 0.01


def _check(scale_p: float, misalignment_p: float) -> BetweenPoints:
    row = {
        "temp": 10.0,
        "chi2": 50.0,
        "dof": 9,
        "p_value": min(scale_p, misalignment_p),
        "coefficient": "misalignment.x.y",
        "difference": 3e-4,
        "z": 7.0,
        "scale_p_value": scale_p,
        "misalignment_p_value": misalignment_p,
    }
    return BetweenPoints([row], row, row["p_value"], 5, row["p_value"] < ALPHA / 2, [10.0])


# three points, three mountings each, 15 holds per mounting (a point's three mounts, five rates
# in both directions and a static hold, give about that)
POINTS = np.repeat([0, 1, 2], 45)
OWN = np.repeat(np.arange(9), 15)


def test_a_misalignment_alone_at_points_mounted_anew_is_the_mountings():
    assert tilted_per_point(_check(0.5, 1e-9), ALPHA, OWN, POINTS)


def test_a_scale_that_fails_too_is_the_sensors():
    assert not tilted_per_point(_check(1e-6, 1e-9), ALPHA, OWN, POINTS)


def test_a_mounting_kept_across_points_lets_the_points_tell():
    kept = OWN.copy()
    kept[45:50] = kept[44]  # the last mounting of point 0 holds the first five holds of point 1
    assert not tilted_per_point(_check(0.5, 1e-9), ALPHA, kept, POINTS)


def test_one_stray_hold_at_a_points_change_does_not_join_the_points():
    stray = OWN.copy()
    stray[45] = stray[44]  # one hold of point 1 still on point 0's last mounting
    assert tilted_per_point(_check(0.5, 1e-9), ALPHA, stray, POINTS)
