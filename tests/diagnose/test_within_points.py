"""The other session's errors within its temperature points (``sessions._within_points``):
what a fixture's tilt at each mount leaves there is taken out with the mount's levels, and
white noise stays within the bar, while a bias that switches between two levels in time
does not."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrocal.diagnosis.sessions import _within_points, wanders_within_points
from gyrocal.fleet.drift import HoldErrors

FLOOR = 1e-3  # deg/s, a hold mean's white noise
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
RATES = (-100.0, -10.0, 0.0, 10.0, 100.0)


def session(seed: int, tilt_urad: float = 0.0, switch: float = 0.0) -> tuple[pd.DataFrame, HoldErrors]:
    """Four points, six mounts, five rates a mount, holds in time order; each mount seated
    with its own small rotation (``tilt_urad``, 1 sigma per axis, the same at every point),
    and a bias on x that switches between 0 and ``switch`` at random times."""
    rng = np.random.default_rng(seed)
    rows = [(p, m, r) for p in range(4) for m in MOUNTS for r in RATES]
    point = np.array([p for p, _, _ in rows])
    mount = np.array([m for _, m, _ in rows])
    rates = np.zeros((len(rows), 3))
    for i, (_, m, r) in enumerate(rows):
        rates[i, "xyz".index(m[1])] = r if m[0] == "+" else -r
    tilt = {m: rng.normal(0.0, tilt_urad * 1e-6, 3) for m in MOUNTS}
    errors = np.array([np.cross(tilt[m], w) for m, w in zip(mount, rates, strict=True)])
    state = np.cumsum(rng.random(len(rows)) < 0.08) % 2  # a switch every dozen holds or so
    errors[:, 0] += switch * state
    errors += rng.normal(0.0, FLOOR, errors.shape)
    other = pd.DataFrame({"point": point, "mount": mount})
    held = HoldErrors(errors, np.full(errors.shape, FLOOR), rates, np.ones(len(rows), bool))
    return other, held


def wanders(other, held) -> bool:
    found = _within_points(other, held, FLOOR, 1e-3)
    return wanders_within_points({"validation_rms": 1.0, **found})  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", range(10))
def test_a_fixture_tilt_at_each_mount_and_white_noise_stay_within_the_bar(seed):
    """A 100 µrad tilt per mount (1 sigma per axis) makes about 0.01 deg/s at 100 deg/s, ten
    floors: the mount's levels take it whole, and white noise is what is left."""
    other, held = session(seed, tilt_urad=100.0)
    assert np.sqrt(np.mean(held.errors**2)) > 2 * FLOOR  # the tilt is there to take
    assert not wanders(other, held)


@pytest.mark.parametrize("seed", range(10))
def test_a_bias_switching_in_time_moves_within_the_points(seed):
    """A bias stepping by ten floors at random times within the points: no level of mount
    and rate, nor any point's own bias and rates, takes it."""
    other, held = session(seed, switch=10 * FLOOR)
    assert wanders(other, held)
