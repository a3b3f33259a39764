"""Model versus measurement: the diagnosis finds what the model lacks, and only then."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from gyrocal.config import DiagnosisSettings, ModelSettings, Settings
from gyrocal.diagnose import candidate_terms, config_line, diagnose, extended
from gyrocal.pipeline import segment_log
from gyrocal.simulate import GyroUnit
from gyrocal.simulate.observations import observations
from gyrocal.terms import make_term

from .conftest import make_log

SIX_MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")

# Effects the default (seed-000) model lacks, at sizes of consumer MEMS datasheets:
# nonlinearity of 0.02-0.05 % of 400 deg/s, a g-sensitivity of 0.01-0.06 deg/s/g.
EFFECTS = {
    "scale_quadratic": ({"scale_quadratic": (1e-6, -8e-7, 6e-7)}, {}),
    "scale_asymmetry": ({"scale_asymmetry": (3e-4, -2e-4, 2.5e-4)}, {}),
    "scale_cubic": ({"scale_cubic": (6e-10, -5e-10, 4e-10)}, {}),
    "g_sensitivity": ({"g_sensitivity": ((0.05, 0.02, -0.01), (0.01, -0.04, 0.02),
                                         (-0.02, 0.01, 0.06))}, {"mounts": SIX_MOUNTS}),
}


@pytest.fixture(scope="module")
def effect_logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("effects")
    return {name: make_log(d, name, seed=11 + k, unit=GyroUnit.seed000().with_effects(fx), **rig)
            for k, (name, (fx, rig)) in enumerate(EFFECTS.items())}


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_a_missing_effect_is_ranked_first_and_adding_it_reaches_the_floor(effect, effect_logs):
    settings = Settings()
    obs = segment_log(effect_logs[effect], settings).observations
    diag = diagnose(settings, obs)
    assert not diag.explains
    assert diag.best is not None and diag.best.term == effect
    assert diag.candidates[0].term == effect
    assert diag.best.validation_rms_with < diag.base.summary["validation_rms"]
    # The fitted size matches the simulated one within its reported uncertainty.
    truth = np.asarray(EFFECTS[effect][0][effect], dtype=float)
    for size in diag.best.size:
        parts = size["coefficient"].split(".")
        want = truth["xyz".index(parts[1])] if truth.ndim == 1 else \
            truth["xyz".index(parts[1]), "xyz".index(parts[2])]
        assert abs(size["value"] - want) < 5 * size["stderr"], size

    fixed = diagnose(extended(settings, effect), obs)
    assert fixed.base.summary["validation_rms"] <= 1.2 * fixed.base.summary["noise_floor"]
    assert fixed.explains and fixed.best is None
    assert "nothing is missing" in fixed.verdict


def test_on_data_the_model_explains_false_alarms_stay_within_the_significance():
    alpha, runs = 0.05, 80
    settings = replace(Settings(), diagnosis=DiagnosisSettings(significance=alpha))
    alarms = 0
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        obs = observations(GyroUnit.random(rng), rng, temperatures=(0.0, 20.0, 40.0),
                           rates=(1.0, 10.0, 100.0, 400.0))
        diag = diagnose(settings, obs)
        alarms += diag.best is not None or not diag.explains
    # Family-wise at alpha by construction; fail only if the rate is clearly above it.
    assert alarms <= stats.binom.ppf(0.999, runs, alpha), alarms


def test_a_temperature_only_effect_is_found_in_a_continuous_model():
    # The seed-000 unit's scale multiplies its misalignment, so the cross-axis terms drift
    # with temperature: a continuous model without misalignment_temp lacks it.
    rng = np.random.default_rng(5)
    obs = observations(GyroUnit.seed000(), rng, temperatures=(-20.0, -5.0, 10.0, 25.0, 40.0, 55.0))
    model = ModelSettings.from_dict({"kind": "continuous", "terms": [
        "bias", "scale", "misalignment", "bias_temp_poly(degree=3)", "scale_temp_poly"]})
    settings = replace(Settings(), model=model)
    assert "misalignment_temp" in candidate_terms(settings)
    diag = diagnose(settings, obs)
    assert diag.best is not None and diag.best.term == "misalignment_temp"
    fixed = diagnose(extended(settings, "misalignment_temp"), obs)
    assert fixed.explains and fixed.best is None
    assert fixed.base.summary["validation_rms"] <= 1.2 * fixed.base.summary["noise_floor"]


def test_without_a_fitting_candidate_the_excess_is_pointed_at_its_covariate(monkeypatch):
    # An error that grows with the temperature rate, with temp_rate withheld from the
    # candidates: the diagnosis cannot name the term but points at the covariate.
    rng = np.random.default_rng(8)
    unit = GyroUnit.seed000().with_effects({"temp_rate": (0.02, -0.015, 0.01)})
    obs = observations(unit, rng, temperatures=(0.0, 20.0, 40.0), temp_rate_sd=0.5)
    settings = Settings()
    diag = diagnose(settings, obs)
    assert diag.best is not None and diag.best.term == "temp_rate"  # the library has it
    import gyrocal.diagnose as module
    monkeypatch.setattr(module, "CANDIDATES", tuple(c for c in module.CANDIDATES if c != "temp_rate"))
    blind_diag = diagnose(settings, obs)
    assert blind_diag.best is None and not blind_diag.explains
    assert blind_diag.covariates[0]["covariate"] == "temperature rate"
    assert "temperature rate" in blind_diag.verdict


def test_candidates_exclude_what_the_model_has_and_grid_models_skip_temperature_only_terms():
    grid = candidate_terms(Settings())
    assert "scale_quadratic" in grid and "bias_temp_poly(degree=1)" not in grid
    assert not {"bias", "scale", "misalignment"} & set(grid)
    with_quadratic = replace(Settings(), model=Settings().model.with_terms(("scale_quadratic",)))
    assert "scale_quadratic" not in candidate_terms(with_quadratic)
    # A user candidate may supersede a model term (a higher degree).
    model = ModelSettings.from_dict({"kind": "continuous", "terms": ["bias", "scale", "misalignment",
                                                                     "bias_temp_poly(degree=2)"]})
    asked = replace(Settings(), model=model,
                    diagnosis=DiagnosisSettings.from_dict({"candidates": ["bias_temp_poly(degree=3)"]}))
    names = candidate_terms(asked)
    assert "bias_temp_poly(degree=3)" in names and "bias_temp_poly(degree=1)" not in names
    assert extended(asked, "bias_temp_poly(degree=3)").model.terms.count("bias_temp_poly(degree=3)") == 1


def test_every_printed_candidate_name_is_accepted_back():
    settings = replace(Settings(), model=ModelSettings.from_dict({"kind": "continuous"}))
    for name in candidate_terms(settings):
        assert make_term(name).spec_string() == name
        assert name in settings.model.with_terms((name,)).terms
    line = config_line(["bias", "scale_temp_poly(degree=2, t_ref=20.0)"])
    import yaml
    assert yaml.safe_load(line)["terms"] == ["bias", "scale_temp_poly(degree=2, t_ref=20.0)"]


def test_the_ladder_steps_add_terms_and_fall_toward_the_floor(effect_logs):
    obs = segment_log(effect_logs["scale_quadratic"], Settings()).observations
    settings = replace(Settings(), diagnosis=DiagnosisSettings.from_dict({"ladder": [
        {"name": "+ nonlinearity", "add": ["scale_quadratic"]}, "g_sensitivity"]}))
    ladder = diagnose(settings, obs).ladder
    assert [row["name"] for row in ladder] == ["configured model", "+ nonlinearity", "+g_sensitivity"]
    assert ladder[1]["validation_rms"] < 0.2 * ladder[0]["validation_rms"]
    assert [p["coefficient"] for p in ladder[1]["parameters"]] == [
        "scale_quadratic.x", "scale_quadratic.y", "scale_quadratic.z"]
    assert "condition number" in ladder[2]["error"]  # three mounts cannot separate g from bias
