"""Allan deviation, IEEE Std 952 noise terms and the coloured-noise simulator."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gyrocal.fit.noise import (
    FLICKER_FACTOR,
    AllanResult,
    NoiseTerms,
    allan_deviation,
    edf_overlapping,
    fit_noise_terms,
)
from gyrocal.io.errors import ConfigError, GyrocalError, InputError
from gyrocal.simulate.noise import GRADES, coloured_noise

from .conftest import needs

try:
    import allantools
except ImportError:  # test-only reference implementation
    allantools = None

needs_allantools = needs(
    {"allantools": allantools is not None}, "a test extra: the reference Allan deviation"
)

TERMS = ("arw", "bias_instability", "rrw", "quantisation")


def _truth(**levels) -> NoiseTerms:
    zero = {k: 0.0 for k in TERMS}
    return NoiseTerms(
        **{**zero, **levels},
        **{f"{k}_stderr": 0.0 for k in TERMS},
        bias_instability_min=0.0,
        tau_min=0.0,
        chi2_reduced=0.0,
    )


@pytest.fixture(scope="module")
def low_grade():
    """About 29 h of the consumer grade at 10 Hz: rate random walk overtakes the flicker plateau
    near 400 s and dominates the last seven octaves."""
    return coloured_noise(np.random.default_rng(20240607), 1 << 20, 10.0, **GRADES["low"])


@needs_allantools
@pytest.mark.parametrize("overlapping", [True, False])
def test_matches_allantools(overlapping):
    rng = np.random.default_rng(7)
    rate = 100.0
    x = 0.3 + rng.normal(0.0, 0.01, (20000, 3)) + np.cumsum(rng.normal(0, 1e-4, (20000, 3)), axis=0)
    res = allan_deviation(x, rate, overlapping=overlapping)
    ref_fn = allantools.oadev if overlapping else allantools.adev
    for axis in range(3):
        tau, ref, _, n = ref_fn(x[:, axis], rate=rate, data_type="freq", taus=res.tau)
        np.testing.assert_allclose(tau, res.tau, rtol=1e-12)
        np.testing.assert_allclose(res.adev[:, axis], ref, rtol=1e-9)
        np.testing.assert_array_equal(res.n_terms, n)


@needs_allantools
def test_edf_is_the_smallest_of_the_howe_allan_barnes_formulas():
    N, ms = 10001, [1, 2, 16, 512, 4096]
    got = edf_overlapping(N, np.array(ms))
    for m, e in zip(ms, got, strict=False):
        ref = [allantools.edf_simple(N, m, a) for a in (0, -2)]
        if m >= 2:  # allantools' m = 1 flicker formula lacks the square of SP 1065 table 5
            ref.append(allantools.edf_simple(N, m, -1))
        assert e == pytest.approx(max(min(ref), 1.0), rel=1e-12)


def test_octave_taus_shapes_and_axes_are_independent():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(1000, 3))
    res = allan_deviation(x, 50.0)
    np.testing.assert_array_equal(res.m, 2 ** np.arange(9))  # 256 <= 1000/2 < 512
    assert res.adev.shape == res.lo.shape == res.hi.shape == (9, 3)
    one = allan_deviation(x[:, 1], 50.0)
    assert one.adev.shape == (9,)
    np.testing.assert_allclose(one.adev, res.adev[:, 1], rtol=1e-13)
    assert np.all(res.lo < res.adev) and np.all(res.adev < res.hi)
    explicit = allan_deviation(x[:, 0], 50.0, taus=[0.02, 0.1, 1.0])
    np.testing.assert_array_equal(explicit.m, [1, 5, 50])


def test_confidence_interval_coverage_on_white_noise():
    """For white noise the true deviation is s / sqrt(m); the 68 % interval (conservative edf)
    must cover it at least at the nominal rate, and not trivially always."""
    s, m_check = 1.0, 32
    covered = []
    for seed in range(300):
        x = np.random.default_rng(seed).normal(0.0, s, 2048)
        r = allan_deviation(x, 1.0, taus=[1.0, 8.0, float(m_check)])
        truth = s / np.sqrt(r.m)
        covered.append((r.lo <= truth) & (truth <= r.hi))
    rate = np.mean(covered, axis=0)
    # binomial sd for 300 draws ~0.027: nominal 0.683 minus 3 sd, and below certainty
    assert np.all(rate >= 0.60) and np.all(rate <= 0.97), rate


def test_fit_recovers_exact_model_in_ieee_units():
    truth = _truth(arw=0.3, bias_instability=8.0, rrw=25.0, quantisation=2.0)
    tau = 0.01 * 2.0 ** np.arange(20)
    adev = truth.adev(tau)
    res = AllanResult(
        tau=tau,
        m=np.arange(20),
        adev=adev,
        n_terms=np.full(20, 10**6),
        edf=np.full(20, 1e6),
        lo=adev,
        hi=adev,
        rate=100.0,
        n_samples=10**7,
    )
    fit = fit_noise_terms(res)
    for k in TERMS:
        assert getattr(fit, k) == pytest.approx(getattr(truth, k), rel=1e-6), k
    # the unit conversions by hand: N deg/sqrt(h) -> sigma(1 s) alone = N/60 deg/s, and so on
    assert _truth(arw=0.3).adev(1.0) == pytest.approx(0.3 / 60.0, rel=1e-12)
    assert _truth(bias_instability=8.0).adev(5.0) == pytest.approx(0.6643 * 8.0 / 3600, rel=1e-4)
    assert _truth(rrw=25.0).adev(3.0) == pytest.approx(25.0 / 3600**1.5, rel=1e-12)
    assert _truth(quantisation=2.0).adev(1.0) == pytest.approx(math.sqrt(3) * 2.0 / 3600, rel=1e-12)


def test_white_noise_arw_within_its_interval():
    """ARW N (deg/sqrt h) of white noise recovered within its stated 1-sigma error at the
    nominal coverage, and that error is small enough to matter."""
    rate, arw = 100.0, 0.4
    hits, rel_err = [], []
    for seed in range(40):
        x = coloured_noise(
            np.random.default_rng(seed), 20000, rate, arw=arw, bias_instability=0.0, rrw=0.0, axes=1
        )[:, 0]
        fit = fit_noise_terms(allan_deviation(x, rate))
        hits.append(abs(fit.arw - arw) <= fit.arw_stderr)
        rel_err.append(fit.arw_stderr / arw)
    assert np.median(rel_err) < 0.02
    assert 0.45 <= np.mean(hits) <= 0.95, np.mean(hits)  # 68 % nominal; 40 draws, sd ~0.07


def test_flicker_plateau_is_0664_b():
    b = 10.0
    x = coloured_noise(np.random.default_rng(3), 200000, 10.0, arw=0.0, bias_instability=b, rrw=0.0)
    r = allan_deviation(x, 10.0)
    mid = (r.tau >= 0.5) & (r.tau <= 200.0)  # away from Nyquist and from the record length
    np.testing.assert_allclose(r.adev[mid], FLICKER_FACTOR * b / 3600.0, rtol=0.10)


def test_coloured_terms_recovered_within_20_percent(low_grade):
    g = GRADES["low"]
    fit = fit_noise_terms(allan_deviation(low_grade, 10.0))
    np.testing.assert_allclose(fit.arw, g["arw"], rtol=0.20)
    np.testing.assert_allclose(fit.bias_instability, g["bias_instability"], rtol=0.20)
    np.testing.assert_allclose(fit.rrw, g["rrw"], rtol=0.20)
    # the datasheet reading min(adev)/0.664 includes white and walk noise at the minimum
    # ... so it agrees with the fitted curve's minimum rather than with B alone
    curve_min = np.min(fit.adev(np.geomspace(1.0, 5000.0, 400)), axis=0) / FLICKER_FACTOR * 3600
    np.testing.assert_allclose(fit.bias_instability_min, curve_min, rtol=0.10)
    # d sigma^2 / d tau = 0 at tau = sqrt(3) N / K (flicker is flat); errors of K dominate
    n_si, k_si = g["arw"] / 60.0, g["rrw"] / 3600.0**1.5
    np.testing.assert_allclose(fit.tau_min, math.sqrt(3.0) * n_si / k_si, rtol=0.30)


def test_floor_is_the_scatter_of_adjacent_hold_means(low_grade):
    fit = fit_noise_terms(allan_deviation(low_grade, 10.0))
    for hold_s in (2.0, 60.0):
        k = int(hold_s * 10)
        means = low_grade[: low_grade.shape[0] // k * k].reshape(-1, k, 3).mean(axis=1)
        scatter = np.sqrt(np.mean(np.diff(means, axis=0) ** 2, axis=0) / 2)
        # >= 1700 hold pairs per axis: sampling error of an rms below 4 % at 1 sigma
        np.testing.assert_allclose(fit.floor(hold_s), scatter, rtol=0.12)
    white = _truth(arw=0.6)
    assert white.floor(25.0) == pytest.approx(0.6 / 60 / 5.0, rel=1e-12)  # N / sqrt(T)


def test_deterministic_and_json_plain(low_grade):
    again = coloured_noise(np.random.default_rng(20240607), 1 << 20, 10.0, **GRADES["low"])
    assert again.tobytes() == low_grade.tobytes()
    a = allan_deviation(low_grade[:50000], 10.0)
    b = allan_deviation(low_grade[:50000].copy(), 10.0)
    assert json.dumps(a.to_dict()) == json.dumps(b.to_dict())
    text = json.dumps(fit_noise_terms(a).to_dict(), allow_nan=False)
    assert json.loads(text)["units"]["arw"] == "deg/sqrt(h)"


@pytest.mark.parametrize(
    "x, rate, kwargs, needle",
    [
        (np.r_[np.zeros(100), np.nan], 10.0, {}, "non-finite"),
        (np.zeros(5), 10.0, {}, "at least"),
        (np.zeros(100), 0.0, {}, "rate"),
        (np.zeros(100), 10.0, {"taus": "weekly"}, "taus"),
        (np.zeros(100), 10.0, {"taus": [100.0]}, "taus"),
        (np.zeros((10, 3, 2)), 10.0, {}, "shape"),
    ],
)
def test_bad_input_is_one_line_error(x, rate, kwargs, needle):
    with pytest.raises(InputError) as err:
        allan_deviation(x, rate, **kwargs)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_bad_levels_rejected():
    with pytest.raises(ConfigError, match="noise.rrw"):
        coloured_noise(np.random.default_rng(0), 10, 10.0, arw=0.1, bias_instability=1.0, rrw=-1.0)
    with pytest.raises(GyrocalError, match="durations"):
        _truth(arw=0.1).floor(0.0)
