"""Issue 53: every option has help, the top-level help puts the user's commands first, and
what the commands print names the log, the verdict and the fix."""

from __future__ import annotations

import argparse
import re
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.protocols import registry
from gyrocal.run import cli
from gyrocal.run.api import simulate_log
from gyrocal.simulate import TurntableProtocol

from ..conftest import make_log


def main(*args):
    return cli.main([str(a) for a in args])


def subcommands() -> dict[str, argparse.ArgumentParser]:
    """Every command the parser accepts, from the parser itself."""
    action = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


@pytest.mark.parametrize("command", sorted(subcommands()))
def test_every_option_says_what_it_takes(command, capsys):
    with pytest.raises(SystemExit) as exit:
        main(command, "--help")
    assert exit.value.code == 0 and capsys.readouterr().out.startswith(f"usage: gyrocal {command}")
    for action in subcommands()[command]._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help and action.help.strip(), f"gyrocal {command} {name} has no help"
        if "--protocol" in action.option_strings:  # finite values: offered as choices
            assert set(action.choices or ()) == set(registry.names()), name


def test_help_lists_the_users_commands_first_and_the_stages_apart(capsys):
    with pytest.raises(SystemExit):
        main("--help")
    text = capsys.readouterr().out
    users, stages = text.split("\ncommands:\n", 1)[1].split("\nworkflow stages:\n", 1)

    def names(section):
        return [line.split()[0] for line in section.splitlines() if re.match(r" {4}\S", line)]

    assert set(names(stages)) == set(cli.STAGES)
    assert set(names(users)) == set(subcommands()) - set(cli.STAGES)
    assert names(users)[:4] == ["simulate", "calibrate", "diagnose", "apply"]
    for stage in cli.STAGES:  # still a command of its own
        with pytest.raises(SystemExit) as exit:
            main(stage, "--help")
        assert exit.value.code == 0


