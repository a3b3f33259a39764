"""The wander-aware fit in time linear in the holds: the semiseparable Cholesky against a
dense matrix and LAPACK, the generators against the covariance written entry by entry, and
the fit against dense generalised least squares on random interval layouts, pole sets and
noise levels."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gyrocal.fit import kernels, wander
from gyrocal.fit.model import DEFAULT_TERMS, Model, fit, observation_floor

from .conftest import needs
from .wander_reference import (
    dense_gls,
    dense_semiseparable,
    dense_whiteners,
    held_covariances,
    time_covariances,
)

AXES = "xyz"
compiled = needs(
    {"the C kernel's semiseparable factor": kernels.LIB is not None},
    "pip builds it on install where gcc is found, as make test does",
)


@st.composite
def layouts(draw, min_holds=2, max_holds=40):
    """Disjoint holds: durations from 0.2 s to an hour, gaps from none to three hours, in a
    shuffled row order; the longest correlation time reaches ten times the span, so the
    pole set changes with the layout."""
    n = draw(st.integers(min_holds, max_holds))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    duration = 10.0 ** rng.uniform(np.log10(0.2), np.log10(3600.0), n)
    gap = np.where(rng.random(n) < 0.3, 0.0, 10.0 ** rng.uniform(-1, np.log10(3 * 3600.0), n))
    start = 1000.0 * rng.random() + np.cumsum(np.r_[0.0, duration[:-1] + gap[1:]])
    end = np.minimum(start + duration, np.r_[start[1:], np.inf])  # back to back: no rounding overlap
    order = rng.permutation(n) if draw(st.booleans()) else np.arange(n)
    return start[order], end[order], rng


def noise_levels(rng, n):
    """Per axis: white noise of each hold (1e-4 to 1e-1 deg/s), a flicker level and a
    random walk, each absent on some axes, from far below the white noise to above it."""
    white = 10.0 ** rng.uniform(-4, -1, 3)[None, :] * rng.uniform(0.5, 2.0, (n, 3))
    flicker = np.where(rng.random(3) < 0.2, 0.0, 10.0 ** rng.uniform(-5, -1.5, 3))
    rrw = np.where(rng.random(3) < 0.2, 0.0, 10.0 ** rng.uniform(-7, -3.5, 3))
    return white, flicker, rrw


@compiled
@given(layouts(), st.integers(1, 6))
def test_the_compiled_factor_matches_numpy_and_lapack(layout, columns):
    a, _, rng = layout
    n, J = len(a), columns
    U, V = rng.normal(size=(n, J)), rng.normal(size=(n, J))
    alpha, beta = rng.uniform(0, 1, (n, J)), rng.uniform(0, 1, (n, J))
    scale = np.where(rng.random(J) < 0.2, 0.0, rng.uniform(0.1, 2.0, J))  # zero: column left out
    C0 = dense_semiseparable(np.zeros(n), U * scale, V * scale, alpha, beta)
    # positive definite: a diagonal above the largest eigenvalue's size, varying by row
    diag = np.abs(np.linalg.eigvalsh(C0)).max() + np.abs(np.diag(C0)) + rng.uniform(0.01, 1, n)
    reference = np.linalg.solve(np.linalg.cholesky(C0 + np.diag(diag)), Y := rng.normal(size=(n, 3)))
    found = kernels.semiseparable_cholesky(diag, U, V, alpha, beta, scale)
    assert found is not None
    Z = kernels.semiseparable_whiten(U, *found, alpha, beta, Y, scale)
    np.testing.assert_allclose(Z, reference, rtol=1e-9, atol=1e-12 * np.abs(reference).max())
    np.testing.assert_array_equal(
        kernels.semiseparable_whiten(U, *found, alpha, beta, Y[:, 1], scale), Z[:, 1]
    )
    lib = kernels.LIB
    try:
        kernels.LIB = None
        W, D = kernels.semiseparable_cholesky(diag, U, V, alpha, beta, scale)
        Zn = kernels.semiseparable_whiten(U, W, D, alpha, beta, Y, scale)
    finally:
        kernels.LIB = lib
    np.testing.assert_allclose(D, found[1], rtol=1e-12)
    np.testing.assert_allclose(Zn, Z, rtol=1e-11, atol=1e-13 * np.abs(Z).max())


def test_a_matrix_that_is_not_positive_definite_is_refused(monkeypatch):
    U = V = np.ones((3, 1))
    decay = np.ones((3, 1))
    for lib in (kernels.LIB, None):
        monkeypatch.setattr(kernels, "LIB", lib)
        assert kernels.semiseparable_cholesky(np.array([1.0, 1.0, 1.0]), U, V, decay, decay) is None
        assert kernels.semiseparable_cholesky(np.array([2.0, 2.0, 2.0]), U, V, decay, decay) is not None


@given(layouts(max_holds=30))
def test_the_generators_are_the_covariance_written_entry_by_entry(layout):
    a, b, _ = layout
    assert np.all(np.diff(a[wander.hold_wander(a, b).order]) >= 0)
    flicker, walk = time_covariances(a, b)
    F, K = held_covariances(a, b)
    np.testing.assert_allclose(F, flicker, rtol=1e-12, atol=1e-14 * np.abs(flicker).max())
    np.testing.assert_allclose(K, walk, rtol=1e-12, atol=1e-14 * np.abs(walk).max())


def observations(a, b, rng, white, flicker, rrw) -> dict:
    """Hold means of a unit with a bias, scale and misalignment, on random rate vectors,
    with the noise model's columns (what segmentation writes)."""
    n = len(a)
    rate = rng.normal(0, 100.0, (n, 3))
    K = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    gyro = rate @ K.T + rng.normal(0, 0.5, 3) + rng.normal(0, 1, (n, 3)) * white * 3
    data = {"t_start": a, "t_end": b, "n": np.full(n, 100.0)}
    for i, ax in enumerate(AXES):
        data[f"rate_{ax}"] = rate[:, i]
        data[f"gyro_{ax}"] = gyro[:, i]
        data[f"std_{ax}"] = white[:, i] * 10.0
        data[f"floor_{ax}"] = np.hypot(white[:, i], flicker[i] + rrw[i] * 30.0)
        data[f"white_{ax}"] = white[:, i]
        data[f"flicker_{ax}"] = np.full(n, flicker[i])
        data[f"rrw_{ax}"] = np.full(n, rrw[i])
    return data


