"""Terms, the weighted fit against an independent reference, honest uncertainties."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

from gyrocal.fit.model import Model, fit
from gyrocal.io.errors import ConfigError, IdentifiabilityError
from gyrocal.simulate.unit import SEED000_B25, SEED000_K25
from gyrocal.terms import TERMS, Term, make_term, register_term

RATES = [0.0] + [s * r for r in (0.1, 1, 10, 50, 100, 150, 200, 250, 300, 400) for s in (1, -1)]


def synthetic_obs(K, B, *, rng, mounts=("+x", "+y", "+z"), sigma=0.05, n=6000):
    """Hold means of a linear gyro, w = K w_true + B + noise/sqrt(n), for the seed's rates."""
    rows = []
    for mount in mounts:
        axis, sign = "xyz".index(mount[1]), 1.0 if mount[0] == "+" else -1.0
        for rate in RATES:
            w_true = np.zeros(3)
            w_true[axis] = sign * rate
            std = sigma * rng.uniform(0.8, 1.2, 3)
            w = K @ w_true + B + rng.normal(0, std / np.sqrt(n))
            rows.append(
                dict(
                    mount=mount,
                    ref_rate=rate,
                    n=n,
                    temp=25.0,
                    **{f"rate_{a}": w_true[i] for i, a in enumerate("xyz")},
                    **{f"gyro_{a}": w[i] for i, a in enumerate("xyz")},
                    **{f"std_{a}": std[i] for i, a in enumerate("xyz")},
                )
            )
    return pd.DataFrame(rows)


def truth_vector(model, K, B):
    out = []
    for name in model.names:
        term, a, *rest = name.split(".")
        i = "xyz".index(a)
        out.append(B[i] if term == "bias" else K[i, i] - 1 if term == "scale" else K[i, "xyz".index(rest[0])])
    return np.array(out)


def test_fit_matches_an_independent_weighted_least_squares():
    rng = np.random.default_rng(1)
    obs = synthetic_obs(SEED000_K25, SEED000_B25, rng=rng)
    result = fit(Model.from_spec(), obs)
    # Seed 000 Eq 15: output a regressed on (w~_x, w~_y, w~_z, 1), weighted by 1/floor².
    Omega = np.column_stack([obs["rate_x"], obs["rate_y"], obs["rate_z"], np.ones(len(obs))])
    for i, a in enumerate("xyz"):
        sw = np.sqrt(obs["n"]) / obs[f"std_{a}"]
        coef, *_ = np.linalg.lstsq(Omega * sw.to_numpy()[:, None], obs[f"gyro_{a}"] * sw, rcond=None)
        K_row, B_a = coef[:3], coef[3]
        assert result.coef(f"bias.{a}") == pytest.approx(B_a, abs=1e-12)
        assert result.coef(f"scale.{a}") == pytest.approx(K_row[i] - 1.0, abs=1e-12)
        for j, b in enumerate("xyz"):
            if b != a:
                assert result.coef(f"misalignment.{a}.{b}") == pytest.approx(K_row[j], abs=1e-12)


def test_reported_standard_errors_are_honest_over_many_experiments():
    """Over 400 simulated calibrations the scatter of each fitted coefficient matches its
    reported standard error, and z = (fit - truth) / stderr follows Student's t with the
    fit's 65 degrees of freedom."""
    rng = np.random.default_rng(7)
    model = Model.from_spec()
    truth = truth_vector(model, SEED000_K25, SEED000_B25)
    values, errors = [], []
    for _ in range(400):
        result = fit(model, synthetic_obs(SEED000_K25, SEED000_B25, rng=rng))
        values.append(result.values)
        errors.append(result.stderr)
    values, errors = np.array(values), np.array(errors)
    N = len(values)
    # The sample sd of N normal draws has relative sd 1/sqrt(2N) = 3.5 %: 4 of them is 14 %.
    ratio = values.std(axis=0, ddof=1) / np.sqrt(np.mean(errors**2, axis=0))
    np.testing.assert_allclose(ratio, 1.0, atol=4 / np.sqrt(2 * N))
    # No bias: each mean within 4 standard errors of the mean.
    bias = np.abs(values.mean(axis=0) - truth) / (values.std(axis=0, ddof=1) / np.sqrt(N))
    assert bias.max() < 4.0
    z = (values - truth) / errors
    # E[t²] = 65/63 for t with 65 dof; the four coefficients of an axis share one scatter
    # estimate, so their z² move together; 0.15 is 4 sd even for fully shared clusters.
    assert np.mean(z**2) == pytest.approx(65 / 63, abs=0.15)
    # P(|t65| > 3) = 0.38 %: 18 of 4800 expected; in clusters of up to 4 the 99.9 % bound
    # is 4 x 13 (Poisson(18/4) quantile).
    assert np.sum(np.abs(z) > 3) <= 52


