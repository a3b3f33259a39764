"""The command line: contract section 6 entry points, one-line errors, exit statuses."""

from __future__ import annotations

import json
import subprocess
import sys

import pyarrow.parquet as pq
import pytest

from gyrocal import cli


def gyrocal(*args):
    """Run the installed console entry point in a subprocess (what rigs and scripts do)."""
    return subprocess.run([sys.executable, "-m", "gyrocal.cli", *map(str, args)],
                          capture_output=True, text=True)


def test_help_lists_the_commands():
    out = gyrocal("--help")
    assert out.returncode == 0
    for command in ("simulate", "calibrate", "apply", "segment", "fit", "validate", "report",
                    "fleet"):
        assert command in out.stdout


def main(*args):
    return cli.main([str(a) for a in args])


def test_simulate_calibrate_apply(tmp_path, capsys):
    logs = tmp_path / "logs"
    assert main("simulate", "--out", logs, "--preset", "quick", "--units", "1", "--seed", "4",
                "--temperatures=0,10,20,30", "--rates", "10,100") == 0
    cal = tmp_path / "cal.json"
    report = tmp_path / "r.html"
    assert main("calibrate", logs / "U001.parquet", "-o", cal, "--report", report,
                "--device", "U001", "--batch", "B1", "--session", "2026-01-01",
                "--tables", tmp_path / "tables") == 0
    out = capsys.readouterr().out
    assert f"calibration -> {cal}" in out and "noise floor" in out
    doc = json.loads(cal.read_text())
    assert (doc["device"], doc["batch"], doc["session"]) == ("U001", "B1", "2026-01-01")
    assert "<table>" in report.read_text()
    assert pq.read_table(tmp_path / "tables" / "table_hold_means.parquet").num_rows == 9
    applied = tmp_path / "applied.parquet"
    assert main("apply", cal, logs / "U001.parquet", "-o", applied) == 0
    assert pq.read_metadata(applied).num_rows == pq.read_metadata(logs / "U001.parquet").num_rows
    unit = tmp_path / "unit"
    assert main("segment", logs / "U001.parquet", "--out", unit) == 0
    assert pq.read_table(unit / "observations.parquet").num_rows == 4 * 3 * 5
    assert main("fit", unit) == 0 and main("validate", unit) == 0
    assert main("report", unit, "-o", tmp_path / "unit.html") == 0
    staged = json.loads((unit / "calibration.json").read_text())
    assert staged["grid"]["coefficients"] == doc["grid"]["coefficients"]


@pytest.mark.parametrize("make, args, expected", [
    (lambda d: d.joinpath("x.parquet").write_bytes(b"garbage"), ["calibrate", "{d}/x.parquet", "-o", "{d}/c.json"],
     "not a readable Parquet file"),
    (lambda d: None, ["calibrate", "{d}/absent.parquet", "-o", "{d}/c.json"], "no such file"),
    (lambda d: d.joinpath("c.json").write_text("{}"), ["apply", "{d}/c.json", "{d}/l.parquet", "-o", "{d}/o"],
     "format is None"),
    (lambda d: None, ["calibrate", "{d}/l.parquet", "--protocol", "servo", "-o", "{d}/c.json"],
     "protocol 'servo' is not supported"),
    (lambda d: None, ["calibrate", "{d}/l.parquet", "--add-term", "nope", "-o", "{d}/c.json"],
     "unknown model term 'nope'"),
    (lambda d: d.joinpath("m.yaml").write_text("terms: [bias]\ninterpolation: cosine\n"),
     ["calibrate", "{d}/l.parquet", "--model", "{d}/m.yaml", "-o", "{d}/c.json"], "interpolation method 'cosine' is not known"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, make, args, expected):
    make(tmp_path)
    out = gyrocal(*[a.format(d=tmp_path) for a in args])
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gyrocal: error: ")
    assert expected in lines[0]
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("args", [["nope"], ["calibrate"], ["apply", "a", "-o"], ["simulate", "--units", "x"]])
def test_usage_mistakes_are_one_line_and_exit_2(args):
    out = gyrocal(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gyrocal: error: ")


def test_an_internal_error_is_one_line_and_exit_1(monkeypatch, capsys):
    import gyrocal.calibration

    def broken(path):
        raise RuntimeError("something\nunexpected")
    monkeypatch.setattr(gyrocal.calibration, "load_calibration", broken)
    assert main("apply", "a.json", "b.parquet", "-o", "c.parquet") == 1
    err = capsys.readouterr().err.strip()
    assert err == ("gyrocal: internal error: RuntimeError: something unexpected "
                   "(rerun with --debug for a traceback)")
