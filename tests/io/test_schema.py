"""The config and manifest schemas: one source of bounds and defaults, one wording of errors."""

from __future__ import annotations

from dataclasses import fields

import jsonschema
import pytest
import yaml

from gyrocal.fleet.manifest import read_manifest
from gyrocal.io import schema
from gyrocal.io.errors import ConfigError
from gyrocal.pipeline.config import DiagnosisSettings, ModelSettings, Settings
from gyrocal.protocols.turntable.segment import SegmentConfig

from .conftest import FLEET_CONFIG, REPO


@pytest.mark.parametrize("name", ["config", "manifest"])
def test_the_schemas_are_valid_json_schemas(name):
    jsonschema.Draft202012Validator.check_schema(schema.load(name))


def test_the_settings_take_their_defaults_from_the_schema():
    seg = schema.section("config", "segmentation")["properties"]
    assert [f.name for f in fields(SegmentConfig)] == list(seg)
    assert SegmentConfig() == SegmentConfig(**{k: p["default"] for k, p in seg.items()})
    model, diagnosis = schema.defaults("config", "model"), schema.defaults("config", "diagnosis")
    assert (
        ModelSettings().kind,
        ModelSettings().interpolation,
        ModelSettings().degree,
        ModelSettings().reference_temperature,
    ) == (model["kind"], model["interpolation"], model["degree"], model["reference_temperature"])
    assert DiagnosisSettings().significance == diagnosis["significance"]
    # Calibration files record this hash: the defaults' values and types are unchanged (it
    # changed with segmentation: settling, issue 38, and hold_max_temp_rate, issue 52).
    assert Settings().sha256() == "9a5f781b7569e4b86b31b2f41b12d7c9b6f0c574f028c8befdb127574908c900"
    assert Settings.from_dict({}) == Settings()
    assert ModelSettings.from_dict({"terms": ("bias", "scale")}).terms == ("bias", "scale")


@pytest.mark.parametrize(
    "section, values, message",
    [
        ("segmentation", {"trim_s": -1}, "segmentation.trim_s must be at least 0, got -1"),
        ("segmentation", {"temp_gap": float("inf")}, "segmentation.temp_gap must be a number, got inf"),
        (
            "model",
            {"interpolation": "cosine"},
            "model.interpolation method 'cosine' is not known; choose one of lagrange3, linear, spline, poly",
        ),
        ("model", {"degree": 2.0}, "model.degree must be a whole number, got 2.0"),
        (
            "model",
            {"expressions": {"door": {"formula": "t", "scope": "all"}}},
            "model.expressions.door.scope 'all' is not known; choose one of point, global",
        ),
        ("diagnosis", {"significance": 1}, "diagnosis.significance must be less than 1, got 1"),
        (
            "diagnosis",
            {"ladder": [{"add": ["scale_quadratic"], "kind": "joint"}]},
            "diagnosis.ladder[0].kind 'joint' is not known; choose one of grid, continuous, null",
        ),
        (
            "protocols",
            {"sweep": {"options": {"fill": 2}}},
            "protocols.sweep.options.fill must be at most 1, got 2",
        ),
        (
            "protocols",
            {"servo": {"options": {"min_revolutions": 0.5}}},
            "protocols.servo.options.min_revolutions must be a whole number, got 0.5",
        ),
        (
            "protocols",
            {"sweep": {"model": {"kind": "joint"}}},
            "protocols.sweep.model.kind 'joint' is not known; choose one of grid, continuous",
        ),
    ],
)
def test_the_workflow_and_the_library_refuse_a_value_in_the_same_words(section, values, message):
    config = yaml.safe_load(FLEET_CONFIG) | {section: values}
    with pytest.raises(ConfigError) as workflow:
        schema.check(config, source="config.yaml")
    with pytest.raises(ConfigError) as library:
        Settings.from_dict({section: values})
    assert str(workflow.value) == f"config.yaml: {message}"
    assert str(library.value) == message


def test_defaults_complete_the_config_but_not_a_protocols_override():
    config = schema.check(
        {
            "devices": "d.tsv",
            "model": {"terms": ["bias"]},
            "protocols": {"sweep": {"model": {"terms": ["bias"]}}},
        }
    )
    assert config["model"] == {"terms": ["bias"], **schema.defaults("config", "model")}
    assert config["segmentation"]["block_s"] == SegmentConfig().block_s
    assert config["diagnosis"]["significance"] == DiagnosisSettings().significance
    assert config["protocols"] == {"sweep": {"model": {"terms": ["bias"]}}}  # the sweep's own kind stays
    assert (
        Settings.from_dict({"protocols": config["protocols"]}).for_protocol("sweep").model.kind
        == "continuous"
    )


def test_the_demo_config_passes():
    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    assert schema.check(config)["demo"] == config["demo"]


