"""Firmware export: the compiled reference C implementation against ``gyrocal apply``,
exact round trips of the numbers, and refusal of models firmware cannot express."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.interpolate import PPoly

from gyrocal.calibration.apply import apply_calibration
from gyrocal.calibration.export import (
    FORMAT,
    UnsupportedModelError,
    add_export_parser,
    export_calibration,
    export_text,
    firmware_tables,
)
from gyrocal.calibration.file import Calibration, load_calibration, save_calibration
from gyrocal.fit.model import DEFAULT_TERMS, Model
from gyrocal.fit.thermal import ConstantCoefficients, TemperatureGrid, interpolation_weights
from gyrocal.io.errors import GyrocalError
from gyrocal.simulate import GyroUnit

from .conftest import make_log, needs, truth_coefficients

GCC = shutil.which("gcc")
needs_gcc = needs(
    {"gcc": GCC is not None},
    "the compiled C check needs it; Debian: apt-get install gcc libc6-dev, as make system-packages does",
)
# The bound: the C code must reproduce apply to 1e-6 deg/s on every sample. Both
# compute in double; what separates them is rounding (a few 1e-16 of 400 deg/s).
ATOL = 1e-6
META = {"device": "U001", "batch": "B1", "session": "2026-01-01", "protocol": "turntable"}

# Reads n x 4 doubles (gyro x, y, z in deg/s, temp in degC) and writes n x 4 doubles
# (compensated x, y, z and the status); "dump" prints the header's tables with %.17g.
DRIVER = r"""
#include <stdio.h>
#include <string.h>
#include "compensation.h"

static void dump(const char *name, const double *v, int n)
{
    int i;
    printf("%s", name);
    for (i = 0; i < n; i++)
        printf(" %.17g", v[i]);
    printf("\n");
}

