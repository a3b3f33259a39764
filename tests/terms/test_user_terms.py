"""Effects as terms: the user's own terms and expressions, temperature-continuous models,
and applying calibrations whose terms need more than gyro and temperature."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.calibration.apply import apply_calibration
from gyrocal.calibration.file import load_calibration, save_calibration
from gyrocal.diagnosis import diagnose, extended
from gyrocal.io.errors import ConfigError
from gyrocal.pipeline.chain import run, segment_log
from gyrocal.pipeline.config import DiagnosisSettings, ModelSettings, Settings
from gyrocal.protocols.turntable.segment import SegmentConfig
from gyrocal.run import cli
from gyrocal.simulate import GyroUnit
from gyrocal.simulate.observations import observations
from gyrocal.terms import user as user_terms
from gyrocal.terms.signals import temperature_rate

from .conftest import make_log

TERM_FILE = '''"""A rate-dependent error no library term describes: odd, growing as sqrt(|rate|)."""
from dataclasses import dataclass

import numpy as np

from gyrocal.terms import AXES, Term, register_term


@register_term("rate_root")
@dataclass(frozen=True)
class RateRoot(Term):
    unit = "deg/s/sqrt(deg/s)"
    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    def coefficients(self):
        return [f"{self.name}.{a}" for a in AXES]

    def columns(self, data):
        return {f"{self.name}.{a}": np.sign(data[f"rate_{a}"]) * np.sqrt(np.abs(data[f"rate_{a}"]))
                for a in AXES}
'''
ROOT = np.array([2e-3, -1.5e-3, 1e-3])  # deg/s per sqrt(deg/s): 0.04 deg/s at 400 deg/s


def true_rates(table: pa.Table) -> np.ndarray:
    """True rate in the sensor frame from the log's mount and reference rate."""
    mount = np.asarray(table.column("mount").cast(pa.string()).to_pylist())
    ref = table.column("ref_rate").to_numpy()
    w = np.zeros((len(ref), 3))
    for i, a in enumerate("xyz"):
        for sign in "+-":
            w[mount == f"{sign}{a}", i] = (1.0 if sign == "+" else -1.0) * ref[mount == f"{sign}{a}"]
    return w


def with_rate_root(log, out):
    """The log with the rate_root error added to the gyro output."""
    table = pq.read_table(log)
    w = true_rates(table)
    for i, a in enumerate("xyz"):
        gyro = table.column(f"gyro_{a}").to_numpy().astype(np.float64)
        gyro += ROOT[i] * np.sign(w[:, i]) * np.sqrt(np.abs(w[:, i]))
        table = table.set_column(
            table.schema.get_field_index(f"gyro_{a}"), f"gyro_{a}", pa.array(gyro.astype(np.float32))
        )
    pq.write_table(table, out)
    return out


def hold_errors(applied, truth_log, obs) -> np.ndarray:
    """Compensated hold means minus the true rate, (holds, 3)."""
    t = pq.read_table(truth_log, columns=["t"]).column("t").to_numpy()
    out = pq.read_table(applied)
    w = true_rates(pq.read_table(truth_log))
    gyro = np.column_stack([out.column(f"gyro_{a}").to_numpy() for a in "xyz"])
    errors = []
    for start, end in zip(obs["t_start"], obs["t_end"], strict=False):
        inside = (t >= start) & (t <= end)
        errors.append((gyro[inside] - w[inside]).mean(axis=0))
    return np.array(errors)


