"""The command line: contract section 6 entry points, one-line errors, exit statuses."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pyarrow.parquet as pq
import pytest

from gyrocal.io.unit_folder import read_part_table
from gyrocal.run import cli


def gyrocal(*args):
    """Run the installed console entry point in a subprocess (what rigs and scripts do)."""
    return subprocess.run(
        [sys.executable, "-m", "gyrocal.run.cli", *map(str, args)], capture_output=True, text=True
    )


COMMANDS = {
    "simulate",
    "calibrate",
    "diagnose",
    "apply",
    "noise",
    "segment",
    "fit",
    "validate",
    "analyse",
    "report",
    "fleet",
    "shard",
    "paper",
    "lookup",
    "registry",
    "drift",
    "export",
    "verify",
    "import",
    "revalidate",
}


def listed_commands(help_text: str, heading: str) -> list[str]:
    """The commands under a heading of the top-level help, in order: each a line of its own
    four spaces in, its name first (a name found anywhere in the text would be found in
    another command's help: "analyse" says fit, validate and diagnose)."""
    lines = help_text.split(f"\n{heading}:\n", 1)[1].splitlines()
    end = next((i for i, line in enumerate(lines) if line and not line.startswith(" ")), len(lines))
    return [line.split()[0] for line in lines[:end] if re.match(r" {4}\S", line)]


def test_help_lists_the_commands():
    out = gyrocal("--help")
    assert out.returncode == 0
    listed = listed_commands(out.stdout, "commands") + listed_commands(out.stdout, "workflow stages")
    assert set(listed) == COMMANDS and len(listed) == len(COMMANDS)
    subparsers = next(a for a in cli.build_parser()._actions if a.dest == "command")
    assert set(subparsers.choices) == set(listed)  # none accepted but left out of the help


def main(*args):
    return cli.main([str(a) for a in args])


@pytest.mark.slow
def test_simulate_calibrate_apply(tmp_path, capsys):
    logs = tmp_path / "logs"
    assert (
        main(
            "simulate",
            "--out",
            logs,
            "--preset",
            "quick",
            "--units",
            "1",
            "--seed",
            "4",
            "--temperatures=0,10,20,30",
            "--rates",
            "10,100",
        )
        == 0
    )
    cal = tmp_path / "cal.json"
    report = tmp_path / "r.html"
    assert (
        main(
            "calibrate",
            logs / "U001.parquet",
            "-o",
            cal,
            "--report",
            report,
            "--device",
            "U001",
            "--batch",
            "B1",
            "--session",
            "2026-01-01",
            "--tables",
            tmp_path / "tables",
        )
        == 0
    )
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
    assert sorted(p.name for p in unit.iterdir()) == ["segmentation.zip"]
    assert read_part_table(unit, "observations")[0].shape[0] == 4 * 3 * 5
    assert main("fit", unit) == 0 and main("validate", unit) == 0
    assert main("report", unit, "-o", tmp_path / "unit.html") == 0
    staged = json.loads((unit / "calibration.json").read_text())
    assert staged["grid"]["coefficients"] == doc["grid"]["coefficients"]
    capsys.readouterr()
    assert main("verify", cal, logs / "U001.parquet") == 0
    assert "(blake3)" in capsys.readouterr().out


def test_verify_accepts_an_old_sha256_record_and_refuses_another_log(tmp_path, capsys):
    """Files written before BLAKE3 record the input's SHA-256: they still verify; a log
    that is not the input is refused in one line, naming it."""
    import hashlib

    log, other = tmp_path / "a.parquet", tmp_path / "b.parquet"
    log.write_bytes(b"PAR1 one log")
    other.write_bytes(b"PAR1 another")
    cal = tmp_path / "old.json"
    cal.write_text(
        json.dumps(
            {
                "provenance": {
                    "input": {"name": "a.parquet", "sha256": hashlib.sha256(log.read_bytes()).hexdigest()}
                }
            }
        )
    )
    assert main("verify", cal, log) == 0
    assert "(sha256)" in capsys.readouterr().out
    assert main("verify", cal, other) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "b.parquet" in err and "sha256" in err
    cal.write_text(json.dumps({"provenance": {"input": {"name": "a.parquet"}}}))
    assert main("verify", cal, log) == 2
    assert "names no input hash" in capsys.readouterr().err


@pytest.mark.parametrize(
    "make, args, expected",
    [
        (
            lambda d: d.joinpath("x.parquet").write_bytes(b"garbage"),
            ["calibrate", "{d}/x.parquet", "-o", "{d}/c.json"],
            "not a readable Parquet file",
        ),
        (lambda d: None, ["calibrate", "{d}/absent.parquet", "-o", "{d}/c.json"], "no such file"),
        (
            lambda d: d.joinpath("c.json").write_text("{}"),
            ["apply", "{d}/c.json", "{d}/l.parquet", "-o", "{d}/o"],
            "format is None",
        ),
        (
            lambda d: None,
            ["calibrate", "{d}/l.parquet", "--protocol", "gimbal", "-o", "{d}/c.json"],
            "invalid choice: 'gimbal'",
        ),
        (
            lambda d: None,
            ["calibrate", "{d}/l.parquet", "--add-term", "nope", "-o", "{d}/c.json"],
            "unknown model term 'nope'",
        ),
        (
            lambda d: d.joinpath("m.yaml").write_text("terms: [bias]\ninterpolation: cosine\n"),
            ["calibrate", "{d}/l.parquet", "--model", "{d}/m.yaml", "-o", "{d}/c.json"],
            "interpolation method 'cosine' is not known",
        ),
        (
            lambda d: None,
            ["simulate", "--log", "{d}/l.parquet", "--effects", '{{"warp": [1, 2, 3]}}'],
            "unknown simulated effect 'warp'",
        ),
        (
            lambda d: None,
            ["simulate", "--log", "{d}/l.parquet", "--effects", '{{"scale_cubic": [1]}}'],
            "scale_cubic must be 3 finite numbers",
        ),
        (
            lambda d: None,
            ["diagnose", "{d}/l.parquet", "--add-term", "bias_temp_poly(degree=9)", "-o", "{d}/d.json"],
            "degree must be an integer from 1 to 5",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, make, args, expected):
    make(tmp_path)
    out = gyrocal(*[a.format(d=tmp_path) for a in args])
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gyrocal: error: ")
    assert expected in lines[0]
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize(
    "args", [["nope"], ["calibrate"], ["apply", "a", "-o"], ["simulate", "--units", "x"]]
)
def test_usage_mistakes_are_one_line_and_exit_2(args):
    out = gyrocal(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gyrocal: error: ")


def test_an_internal_error_is_one_line_and_exit_1(monkeypatch, capsys):
    import gyrocal.calibration.file

    def broken(path):
        raise RuntimeError("something\nunexpected")

    monkeypatch.setattr(gyrocal.calibration.file, "load_calibration", broken)
    assert main("apply", "a.json", "b.parquet", "-o", "c.parquet") == 1
    err = capsys.readouterr().err.strip()
    assert err == (
        "gyrocal: internal error: RuntimeError: something unexpected (rerun with --debug for a traceback)"
    )


def test_diagnose_writes_the_contract_fields_and_its_names_go_back_into_add_term(tmp_path, capsys):
    log = tmp_path / "u.parquet"
    assert (
        main(
            "simulate",
            "--log",
            log,
            "--preset",
            "quick",
            "--temperatures=0,10,20,30",
            "--effects",
            '{"scale_asymmetry": [3e-4, -2e-4, 2.5e-4]}',
        )
        == 0
    )
    model = tmp_path / "model.yaml"
    model.write_text("model:\n  terms: [bias, scale, misalignment]\n")
    out = tmp_path / "d.json"
    assert (
        main(
            "diagnose",
            log,
            "--protocol",
            "turntable",
            "-o",
            out,
            "--model",
            model,
            "--residuals",
            tmp_path / "r.parquet",
        )
        == 0
    )
    assert "Missing effect: scale_asymmetry" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["excess"] == pytest.approx(doc["validation_rms"] / doc["noise_floor"], rel=1e-12)
    ranked = [c for c in doc["candidates"] if c["validation_rms_with"] is not None]
    assert ranked[0]["term"] == "scale_asymmetry"
    assert [c["validation_rms_with"] for c in ranked] == sorted(c["validation_rms_with"] for c in ranked)
    assert all(0 <= c["p_value"] <= 1 for c in ranked)
    # Significant only below the candidates' Bonferroni share of half the level.
    assert doc["best"]["p_value"] < doc["significance"] / 2 / len(ranked)
    assert all(c["significant"] == (c["p_value"] < doc["significance"] / 2 / len(ranked)) for c in ranked)
    residuals = pq.read_table(tmp_path / "r.parquet")
    assert {"z_x", "resid_y", "floor_z", "temp", "ref_rate", "mount"} <= set(residuals.column_names)
    for candidate in doc["candidates"]:  # every printed name is accepted back
        args = cli.build_parser().parse_args(
            ["diagnose", str(log), "-o", "x", "--add-term", candidate["term"]]
        )
        assert candidate["term"] in cli._settings(args).model.terms
    again = tmp_path / "d2.json"
    assert main("diagnose", log, "-o", again, "--add-term", doc["best"]["term"]) == 0
    assert json.loads(again.read_text())["best"] is None


def test_the_command_line_sets_one_blas_thread_before_numpy_loads():
    """The BLAS thread count is read when numpy loads: gyrocal.run.blas_threads must come first,
    and a count the user set is kept."""
    import os

    probe = (
        "import os, sys, gyrocal.run.cli; order = list(sys.modules); "
        "print(order.index('gyrocal.run.blas_threads') < order.index('numpy'), "
        "os.environ['OPENBLAS_NUM_THREADS'])"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["True", "1"]
    out = subprocess.run(
        [sys.executable, "-c", probe],
        env={**env, "OPENBLAS_NUM_THREADS": "3"},
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert out == ["True", "3"]
