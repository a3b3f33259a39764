"""A joint grid of many points is solved from its normal equations point by point (each point
reads only the nodes around it), and its points' wander whiteners run as one pass: both give
the fit the whole design's SVD and the point-by-point whitening give."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrocal.fit import model as fit_module
from gyrocal.fit import thermal, wander
from gyrocal.fit.model import DEFAULT_TERMS, Model, columns_of, shares_wander
from gyrocal.io.errors import IdentifiabilityError

from .test_hold_temperature import holds

POINTS = np.linspace(-30.0, 80.0, 20)  # 20 nodes x 4 coefficients per axis: 80 columns
HOLD_S, GAP_S = 30.0, 10.0


def many_points(seed: int = 3) -> dict:
    """Holds at 20 points with a noise model whose slow wander (flicker) the holds share, so
    each point's holds are whitened among themselves (:func:`thermal._weights_by_point`)."""
    rng = np.random.default_rng(seed)
    rows = [r for k, t in enumerate(POINTS) for r in holds(rng, k, float(t), warm_first=0.5 * (k % 3 == 0))]
    obs = pd.DataFrame(rows)
    obs["t_start"] = np.arange(len(obs)) * (HOLD_S + GAP_S) + 3600.0 * obs["point"]
    obs["t_end"] = obs["t_start"] + HOLD_S
    for a in "xyz":
        obs[f"white_{a}"] = obs[f"std_{a}"] / np.sqrt(obs["n"])
        obs[f"floor_{a}"] = obs[f"white_{a}"]
        obs[f"flicker_{a}"] = 2e-4
        obs[f"rrw_{a}"] = 0.0
    data = columns_of(obs)
    assert shares_wander(data)
    return data


def joint(data: dict, *, design: dict | None = None) -> thermal.JointGridFit:
    model = Model.from_spec(DEFAULT_TERMS)
    used = [int(p) for p in np.unique(data["point"])]
    return thermal._fit_joint(model, data, method="lagrange3", degree=3, used=used, design=design)


def test_the_block_solve_is_the_svd_solve(monkeypatch):
    data = many_points()
    calls = []
    normal = fit_module._block_normal
    monkeypatch.setattr(fit_module, "_block_normal", lambda *a: calls.append(1) or normal(*a))
    by_blocks = joint(data)
    loo_blocks = by_blocks.leave_out(7)
    assert len(calls) == 6  # three axes, each fit solved by blocks (80 columns per axis)
    monkeypatch.setattr(fit_module, "BLOCK_SOLVE_COLUMNS", 10**9)
    by_svd = joint(data)
    loo_svd = by_svd.leave_out(7)
    assert len(calls) == 6
    # the same least squares: differences are rounding, a millionth of a standard error
    for a, b in ((by_blocks, by_svd), (loo_blocks, loo_svd)):
        assert a is not None and b is not None
        np.testing.assert_allclose(a.fit.values, b.fit.values, rtol=0, atol=1e-6 * b.fit.stderr.min())
        np.testing.assert_allclose(a.fit.stderr, b.fit.stderr, rtol=1e-9)


def test_the_covariance_at_a_temperature_is_the_mapping_of_the_joint_one():
    fitted = joint(many_points())
    at = np.array([-30.0, -12.3, 4.0, 41.7, 80.0])
    weights = fitted.grid.weights(at)
    index = {name: j for j, name in enumerate(fitted.fit.names)}
    # the coefficients at ``at`` as a linear map of the joint parameters, built entry by entry
    A = np.zeros((len(at), len(fitted.names), len(index)))
    for c, name in enumerate(fitted.names):
        for k, p in enumerate(fitted.point_ids):
            A[:, c, index[f"{name}.@{p}"]] = weights[:, k]
    expected = np.einsum("ncj,jk,ndk->ncd", A, fitted.fit.covariance, A)
    np.testing.assert_allclose(fitted.covariance_at(at), expected, rtol=1e-12, atol=0)
    k = 4
    own = fitted.point_fit(fitted.point_ids[k]).covariance
    np.testing.assert_array_equal(own, fitted.covariance_at(fitted.grid.temperatures[k : k + 1])[0])


def test_a_collinear_design_is_refused_alike(monkeypatch):
    """A design two of whose columns are one (a misalignment column a copy of the bias's)
    is refused by both solves, naming the same coefficients and the SVD's condition."""
    data = many_points()
    design = Model.from_spec(DEFAULT_TERMS).design(data)
    design["misalignment.x.y"] = 0.5 * np.broadcast_to(design["bias.x"], len(data["point"]))
    refused, conditions = [], []
    refuse = fit_module._refuse_unexcited
    monkeypatch.setattr(fit_module, "_refuse_unexcited", lambda *a: conditions.append(a[2]) or refuse(*a))
    for columns in (fit_module.BLOCK_SOLVE_COLUMNS, 10**9):
        monkeypatch.setattr(fit_module, "BLOCK_SOLVE_COLUMNS", columns)
        with pytest.raises(IdentifiabilityError) as info:
            joint(data, design=dict(design))
        refused.append((set(info.value.parameters), str(info.value)))
    # an exact collinearity: the SVD's condition is 1/rounding, about 1e16, in both
    assert 1e13 < conditions[0] < 1e19 and 1e13 < conditions[1] < 1e19, conditions
    assert refused[0][0] == refused[1][0]
    assert any(p.startswith("misalignment.x.y.@") for p in refused[0][0]), refused[0][0]
    assert "no rotation or holds that separate them" in refused[0][1], refused[0][1]
    assert "no rotation or holds that separate them" in refused[1][1], refused[1][1]


def test_points_whitened_in_one_pass_are_whitened_point_by_point():
    """Three points' holds (each point's own white levels, 40 s apart, an hour between the
    points, so each has its own poles), whitened in one pass and point by point: the same
    numbers to the last bit."""
    rng = np.random.default_rng(11)
    parts, records = [], []
    for k, n in enumerate((7, 12, 5)):
        t0 = 3600.0 * k + np.arange(n) * 40.0 + rng.uniform(0, 5, n)
        white = [rng.uniform(5e-4, 2e-3, n) for _ in range(3)]
        found = wander.whiteners(t0, t0 + 30.0, white, [2e-3] * 3, [1e-5] * 3)
        assert found is not None and isinstance(found[0], wander.Whitener)
        parts.append(found[0])
        records.append(rng.normal(size=(n, 4)))
    assert len({w.gen.U.shape[1] for w in parts}) > 1  # padded to the most poles
    together = wander.stacked(parts)
    assert together is not None
    taken = np.vstack([y[w.gen.order] for y, w in zip(records, parts, strict=True)])
    expected = np.vstack([w(y) for y, w in zip(records, parts, strict=True)])
    assert np.array_equal(together(taken), expected)
