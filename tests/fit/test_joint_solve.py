"""A joint grid of many points is solved from its normal equations point by point (each point
reads only the nodes around it), and its points' wander whiteners run as one pass: both give
the fit the whole design's SVD and the point-by-point whitening give."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrocal.fit import model as fit_model_module
from gyrocal.fit import wander
from gyrocal.fit.model import DEFAULT_TERMS, Model
from gyrocal.fit.thermal import fit_model
from gyrocal.io.errors import IdentifiabilityError

from .test_hold_temperature import holds

POINTS = np.linspace(-30.0, 80.0, 20)  # 20 nodes x 4 coefficients per axis: 80 columns


def many_points(mounts_seed: int = 3, one_mount: bool = False) -> pd.DataFrame:
    rng = np.random.default_rng(mounts_seed)
    rows = [r for k, t in enumerate(POINTS) for r in holds(rng, k, float(t), warm_first=0.5 * (k % 3 == 0))]
    obs = pd.DataFrame(rows)
    return obs[obs["mount"] == "+x"] if one_mount else obs


def fitted_both_ways(monkeypatch, obs):
    """The grid solved by blocks (the default at 80 columns) and by the SVD of the design."""
    by_blocks = fit_model(Model.from_spec(DEFAULT_TERMS), obs, kind="grid", method="lagrange3")
    monkeypatch.setattr(fit_model_module, "BLOCK_SOLVE_COLUMNS", 10**9)
    by_svd = fit_model(Model.from_spec(DEFAULT_TERMS), obs, kind="grid", method="lagrange3")
    monkeypatch.undo()
    return by_blocks, by_svd


def test_the_block_solve_is_the_svd_solve(monkeypatch):
    by_blocks, by_svd = fitted_both_ways(monkeypatch, many_points())
    assert len(by_blocks.fit.names) >= 3 * fit_model_module.BLOCK_SOLVE_COLUMNS
    # the same least squares: differences are rounding, a millionth of a standard error
    for a, b in ((by_blocks, by_svd), (by_blocks.leave_out(7), by_svd.leave_out(7))):
        assert a is not None and b is not None
        np.testing.assert_allclose(a.fit.values, b.fit.values, rtol=0, atol=1e-6 * b.fit.stderr.min())
        np.testing.assert_allclose(a.fit.stderr, b.fit.stderr, rtol=1e-9)
        np.testing.assert_allclose(
            a.covariance_at(POINTS[5:9]), b.covariance_at(POINTS[5:9]), rtol=1e-8, atol=0
        )


def test_a_design_the_holds_do_not_excite_is_refused_alike(monkeypatch):
    obs = many_points(one_mount=True)  # turning about x alone: y and z's scales are not excited
    refused = []
    for columns in (fit_model_module.BLOCK_SOLVE_COLUMNS, 10**9):
        monkeypatch.setattr(fit_model_module, "BLOCK_SOLVE_COLUMNS", columns)
        with pytest.raises(IdentifiabilityError) as info:
            fit_model(Model.from_spec(DEFAULT_TERMS), obs, kind="grid", method="lagrange3", profile=False)
        refused.append(set(info.value.parameters))
    assert refused[0] == refused[1] and any(p.startswith("scale.y") for p in refused[0])


def test_points_whitened_in_one_pass_are_whitened_point_by_point():
    """Three points' holds (each point's own white levels, 40 s apart, an hour between the
    points), whitened in one pass and point by point: the same numbers to the last bit."""
    rng = np.random.default_rng(11)
    parts, records = [], []
    for k, n in enumerate((7, 12, 5)):
        t0 = 3600.0 * k + np.arange(n) * 40.0 + rng.uniform(0, 5, n)
        white = [rng.uniform(5e-4, 2e-3, n) for _ in range(3)]
        found = wander.whiteners(t0, t0 + 30.0, white, [2e-3] * 3, [1e-5] * 3)
        assert found is not None and isinstance(found[0], wander.Whitener)
        parts.append(found[0])
        records.append(rng.normal(size=(n, 4)))
    together = wander.stacked(parts)
    assert together is not None
    taken = np.vstack([y[w.gen.order] for y, w in zip(records, parts, strict=True)])
    expected = np.vstack([w(y) for y, w in zip(records, parts, strict=True)])
    assert np.array_equal(together(taken), expected)