int main(int argc, char **argv)
{
    FILE *in, *out;
    double s[4], r[4];
    if (argc == 2 && strcmp(argv[1], "dump") == 0) {
        dump("temperature", gyrocal_temperature, GYROCAL_N_POINTS);
        dump("K", &gyrocal_K[0][0][0], 9 * GYROCAL_N_POINTS);
        dump("B", &gyrocal_B[0][0], 3 * GYROCAL_N_POINTS);
        dump("K_inv", &gyrocal_K_inv[0][0][0], 9 * GYROCAL_N_POINTS);
        printf("device %s\n", GYROCAL_DEVICE);
        return 0;
    }
    if (argc != 3 || !(in = fopen(argv[1], "rb")) || !(out = fopen(argv[2], "wb")))
        return 2;
    while (fread(s, sizeof(double), 4, in) == 4) {
        r[3] = gyrocal_compensate(s, s[3], r);
        fwrite(r, sizeof(double), 4, out);
    }
    fclose(in);
    return fclose(out) != 0;
}
"""


def grid_calibration(temps, method="lagrange3", degree=2, *, terms=DEFAULT_TERMS, seed=0):
    """The seed-000 unit at ``temps``, each point perturbed (seeded) so that K and B bend
    strongly with temperature and the interpolation rules disagree by far more than ATOL."""
    model = Model.from_spec(terms)
    unit = GyroUnit.seed000()
    rng = np.random.default_rng(seed)
    values = np.array([[truth_coefficients(unit, T).get(n, 0.0) for n in model.names] for T in temps])
    size = np.array([0.3 if n.startswith("bias") else 3e-3 for n in model.names])
    values = values + size * rng.standard_normal(values.shape)
    grid = TemperatureGrid(
        np.asarray(temps, float), tuple(model.names), values, np.full_like(values, 1e-4), method, degree
    )
    return Calibration(model, grid, meta=dict(META))


CONTINUOUS_TERMS = (
    *DEFAULT_TERMS,
    "bias_temp_poly(degree=3)",
    "scale_temp_poly(degree=2)",
    "misalignment_temp",
)


def continuous_calibration(temps, seed=0):
    """A temperature-continuous model (as a sweep fits): the seed-000 unit at 25 °C plus
    temperature polynomials of bias (cubic), scale (quadratic) and misalignment (linear)."""
    model = Model.from_spec(CONTINUOUS_TERMS)
    base = truth_coefficients(GyroUnit.seed000(), 25.0)
    rng = np.random.default_rng(seed)
    size = {
        "bias_temp_poly": {"c1": 5e-3, "c2": 1e-4, "c3": 2e-6},
        "scale_temp_poly": {"c1": 1e-4, "c2": 2e-6},
        "misalignment_temp": 2e-5,
    }
    values = []
    for name in model.names:
        term, rest = name.split(".")[0], name.split(".")[-1]
        scale = size.get(term)
        values.append(
            base[name]
            if scale is None
            else (scale[rest] if isinstance(scale, dict) else scale) * rng.standard_normal()
        )
    values = np.array(values)
    grid = ConstantCoefficients(np.asarray(temps, float), tuple(model.names), values, np.abs(values))
    return Calibration(model, grid, meta=dict(META))


def make_calibration(case):
    temps, method, degree = CASES[case]
    if method == "continuous":
        return continuous_calibration(temps)
    return grid_calibration(temps, method, degree)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """A simulated log from -10 to 40 °C (beyond the 0-30 °C grids below, so clamping is
    exercised), plus rows at exactly the grid temperatures, at the range ends and a NaN."""
    d = tmp_path_factory.mktemp("export_log")
    source = pq.read_table(
        make_log(d, temperatures=(-10.0, 5.0, 40.0), rates=(10.0, 400.0)),
        columns=["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"],
    )
    cols = {c: source.column(c).to_numpy().astype(np.float64) for c in source.column_names}
    extra_temp = np.array([0.0, 10.0, 20.0, 30.0, 15.0, -40.0, 85.0, np.nan])
    k = len(extra_temp)
    extra = {
        "t": cols["t"][-1] + 0.01 * np.arange(1, k + 1),
        "temp": extra_temp,
        "gyro_x": np.full(k, 123.4),
        "gyro_y": np.full(k, -321.0),
        "gyro_z": np.full(k, 7.5),
        "ref_rate": np.zeros(k),
    }
    table = pa.table({c: np.concatenate([cols[c], extra[c]]) for c in cols})
    path = d / "log.parquet"
    pq.write_table(table, path)
    return path


@pytest.fixture(scope="module")
def samples(log, tmp_path_factory):
    """The log's gyro and temperature as the C program reads them (n x 4 float64)."""
    t = pq.read_table(log, columns=["gyro_x", "gyro_y", "gyro_z", "temp"])
    data = np.column_stack([t.column(c).to_numpy() for c in t.column_names]).astype(np.float64)
    path = tmp_path_factory.mktemp("samples") / "samples.f64"
    data.tofile(path)
    return path, data