MODEL = Model.from_spec(DEFAULT_TERMS)


@given(layouts(min_holds=8, max_holds=60))
def test_the_fit_is_dense_generalised_least_squares(layout):
    """Coefficients, standard errors and chi-square to 1e-9 relative: the same estimator,
    not an approximation of it."""
    a, b, rng = layout
    white, flicker, rrw = noise_levels(rng, len(a))
    data = observations(a, b, rng, white, flicker, rrw)
    result = fit(MODEL, data)
    floor = observation_floor(data)
    floor = np.maximum(floor, 1e-3 * np.median(floor, axis=0))  # the fit's own clamp
    whiten = dense_whiteners(data, floor)
    design = MODEL.design(data)
    for i, ax in enumerate(AXES):
        names = MODEL.axis_names(ax)
        X = np.column_stack([np.broadcast_to(design[c], len(a)) for c in names])
        theta, cov, chi2 = dense_gls(X, data[f"gyro_{ax}"] - data[f"rate_{ax}"], whiten[i])
        stderr = np.sqrt(np.diag(cov))
        at = [MODEL.names.index(c) for c in names]
        # relative to the value, or to its standard error where that is larger (a value
        # within its noise of zero)
        error = np.abs(result.values[at] - theta) / np.maximum(np.abs(theta), stderr)
        assert error.max() < 1e-9, error
        np.testing.assert_allclose(result.stderr[at], stderr, rtol=1e-9)
        assert result.chi2[ax] == pytest.approx(chi2, rel=1e-9)


def test_row_order_does_not_change_the_fit():
    rng = np.random.default_rng(3)
    n = 80
    a = np.cumsum(rng.uniform(5, 60, n))
    b = a + rng.uniform(1, 4, n)
    data = observations(a, b, rng, *noise_levels(np.random.default_rng(4), n))
    shuffle = rng.permutation(n)
    one = fit(MODEL, data)
    other = fit(MODEL, {k: v[shuffle] for k, v in data.items()})
    np.testing.assert_array_equal(one.values, other.values)
    np.testing.assert_array_equal(one.stderr, other.stderr)
    assert one.chi2 == other.chi2
    np.testing.assert_array_equal(one.residuals[shuffle], other.residuals)


def test_holds_that_overlap_in_time_are_weighted_by_their_floor():
    """No segmenter makes them; the covariance is that of disjoint holds, so such
    observations fall back to independent noise rather than a wrong covariance."""
    rng = np.random.default_rng(5)
    n = 30
    a = np.cumsum(rng.uniform(5, 60, n))
    b = a + rng.uniform(1, 4, n)
    b[10] = a[11] + 0.5
    data = observations(a, b, rng, *noise_levels(np.random.default_rng(6), n))
    plain = {k: v for k, v in data.items() if not k.startswith(("white_", "flicker_", "rrw_"))}
    np.testing.assert_array_equal(fit(MODEL, data).values, fit(MODEL, plain).values)


