"""Interpolation across temperature: seed 000 Eq 21-22, the other methods, clamping."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from gyrocal.fit.thermal import OutOfRangeWarning, TemperatureGrid, interpolation_weights, lagrange3_weights
from gyrocal.io.errors import ConfigError

NODES = np.array([-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0])  # Table 1


def eq22(T_k, T_i2, T_i1, T_i):
    """L0, L1, L2 of seed 000 Eq 22, written out as printed."""
    L0 = (T_k - T_i2) * (T_k - T_i1) / ((T_i - T_i2) * (T_i - T_i1))
    L1 = (T_k - T_i2) * (T_k - T_i) / ((T_i1 - T_i2) * (T_i1 - T_i))
    L2 = (T_k - T_i) * (T_k - T_i1) / ((T_i2 - T_i) * (T_i2 - T_i1))
    return L0, L1, L2


def test_lagrange_weights_are_eq22_on_every_interval():
    rng = np.random.default_rng(0)
    for i in range(2, len(NODES)):  # T_{i-1} < T_k < T_i with T_{i-2} available
        T_k = rng.uniform(NODES[i - 1], NODES[i], 50)
        W = lagrange3_weights(NODES, T_k)
        L0, L1, L2 = eq22(T_k, NODES[i - 2], NODES[i - 1], NODES[i])
        np.testing.assert_allclose(W[:, i], L0, rtol=0, atol=1e-13)
        np.testing.assert_allclose(W[:, i - 1], L1, rtol=0, atol=1e-13)
        np.testing.assert_allclose(W[:, i - 2], L2, rtol=0, atol=1e-13)
        assert np.count_nonzero(W, axis=1).max() == 3


def test_lagrange_is_exact_for_quadratics_and_has_the_cubic_remainder():
    x = np.linspace(-40, 50, 1001)
    quad = lambda t: 0.3 - 2e-3 * t + 4e-5 * t**2  # noqa: E731
    W = lagrange3_weights(NODES, x)
    np.testing.assert_allclose(W @ quad(NODES), quad(x), rtol=0, atol=1e-12)
    # For a cubic c t³ the error of three-point interpolation is c (x-a)(x-b)(x-d).
    c = 1e-7
    i = np.clip(np.searchsorted(NODES, x, side="left"), 1, len(NODES) - 1)
    lo = np.maximum(i - 2, 0)
    a, b, d = NODES[lo], NODES[lo + 1], NODES[lo + 2]
    np.testing.assert_allclose(
        W @ (c * NODES**3) - c * x**3, -c * (x - a) * (x - b) * (x - d), rtol=0, atol=1e-12
    )


def test_every_method_passes_through_the_nodes():
    values = np.sin(NODES / 20.0)
    for method in ("lagrange3", "linear", "spline"):
        W = interpolation_weights(method, NODES, NODES)
        np.testing.assert_allclose(W @ values, values, rtol=0, atol=1e-12, err_msg=method)


def test_spline_is_the_natural_cubic_spline_and_poly_fits_polynomials():
    values = np.cos(NODES / 15.0)
    x = np.linspace(-40, 50, 333)
    W = interpolation_weights("spline", NODES, x)
    np.testing.assert_allclose(
        W @ values, CubicSpline(NODES, values, bc_type="natural")(x), rtol=0, atol=1e-12
    )
    cubic = 1 + 1e-2 * NODES - 3e-4 * NODES**2 + 2e-6 * NODES**3
    W = interpolation_weights("poly", NODES, x, degree=3)
    np.testing.assert_allclose(W @ cubic, 1 + 1e-2 * x - 3e-4 * x**2 + 2e-6 * x**3, rtol=0, atol=1e-10)


def test_outside_the_range_every_method_clamps_and_warns():
    grid = TemperatureGrid(
        NODES, ("bias.x",), NODES[:, None] * 1e-3 + 1.0, np.full((10, 1), 1e-4), "lagrange3"
    )
    for method in ("lagrange3", "linear", "spline", "poly"):
        g = TemperatureGrid(grid.temperatures, grid.names, grid.values, grid.stderr, method)
        with pytest.warns(OutOfRangeWarning, match="2 of 3 samples"):
            v = g.at([-60.0, 0.0, 80.0])["bias.x"]
        ends = g.at([-40.0, 50.0], warn=False)["bias.x"]
        np.testing.assert_allclose(v[[0, 2]], ends, rtol=0, atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grid.at([-40.0, 50.0])  # the ends themselves are inside


def test_uncertainty_propagates_through_the_weights():
    se = np.full((10, 1), 2e-4)
    grid = TemperatureGrid(NODES, ("bias.x",), np.zeros((10, 1)), se, "lagrange3")
    at_node = grid.stderr_at([10.0])["bias.x"]
    np.testing.assert_allclose(at_node, 2e-4, rtol=1e-12)
    L = np.array(eq22(5.0, -10.0, 0.0, 10.0))
    np.testing.assert_allclose(grid.stderr_at([5.0])["bias.x"], 2e-4 * np.sqrt(np.sum(L**2)), rtol=1e-12)


def test_small_grids_and_bad_methods():
    one = interpolation_weights("lagrange3", [20.0], [0.0, 20.0, 40.0])
    np.testing.assert_array_equal(one, np.ones((3, 1)))
    two = interpolation_weights("lagrange3", [0.0, 20.0], [10.0])
    np.testing.assert_allclose(two, [[0.5, 0.5]])
    with pytest.raises(ConfigError, match="interpolation method 'akima' is not known"):
        interpolation_weights("akima", NODES, [0.0])
    with pytest.raises(ConfigError, match="increase"):
        TemperatureGrid(np.array([10.0, 0.0]), ("a.x",), np.zeros((2, 1)), np.zeros((2, 1)))