def test_diagnose_without_output_prints_the_verdict_and_writes_nothing(logs, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    log = shutil.copy(logs["complete"], tmp_path / "u.parquet")
    assert main("diagnose", log) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"diagnosis of {log}"
    assert "noise floor" in out[1]  # the verdict weighs the residuals against the floor
    assert sorted(p.name for p in tmp_path.iterdir()) == ["u.parquet"]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gyrocal: error: "), err
    return err[0]


@pytest.mark.parametrize("name", ["rig.csv", "rig.parquet", "rig.tsv"])
def test_a_csv_file_is_named_as_such_with_the_import_line(logs, tmp_path, capsys, name):
    """The bytes decide, not the name: a CSV saved as .parquet is text all the same."""
    sep = "\t" if name.endswith(".tsv") else ","
    path = tmp_path / name
    path.write_text(
        sep.join(["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"]) + "\n" + sep.join("012350") + "\n"
    )
    cal = tmp_path / "cal.json"
    for args in (["calibrate", path, "-o", cal], ["diagnose", path], ["noise", path]):
        assert main(*args) == 2
        line = one_line_error(capsys)
        kind = "TSV" if sep == "\t" else "CSV"
        assert f"{path}: " in line and f"looks like {kind} text" in line
        assert f"gyrocal import {path} -o LOG.parquet" in line
        assert ("--format" in line) == (name == "rig.parquet")  # import tells csv by the name
    assert not cal.exists()


def test_a_semicolon_file_is_named_with_the_map_that_imports_it(tmp_path, capsys):
    """import reads commas and tabs by itself; a semicolon needs the map's delimiter."""
    path = tmp_path / "rig.csv"
    path.write_text("t;gyro_x;gyro_y;gyro_z;temp;ref_rate\n0;1;2;3;5;0\n")
    assert main("calibrate", path, "-o", tmp_path / "cal.json") == 2
    line = one_line_error(capsys)
    assert "looks like CSV text" in line and "--map MAP.yaml (with delimiter: ';')" in line


def test_a_cut_parquet_file_is_called_truncated(logs, tmp_path, capsys):
    whole = logs["complete"].read_bytes()
    cut = tmp_path / "cut.parquet"
    cut.write_bytes(whole[: len(whole) // 2])
    shutil.copy(logs["complete"], tmp_path / "log.parquet")
    main("calibrate", tmp_path / "log.parquet", "-o", tmp_path / "cal.json")
    capsys.readouterr()
    for args in (
        ["calibrate", cut, "-o", tmp_path / "c.json"],
        ["apply", tmp_path / "cal.json", cut, "-o", "x"],
    ):
        assert main(*args) == 2
        line = one_line_error(capsys)
        assert f"{cut}: " in line and "truncated" in line and f"({len(whole) // 2} bytes;" in line


@pytest.mark.slow
def test_a_report_without_a_device_names_the_log(logs, tmp_path, capsys):
    log = shutil.copy(logs["complete"], tmp_path / "2026-01-07.parquet")
    report = tmp_path / "r.html"
    assert main("calibrate", log, "-o", tmp_path / "cal.json", "--report", report) == 0
    html = report.read_text()
    assert "<h1>Calibration of 2026-01-07.parquet</h1>" in html
    assert "<title>gyrocal · 2026-01-07.parquet · –</title>" in html
    assert main("calibrate", log, "-o", tmp_path / "cal.json", "--report", report, "--device", "U7") == 0
    assert "<h1>Calibration of U7</h1>" in report.read_text()


def rows_at(path, temps):
    """A log of still rows at the given temperatures (the columns apply reads)."""
    n = len(temps)
    zeros = pa.array(np.zeros(n, np.float32))
    table = pa.table(
        {
            "t": np.arange(n) * 0.01,
            "gyro_x": zeros,
            "gyro_y": zeros,
            "gyro_z": zeros,
            "temp": pa.array(np.asarray(temps, np.float32)),
            "ref_rate": zeros,
        }
    )
    pq.write_table(table, path)
    return path


def test_apply_tolerates_the_calibrations_own_readings_beyond_its_ends(logs, tmp_path, capsys):
    cal_path = tmp_path / "cal.json"
    assert main("calibrate", logs["complete"], "-o", cal_path) == 0
    cal = load_calibration(cal_path)
    below, above = cal.range_tolerance()
    # 1.5 times the farthest of thousands of readings with the simulated sensor's noise
    # beyond the end point (about 4.5 standard deviations): 6-7 of them, not a hold mean's
    # scatter nor a chamber's degree.
    sigma = TurntableProtocol.temp_noise
    assert 4 * sigma < below < 12 * sigma and 4 * sigma < above < 12 * sigma
    lo, hi = cal.grid.span
    capsys.readouterr()
    within = rows_at(tmp_path / "within.parquet", [lo - below / 2, hi + above / 2, (lo + hi) / 2])
    assert main("apply", cal_path, within, "-o", tmp_path / "a.parquet") == 0
    assert "warning" not in capsys.readouterr().err
    beyond = rows_at(tmp_path / "beyond.parquet", [hi + 2 * above, hi + above / 2, lo - 2 * below, lo])
    assert main("apply", cal_path, beyond, "-o", tmp_path / "b.parquet") == 0
    err = capsys.readouterr().err
    assert "2 of 4 rows lie outside the calibrated" in err and "own readings' scatter" in err


def test_a_sweep_calibration_tolerates_its_readings_noise_not_its_bins(tmp_path, capsys):
    """A sweep's bins end near its readings' extremes: beyond them by more than the readings'
    own noise is beyond the data (a bin's width, ten degrees, is no tolerance)."""
    log = tmp_path / "sweep.parquet"
    simulate_log(log, device="S1", protocol="sweep")
    cal_path = tmp_path / "cal.json"
    assert main("calibrate", log, "--protocol", "sweep", "-o", cal_path) == 0
    cal = load_calibration(cal_path)
    sigma = TurntableProtocol.temp_noise  # the simulated sensors' temperature noise alike
    below, above = cal.range_tolerance()
    assert below < 12 * sigma and above < 12 * sigma
    lo, hi = cal.grid.span
    capsys.readouterr()
    beyond = rows_at(tmp_path / "beyond.parquet", [hi + 0.5, lo - 0.5, (lo + hi) / 2])
    assert main("apply", cal_path, beyond, "-o", tmp_path / "b.parquet") == 0
    assert "2 of 3 rows lie outside the calibrated" in capsys.readouterr().err


def test_another_session_of_the_same_rig_applies_without_a_warning(logs, tmp_path, capsys):
    """The motivating case: the same rig reads the same points with fresh sensor noise."""
    cal = tmp_path / "cal.json"
    assert main("calibrate", logs["complete"], "-o", cal) == 0
    again = make_log(tmp_path, "again", seed=11)
    capsys.readouterr()
    assert main("apply", cal, again, "-o", tmp_path / "a.parquet") == 0
    assert "outside the calibrated" not in capsys.readouterr().err
