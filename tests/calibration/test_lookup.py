"""Calibration lookup: closest, before, after, far warning, none, skipped files, ties."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from gyrocal.calibration.file import Calibration, save_calibration
from gyrocal.calibration.lookup import NoCalibrationError, add_lookup_parser, find_calibration
from gyrocal.fit.model import DEFAULT_TERMS, Model
from gyrocal.fit.thermal import TemperatureGrid
from gyrocal.io.errors import ConfigError, InputError
from gyrocal.io.failure import record


def calibration(device, session, batch="B1", bias=0.0):
    model = Model.from_spec(DEFAULT_TERMS)
    values = np.zeros((2, len(model.names)))
    values[:, 0] = bias  # bias.x tells files apart
    grid = TemperatureGrid(np.array([0.0, 40.0]), tuple(model.names), values, values + 1e-4)
    return Calibration(
        model, grid, meta={"device": device, "batch": batch, "session": session, "protocol": "turntable"}
    )


def put(caldir, device, session, batch="B1", name="calibration.json", **kw):
    path = caldir / batch / device / session / name
    path.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(calibration(device, session, batch, **kw), path)
    return path


@pytest.fixture
def caldir(tmp_path):
    """The workflow's layout for U001 (three sessions, one failed, one unreadable), U002,
    and an older U001 calibration kept elsewhere under another name."""
    root = tmp_path / "results"
    for session in ("2026-01-05", "2026-03-01", "2026-06-05"):
        put(root, "U001", session)
        (root / "B1" / "U001" / session / "validation.json").write_text('{"validation_rms": 0.1}')
    put(root, "U002", "2026-02-20")
    failed = root / "B1" / "U001" / "2026-04-01"
    failed.mkdir(parents=True)
    rec = record(
        "fit", ConfigError("the fit failed"), {"device": "U001", "batch": "B1", "session": "2026-04-01"}
    )
    for name in ("calibration.json", "validation.json"):
        (failed / name).write_text(json.dumps(rec, indent=2))
    broken = root / "B1" / "U001" / "2026-05-01" / "calibration.json"
    broken.parent.mkdir(parents=True)
    broken.write_text('{"format": "gyrocal.calibration/1", "device": "U001", "sess')
    archive = root / "archive"
    archive.mkdir()
    save_calibration(calibration("U001", "2025-11-20"), archive / "U001-first.json")
    return root


def test_closest_either_side(caldir):
    r = find_calibration(caldir, "U001", "2026-02-20")
    assert r.session == "2026-03-01" and r.days_away == 9 and r.warning is None
    assert r.path == caldir / "B1" / "U001" / "2026-03-01" / "calibration.json"
    assert r.calibration.meta["session"] == "2026-03-01"
    assert r.candidates == 4  # three in the layout, one archived
    assert r.skipped == {"failed_sessions": 1, "unreadable": 1}
    assert find_calibration(caldir, "U001", "2025-11-01").path == caldir / "archive" / "U001-first.json"


def test_before_and_after(caldir):
    before = find_calibration(caldir, "U001", "2026-02-20", "before")
    assert (before.session, before.days_away) == ("2026-01-05", -46)
    after = find_calibration(caldir, "U001", "2026-03-02", "after")
    assert (after.session, after.days_away) == ("2026-06-05", 95)
    same_day = find_calibration(caldir, "U001", "2026-03-01", "before")  # on the date counts
    assert (same_day.session, same_day.days_away) == ("2026-03-01", 0)
    assert find_calibration(caldir, "U001", "2026-03-01", "after").session == "2026-03-01"


def test_far_warning(caldir):
    r = find_calibration(caldir, "U001", "2026-02-20", "before")
    assert r.warning == (
        "the nearest calibration of U001 (session 2026-01-05) is 46 days before 2026-02-20, more than 30"
    )
    assert find_calibration(caldir, "U001", "2026-02-20", "before", max_days=46).warning is None
    # The failed 2026-04-01 session is no candidate: the nearest is 31 days away.
    r = find_calibration(caldir, "U001", "2026-04-01")
    assert r.session == "2026-03-01" and r.days_away == -31 and "31 days before" in r.warning


def test_latest_without_a_date(caldir):
    r = find_calibration(caldir, "U001")
    assert r.session == "2026-06-05" and r.days_away is None and r.warning is None


def test_none(caldir):
    with pytest.raises(
        NoCalibrationError,
        match=r"no calibration of device U404 in this folder: "
        r"searched 6 calibration files of 2 devices \(U001, U002\)",
    ) as err:
        find_calibration(caldir, "U404", "2026-01-01")
    assert err.value.exit_status == 2 and str(caldir) in str(err.value)
    with pytest.raises(
        NoCalibrationError,
        match=r"U001 on or before 2025-01-01 \(its 4 sessions "
        r"are from 2025-11-20 to 2026-06-05\)",
    ):
        find_calibration(caldir, "U001", "2025-01-01", "before")
    with pytest.raises(NoCalibrationError, match="U002 on or after 2026-02-21"):
        find_calibration(caldir, "U002", "2026-02-21", "after")


def test_failure_records_and_unreadable_files_are_skipped(tmp_path):
    root = tmp_path / "results"
    failed = root / "B2" / "U003" / "2026-01-06"
    failed.mkdir(parents=True)
    (failed / "calibration.json").write_text(
        json.dumps(record("segment", ConfigError("no holds"), {"device": "U003", "session": "2026-01-06"}))
    )
    bad = root / "B2" / "U003" / "2026-02-06" / "calibration.json"
    bad.parent.mkdir(parents=True)
    doc = calibration("U003", "2026-02-06").to_dict()
    doc["grid"]["B"][0][0] += 1.0  # edited by hand: refused by the parser
    bad.write_text(json.dumps(doc))
    with pytest.raises(NoCalibrationError) as err:
        find_calibration(root, "U003")
    message = str(err.value)
    assert "U003 failed in session 2026-01-06" in message
    assert "1 unreadable (first: " in message and "do not match the coefficients" in message
    assert "\n" not in message
    good = put(root, "U003", "2026-03-06", batch="B2")
    r = find_calibration(root, "U003", "2026-02-06")
    assert r.path == good and r.skipped == {"failed_sessions": 1, "unreadable": 1}


def test_ties_go_to_the_earlier_session_then_the_path(tmp_path):
    root = tmp_path / "cal"
    put(root, "U001", "2026-01-01")
    put(root, "U001", "2026-01-11")
    r = find_calibration(root, "U001", "2026-01-06")  # 5 days either side
    assert (r.session, r.days_away) == ("2026-01-01", -5)
    # The same session twice (recalibrated into another batch folder, a copy): the path decides,
    # whatever order the files were written in.
    put(root, "U001", "2026-01-11", batch="B9", bias=2.0)
    put(root, "U001", "2026-01-11", batch="B0", bias=1.0)
    r = find_calibration(root, "U001", "2026-01-11")
    assert r.path == root / "B0" / "U001" / "2026-01-11" / "calibration.json"
    assert r.calibration.grid.values[0, 0] == 1.0
    assert find_calibration(root, "U001").path == r.path


def test_layout_names_stand_in_for_missing_metadata(tmp_path):
    root = tmp_path / "cal"
    path = put(root, "U007", "2026-05-05")
    doc = json.loads(path.read_text())
    doc["device"] = doc["session"] = None
    path.write_text(json.dumps(doc))
    assert find_calibration(root, "U007", "2026-05-01").days_away == 4


def test_bad_arguments(caldir, tmp_path):
    with pytest.raises(ConfigError, match="needs the date"):
        find_calibration(caldir, "U001", None, "before")
    with pytest.raises(ConfigError, match="'2026-13-01' is not a date"):
        find_calibration(caldir, "U001", "2026-13-01")
    with pytest.raises(ConfigError, match="max_days"):
        find_calibration(caldir, "U001", "2026-01-01", max_days=-1)
    with pytest.raises(InputError, match="is not a folder"):
        find_calibration(tmp_path / "absent", "U001")


def lookup_cli(*argv):
    parser = argparse.ArgumentParser(prog="gyrocal")
    add_lookup_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["lookup", *map(str, argv)])
    return args.func(args)


def test_cli(caldir, capsys):
    assert lookup_cli(caldir, "U001", "--date", "2026-02-20", "--before") == 0
    out, err = capsys.readouterr()
    path, summary = out.splitlines()
    assert path == str(caldir / "B1" / "U001" / "2026-01-05" / "calibration.json")
    assert summary.strip() == (
        "U001 session 2026-01-05 (46 days before 2026-02-20), protocol "
        "turntable, batch B1; skipped 1 failed session, 1 unreadable file"
    )
    hint = (
        f"gyrocal: hint: {caldir} has no registry, so every file was read; gyrocal registry "
        f"rebuild {caldir} indexes them for lookups in milliseconds\n"
    )
    assert err == (
        "gyrocal: warning: the nearest calibration of U001 (session 2026-01-05) is 46 "
        "days before 2026-02-20, more than 30\n" + hint
    )
    assert lookup_cli(caldir, "U001", "--date", "2026-02-20", "--max-days", "60", "--json") == 0
    out, err = capsys.readouterr()
    rec = json.loads(out)
    assert err == hint
    assert (rec["session"], rec["days_away"], rec["warning"], rec["max_days"]) == ("2026-03-01", 9, None, 60)
    assert (rec["device"], rec["batch"], rec["protocol"]) == ("U001", "B1", "turntable")
    with pytest.raises(SystemExit):
        lookup_cli(caldir, "U001", "--before", "--after", "--date", "2026-01-01")
    capsys.readouterr()