HEADER = "device\tbatch\tsession\tprotocol\tpath\n"


@pytest.mark.parametrize(
    "row, message",
    [
        (
            "bad id!\tB1\t2026-01-01\tturntable\tx.parquet",
            "device 'bad id!' does not match ^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$",
        ),
        (
            "U1\tB/1\t2026-01-01\tturntable\tx.parquet",
            "batch 'B/1' must be a name without slashes or tabs, not . or ..",
        ),
        ("U1\tB1\t2026-02-30\tturntable\tx.parquet", "session '2026-02-30' is not an ISO date YYYY-MM-DD"),
        ("U1\tB1\t26-2-3\tturntable\tx.parquet", "session '26-2-3' is not an ISO date YYYY-MM-DD"),
        (
            "U1\tB1\t2026-01-01\tgimbal\tx.parquet",
            "protocol 'gimbal' is not known; choose one of turntable, servo, sweep, ferraris, static",
        ),
        ("U1\tB1\t2026-01-01\tservo\t", "path '' is empty"),
        # Hostile rows: ids name output folders (results/{batch}/{device}/{session}).
        (
            "U1\t..\t2026-01-01\tturntable\tu1.parquet",
            "batch '..' must be a name without slashes or tabs, not . or ..",
        ),
        (
            "U1\t.\t2026-01-01\tturntable\tu1.parquet",
            "batch '.' must be a name without slashes or tabs, not . or ..",
        ),
        (
            "../U1\tB1\t2026-01-01\tturntable\tu1.parquet",
            "device '../U1' does not match ^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$",
        ),
        (
            "<script>\tB1\t2026-01-01\tturntable\tu1.parquet",
            "device '<script>' does not match ^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$",
        ),
        (
            "U1\tB1\t2026-01-01; rm -rf /\tturntable\tu1.parquet",
            "session '2026-01-01; rm -rf /' is not an ISO date YYYY-MM-DD",
        ),
        (
            "U1\tB1\t2026-01-01\tturntable; rm\tu1.parquet",
            "protocol 'turntable; rm' is not known; choose one of turntable, servo, sweep, ferraris, static",
        ),
        (
            "U0\tB1\t2026-01-01\tturntable\tother.parquet",
            "device U0 session 2026-01-01 is listed twice (first on line 2)",
        ),
    ],
)
def test_a_bad_manifest_row_is_named_by_line_and_column(tmp_path, row, message):
    path = tmp_path / "devices.tsv"
    path.write_text(HEADER + "U0\tB1\t2026-01-01\tturntable\tu0.parquet\n" + row + "\n")
    with pytest.raises(ConfigError) as err:
        read_manifest(path)
    assert str(err.value) == f"{path}: line 3: {message}"


def test_a_good_manifest_reads_every_row(tmp_path):
    path = tmp_path / "devices.tsv"
    path.write_text(
        HEADER + "U0\tB1\t2026-01-01\tturntable\tlogs/u0.parquet\n"
        "U1\tB1\t2026-01-01\tsweep\ts3://bucket/u1.parquet\n"
    )
    rows = read_manifest(path)
    assert [r["log"] for r in rows] == [str(tmp_path / "logs" / "u0.parquet"), "s3://bucket/u1.parquet"]


MODELS = {
    "U7": {"add": ["scale_cubic"]},
    "B2": {"kind": "continuous"},
    "U1*": {"add": ["g_squared"]},
    "U*": {"add": ["scale_asymmetry"]},
    "line-3 warm": {"add": ["temp_lag"]},
}


@pytest.mark.parametrize(
    "device, batch, column, entry",
    [
        ("U7", "B2", "", "U7"),  # its device's before its batch's
        ("U8", "B2", "", "B2"),  # its batch's before a pattern's
        ("U12", "B1", "", "U1*"),  # the first pattern that matches, in written order
        ("U22", "B1", "", "U*"),
        ("X1", "B1", "", None),  # the fleet's model
        ("U7", "B2", "line-3 warm", "line-3 warm"),  # the manifest's column before all of them
    ],
)
def test_a_unit_takes_the_models_entry_its_row_device_batch_or_pattern_names(device, batch, column, entry):
    from gyrocal.fleet.manifest import model_entry

    row = {"device": device, "batch": batch, "session": "2026-01-01", "model": column}
    assert model_entry(row, MODELS) == entry


