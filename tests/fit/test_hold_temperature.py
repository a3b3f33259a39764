"""A grid calibration fits each hold at its own temperature: a hold taken while the unit was
still off its point (the chamber door opened at a remount) is fitted with the coefficients
the interpolation gives at that temperature, as apply will give them."""

from __future__ import annotations

import numpy as np
import pandas as pd

from gyrocal.fit.model import DEFAULT_TERMS, Model
from gyrocal.fit.thermal import fit_grid, fit_model

RATES = [0.0] + [s * r for r in (0.1, 1, 10, 50, 100, 200, 400) for s in (1, -1)]
SIGMA, N = 0.05, 6000  # deg/s per sample, samples per hold: 6.5e-4 deg/s per hold mean
S0, S1, S2 = 3e-4, 2e-5, 1e-7  # scale: 1 + S0 + S1 dT + S2 dT², per axis times (1, 1.5, 2)
B0, B1, B2 = 0.05, 2e-3, 1e-5  # bias (deg/s): the same way
MIS = np.array([[0, 2e-4, -1e-4], [3e-4, 0, 1.5e-4], [-2e-4, 1e-4, 0]])


def truth(temp: float) -> tuple[np.ndarray, np.ndarray]:
    """K and B at ``temp``: quadratic in it, so three-point Lagrange interpolation through
    any three nodes is exact and only the fit's noise stands between the fit and the truth."""
    d = temp - 25.0
    per_axis = np.array([1.0, 1.5, 2.0])
    K = np.eye(3) + np.diag((S0 + S1 * d + S2 * d * d) * per_axis) + MIS
    return K, (B0 + B1 * d + B2 * d * d) * per_axis


def holds(rng, point: int, temp: float, *, warm_first: float = 0.0, rates=RATES) -> list[dict]:
    """Hold means on three mounts at ``temp``; with ``warm_first``, each mount's first two
    holds (its top rate both ways, taken right after the remount) are that much warmer."""
    rows = []
    for mount in ("+x", "+y", "+z"):
        axis = "xyz".index(mount[1])
        for k, rate in enumerate(sorted(rates, key=lambda r: -abs(r))):
            t = temp + (warm_first if k < 2 else 0.0) + rng.normal(0, 0.01)
            K, B = truth(t)
            w_true = np.zeros(3)
            w_true[axis] = rate
            std = SIGMA * rng.uniform(0.9, 1.1, 3)
            w = K @ w_true + B + rng.normal(0, std / np.sqrt(N))
            rows.append(
                dict(
                    point=point,
                    mount=mount,
                    ref_rate=rate,
                    n=N,
                    temp=t,
                    **{f"rate_{a}": w_true[i] for i, a in enumerate("xyz")},
                    **{f"gyro_{a}": w[i] for i, a in enumerate("xyz")},
                    **{f"std_{a}": std[i] for i, a in enumerate("xyz")},
                )
            )
    return rows


def session(seed: int = 7) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = holds(rng, 0, -20.0, warm_first=3.0) + holds(rng, 1, 25.0) + holds(rng, 2, 70.0, warm_first=-2.0)
    # a stray point: two holds the segmenter split off between the points, too few to fit alone
    rows += holds(rng, 3, 40.0, rates=[200.0])[:2]
    return pd.DataFrame(rows)


def z_scores(grid) -> np.ndarray:
    """(fitted - true) over the stated standard error, every coefficient at every node."""
    model = Model.from_spec(DEFAULT_TERMS)
    out = []
    for k, temp in enumerate(grid.temperatures):
        K, B = truth(float(temp))
        for j, name in enumerate(grid.names):
            term, a, *rest = name.split(".")
            i = "xyz".index(a)
            true = B[i] if term == "bias" else K[i, i] - 1 if term == "scale" else K[i, "xyz".index(rest[0])]
            out.append((grid.values[k, j] - true) / grid.stderr[k, j])
    assert len(out) == len(grid.temperatures) * len(model.names)
    return np.array(out)


def test_holds_off_their_point_are_fitted_where_they_were():
    obs = session()
    fitted = fit_model(Model.from_spec(DEFAULT_TERMS), obs, kind="grid", method="lagrange3")
    # each node at its settled holds' temperature, not pulled by the warm ones (the end
    # nodes past all but 5 % of them: 1.6 times the 0.01 °C scatter of a hold's temperature)
    np.testing.assert_allclose(fitted.grid.temperatures, [-20.0, 25.0, 70.0], atol=0.03)
    z = z_scores(fitted.grid)
    # 36 coefficients: beyond 4.5 standard errors by chance with probability 2.5e-4
    assert np.max(np.abs(z)) < 4.5, np.round(z, 1)
    # The same holds each taken at its point's temperature: the warm holds' change of scale
    # and bias (S1 · 3 °C · 400 deg/s is 37 times a hold's noise on x) lands in the point's
    # coefficients, about 9 standard errors off; beyond 6 whatever the noise's draw.
    alone = fit_grid(Model.from_spec(DEFAULT_TERMS), obs[obs["point"] < 3], method="lagrange3")
    assert np.max(np.abs(z_scores(alone.grid))) > 6


def test_a_stray_points_holds_take_part_at_their_temperature():
    obs = session()
    fitted = fit_model(Model.from_spec(DEFAULT_TERMS), obs, kind="grid", method="lagrange3")
    table = fitted.points.set_index("point")
    assert not table.loc[3, "used"] and table.loc[[0, 1, 2], "used"].all()
    assert len(fitted.rows[0]) == len(obs)  # the stray holds are fitted, inside the span
    # left out, the middle point is predicted by the two others and the stray holds near it
    loo = fitted.leave_out(1)
    assert loo is not None and list(loo.point_ids) == [0, 2]
    assert set(np.unique(loo.data["point"])) == {0, 2, 3}
