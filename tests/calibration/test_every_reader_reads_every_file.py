"""Every calibration file gyrocal writes, every reader reads (gyrocal.calibration.file).

The covariance is written exactly (symmetric to the bit, its diagonal the squared standard
errors as written), judged at each entry's own scale when read, and files written by
``gyrocal calibrate`` for random units of every protocol and every kind of model go to
every reader: the property the benchmark ``benchmarks/roundtrip.py`` counts over 200 units.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.roundtrip import MODELS, READERS, run_case
from gyrocal.calibration.file import (
    Calibration,
    covariance_problem,
    dumps,
    load_calibration,
    save_calibration,
)
from gyrocal.fit.model import Model
from gyrocal.fit.thermal import ConstantCoefficients, TemperatureGrid
from gyrocal.io.errors import CalibrationFileError, GyrocalError

NAMES = tuple(Model.from_spec().names)


def fitted_like_covariance(rng, points: int, scales: np.ndarray) -> np.ndarray:
    """Covariances as a fit's products leave them: positive definite, coefficients of very
    different sizes (``scales``, their standard deviations), the two triangles a few ulps
    apart, some pairs correlated at 1e-9 of their scale (next to nothing, but not zero)."""
    C = len(scales)
    out = np.empty((points, C, C))
    for p in range(points):
        A = rng.normal(size=(C, C)) * np.where(rng.random((C, C)) < 0.3, 1e-9, 1.0)
        S = A @ A.T + np.eye(C) * 0.1
        d = np.sqrt(np.diag(S))
        R = S / np.outer(d, d)
        M = R * np.outer(scales, scales)
        # (L / s²) @ Lᵀ evaluated in another order on each side: the rounding of a product
        M = M * (1 + rng.choice([-1, 0, 1], size=(C, C)) * 2.0**-52)
        out[p] = M
    return out


def grid_with(cov: np.ndarray, temps=None) -> Calibration:
    P = cov.shape[0]
    temps = np.linspace(-20.0, 60.0, P) if temps is None else np.asarray(temps)
    stderr = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    grid = TemperatureGrid(temps, NAMES, np.zeros((P, len(NAMES))), stderr, covariance=cov)
    return Calibration(Model.from_spec(), grid, meta={"device": "X"})


@given(
    seed=st.integers(0, 2**32 - 1),
    points=st.integers(1, 8),
    decades=st.lists(st.floats(-13.0, 1.0), min_size=len(NAMES), max_size=len(NAMES)),
)
def test_the_covariance_is_written_exactly_and_read_at_its_own_scale(seed, points, decades):
    """Before, the writer wrote the fit's matrix as it came (|C_ij − C_ji| ≈ 5e-23 beside
    entries of 1e-14) and the reader compared element by element: such files were refused."""
    rng = np.random.default_rng(seed)
    cov = fitted_like_covariance(rng, points, 10.0 ** np.array(decades))
    doc = grid_with(cov).to_dict()
    written = np.array(doc["grid"]["covariance"])
    stderr = np.array([doc["grid"]["stderr"][n] for n in NAMES]).T
    np.testing.assert_array_equal(written, np.swapaxes(written, -1, -2))  # to the bit
    np.testing.assert_array_equal(np.diagonal(written, axis1=-2, axis2=-1), stderr**2)
    np.testing.assert_allclose(written, cov, rtol=1e-15, atol=0)  # only rounding moved
    again = Calibration.from_dict(json.loads(dumps(doc)))
    np.testing.assert_array_equal(again.grid.covariance, written)
    # The reader takes the fit's own matrix, rounding and all, as it takes the exact one.
    raw = {**doc, "grid": {**doc["grid"], "covariance": cov.tolist()}}
    Calibration.from_dict(json.loads(json.dumps(raw)))


@given(
    seed=st.integers(0, 2**32 - 1),
    size=st.floats(-12.0, 0.0),
    pair=st.tuples(st.integers(0, len(NAMES) - 1), st.integers(0, len(NAMES) - 1)).filter(
        lambda p: p[0] != p[1]
    ),
)
def test_an_asymmetry_beyond_rounding_is_named_with_its_point_pair_and_size(seed, size, pair):
    """A tiny coefficient's covariance moved by 1e-6 of its own scale is found, however
    small it is beside the others, and the error names where."""
    rng = np.random.default_rng(seed)
    scales = np.ones(len(NAMES))
    scales[list(pair)] = 10.0**size
    cov = fitted_like_covariance(rng, 3, scales)
    stderr = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    i, j = pair
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    cov[1, i, j] += 1e-6 * stderr[1, i] * stderr[1, j]
    problem = covariance_problem(cov, stderr, NAMES, [-20.0, 20.0, 60.0])
    assert problem is not None
    assert "at 20 °C (point 2 of 3) is not symmetric" in problem
    assert f"C[{NAMES[i]},{NAMES[j]}]" in problem
    times = float(re.search(r", ([0-9.e+-]+) times sqrt", problem).group(1))
    assert times == pytest.approx(1e-6, rel=1e-3)


def test_the_issue_s_matrix_reads_and_a_correlation_beyond_one_does_not():
    """The refused files' pattern: entries about 1e-14, a pair about 3e-19 whose transpose
    differs by 6.6e-28 (2e-9 of the entry, 1e-17 of the pair's scale)."""
    rng = np.random.default_rng(4)
    scales = np.full(len(NAMES), 1e-7)
    cov = fitted_like_covariance(rng, 2, scales)
    cov[:, 4, 8] = -3.2514595296411492e-19
    cov[:, 8, 4] = -3.2514595230266103e-19
    stderr = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    assert covariance_problem(cov, stderr, NAMES, [0.0, 40.0]) is None
    cov[1, 4, 8] = cov[1, 8, 4] = 1.01 * stderr[1, 4] * stderr[1, 8]
    problem = covariance_problem(cov, stderr, NAMES, [0.0, 40.0])
    assert "at 40 °C (point 2 of 2) is not a covariance" in problem and "1.01 times" in problem


def test_a_continuous_calibration_s_covariance_is_checked_too():
    rng = np.random.default_rng(0)
    cov = fitted_like_covariance(rng, 1, 10.0 ** rng.uniform(-10, -1, len(NAMES)))[0]
    stderr = np.sqrt(np.diag(cov))
    grid = ConstantCoefficients(np.array([0.0, 40.0]), NAMES, np.zeros(len(NAMES)), stderr, covariance=cov)
    doc = Calibration(Model.from_spec(), grid).to_dict()
    written = np.array(doc["grid"]["covariance"])
    np.testing.assert_array_equal(written, written.T)
    doc["grid"]["covariance"][2][5] += 1e-6 * stderr[2] * stderr[5]
    with pytest.raises(
        CalibrationFileError,
        match=r"grid.covariance is not symmetric: "
        r"\|C\[bias.z,scale.z\] − C\[scale.z,bias.z\]\|",
    ):
        Calibration.from_dict(json.loads(json.dumps(doc)))


def test_a_file_that_would_not_read_back_is_never_written(complete_run, tmp_path, monkeypatch):
    """calibrate reads back what it wrote with apply's loader: a writer that broke the
    format fails the stage with one line and leaves nothing under the target's name."""
    cal = complete_run.calibration
    real = Calibration.to_dict

    def broken(self):
        doc = real(self)
        doc["grid"]["stderr"]["bias.x"] = [-1.0] * len(doc["grid"]["temperature"])
        return doc

    monkeypatch.setattr(Calibration, "to_dict", broken)
    target = tmp_path / "cal.json"
    with pytest.raises(GyrocalError, match="the calibration written does not read back") as info:
        save_calibration(cal, target)
    assert str(target) in str(info.value) and "\n" not in str(info.value)
    assert not target.exists() and not list(tmp_path.iterdir())


def test_json_numbers_are_the_floats_shortest_repr(complete_run, tmp_path):
    """Every number in the file is the shortest text that reads back as the same float, and
    the file read and written again is the same file."""
    path = tmp_path / "cal.json"
    save_calibration(complete_run.calibration, path)
    text = path.read_text()
    tokens = []
    json.loads(text, parse_float=lambda tok: tokens.append(tok) or float(tok))
    assert len(tokens) > 1000
    assert all(repr(float(tok)) == tok for tok in tokens)
    assert dumps(load_calibration(path).to_dict()) == text


# ---------------------------------------------------------------------------------------
# Files written by `gyrocal calibrate` for units of every protocol and model kind, given to
# every reader. Units come from the independent generators (benchmarks/zoo,
# tests/protocols/ferraris_gen, tests/protocols/chamber); the protocol is shortened (`small`) to keep each example to seconds.


def _case(protocol, model_index, effect, noise, coefficient_scale, noise_scale, unit_seed, kind):
    family = "turntable" if protocol.startswith("turntable") else protocol
    models = MODELS[family]
    label, model = models[model_index % len(models)]
    if model.get("mounts"):
        protocol = f"turntable{model['mounts']}"
    case = {
        "index": 0,
        "protocol": protocol,
        "family": family,
        "model_label": label,
        "model": model,
        "unit_seed": unit_seed,
    }
    if family == "ferraris":
        return {**case, "kind": kind}
    if family == "static":
        return {**case, "noise_scale": noise_scale}
    return {
        **case,
        "noise": noise,
        "effect": effect if family != "servo" else "none",
        "coefficient_scale": coefficient_scale,
        "noise_scale": noise_scale,
    }


def cases(protocol):
    return st.builds(
        _case,
        st.just(protocol),
        st.integers(0, 100),
        st.sampled_from(
            ["none", "g_sensitivity", "scale_quadratic", "warmup", "die_lag", "temp_rate", "hysteresis"]
        ),
        st.sampled_from(["white", "coloured"]),
        st.floats(0.03, 10.0),
        st.floats(0.1, 10.0),
        st.integers(1, 9999),
        st.sampled_from(["clean", "annotated", "temperature", "gsens"]),
    )


@pytest.mark.slow
@pytest.mark.parametrize("protocol", ["turntable3", "turntable6", "sweep", "servo", "ferraris", "static"])
@settings(max_examples=2, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_every_reader_reads_every_file_calibrate_writes(protocol, data, tmp_path_factory):
    case = data.draw(cases(protocol))
    row = run_case(case, tmp_path_factory.mktemp("unit"), small=True)
    assert row["calibrate"][0] in ("read", "not calibrated"), row["calibrate"]
    if row["calibrate"][0] == "not calibrated":  # the log cannot excite the model: said so
        assert "do not excite" in row["calibrate"][1] or "cannot fit" in row["calibrate"][1], row
        return
    for reader in READERS:
        outcome, message = row[reader]
        assert outcome in ("read", "not for it"), f"{reader}: {message}"
        if outcome == "not for it":  # by design, and said in one line
            assert reader in ("export", "revalidate") and "\n" not in message, message