def compile_driver(header_text: str, folder):
    (folder / "compensation.h").write_text(header_text)
    (folder / "driver.c").write_text(DRIVER)
    exe = folder / "driver"
    out = subprocess.run(
        [
            GCC,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-o",
            str(exe),
            str(folder / "driver.c"),
            "-lm",
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    return exe


def applied(cal, log, tmp_path, name="cal.json"):
    """gyrocal apply's output (n x 3) with the calibration as read back from its file."""
    path = tmp_path / name
    save_calibration(cal, path)
    out = tmp_path / f"{name}.parquet"
    apply_calibration(load_calibration(path), log, out)
    t = pq.read_table(out, columns=["gyro_x", "gyro_y", "gyro_z"])
    return path, np.column_stack([t.column(c).to_numpy() for c in t.column_names])


CASES = {  # name: (grid temperatures, method, degree)
    "lagrange3": ((0.0, 10.0, 20.0, 30.0), "lagrange3", 2),
    "linear": ((0.0, 10.0, 20.0, 30.0), "linear", 2),
    "spline": ((0.0, 7.5, 20.0, 30.0), "spline", 2),
    "poly": ((0.0, 5.0, 10.0, 20.0, 30.0), "poly", 2),
    "lagrange3-two-points": ((0.0, 30.0), "lagrange3", 2),
    "one-point": ((20.0,), "lagrange3", 2),
    "continuous": ((0.0, 10.0, 20.0, 30.0), "continuous", 3),  # degree of K(T), B(T)
}


@needs_gcc
@pytest.mark.parametrize("case", list(CASES))
def test_compiled_c_matches_apply(case, log, samples, tmp_path):
    temps, method, degree = CASES[case]
    cal = make_calibration(case)
    cal_path, expected = applied(cal, log, tmp_path)
    file_cal = load_calibration(cal_path)
    exe = compile_driver(export_text(file_cal, "c-header", source=cal_path), tmp_path)
    sample_path, data = samples
    out = tmp_path / "out.f64"
    run = subprocess.run([str(exe), str(sample_path), str(out)], capture_output=True)
    assert run.returncode == 0
    result = np.fromfile(out, dtype=np.float64).reshape(-1, 4)
    assert result.shape[0] == data.shape[0] == expected.shape[0]

    good = np.isfinite(data).all(axis=1)
    assert good.sum() == len(data) - 1  # the one NaN row
    np.testing.assert_allclose(result[good, :3], expected[good], rtol=0, atol=ATOL)
    assert np.isnan(result[~good, :3]).all() and np.isnan(expected[~good]).all()
    status = np.where(~good, -1, np.where(file_cal.grid.outside(data[:, 3]), 1, 0))
    np.testing.assert_array_equal(result[:, 3], status)
    if len(temps) > 1:
        assert (status == 1).sum() > 100 and (status == 0).sum() > 100
    # Teeth: compensation moves the rates by far more than ATOL, and another interpolation
    # rule gives answers the comparison would reject.
    assert np.max(np.abs(result[good, :3] - data[good, :3])) > 1.0
    if method == "continuous":  # the temperature polynomials matter
        wrong = cal.compensate(data[good, :3], {"temp": np.full(good.sum(), 15.0)}, warn=False)
        assert np.max(np.abs(result[good, :3] - wrong)) > 1e-3
    elif len(temps) > 2:
        other = "linear" if method != "linear" else "lagrange3"
        wrong = grid_calibration(temps, other, degree).compensate(
            data[good, :3], {"temp": data[good, 3]}, warn=False
        )
        assert np.max(np.abs(result[good, :3] - wrong)) > 1e-3


@needs_gcc
def test_header_numbers_read_back_exactly(tmp_path):
    """The C literals are the calibration's doubles bit for bit (shortest repr)."""
    cal = grid_calibration((0.0, 10.0, 20.0, 30.0))
    exe = compile_driver(export_text(cal, "c-header"), tmp_path)
    lines = subprocess.run([str(exe), "dump"], capture_output=True, text=True, check=True).stdout
    dumped = {line.split()[0]: line.split()[1:] for line in lines.splitlines()}
    K, B = cal.matrices()
    assert [float(v) for v in dumped["temperature"]] == cal.grid.temperatures.tolist()
    assert [float(v) for v in dumped["K"]] == K.ravel().tolist()
    assert [float(v) for v in dumped["B"]] == B.ravel().tolist()
    assert [float(v) for v in dumped["K_inv"]] == np.linalg.inv(K).ravel().tolist()
    assert dumped["device"] == ["U001"]


@pytest.mark.parametrize("case", ["lagrange3", "linear", "spline", "poly", "continuous"])
def test_json_round_trips_and_reproduces_the_calibration(case, tmp_path):
    """Every number reads back exactly; the documented rule applied to the JSON tables by
    an independent evaluator gives K(T) and B(T) of the calibration."""
    temps, method, degree = CASES[case]
    cal = make_calibration(case)
    cal_path = tmp_path / "cal.json"
    save_calibration(cal, cal_path)
    out = tmp_path / "fw.json"
    tables = export_calibration(cal, "json", out, source=cal_path)
    text = out.read_text()
    assert export_text(cal, "json", source=cal_path) == text  # same inputs, same bytes
    doc = json.loads(text)
    assert doc["format"] == FORMAT and doc["device"] == "U001"
    assert doc["interpolation"]["method"] == ("poly" if method == "continuous" else method)
    assert doc["interpolation"]["outside_range"] == "clamp"
    K, B = cal.matrices()
    assert doc["temperature"] == list(temps)
    assert doc["K"] == K.tolist() and doc["B"] == B.tolist()
    assert doc["K_inv"] == np.linalg.inv(K).tolist()

    T = np.linspace(-5.0, 35.0, 161)  # beyond the grid: clamped
    Tc = np.clip(T, temps[0], temps[-1])
    grid_K, grid_B = np.array(doc["K"]), np.array(doc["B"])
    if method in ("lagrange3", "linear"):
        W = interpolation_weights(method, doc["temperature"], Tc)
        got_K, got_B = np.einsum("np,pab->nab", W, grid_K), W @ grid_B
    elif method == "spline":
        assert doc["spline"]["K"] == tables.spline_K.tolist()
        c_K = np.array(doc["spline"]["K"]).transpose(1, 0, 2, 3)  # (4, P-1, 3, 3)
        got_K = PPoly(c_K, np.array(temps))(Tc)
        got_B = PPoly(np.array(doc["spline"]["B"]).transpose(1, 0, 2), np.array(temps))(Tc)
    else:
        p = doc["poly"]
        assert p["K"] == tables.poly_K.tolist() and p["degree"] == degree
        x = (Tc - p["centre"]) / p["half_range"]
        got_K = np.moveaxis(np.polynomial.legendre.legval(x, np.array(p["K"])), -1, 0)
        got_B = np.polynomial.legendre.legval(x, np.array(p["B"])).T
    want_K, want_B = cal.matrices_at(T)
    np.testing.assert_allclose(got_K, want_K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_B, want_B, rtol=0, atol=1e-12)


def test_unsupported_models_are_refused():
    cal = grid_calibration((0.0, 10.0, 20.0), terms=(*DEFAULT_TERMS, "scale_quadratic", "g_sensitivity"))
    with pytest.raises(UnsupportedModelError, match="terms scale_quadratic, g_sensitivity are beyond"):
        firmware_tables(cal)
    # A grid interpolates coefficients: a temperature term there is not K and B per point.
    grid = grid_calibration((0.0, 10.0, 20.0), terms=(*DEFAULT_TERMS, "bias_temp_poly"))
    with pytest.raises(UnsupportedModelError, match="term bias_temp_poly is beyond .* temperature-grid"):
        firmware_tables(grid)
    model = Model.from_spec((*DEFAULT_TERMS, "bias_temp_poly", "temp_rate"))
    values = np.full(len(model.names), 1e-3)
    continuous = Calibration(
        model,
        ConstantCoefficients(np.array([0.0, 20.0]), tuple(model.names), values, values),
        meta=dict(META),
    )
    with pytest.raises(UnsupportedModelError, match=r"term temp_rate is beyond") as err:
        export_text(continuous, "json")
    assert err.value.exit_status == 2 and "\n" not in str(err.value)


def test_continuous_seed000_model_exports_as_constant():
    model = Model.from_spec(DEFAULT_TERMS)
    values = np.linspace(-2e-3, 2e-3, len(model.names))
    cal = Calibration(
        model,
        ConstantCoefficients(np.array([0.0, 20.0, 40.0]), tuple(model.names), values, values),
        meta=dict(META),
    )
    doc = json.loads(export_text(cal, "json"))
    assert doc["interpolation"]["method"] == "poly"
    assert doc["interpolation"]["calibration_method"] == "continuous"
    assert doc["poly"]["degree"] == 0
    K, B = cal.matrices_at([10.0])
    np.testing.assert_allclose(np.array(doc["poly"]["K"]), K, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.array(doc["poly"]["B"]), B, rtol=0, atol=1e-15)


def export_cli(*argv):
    parser = argparse.ArgumentParser(prog="gyrocal")
    add_export_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["export", *map(str, argv)])
    return args.func(args)


def test_cli_formats_and_errors(tmp_path, capsys):
    cal_path = tmp_path / "cal.json"
    save_calibration(grid_calibration((0.0, 10.0, 20.0)), cal_path)
    assert export_cli(cal_path, "-o", tmp_path / "fw.h") == 0  # format from the suffix
    assert "#define GYROCAL_N_POINTS 3" in (tmp_path / "fw.h").read_text()
    assert "firmware c-header ->" in capsys.readouterr().out
    assert export_cli(cal_path, "--format", "json", "-o", tmp_path / "fw.txt") == 0
    assert json.loads((tmp_path / "fw.txt").read_text())["format"] == FORMAT
    with pytest.raises(GyrocalError, match="cannot tell the export format"):
        export_cli(cal_path, "-o", tmp_path / "fw.bin")
    bad = tmp_path / "quadratic.json"
    save_calibration(grid_calibration((0.0, 10.0, 20.0), terms=(*DEFAULT_TERMS, "scale_quadratic")), bad)
    with pytest.raises(UnsupportedModelError, match=r"quadratic.json: .*term scale_quadratic is beyond"):
        export_cli(bad, "-o", tmp_path / "q.h")
    assert not (tmp_path / "q.h").exists()


# Reads n x 5 doubles (t in s, gyro x, y, z in deg/s, temp in degC), writes n x 4 as DRIVER.
DIE_DRIVER = r"""
#include <stdio.h>
#include "compensation.h"

int main(int argc, char **argv)
{
    FILE *in, *out;
    double s[5], r[4];
    gyrocal_state die = GYROCAL_STATE_INIT;
    if (argc != 3 || !(in = fopen(argv[1], "rb")) || !(out = fopen(argv[2], "wb")))
        return 2;
    while (fread(s, sizeof(double), 5, in) == 5) {
        r[3] = gyrocal_compensate_sample(&die, s[0], s + 1, s[4], r);
        fwrite(r, sizeof(double), 4, out);
    }
    fclose(in);
    return fclose(out) != 0;
}
"""


def compiled_samples(header: str, log, tmp_path):
    """The log's samples (t, gyro, temp) in time order, and what the compiled header's
    per-sample compensation (:data:`DIE_DRIVER`) makes of them."""
    (tmp_path / "compensation.h").write_text(header)
    (tmp_path / "driver.c").write_text(DIE_DRIVER)
    exe = tmp_path / "driver"
    built = subprocess.run(
        [
            GCC,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-o",
            str(exe),
            str(tmp_path / "driver.c"),
            "-lm",
        ],
        capture_output=True,
        text=True,
    )
    assert built.returncode == 0, built.stderr
    t = pq.read_table(log, columns=["t", "gyro_x", "gyro_y", "gyro_z", "temp"])
    data = np.column_stack([t.column(c).to_numpy() for c in t.column_names]).astype(np.float64)
    data.tofile(tmp_path / "in.f64")
    run = subprocess.run([str(exe), str(tmp_path / "in.f64"), str(tmp_path / "out.f64")], capture_output=True)
    assert run.returncode == 0
    return data, np.fromfile(tmp_path / "out.f64", dtype=np.float64).reshape(-1, 4)


@needs_gcc
@pytest.mark.parametrize("case", ["lagrange3", "continuous"])
def test_compiled_c_runs_the_die_lag_as_apply_does(case, log, tmp_path):
    """A calibration at the die's temperature: the header carries the lag as a filter with
    its state, and the compiled code, fed the samples in order, reproduces apply."""
    cal = make_calibration(case)
    from gyrocal.fit.model import Model

    cal = Calibration(
        Model(cal.model.terms + (Model.from_spec(["die_temperature(tau=45.0)"]).terms)),
        cal.grid,
        meta=dict(META),
    )
    cal_path, expected = applied(cal, log, tmp_path)
    header = export_text(load_calibration(cal_path), "c-header", source=cal_path)
    assert "#define GYROCAL_DIE_TAU (45.0)" in header
    document = json.loads(export_text(load_calibration(cal_path), "json", source=cal_path))
    assert document["die_temperature"]["tau_s"] == 45.0
    data, result = compiled_samples(header, log, tmp_path)
    good = np.isfinite(data).all(axis=1)
    np.testing.assert_allclose(result[good, :3], expected[good], rtol=0, atol=ATOL)
    assert np.isnan(result[~good, :3]).all() and np.isnan(expected[~good]).all()
    # Teeth: the same compensation at the logged temperature differs by far more.
    logged = cal.compensate(
        data[good, 1:4], {"t": data[good, 0], "temp": data[good, 4], "temp_logged": data[good, 4]}, warn=False
    )
    assert np.max(np.abs(result[good, :3] - logged)) > 1e-3


def spline_calibration(kind: str):
    """The seed-000 unit with empirical terms firmware can evaluate: a spline of time since
    power-on on a grid; a continuous model with a spline of the temperature (a bias) and
    one of time times the own rate (a scale relaxing after power-on)."""
    if kind == "grid":
        cal = grid_calibration((0.0, 10.0, 20.0, 30.0), "lagrange3", 2)
        extra = ['smooth(input="t", knots=[0.0, 20.0, 60.0, 120.0])']
    else:
        cal = continuous_calibration((0.0, 10.0, 20.0, 30.0))
        extra = [
            'smooth(input="temp", knots=[-10.0, 5.0, 20.0, 40.0], linear=False)',
            'smooth(input="t", knots=[0.0, 30.0, 120.0], by="rate_own")',
        ]
    return with_terms(cal, kind, extra, lambda n: 1e-3 if "by_rate" in n else 0.2, seed=4)


def with_terms(cal, kind: str, extra, size_of, seed: int):
    """``cal`` with the terms ``extra``, their coefficients drawn (seeded) at ``size_of(name)``
    and the same at every grid point (session-wide, as a series term's are)."""
    from gyrocal.fit.model import Model

    model = Model(cal.model.terms + Model.from_spec(extra).terms)
    new = [n for n in model.names if n not in cal.grid.names]
    size = np.array([size_of(n) for n in new])
    add = size * np.random.default_rng(seed).standard_normal(len(new))
    g = cal.grid
    if kind == "grid":
        values = np.column_stack([g.values, np.tile(add, (len(g.temperatures), 1))])
        grid = TemperatureGrid(
            g.temperatures, tuple(model.names), values, np.full_like(values, 1e-4), g.method, g.degree
        )
    else:
        values = np.r_[g.values, add]
        grid = ConstantCoefficients(g.temperatures, tuple(model.names), values, np.abs(values) + 1e-6)
    return Calibration(model, grid, meta=dict(META))


@needs_gcc
@pytest.mark.parametrize("kind", ["grid", "continuous"])
def test_compiled_c_adds_the_empirical_terms_as_apply_does(kind, log, tmp_path):
    """Splines of time since power-on and of the temperature (a bias, or a scale by the own
    rate): the header evaluates them by de Boor's algorithm and adds them to B or K's
    diagonal; fed the samples in order, the compiled code reproduces apply."""
    cal = spline_calibration(kind)
    cal_path, expected = applied(cal, log, tmp_path)
    header = export_text(load_calibration(cal_path), "c-header", source=cal_path)
    assert "gyrocal_bspline" in header and "gyrocal_compensate_sample" in header
    document = json.loads(export_text(load_calibration(cal_path), "json", source=cal_path))
    assert {s["input"] for s in document["splines"]} == ({"t"} if kind == "grid" else {"t", "temp"})
    data, result = compiled_samples(header, log, tmp_path)
    good = np.isfinite(data).all(axis=1)
    np.testing.assert_allclose(result[good, :3], expected[good], rtol=0, atol=ATOL)
    # Teeth: without the splines the compensation differs by far more.
    from gyrocal.calibration.export import _without_splines

    bare = _without_splines(cal).compensate(
        data[good, 1:4], {"t": data[good, 0] - data[0, 0], "temp": data[good, 4]}, warn=False
    )
    assert np.max(np.abs(result[good, :3] - bare)) > 1e-2


def test_splines_of_other_inputs_are_refused_by_name():
    from gyrocal.fit.model import Model

    cal = grid_calibration((0.0, 10.0, 20.0, 30.0))
    model = Model(
        cal.model.terms
        + Model.from_spec(['smooth(input="rate_own", knots=[-400.0, 0.0, 400.0], linear=False)']).terms
    )
    names = tuple(model.names)
    values = np.zeros((4, len(names)))
    cal = Calibration(
        model,
        TemperatureGrid(np.array([0.0, 10.0, 20.0, 30.0]), names, values, np.full_like(values, 1e-4)),
        meta=dict(META),
    )
    with pytest.raises(UnsupportedModelError, match=r"smooth\(input=rate_own\)"):
        export_text(cal, "c-header")


HISTORY_TERMS = [
    "expression(label='pole', formula='lag(rate_own, tau) - rate_own', parameters={'tau': 4.0})",
    "expression(label='heat', formula='lag(sqrt(rate_x**2 + rate_y**2 + rate_z**2), tau)', "
    "parameters={'tau': 90.0})",
    "expression(label='drag', formula='lag(rate_x**2 + rate_y**2 + rate_z**2, tau)', "
    "parameters={'tau': 300.0})",
]


def history_calibration(kind: str):
    """The seed-000 unit with the histories the diagnosis offers: a slow pole of the own
    rate (a lag of the raw output less the true rate), heat from turning (a lag of the
    output's magnitude) and a drag's (of its square), sized well beyond ATOL."""
    cal = (
        grid_calibration((0.0, 10.0, 20.0, 30.0))
        if kind == "grid"
        else continuous_calibration((0.0, 10.0, 20.0, 30.0))
    )
    size = {"pole": 3e-3, "heat": 1e-4, "drag": 1e-7}
    return with_terms(cal, kind, HISTORY_TERMS, lambda n: size[n.split(".")[0]], seed=5)


def compiled_runs_histories_as_apply(cal, header, expected, log, tmp_path):
    """The compiled header, fed the log's samples in order, gives apply's output (NaN where
    apply's is), and the calibration without its histories differs from it by far more.
    Returns the samples and which are finite."""
    data, result = compiled_samples(header, log, tmp_path)
    good = np.isfinite(data).all(axis=1)
    np.testing.assert_allclose(result[good, :3], expected[good], rtol=0, atol=ATOL)
    assert np.isnan(result[~good, :3]).all() and np.isnan(expected[~good]).all()
    from gyrocal.calibration.export import _without_splines

    bare = _without_splines(cal).compensate(
        data[good, 1:4], {"t": data[good, 0], "temp": data[good, 4]}, warn=False
    )
    assert np.max(np.abs(result[good, :3] - bare)) > 1e-2
    return data, good


@needs_gcc
@pytest.mark.parametrize("kind", ["grid", "continuous"])
def test_compiled_c_runs_the_histories_as_apply_does(kind, log, tmp_path):
    """A slow pole, heat from turning and a drag's heat (issue 38): the header runs each as a
    first-order lag of the raw output with its state, adds it to B (the slow pole's true
    rate to K's diagonal), and fed the samples in order the compiled code reproduces apply;
    the JSON names the filter, its input and its time constant."""
    cal = history_calibration(kind)
    cal_path, expected = applied(cal, log, tmp_path)
    header = export_text(load_calibration(cal_path), "c-header", source=cal_path)
    assert "gyrocal_run_histories" in header and "#define GYROCAL_POLE_TAU (4.0)" in header
    document = json.loads(export_text(load_calibration(cal_path), "json", source=cal_path))
    assert [(h["label"], h["tau_s"]) for h in document["histories"]] == [
        ("pole", 4.0),
        ("heat", 90.0),
        ("drag", 300.0),
    ]
    assert "K's diagonal" in document["histories"][0]["adds_to"]
    # Teeth: the same calibration without its histories differs by far more.
    compiled_runs_histories_as_apply(cal, header, expected, log, tmp_path)


def test_histories_firmware_cannot_run_are_refused_by_name():
    """A history of another form (a play operator's bare output, a Duhem state scaled, a lag
    of another formula) is refused, naming the term; the offered forms are not."""
    from gyrocal.calibration.export import history_form, temperature_history_form, unsupported_terms

    assert history_form(
        {
            "name": "expression",
            "label": "p",
            "formula": "lag(rate_own,tau)-rate_own",
            "parameters": {"tau": 3.0},
        }
    ) == ("own", -1.0)
    assert (
        temperature_history_form(
            {"name": "expression", "label": "d", "formula": "duhem(temp,w)", "parameters": {"w": 3.0}}
        )
        == "duhem"
    )
    refused = unsupported_terms(
        [
            {"name": "expression", "label": "d", "formula": "play(temp, w)", "parameters": {"w": 3.0}},
            {"name": "expression", "label": "s", "formula": "2 * duhem(temp, w)", "parameters": {"w": 3.0}},
            {
                "name": "expression",
                "label": "q",
                "formula": "lag(rate_x * rate_y, tau)",
                "parameters": {"tau": 3.0},
            },
        ]
    )
    assert refused == ["expression", "expression", "expression"]
    # the fixture's faces are the rig's: zero off it, left behind rather than refused
    names = ("bias", "scale", "misalignment", "misalignment_faces", "scale_cubic")
    assert unsupported_terms([{"name": n} for n in names]) == ["scale_cubic"]


TEMPERATURE_HISTORY_TERMS = [
    "expression(label='way', formula='2 * (temp - play(temp, w)) / w', parameters={'w': 3.0})",
    "expression(label='strain', formula='duhem(temp, w)', parameters={'w': 6.0})",
    "expression(label='table', formula='sign(play(temp, w) - T0 - m)', parameters={'T0': -12.0, 'm': 20.0, 'w': 2.5})",
]


@needs_gcc
@pytest.mark.parametrize("kind", ["grid", "continuous"])
def test_compiled_c_runs_the_temperatures_histories_as_apply_does(kind, log, tmp_path):
    """The temperature's direction through a play operator, a Duhem state and a switch with
    hysteresis (issue 38), on a log that starts below the room (falling from it), rises
    through the switch and jumps about at its end: the header runs each on the logged
    temperature through the lag apply reads it by, from a unit brought from the room, adds
    it to B, and fed the samples in order the compiled code reproduces apply; the JSON
    names the operator, its width and the lag."""
    cal = with_terms(
        grid_calibration((0.0, 10.0, 20.0, 30.0))
        if kind == "grid"
        else continuous_calibration((0.0, 10.0, 20.0, 30.0)),
        kind,
        TEMPERATURE_HISTORY_TERMS,
        lambda n: 0.05,
        seed=7,
    )
    cal_path, expected = applied(cal, log, tmp_path)
    header = export_text(load_calibration(cal_path), "c-header", source=cal_path)
    assert "gyrocal_temperature_history" in header and "#define GYROCAL_TABLE_M (20.0)" in header
    document = json.loads(export_text(load_calibration(cal_path), "json", source=cal_path))
    assert [(h["label"], h["operator"], h["w"]) for h in document["temperature_histories"]] == [
        ("way", "direction", 3.0),
        ("strain", "duhem", 6.0),
        ("table", "switch", 2.5),
    ]
    assert all(h["lag_tau_s"] == 2.0 for h in document["temperature_histories"])
    # Teeth: without its histories the compensation differs by far more, and the switch
    # turned within the log (its sign took both values).
    data, good = compiled_runs_histories_as_apply(cal, header, expected, log, tmp_path)
    from gyrocal.terms.signals import TEMPERATURE_SMOOTHING_S, first_order_lag, temperature_play

    lagged = first_order_lag(data[good, 0], data[good, 4], TEMPERATURE_SMOOTHING_S)
    assert set(np.unique(np.sign(temperature_play(lagged, 2.5) + 12.0 - 20.0))) == {-1.0, 1.0}