@pytest.mark.slow
def test_a_users_term_file_is_fitted_diagnosed_written_and_applied(tmp_path, registry, capsys):
    workflow = tmp_path / "my_workflow"
    workflow.mkdir()
    term_file = workflow / "my_terms.py"
    term_file.write_text(TERM_FILE)
    log = with_rate_root(make_log(tmp_path, "plain", seed=21), tmp_path / "rate_root.parquet")

    settings = replace(Settings(), model=ModelSettings.from_dict({"term_files": [str(term_file)]}))
    obs = segment_log(log, settings).observations
    diag = diagnose(settings, obs)
    assert diag.best is not None and diag.best.term == "rate_root"
    fixed = diagnose(extended(settings, "rate_root"), obs)
    assert fixed.base.summary["validation_rms"] <= 1.2 * fixed.base.summary["noise_floor"]
    pooled = {s["coefficient"]: s for s in diag.best.size}
    for i, a in enumerate("xyz"):
        assert abs(pooled[f"rate_root.{a}"]["value"] - ROOT[i]) < 5 * pooled[f"rate_root.{a}"]["stderr"]

    # The command line: diagnose names it, calibrate adds it, the file records its source.
    assert cli.main(["diagnose", str(log), "--terms", str(term_file), "-o", str(tmp_path / "d.json")]) == 0
    assert json.loads((tmp_path / "d.json").read_text())["candidates"][0]["term"] == "rate_root"
    cal_path = tmp_path / "cal.json"
    assert (
        cli.main(
            ["calibrate", str(log), "--terms", str(term_file), "--add-term", "rate_root", "-o", str(cal_path)]
        )
        == 0
    )
    spec = next(t for t in json.loads(cal_path.read_text())["model"]["terms"] if t["name"] == "rate_root")
    assert spec["source"] == {"file": "my_terms.py", "sha256": user_terms.file_hash(term_file)}

    applied = tmp_path / "applied.parquet"
    assert cli.main(["apply", str(cal_path), str(log), "--terms", str(term_file), "-o", str(applied)]) == 0
    floor = np.sqrt(np.mean(fixed.residuals[[f"floor_{a}" for a in "xyz"]].to_numpy() ** 2))
    with_term = hold_errors(applied, log, obs)
    assert np.sqrt(np.mean(with_term**2)) < 1.5 * floor  # all holds, end points included
    plain = tmp_path / "plain_cal.json"
    assert cli.main(["calibrate", str(log), "-o", str(plain)]) == 0
    assert cli.main(["apply", str(plain), str(log), "-o", str(applied)]) == 0
    # In sample the seed-000 terms absorb most of the effect; what is left is about the
    # floor again (RMS of 1134 hold errors: about 2 % precision).
    without = hold_errors(applied, log, obs)
    assert np.sqrt(np.mean(without**2)) > 1.25 * np.sqrt(np.mean(with_term**2))

    # Elsewhere: without the file, or with the file changed, apply refuses in one line.
    def fresh(*args):
        return subprocess.run(
            [sys.executable, "-m", "gyrocal", *map(str, args)], capture_output=True, text=True, cwd=tmp_path
        )

    out = fresh("apply", cal_path, log, "-o", applied)
    assert out.returncode == 2 and "my_terms.py" in out.stderr and len(out.stderr.splitlines()) == 1
    term_file.write_text(TERM_FILE + "# edited\n")
    out = fresh("apply", cal_path, log, "--terms", term_file, "-o", applied)
    assert out.returncode == 2 and "definition differs" in out.stderr


def test_the_same_term_file_under_two_paths_loads_once(tmp_path, registry):
    """Copies of one term file (two workflow folders, one Python process) are one code: the
    second path gets the first one's terms, where registering them again refused the
    name; a changed copy is another file and is refused as before."""
    first, second, changed = (tmp_path / d / "my_terms.py" for d in ("a", "b", "c"))
    for path, text in ((first, TERM_FILE), (second, TERM_FILE), (changed, TERM_FILE + "\n# v2\n")):
        path.parent.mkdir()
        path.write_text(text)
    digest, added = user_terms.load_term_file(first)
    assert added == ["rate_root"]
    assert user_terms.load_term_file(second) == (digest, ["rate_root"])
    with pytest.raises(ConfigError, match="'rate_root' is already registered"):
        user_terms.load_term_file(changed)


def test_an_expression_term_is_tried_fitted_and_kept_in_the_file(tmp_path):
    # A bias growing with the square of the temperature rate, described in one line.
    rng = np.random.default_rng(4)
    obs = observations(GyroUnit.seed000(), rng, temperatures=(0.0, 20.0, 40.0), temp_rate_sd=1.0)
    coef = np.array([4e-3, -3e-3, 2e-3])
    for i, a in enumerate("xyz"):
        obs[f"gyro_{a}"] += coef[i] * obs["temp_rate"] ** 2
    expression = {"name": "expression", "label": "dTdt2", "formula": "temp_rate ** 2"}
    settings = replace(Settings(), diagnosis=DiagnosisSettings.from_dict({"candidates": [expression]}))
    diag = diagnose(settings, obs)
    assert diag.best is not None and diag.best.term == 'expression(label="dTdt2", formula="temp_rate ** 2")'
    model = ModelSettings.from_dict({"expressions": {"dTdt2": "temp_rate ** 2"}})
    fixed = diagnose(replace(settings, model=model), obs)
    assert fixed.explains and fixed.best is None
    sizes = {p["coefficient"]: p for p in diagnose(settings, obs).best.size}
    for i, a in enumerate("xyz"):
        assert abs(sizes[f"dTdt2.{a}"]["value"] - coef[i]) < 5 * sizes[f"dTdt2.{a}"]["stderr"]


