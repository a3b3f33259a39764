"""The profile of a term's nonlinear parameters: started from a joint grid, not one guess,
and its uncertainty the profile's, with a rival valley named.

The least-squares fit is replaced by a χ² surface written in closed form, so what the
profile finds can be checked against where the surface's minima are."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from gyrocal.fit.model import Model
from gyrocal.fit.profile import profiled_fit
from gyrocal.terms import make_term

DOF = 200
BUMP = {
    "name": "expression",
    "label": "bump",
    "formula": "exp(-((abs(rate_own) - m) / w) ** 2)",
    # the start a single-guess search would take: far from the true place and width
    "parameters": {"m": 40.0, "w": 12.6},
    "profile": {"m": [4.0, 400.0], "w": [0.8, 200.0]},
}


def _surface(valleys):
    """A fit whose χ² over (log m, log w) is DOF plus the deepest of Gaussian valleys, each
    (m, w, depth, width in log units)."""

    def fit_linear(model: Model):
        p = model.terms[0].parameters
        x, y = math.log(p["m"]), math.log(p["w"])
        chi2 = DOF - max(
            depth * math.exp(-((x - math.log(m)) ** 2 + (y - math.log(w)) ** 2) / (2 * s**2))
            for m, w, depth, s in valleys
        )
        fit = SimpleNamespace(chi2={"x": chi2}, dof={"x": DOF})
        return SimpleNamespace(fits=(fit,), used_points=lambda: [0])

    return fit_linear


def _profiled(valleys):
    fitted = profiled_fit(Model((make_term(BUMP),)), _surface(valleys))
    return {p["parameter"]: p for p in fitted.profiled}


def test_a_place_and_width_are_found_where_one_guess_would_stop_in_a_side_valley():
    """A shallow valley at the start (m = 40, w = 12.6) and the deep one at m = 150, w = 40,
    narrow in the width: scanned one parameter at a time from the start, the place never
    sees the deep valley (at w = 12.6 it is 4 log-widths away); the joint grid does."""
    found = _profiled([(40.0, 12.6, 5.0, 0.5), (150.0, 40.0, 80.0, 0.15)])
    assert found["m"]["value"] == pytest.approx(150.0, rel=0.01)
    assert found["w"]["value"] == pytest.approx(40.0, rel=0.01)
    assert "rival" not in found["m"] and "rival" not in found["w"]


def test_the_uncertainty_is_the_profile_interval():
    """For a Gaussian valley of log-width s and depth D, χ² rises by s² = χ²/dof (here
    (DOF − D)/DOF ≈ 1) where D(1 − exp(−u²/2s²)) = s²: the interval's half-width in log θ
    is s·sqrt(−2 ln(1 − s²/D)); the reported error is at least that (× θ)."""
    depth, s = 80.0, 0.15
    found = _profiled([(150.0, 40.0, depth, s)])
    s2 = (DOF - depth) / DOF
    half = s * math.sqrt(-2 * math.log(1 - s2 / depth))
    low, high = found["m"]["interval"]
    assert math.log(high / low) / 2 == pytest.approx(half, rel=0.1)
    assert found["m"]["stderr"] >= 150.0 * half * 0.9


def test_two_valleys_that_fit_alike_are_both_named():
    """Two valleys of equal depth far apart in the place: the value reported is one of them,
    and the other is named as a rival the data do not exclude."""
    found = _profiled([(20.0, 10.0, 60.0, 0.2), (200.0, 10.0, 60.0, 0.2)])
    values = sorted([found["m"]["value"], found["m"]["rival"]])
    assert values[0] == pytest.approx(20.0, rel=0.05) and values[1] == pytest.approx(200.0, rel=0.05)
