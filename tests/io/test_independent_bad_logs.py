"""Bad inputs from a generator gyrocal's authors did not write (tests/io/badlogs, NOTE.md):
its good log must calibrate to its own truth, and each bad kind must end as its author,
reading only the contract and the physics, expected — refused with one line naming the
file, or calibrated with a recorded warning, or accepted — never with NaN in a file or an
unflagged implausible calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gyrocal.run.cli import main

from .badlogs.generator import EXPECT, KINDS, K_at, good_log, sensor_params


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    return good_log(tmp_path_factory.mktemp("badlogs") / "good.parquet", seed=0)


def calibrate(log, out, capsys):
    status = main(["calibrate", str(log), "-o", str(out)])
    return status, capsys.readouterr().err


def test_the_good_log_calibrates_to_its_own_truth(good, tmp_path, capsys):
    out = tmp_path / "cal.json"
    status, err = calibrate(good, out, capsys)
    assert status == 0, err
    cal = json.loads(out.read_text())
    assert cal["warnings"] == []
    truth = sensor_params(0)
    stderr = cal["grid"]["stderr"]
    axes = "xyz"
    for k, (temp, K, B) in enumerate(
        zip(cal["grid"]["temperature"], cal["grid"]["K"], cal["grid"]["B"], strict=False)
    ):
        # Each term within five of its reported standard errors of the generator's truth.
        dT = temp - 25.0
        true_K = K_at(truth, temp)
        true_B = truth["b0"] + truth["b1"] * dT + truth["b2"] * dT**2
        for i, a in enumerate(axes):
            assert abs(B[i] - true_B[i]) <= 5 * stderr[f"bias.{a}"][k], (temp, a, B[i], true_B[i])
            for j, b in enumerate(axes):
                name = f"scale.{a}" if i == j else f"misalignment.{a}.{b}"
                assert abs(K[i][j] - true_K[i, j]) <= 5 * stderr[name][k], (temp, name, K[i][j], true_K[i, j])


@pytest.mark.parametrize("kind", list(KINDS))
def test_an_independently_made_bad_log(kind, good, tmp_path, capsys):
    _, category, mutate = KINDS[kind]
    verdict, expected = EXPECT[kind]
    log, out = tmp_path / "U001.parquet", tmp_path / "cal.json"
    mutate(good, log)
    status, err = calibrate(log, out, capsys)
    assert "Traceback" not in err and "internal error" not in err, err
    if verdict == "refuse":
        lines = err.strip().splitlines()
        assert status == 2 and len(lines) == 1 and lines[0].startswith(f"gyrocal: error: {log}: "), (
            f"{kind}: expected a refusal ({expected}); got {err!r}"
        )
        assert not out.exists()
        return
    assert status == 0, f"{kind}: expected a calibration ({expected}); got {err!r}"

    def refuse(name):
        raise AssertionError(f"{name} in the calibration file")

    cal = json.loads(out.read_text(), parse_constant=refuse)
    codes = [w["code"] for w in cal["warnings"]]
    diag = np.diagonal(np.array(cal["grid"]["K"]), axis1=1, axis2=2)
    assert np.all(np.abs(diag - 1) < 0.1) or "scale_far_from_one" in codes
    if verdict == "warn":
        assert codes, f"{kind}: expected a warning ({expected}); none recorded"
    elif category == "contract":  # what the contract allows is calibrated without a word
        assert codes == [], f"{kind}: {codes}"
