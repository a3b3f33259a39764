"""`gyrocal revalidate`: a calibration judged on the next session of its unit, in process, on
the quick simulated sessions of test_drift.py (three temperatures)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from gyrocal.calibration.file import save_calibration
from gyrocal.run import cli
from gyrocal.simulate import GyroUnit, TurntableProtocol, simulate_unit

from .test_drift import SHIFT, TEMPS, session, shifted


def main(*args):
    return cli.main([str(a) for a in args])


@pytest.fixture(scope="module")
def unit_sessions(tmp_path_factory):
    """The first session's calibration file, and the logs of two later sessions of the unit:
    as it was, and after its bias moved by SHIFT."""
    d = tmp_path_factory.mktemp("revalidate")
    unit = GyroUnit.seed000()
    cal, _ = session(d, unit, 1, "2026-01-10")
    save_calibration(cal, d / "cal.json")
    out = {"cal": d / "cal.json"}
    for name, u, seed in (("next", unit, 2), ("moved", shifted(unit), 3)):
        out[name] = d / f"{name}.parquet"
        simulate_unit(
            out[name],
            rig=TurntableProtocol.quick(temperatures=TEMPS),
            unit=u,
            rng=np.random.default_rng(seed),
            device="D1",
            session="2026-03-10",
        )
    return out


def printed(text: str) -> dict:
    """The figures of the printout, as printed."""
    m = re.search(
        r"  (\d+) holds scored.*\n  hold-mean RMS (\S+) deg/s: noise floor (\S+) \((\S+)x\), "
        r"expected of a correct calibration (\S+) \((\S+)x\)",
        text,
    )
    assert m, text
    holds, rms, floor, excess, expected, over = m.groups()
    return {
        "holds_scored": int(holds),
        "validation_rms": rms,
        "noise_floor": floor,
        "excess": excess,
        "expected_rms": expected,
        "excess_over_expected": over,
        "verdict": text.splitlines()[-1].strip(),
    }


def no_nan(text: str) -> dict:
    def refuse(name):
        raise AssertionError(f"{name} in the JSON")

    return json.loads(text, parse_constant=refuse)


def test_the_next_session_of_the_same_unit_is_at_the_expected_multiple(unit_sessions, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main("revalidate", unit_sessions["cal"], unit_sessions["next"], "-o", out) == 0
    shown = printed(capsys.readouterr().out)
    doc = no_nan(out.read_text())
    assert shown["verdict"] == "the calibration carries over to this session" and doc["holds"]
    # A correct calibration leaves expected_rms: the floor and its own uncertainty. The RMS of
    # N hold-mean errors scatters about it by 1/sqrt(2N) of itself (4σ here; .2f rounding).
    expected = doc["expected_rms"] / doc["noise_floor"]
    N = 3 * doc["holds_scored"]
    assert 1 <= expected < 1.2
    assert abs(float(shown["excess"]) - expected) < 4 * expected / np.sqrt(2 * N) + 0.005


def test_a_unit_whose_bias_moved_is_missed_and_the_file_says_what_was_printed(
    unit_sessions, tmp_path, capsys
):
    out = tmp_path / "r.json"
    assert main("revalidate", unit_sessions["cal"], unit_sessions["moved"], "-o", out) == 0
    shown = printed(capsys.readouterr().out)
    doc = no_nan(out.read_text())
    assert not doc["holds"]
    assert shown["verdict"].startswith(f"it misses this session by {doc['excess']:.3g} times the floor")
    assert shown["verdict"] == doc["verdict"]
    for key, spec in (
        ("validation_rms", ".3g"),
        ("noise_floor", ".3g"),
        ("excess", ".2f"),
        ("expected_rms", ".3g"),
        ("excess_over_expected", ".2f"),
    ):
        assert shown[key] == format(doc[key], spec), key
    assert shown["holds_scored"] == doc["holds_scored"]
    assert doc["excess"] == pytest.approx(doc["validation_rms"] / doc["noise_floor"], rel=1e-12)
    # The error is the shift on top of the expected: sqrt(expected² + mean(shift²)).
    np.testing.assert_allclose(
        doc["validation_rms"], np.sqrt(doc["expected_rms"] ** 2 + np.mean(SHIFT**2)), rtol=0.1
    )


def test_the_file_carries_its_format_and_whose_calibration_on_which_log(unit_sessions, tmp_path):
    out = tmp_path / "r.json"
    assert (
        main("revalidate", unit_sessions["cal"], unit_sessions["next"], "--protocol", "turntable", "-o", out)
        == 0
    )
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    doc = no_nan(text)
    assert doc["format"] == "gyrocal.revalidation/1"
    assert (doc["device"], doc["batch"], doc["session"]) == ("D1", "B1", "2026-01-10")
    assert (doc["calibration"], doc["log"]) == ("cal.json", "next.parquet")
    assert len(doc["table"]) == 9 and {r["rotating"] for r in doc["table"]} == {"x", "y", "z"}


@pytest.fixture(scope="module")
def servo_cal(tmp_path_factory):
    d = tmp_path_factory.mktemp("servo")
    assert (
        main(
            "simulate", "--protocol", "servo", "--log", d / "s.parquet", "--preset", "quick", "--device", "S1"
        )
        == 0
    )
    assert main("calibrate", d / "s.parquet", "--protocol", "servo", "-o", d / "servo.json") == 0
    return d / "servo.json"


@pytest.mark.parametrize(
    "case, expected",
    [
        ("servo", "servo.json: a servo calibration cannot be revalidated"),
        ("no log", "absent.parquet: no such file"),
        ("corrupt", "corrupt.json: not valid JSON"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_no_traceback(
    case, expected, unit_sessions, servo_cal, tmp_path, capsys
):
    cal, log = unit_sessions["cal"], unit_sessions["next"]
    if case == "servo":
        cal = servo_cal
    elif case == "no log":
        log = tmp_path / "absent.parquet"
    else:
        cal = tmp_path / "corrupt.json"
        cal.write_text('{"format": "gyrocal.calibration/1", ')
    capsys.readouterr()
    assert main("revalidate", cal, log, "-o", tmp_path / "r.json") == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gyrocal: error: ") and expected in lines[0]
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "r.json").exists()