def test_refits_of_the_same_holds_reuse_their_factor(monkeypatch):
    rng = np.random.default_rng(7)
    n = 50
    a = np.cumsum(rng.uniform(5, 60, n))
    data = observations(a, a + 3.0, rng, *noise_levels(np.random.default_rng(8), n))
    wander._cache.clear()
    calls = []
    factor = kernels.semiseparable_cholesky
    monkeypatch.setattr(kernels, "semiseparable_cholesky", lambda *x: calls.append(1) or factor(*x))
    first = fit(MODEL, data)
    count = len(calls)
    assert count == 3  # one factor per output axis
    again = fit(Model.from_spec(["bias", "scale"]), data)  # another model, the same holds
    assert len(calls) == count
    keep = np.arange(n) >= 10
    fit(MODEL, {k: v[keep] for k, v in data.items()})  # other holds: factored anew
    assert len(calls) == 2 * count
    np.testing.assert_array_equal(first.values, fit(MODEL, data).values)
    assert again.n_obs == n


# -- refits that reuse what the fit of all holds made ----------------------------------------


@pytest.fixture(scope="module")
def coloured_sweep(tmp_path_factory):
    """A short sweep of a complete unit with a Gauss-Markov bias and a rate random walk, from
    the independent generator, segmented: observations with the noise model's columns and
    the session's temperature record."""
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings

    path = tmp_path_factory.mktemp("sweep") / "sweep.parquet"
    write_session(
        make_unit(effect="none", protocol="sweep", noise="coloured", seed=1),
        path,
        session=0,
        seed=5,
        rate_hz=5.0,
        ramp_c_per_h=60.0,
    )
    obs = segment_log(path, Settings(), "sweep").observations
    assert max(obs[f"{k}_{a}"].max() for k in ("flicker", "rrw") for a in AXES) > 0  # wander modelled
    return obs


def same_fit(a, b) -> None:
    for x, y in zip(a.fits, b.fits, strict=False):
        np.testing.assert_array_equal(x.values, y.values)
        np.testing.assert_array_equal(x.stderr, y.stderr)
        assert x.chi2 == y.chi2


def test_leaving_a_point_out_reuses_the_columns_and_gives_the_fresh_fit(coloured_sweep, monkeypatch):
    """Bit for bit what fitting the remaining holds from scratch gives, with the series
    terms' quadrature made once: a hold's columns are its own."""
    from gyrocal.fit.thermal import fit_continuous
    from gyrocal.terms import signals

    obs = coloured_sweep
    model = Model.from_spec(["bias", "bias_temp_poly(degree=1)", "temp_rate"])
    fitted = fit_continuous(model, obs)
    calls = []
    made = signals._nodes
    monkeypatch.setattr(signals, "_nodes", lambda *x: calls.append(1) or made(*x))
    points = np.unique(obs["point"])
    refits = [fitted.leave_out(int(p)) for p in points]
    assert calls == []
    monkeypatch.undo()
    for p, refit in zip(points, refits, strict=False):
        keep = obs["point"].to_numpy() != p
        same_fit(refit, fit_continuous(model, obs[keep]))


def test_a_joint_grid_leaves_a_point_out_as_a_fresh_fit_would(logs):
    from dataclasses import replace

    from gyrocal.fit.thermal import JointGridFit, _fit_joint, fit_model
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import ModelSettings, Settings

    obs = segment_log(logs["complete"], Settings()).observations
    m = replace(
        Settings(), model=ModelSettings.from_dict({"expressions": {"warmup": {"formula": "exp(-t / 1200)"}}})
    ).model
    fitted = fit_model(m.build(), obs, kind=m.kind, method=m.interpolation, degree=m.degree)
    assert isinstance(fitted, JointGridFit)
    for p in fitted.used_points()[:3]:
        keep = fitted.data["point"].astype(int) != p
        fresh = _fit_joint(
            fitted.model,
            {k: v[keep] for k, v in fitted.data.items()},
            method=fitted.grid.method,
            degree=fitted.grid.degree,
            used=[q for q in fitted.point_ids if q != p],
            rows=fitted.rows[0][keep],
            excluded=fitted.excluded,
        )
        same_fit(fitted.leave_out(p), fresh)


def test_the_quadrature_nodes_are_made_once_for_the_same_holds(coloured_sweep, monkeypatch):
    from gyrocal.fit.model import columns_of
    from gyrocal.terms import signals

    data = columns_of(coloured_sweep)
    model = Model.from_spec(["temp_rate"])
    first = model.design(data)
    calls = []
    made = signals._nodes
    monkeypatch.setattr(signals, "_nodes", lambda *x: calls.append(1) or made(*x))
    for tau in (60.0, 600.0):  # a profiled lag asks for the same holds at every value
        Model.from_spec([f"temp_lag(tau={tau})"]).design(data)
    again = model.design(data)
    assert calls == []
    for name in first:
        np.testing.assert_array_equal(first[name], again[name])
    data["series"]._cache.clear()
    for name, values in model.design(data).items():
        np.testing.assert_array_equal(values, first[name])