def test_protocol_without_rotation_about_y_is_refused_naming_the_coefficients():
    obs = synthetic_obs(SEED000_K25, SEED000_B25, rng=np.random.default_rng(2), mounts=("+x", "+z"))
    with pytest.raises(IdentifiabilityError) as info:
        fit(Model.from_spec(), obs, source="unit.parquet", label="25.0 °C")
    assert set(info.value.parameters) >= {"scale.y", "misalignment.x.y", "misalignment.z.y"}
    text = str(info.value)
    assert "scale.y" in text and "25.0 °C" in text and text.startswith("unit.parquet: ")


def test_collinear_design_is_refused():
    obs = synthetic_obs(SEED000_K25, SEED000_B25, rng=np.random.default_rng(3))
    only_one_rate = obs[obs["ref_rate"] == 100.0]  # scale and bias cannot be separated
    with pytest.raises(IdentifiabilityError) as info:
        fit(Model.from_spec(), only_one_rate)
    assert "bias.x" in info.value.parameters and "scale.x" in info.value.parameters


def test_too_few_observations_leave_no_uncertainty_and_are_refused():
    obs = synthetic_obs(SEED000_K25, SEED000_B25, rng=np.random.default_rng(4))
    few = obs[obs["ref_rate"].isin([100.0, -100.0])].iloc[:4]
    with pytest.raises(IdentifiabilityError):
        fit(Model.from_spec(), few)


def test_compensation_inverts_the_model():
    rng = np.random.default_rng(5)
    model = Model.from_spec()
    coefs = dict(zip(model.names, truth_vector(model, SEED000_K25, SEED000_B25), strict=False))
    w_true = rng.uniform(-400, 400, (1000, 3))
    w = w_true @ SEED000_K25.T + SEED000_B25
    back, J = model.compensate(coefs, w, {"temp": np.zeros(1000)})
    np.testing.assert_allclose(back, w_true, rtol=0, atol=1e-9)
    np.testing.assert_allclose(J[0], SEED000_K25, rtol=0, atol=1e-12)


def test_unknown_and_clashing_terms_are_config_errors():
    with pytest.raises(ConfigError, match="unknown model term 'nope'.*bias"):
        make_term("nope")
    with pytest.raises(ConfigError, match="both define bias.x"):
        Model.from_spec(["bias", "bias"])
    with pytest.raises(ConfigError, match="term scale"):
        make_term({"name": "scale", "degree": 2})


def test_a_registered_term_takes_part_like_the_library_ones():
    @register_term("test_rate_squared")
    @dataclass(frozen=True)
    class RateSquared(Term):
        """Scale nonlinearity: error proportional to the signed square of the rate."""

        unit = "1/(deg/s)"
        needs = frozenset({"rate_x", "rate_y", "rate_z"})

        def coefficients(self):
            return [f"test_rate_squared.{a}" for a in "xyz"]

        def columns(self, data):
            return {f"test_rate_squared.{a}": data[f"rate_{a}"] * np.abs(data[f"rate_{a}"]) for a in "xyz"}

    try:
        rng = np.random.default_rng(6)
        obs = synthetic_obs(SEED000_K25, SEED000_B25, rng=rng)
        k2 = 2e-6
        for a in "xyz":
            obs[f"gyro_{a}"] += k2 * obs[f"rate_{a}"] * obs[f"rate_{a}"].abs()
        result = fit(Model.from_spec(["bias", "scale", "misalignment", "test_rate_squared"]), obs)
        i = result.names.index("test_rate_squared.x")
        assert abs(result.values[i] - k2) < 4 * result.stderr[i]
    finally:
        TERMS.pop("test_rate_squared")