def test_expressions_refuse_anything_but_arithmetic():
    from gyrocal.io.errors import ConfigError

    for formula in (
        "__import__('os')",
        "temp.real",
        "[temp]",
        "temp if temp else 0",
        "open('x')",
        "sin(temp, rate_x)",
        "abs()",
        "9" * 5000,
        "1e400",
        "True",
        "std_x * 2",
        "(" * 300 + "temp" + ")" * 300,
    ):
        with pytest.raises(ConfigError):
            ModelSettings.from_dict({"expressions": {"bad": formula}})


def test_a_continuous_model_is_validated_written_and_applied_like_a_grid(tmp_path, logs):
    model = {
        "kind": "continuous",
        "terms": [
            "bias",
            "scale",
            "misalignment",
            "bias_temp_poly(degree=3)",
            "scale_temp_poly",
            "misalignment_temp",
        ],
    }
    settings = replace(Settings(), model=ModelSettings.from_dict(model))
    result = run(logs["complete"], settings)
    cal = result.calibration
    assert cal.kind == "continuous"
    s = result.validation.summary
    assert s["model_kind"] == "continuous" and s["held_out"] == "temperature"
    assert s["validation_rms"] <= 1.2 * s["noise_floor"]
    path = tmp_path / "cal.json"
    save_calibration(cal, path)
    again = load_calibration(path)
    save_calibration(again, tmp_path / "again.json")
    assert (tmp_path / "again.json").read_bytes() == path.read_bytes()
    doc = json.loads(path.read_text())
    assert doc["model"]["kind"] == "continuous" and doc["model"]["interpolation"]["method"] == "none"
    # K and B at temperatures inside the range match the unit's within 5 standard errors
    # (each coefficient's error carried to that temperature, correlations ignored).
    temps = (-5.0, 15.0, 40.0)
    K, B = again.matrices_at(temps)
    unit = GyroUnit.seed000()
    se = dict(zip(cal.grid.names, cal.grid.stderr, strict=False))
    for k, temp in enumerate(temps):
        dT = temp - 25.0
        for i, a in enumerate("xyz"):
            bias_se = np.sqrt(
                se[f"bias.{a}"] ** 2 + sum((dT**j * se[f"bias_temp_poly.{a}.c{j}"]) ** 2 for j in (1, 2, 3))
            )
            assert abs(B[k, i] - unit.B(temp)[i]) < 5 * bias_se
            scale_se = np.hypot(se[f"scale.{a}"], dT * se[f"scale_temp_poly.{a}.c1"])
            assert abs(K[k, i, i] - unit.K(temp)[i, i]) < 5 * scale_se
            for j, b in enumerate("xyz"):
                if a != b:
                    cross_se = np.hypot(se[f"misalignment.{a}.{b}"], dT * se[f"misalignment_temp.{a}.{b}"])
                    assert abs(K[k, i, j] - unit.K(temp)[i, j]) < 5 * cross_se
    applied = tmp_path / "applied.parquet"
    apply_calibration(again, logs["complete"], applied)
    errors = hold_errors(applied, logs["complete"], result.segmentation.observations)
    assert np.sqrt(np.mean(errors**2)) < 1.5 * s["noise_floor"]


def test_temperature_rate_is_the_local_slope():
    t = np.arange(0.0, 600.0, 0.01)
    temp = 20.0 + 0.5 * t / 60.0 + np.random.default_rng(1).normal(0, 0.02, len(t))
    rate = temperature_rate(t, temp)
    np.testing.assert_allclose(rate, 0.5, atol=0.01)  # ends too: odd reflection keeps the trend
    temp[1000:1500] = np.nan  # a gap of 5 s and non-finite rows
    rate = temperature_rate(t, temp)
    assert np.isnan(rate[1000:1500]).all()
    np.testing.assert_allclose(rate[~np.isnan(temp)], 0.5, atol=0.01)
    assert np.isnan(temperature_rate(t[:1], temp[:1])).all()


@pytest.mark.slow
def test_a_temperature_rate_term_is_found_and_applied_from_the_log(tmp_path):
    # The chamber door lets the die warm and cool around each handling: holds see dT/dt.
    unit = GyroUnit.seed000().with_effects({"temp_rate": (0.02, -0.015, 0.01)})
    log = make_log(tmp_path, "door", seed=3, unit=unit, door_coupling=0.3, unit_tau_s=20.0, air_tau_s=2.0)
    settings = replace(
        Settings(), segmentation=SegmentConfig.from_dict({"max_temp_rate": 10.0, "hold_max_temp_rate": 10.0})
    )
    obs = segment_log(log, settings).observations
    diag = diagnose(settings, obs)
    assert diag.best is not None and diag.best.term == "temp_rate"
    fixed = extended(settings, "temp_rate")
    result = run(log, fixed)
    s = result.validation.summary
    assert s["validation_rms"] <= 1.2 * s["noise_floor"]
    applied = tmp_path / "applied.parquet"
    apply_calibration(result.calibration, log, applied)
    with_term = hold_errors(applied, log, obs)
    apply_calibration(run(log, settings).calibration, log, applied)
    without = hold_errors(applied, log, obs)
    assert np.sqrt(np.mean(with_term**2)) < 0.5 * np.sqrt(np.mean(without**2))


