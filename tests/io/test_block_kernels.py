"""The compiled kernels (the read's block statistics, the fit's Allan sums) against their numpy
fallback and a direct reference."""

from __future__ import annotations

import numpy as np
import pytest

from gyrocal.fit import kernels
from gyrocal.io import blockstats

from .conftest import needs

pytestmark = needs(
    {
        "the C kernel gyrocal.io._blockstats": blockstats.LIB is not None,
        "the C kernel gyrocal.fit._kernels": kernels.LIB is not None,
    },
    "pip builds it on install where gcc is found, as make test does",
)


@pytest.fixture
def numpy_only(monkeypatch):
    monkeypatch.setattr(blockstats, "LIB", None)


def run_moments(v):
    mean = np.empty((len(v), 3))
    var = np.empty((len(v), 3), dtype=np.float32)
    blockstats.block_moments(v, mean[:, 1], var[:, 1], [np.empty(0, np.float32)])
    return mean[:, 1], var[:, 1]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("size", [4, 7, 50])
def test_moments_match_the_numpy_path_and_a_float64_reference(dtype, size, monkeypatch):
    rng = np.random.default_rng(size)
    x = (400.0 + rng.normal(0, 0.05, 200 * size)).astype(dtype)  # large offset, small noise
    x[3 * size : 4 * size] = -12.5  # a constant block: zero variance
    v = x.reshape(-1, size)
    ref = v.astype(np.float64)
    compiled = run_moments(v)
    monkeypatch.setattr(blockstats, "LIB", None)
    fallback = run_moments(v)
    for mean, var in (compiled, fallback):
        np.testing.assert_allclose(mean, ref.mean(axis=1), rtol=0, atol=1e-7)  # deg/s
        # variance to a part in 1e4 of the noise variance (float32 sums in the fallback)
        np.testing.assert_allclose(var, ref.var(axis=1, ddof=1), rtol=1e-4, atol=1e-9)
        assert var[3] == 0.0


def test_means_skip_non_finite_values_only_when_asked(monkeypatch):
    v = np.arange(24, dtype=np.float32).reshape(4, 6)
    v[1, 2] = np.nan
    v[2, :] = np.nan
    v[3, 0] = np.inf
    for lib in (blockstats.LIB, None):
        monkeypatch.setattr(blockstats, "LIB", lib)
        plain, finite = np.empty(4), np.empty(4)
        blockstats.block_mean(v, plain)
        blockstats.block_mean(v, finite, finite_only=True)
        assert np.isnan(plain[1]) and np.isnan(plain[2]) and plain[0] == pytest.approx(2.5)
        np.testing.assert_allclose(finite[[0, 1, 3]], [2.5, (6 + 7 + 9 + 10 + 11) / 5, 21.0])
        assert np.isnan(finite[2])


def test_segmentation_is_the_same_on_either_path(logs, monkeypatch):
    from gyrocal.protocols.turntable.segment import segment_file

    _, compiled = segment_file(logs["complete"])
    monkeypatch.setattr(blockstats, "LIB", None)
    _, fallback = segment_file(logs["complete"])
    a, b = compiled.observations, fallback.observations
    assert len(a) == len(b) and (a["t_start"].to_numpy() == b["t_start"].to_numpy()).all()
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        np.testing.assert_allclose(a[c], b[c], rtol=0, atol=1e-7)  # floor ≈ 2e-3 deg/s
    for c in ("std_x", "std_y", "std_z"):
        np.testing.assert_allclose(a[c], b[c], rtol=1e-4)


def test_second_difference_sums_match_numpy_and_a_direct_sum(monkeypatch):
    rng = np.random.default_rng(9)
    theta = np.cumsum(rng.normal(0, 0.01, 40_003))  # odd length: the lanes' tail is exercised
    m = np.array([1, 2, 3, 64, 1024, 20_001, 20_002])
    direct = [float(np.sum((theta[2 * k :] - 2 * theta[k:-k] + theta[: -2 * k]) ** 2)) for k in m]
    compiled = kernels.second_diff_sumsq(theta, m)
    monkeypatch.setattr(kernels, "LIB", None)
    fallback = kernels.second_diff_sumsq(theta, m)
    np.testing.assert_allclose(compiled, direct, rtol=1e-12)
    np.testing.assert_allclose(fallback, direct, rtol=1e-12)
    assert compiled[-2] > 0 and compiled[-1] == 0.0  # one difference left, then none