def _spline_holds(t, seed=0, floor=0.002):
    """Hold means whose bias follows a smooth warm-up in t, with white noise at the floor."""
    rng = np.random.default_rng(seed)
    n = len(t)
    truth = 0.3 * np.exp(-t / 800.0)
    data = {
        "t_start": t - 10.0,
        "t_end": t + 10.0,
        "n": np.full(n, 100.0),
        **{f"rate_{a}": np.zeros(n) for a in "xyz"},
    }
    from gyrocal.terms.signals import Series

    record = np.arange(0.0, t.max() + 60.0, 1.0)
    data["series"] = Series(record, np.full(record.size, 25.0), 0.0, 60.0, np.ones(record.size))
    for a in "xyz":
        data[f"gyro_{a}"] = 0.1 + truth + floor * rng.standard_normal(n)
        data[f"std_{a}"] = np.full(n, floor * 10.0)
    return data, truth


def test_a_light_penalty_leaves_a_well_sampled_spline_as_least_squares_fits_it():
    """Where holds determine every coefficient, the spline's penalty changes the fitted hold
    means by far less than their noise floor; across a stretch without holds it draws a bounded curve
    where least squares alone would have no answer."""
    from gyrocal.fit.model import fit

    spec = 'smooth(input="t", knots=[20.0, 600.0, 1500.0, 3000.0, 5000.0])'
    model = Model.from_spec(["bias", spec])
    data, truth = _spline_holds(np.arange(20.0, 5000.0, 40.0))
    result = fit(model, data)
    names = model.axis_names("x")
    design = model.design(data)
    X = np.column_stack([np.broadcast_to(np.asarray(design[n], float), (len(truth),)) for n in names])
    plain, *_ = np.linalg.lstsq(X, data["gyro_x"], rcond=None)
    penalised = np.array([result.coef(n) for n in names])
    # The fitted hold means (bias and spline are correlated: compare what they predict).
    assert np.max(np.abs(X @ penalised - X @ plain)) < 0.2 * 0.002
    gap = (data["t_start"] < 1200) | (data["t_start"] > 2600)
    holed = {k: (v[gap] if np.ndim(v) == 1 and len(v) == len(gap) else v) for k, v in data.items()}
    bridged = fit(model, holed)
    inside = np.linspace(1250.0, 2550.0, 20)
    shape = model.terms[1].shape({n: bridged.coef(n) for n in bridged.names}, inside, "x")
    # The bridge stays within the warm-up's own range at the gap's ends (no wild swing).
    ends = model.terms[1].shape({n: bridged.coef(n) for n in bridged.names}, np.array([1200.0, 2600.0]), "x")
    assert np.all(shape <= ends.max() + 0.01) and np.all(shape >= ends.min() - 0.01)


def test_holds_share_wander_only_with_bias_instability_or_rate_random_walk():
    """Whether the fit whitens the holds jointly, and the diagnosis' verdict gives
    sqrt(χ²/dof) rather than RMS ÷ floor: only when the noise model has flicker or RRW."""
    from gyrocal.fit.model import shares_wander

    white = {f"white_{a}": np.full(4, 1e-3) for a in "xyz"}
    quiet = {**white, **{f"{k}_{a}": np.zeros(4) for k in ("flicker", "rrw") for a in "xyz"}}
    assert not shares_wander({}) and not shares_wander(quiet)
    assert shares_wander({**quiet, "rrw_y": np.full(4, 1e-5)})
    assert shares_wander({**quiet, "flicker_x": np.full(4, 1e-4)})
    assert not shares_wander({k: v[:1] for k, v in {**quiet, "rrw_y": np.full(4, 1e-5)}.items()})