def test_a_term_restricted_to_the_part_a_protocol_sees_round_trips():
    from gyrocal.io.errors import ConfigError
    from gyrocal.pipeline.config import ModelSettings
    from gyrocal.terms import Restricted, make_term

    part = make_term('g_sensitivity(drop=["x.z", "y.z", "z.z"])')
    assert isinstance(part, Restricted)
    assert part.coefficients() == [f"g_sensitivity.{a}.{b}" for a in "xyz" for b in "xy"]
    assert make_term(part.spec()).spec_string() == part.spec_string()
    assert make_term(part.spec_string()) == part
    columns = part.columns({f"accel_{b}": np.arange(3.0) + i for i, b in enumerate("xyz")})
    assert sorted(columns) == part.coefficients()
    # The same effect: in a model it replaces the full term, and the full term replaces it.
    model = ModelSettings().with_terms(("g_sensitivity",)).with_terms((part.spec_string(),))
    assert model.terms[-1] == part.spec_string() and len(model.terms) == 4
    assert ModelSettings(terms=model.terms).with_terms(("g_sensitivity",)).terms[-1] == "g_sensitivity"
    with pytest.raises(ConfigError, match="has no coefficient x.w to drop"):
        make_term('g_sensitivity(drop=["x.w"])')


def test_an_empirical_term_is_a_spline_without_its_constant():
    from gyrocal.io.errors import ConfigError
    from gyrocal.terms import make_term
    from gyrocal.terms.empirical import spline_basis

    term = make_term('smooth(input="t", knots=[0.0, 100.0, 400.0, 1000.0])')
    assert make_term(term.spec_string()) == term and make_term(term.spec()) == term
    assert term.coefficient_scope == "global" and term.size == 5  # K + 1: the constant left out
    x = np.linspace(-50.0, 1200.0, 400)
    basis = spline_basis(x, term.knots)
    first = 1.0 - basis.sum(axis=1)  # the B-splines sum to one: the one left out
    assert np.all(first >= -1e-12) and first[x <= 0].min() == pytest.approx(1.0)
    np.testing.assert_array_equal(basis[x >= 1000], basis[x >= 1000][:1].repeat((x >= 1000).sum(), 0))
    # A cubic is in the span (with the constant), to rounding: the basis is a cubic spline.
    u = np.clip(x, 0, 1000) / 1000
    cubic = 3 * u**3 - u**2 + 0.5 * u
    design = np.column_stack([np.ones_like(x), basis])
    coef, *_ = np.linalg.lstsq(design, cubic, rcond=None)
    assert np.max(np.abs(design @ coef - cubic)) < 1e-12
    omega = term.penalty(term.coefficients()[: term.size])
    assert np.all(np.linalg.eigvalsh(omega) > -1e-12)
    by_rate = make_term('smooth(input="temp", knots=[-20.0, 25.0, 70.0], by="rate_own", linear=False)')
    assert by_rate.varies_with_temperature and by_rate.unit == "1" and by_rate.size == 3
    cols = by_rate.columns(
        {
            "temp": np.array([25.0, 25.0]),
            "rate_x": np.array([2.0, 0.0]),
            "rate_y": np.zeros(2),
            "rate_z": np.zeros(2),
        }
    )
    assert cols["smooth_temp_by_rate.x.k1"][1] == 0.0 and cols["smooth_temp_by_rate.x.k1"][0] != 0.0
    for bad in (
        'smooth(input="pressure", knots=[0, 1])',
        'smooth(input="t", knots=[1, 0])',
        'smooth(input="t", knots=[0, 1], by="accel")',
    ):
        with pytest.raises(ConfigError):
            make_term(bad)


def test_an_own_axis_formula_is_the_three_per_axis_formulas():
    from gyrocal.fit.model import Model
    from gyrocal.terms.signals import Inputs

    rng = np.random.default_rng(0)
    data = Inputs({f"rate_{a}": rng.normal(0, 100, 5) for a in "xyz"} | {"t": np.arange(5.0) * 60})
    own = Model.from_spec([{"name": "expression", "label": "sw", "formula": "rate_own * exp(-t / 300)"}])
    design = own.design(data)
    for a in "xyz":
        np.testing.assert_allclose(design[f"sw.{a}"], data[f"rate_{a}"] * np.exp(-data["t"] / 300))
    assert own.terms[0].needs == {"rate_x", "rate_y", "rate_z", "t"}