def test_the_manifests_model_column_is_read_written_to_shards_and_must_name_an_entry(tmp_path):
    from gyrocal.fleet.manifest import model_entry, write_shards

    path = tmp_path / "devices.tsv"
    path.write_text(
        "device\tbatch\tsession\tprotocol\tpath\tmodel\n"
        "U0\tB1\t2026-01-01\tturntable\tu0.parquet\twarm\n"
        "U1\tB1\t2026-01-01\tturntable\tu1.parquet\t\n"
    )
    rows = read_manifest(path)
    assert [r["model"] for r in rows] == ["warm", ""]
    with pytest.raises(
        ConfigError,
        match="device U0 session 2026-01-01: the manifest's model column "
        "names 'warm', which the config's models: does not have",
    ):
        model_entry(rows[0], {"cold": {"add": ["temp_lag"]}})
    (shard,) = write_shards(rows, 10, tmp_path / "shards")
    assert [r["model"] for r in read_manifest(shard)] == ["warm", ""]
    bad = tmp_path / "bad.tsv"
    bad.write_text(
        "device\tbatch\tsession\tprotocol\tpath\tmodel\nU0\tB1\t2026-01-01\tturntable\tu0.parquet\ta/b\n"
    )
    with pytest.raises(ConfigError, match="line 2: model 'a/b' must name an entry"):
        read_manifest(bad)


def test_a_models_entry_changes_the_unit_model_key_by_key_and_adds_terms():
    from gyrocal.pipeline.config import Settings

    fleet = {
        "model": {"terms": ["bias", "scale", "misalignment", "scale_quadratic"], "interpolation": "linear"}
    }
    unit = Settings.from_dict(
        {**fleet, "unit": {"entry": "U7", "model": {"add": ["scale_cubic", "scale_quadratic"]}}}
    )
    assert unit.model.terms == ("bias", "scale", "misalignment", "scale_quadratic", "scale_cubic")
    assert unit.model.interpolation == "linear" and unit.model_entry == "U7"
    # key by key: terms replaced, kind changed, the rest the fleet's
    other = Settings.from_dict(
        {**fleet, "unit": {"entry": "B2", "model": {"terms": ["bias", "scale"], "kind": "continuous"}}}
    )
    assert other.model.terms == ("bias", "scale") and other.model.kind == "continuous"
    assert Settings.from_dict(other.to_dict()) == other  # what a job is handed reads back
    assert other.sha256() != Settings.from_dict(fleet).sha256()
    # a sweep unit's entry goes on top of its protocol's own model
    sweep = unit.for_protocol("sweep")
    assert sweep.model.kind == "continuous" and "scale_cubic" in sweep.model.terms
    with pytest.raises(ConfigError, match="models.U7.add must hold at least 1 item"):
        Settings.from_dict({"unit": {"entry": "U7", "model": {"add": []}}})
    with pytest.raises(ConfigError, match="unknown model term 'scale_cubi'"):
        Settings.from_dict({"unit": {"entry": "U7", "model": {"add": ["scale_cubi"]}}})


def test_a_fix_line_for_a_unit_that_takes_a_batch_entry_keeps_that_entry_and_adds_the_fix():
    """The device's own entry comes before its batch's: the line printed for it carries the
    batch's settings and the whole list of terms, so pasting it changes that unit by the fix
    alone."""
    import yaml

    from gyrocal.diagnosis.evaluation import unit_config_line
    from gyrocal.fleet.manifest import model_entry
    from gyrocal.pipeline.config import Settings

    batch = {"interpolation": "linear", "reference_temperature": 30.0, "add": ["scale_cubic"]}
    unit = Settings.from_dict({"unit": {"entry": "B2", "model": batch}})
    line = unit_config_line("yes", unit, {"term": "scale_quadratic"})  # a device YAML reads as true
    models = yaml.safe_load(line)["models"]
    assert (
        list(models) == ["yes"]
        and model_entry({"device": "yes", "batch": "B2", "model": ""}, {"B2": batch, **models}) == "yes"
    )
    pasted = Settings.from_dict({"unit": {"entry": "yes", "model": models["yes"]}})
    assert pasted.model == unit.model.with_terms(("scale_quadratic",))
    # the whole fleet's line is the fleet's model with the fix, not this unit's
    from gyrocal.diagnosis.evaluation import with_unit_lines

    doc = with_unit_lines({"best": {"term": "scale_quadratic", "config_line": "x"}}, "yes", unit)
    assert doc["best"]["config_line"] == "terms: [bias, scale, misalignment, scale_quadratic]"


def test_a_key_given_twice_in_a_config_file_is_refused_naming_both_lines(tmp_path):
    from gyrocal.pipeline.config import read_yaml

    path = tmp_path / "config.yaml"
    path.write_text("model: {terms: [bias]}\nmodels:\n  U1: {add: [x]}\nmodels:\n  U2: {add: [y]}\n")
    with pytest.raises(ConfigError, match="line 4: models is given twice \\(first on line 2\\)"):
        read_yaml(path)
    from gyrocal.fleet.manifest import model_entry

    with pytest.raises(ConfigError, match="the key 1234 is read as a number, not a name: quote it"):
        model_entry({"device": "1234", "batch": "B", "model": ""}, {1234: {"add": ["x"]}})
