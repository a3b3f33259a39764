"""The bad-input catalogue: each kind of wrong log, built from a good simulated one, and what
`gyrocal calibrate` must do with it (docs/inputs.md has the table).

Outcomes: ``error`` — exit status 2 and one line on stderr naming the file and the
problem, and no calibration file; ``warning`` — a calibration whose ``warnings`` list holds
the code, with scale factors within 10 % of 1 (not an implausible calibration) and no NaN
anywhere in the file; ``ok`` — a calibration without warnings.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.io.plausibility import CODES
from gyrocal.run.cli import main

from .conftest import make_log


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    return pq.read_table(make_log(tmp_path_factory.mktemp("good")))


def column(table: pa.Table, name: str, values, type_=None) -> pa.Table:
    type_ = pa.float64() if type_ is None else type_
    i = table.schema.get_field_index(name)
    return table.set_column(i, pa.field(name, type_), pa.array(values, type=type_))


def scaled(table, names, factor):
    for n in names:
        table = column(table, n, table[n].to_numpy().astype(float) * factor)
    return table


GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")


def with_units(table, units: str):
    return table.replace_schema_metadata({b"gyrocal.units": units.encode()})


def temp_stretch(table, value):
    """temp set to ``value`` (a number, or NaN) over the log's second sixth."""
    temp = table["temp"].to_numpy().astype(float)
    n = len(temp)
    temp[n // 3 : n // 3 + n // 6] = temp[n // 3] if value == "stuck" else value
    return column(table, "temp", temp)


def some_rows(table, keep):
    return table.filter(pa.array(keep))


def holds_off_reference(table):
    """Three of the fastest holds' reference 1 % off: within segmentation's tolerance
    (a reference that disagrees grossly is rejected hold by hold), far beyond the noise."""
    ref = table["ref_rate"].to_numpy().astype(float)
    start, stop = runs(np.abs(ref) > 390, 100)  # the ±400 deg/s holds, not a ramp's ripple
    for i in (1, 4, 7):
        ref[start[i] : stop[i]] *= 1.01
    return column(table, "ref_rate", ref)


def runs(mask, min_len=1000):
    """Starts and stops (exclusive) of the runs of True at least ``min_len`` long."""
    edges = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    start, stop = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    long = stop - start >= min_len
    return start[long], stop[long]


def point_with_few_holds(table, every=4):
    """The warmest temperature point's holds but one in ``every`` dropped, over all mounts."""
    temp = table["temp"].to_numpy()
    start, stop = runs(np.abs(table["ref_rate"].to_numpy()) > 0.05, 100)
    drop = np.zeros(table.num_rows, bool)
    for i, (a, b) in enumerate(zip(start, stop, strict=False)):
        if temp[a] > 35 and i % every:
            drop[a:b] = True
    return some_rows(table, ~drop)


def mount_missing(table):
    mount = np.array(table["mount"].to_pylist(), dtype=object)
    return some_rows(table, mount != "+z")


def rotated_labels(table):
    rot = {"+x": "+y", "+y": "+z", "+z": "+x"}
    labels = [rot.get(v, v) for v in table["mount"].to_pylist()]
    i = table.schema.get_field_index("mount")
    return table.set_column(i, "mount", pa.array(labels).dictionary_encode())


def rng_keep(n, share, seed=0):
    keep = np.ones(n, bool)
    keep[np.random.default_rng(seed).choice(n, int(share * n), replace=False)] = False
    return keep


def first_rows(table, n):
    return table.slice(0, n)


# kind -> (build(good table) -> table or bytes, outcome, expected: message regex or warning code)
KINDS = {
    # -- not a log at all, or not the contract's --------------------------------------------
    "zero-byte file": (
        lambda g: b"",
        "error",
        r"^[^(]*not a readable Parquet file \(Parquet file size is 0 bytes\)$",
    ),
    "truncated Parquet": (lambda g: "truncate", "error", r"cannot read|not a Parquet|truncated|corrupt"),
    "CSV, not Parquet": (lambda g: b"t,gyro_x\n0,1\n", "error", r"not a readable Parquet file"),
    "required column missing": (lambda g: g.drop(["ref_rate"]), "error", r"missing required column ref_rate"),
    "gyro as strings": (
        lambda g: column(g, "gyro_x", [str(v) for v in g["gyro_x"].to_numpy()], pa.string()),
        "error",
        r"gyro_x",
    ),
    "time as integers": (lambda g: column(g, "t", np.arange(g.num_rows), pa.int64()), "error", r"column t"),
    "an all-NaN gyro axis": (
        lambda g: column(g, "gyro_y", np.full(g.num_rows, np.nan)),
        "error",
        r"column gyro_y holds no finite value",
    ),
    "time backwards": (
        lambda g: g.take(pa.array(np.arange(g.num_rows)[::-1])),
        "error",
        r"not strictly increasing",
    ),
    "duplicate timestamps": (
        lambda g: column(g, "t", np.floor(g["t"].to_numpy() * 10) / 10),
        "error",
        r"not strictly increasing",
    ),
    "shuffled rows": (
        lambda g: g.take(pa.array(np.random.default_rng(1).permutation(g.num_rows))),
        "error",
        r"not strictly increasing",
    ),
    "clock reset mid-log": (
        lambda g: column(
            g,
            "t",
            np.where(
                np.arange(g.num_rows) < g.num_rows // 2,
                g["t"].to_numpy(),
                g["t"].to_numpy() - g["t"].to_numpy()[g.num_rows // 2],
            ),
        ),
        "error",
        r"not strictly increasing",
    ),
    "no rows": (lambda g: g.slice(0, 0), "error", r"no rows"),
    "ten rows": (lambda g: first_rows(g, 10), "error", r"."),
    "a stuck gyro axis": (
        lambda g: column(g, "gyro_z", np.full(g.num_rows, 0.25)),
        "error",
        r"gyro_z reads 0.25 in every row",
    ),
    "values of 1e30": (
        lambda g: column(g, "gyro_x", np.where(np.arange(g.num_rows) % 7 == 0, 1e30, g["gyro_x"].to_numpy())),
        "error",
        r"exceed ±1e\+08.*corrupted",
    ),
    "units metadata not JSON": (lambda g: with_units(g, "{gyro: rad"), "error", r"gyrocal.units"),
    "units metadata with an unknown unit": (
        lambda g: with_units(g, '{"gyro": "furlong/s"}'),
        "error",
        r"furlong",
    ),
    "mount labels that are no mount": (
        lambda g: g.set_column(g.schema.get_field_index("mount"), "mount", pa.array(["up"] * g.num_rows)),
        "error",
        r"mount",
    ),
    # -- handled without a word needed ---------------------------------------------------------
    "a NaN burst": (
        lambda g: column(
            g, "gyro_x", np.where((np.arange(g.num_rows) // 500) % 97 == 3, np.nan, g["gyro_x"].to_numpy())
        ),
        "ok",
        None,
    ),
    "inf values": (
        lambda g: column(
            g, "gyro_y", np.where(np.arange(g.num_rows) % 1009 == 0, np.inf, g["gyro_y"].to_numpy())
        ),
        "ok",
        None,
    ),
    "extra columns": (lambda g: g.append_column("humidity", pa.array(np.zeros(g.num_rows))), "ok", None),
    "a one-hour logging gap": (
        lambda g: column(
            g, "t", g["t"].to_numpy() + np.where(np.arange(g.num_rows) >= g.num_rows // 2, 3600.0, 0.0)
        ),
        "ok",
        None,
    ),
    "units declared: gyro in rad/s": (
        lambda g: with_units(scaled(g, GYRO, math.pi / 180), '{"gyro": "rad/s"}'),
        "ok",
        None,
    ),
    "units declared: gyro in mdps": (
        lambda g: with_units(scaled(g, GYRO, 1000.0), '{"gyro": "mdps"}'),
        "ok",
        None,
    ),
    "units declared: t in ms": (lambda g: with_units(scaled(g, ["t"], 1000.0), '{"t": "ms"}'), "ok", None),
    # -- the contract kept, the content implausible --------------------------------------------
    "gyro in rad/s, undeclared": (lambda g: scaled(g, GYRO, math.pi / 180), "error", r"look like rad/s"),
    "reference in rad/s, undeclared": (
        lambda g: scaled(g, ["ref_rate"], math.pi / 180),
        "error",
        r"ref_rate looks like rad/s",
    ),
    "gyro in mdps, undeclared": (lambda g: scaled(g, GYRO, 1000.0), "error", r"look like mdps"),
    "gyro in raw counts": (lambda g: scaled(g, GYRO, 131.0), "error", r"raw counts"),
    "reference sign flipped": (lambda g: scaled(g, ["ref_rate"], -1.0), "error", r"opposite sign convention"),
    "one gyro axis inverted": (lambda g: scaled(g, ["gyro_y"], -1.0), "error", r"gyro_y reads against"),
    "gyro axes swapped": (
        lambda g: column(
            column(g, "gyro_x", g["gyro_y"].to_numpy().astype(float)),
            "gyro_y",
            g["gyro_x"].to_numpy().astype(float),
        ),
        "error",
        r"permuted",
    ),
    "mount labels naming the wrong axes": (rotated_labels, "error", r"contradicts"),
    "a mount missing": (mount_missing, "error", r"excite|z"),
    "temperature in kelvin, undeclared": (
        lambda g: column(g, "temp", g["temp"].to_numpy() + 273.15),
        "error",
        r"kelvin",
    ),
    "time in milliseconds, undeclared": (
        lambda g: scaled(g, ["t"], 1000.0),
        "error",
        r"t does not count seconds: samples 10 s apart and a session "
        r"of 32\.9 days, .*; in milliseconds, samples 10 ms apart .*"
        r'\{"t": "ms"\}',
    ),
    "time in microseconds, undeclared": (
        lambda g: scaled(g, ["t"], 1e6),
        "error",
        r"t does not count seconds: samples 2\.78 h apart and a "
        r"session of .* years, .*in microseconds, samples 10 ms apart",
    ),
    "temperature sensor dropout": (lambda g: temp_stretch(g, np.nan), "warning", "temperature_dropout"),
    "temperature stuck": (lambda g: temp_stretch(g, "stuck"), "warning", "temperature_stuck"),
    "temperature error code": (lambda g: temp_stretch(g, 850.0), "warning", "temperature_out_of_range"),
    "accelerometer in m/s²": (lambda g: scaled(g, ACCEL, 9.80665), "warning", "accel_units"),
    "accelerometer in mg": (lambda g: scaled(g, ACCEL, 1000.0), "warning", "accel_scale"),
    "sample-time jitter": (
        lambda g: column(
            g, "t", g["t"].to_numpy() + np.random.default_rng(2).uniform(-0.003, 0.003, g.num_rows)
        ),
        "warning",
        "sample_jitter",
    ),
    "dropped samples": (lambda g: some_rows(g, rng_keep(g.num_rows, 0.05)), "warning", "dropped_samples"),
    "a point with few holds": (point_with_few_holds, "warning", "point_few_holds"),
    "a point with too few holds to fit": (lambda g: point_with_few_holds(g, 20), "warning", "point_excluded"),
    "holds off their reference": (holds_off_reference, "warning", "holds_disagree_with_reference"),
    "reverse holds missing": (
        lambda g: some_rows(g, g["ref_rate"].to_numpy() >= 0),
        "warning",
        "protocol_unbalanced",
    ),
    "a few 1e30 spikes": (
        lambda g: column(
            g, "gyro_x", np.where(np.arange(g.num_rows) % 20011 == 5, 1e30, g["gyro_x"].to_numpy())
        ),
        "warning",
        "gyro_out_of_range",
    ),
    "gyro clipped at ±300 deg/s": (
        lambda g: column(g, "gyro_z", np.clip(g["gyro_z"].to_numpy(), -300, 300)),
        "warning",
        "holds_rejected",
    ),
    "reference 20 % off on some holds": (
        lambda g: column(
            g, "ref_rate", np.where((g["t"].to_numpy() // 500) % 4 == 1, 1.2, 1.0) * g["ref_rate"].to_numpy()
        ),
        "warning",
        "holds_rejected",
    ),
    # the slow holds of those pass segmentation's tolerance and pull two points' scale to 0.83
    "reference 20 % off, the fit's view": (
        lambda g: column(
            g, "ref_rate", np.where((g["t"].to_numpy() // 500) % 4 == 1, 1.2, 1.0) * g["ref_rate"].to_numpy()
        ),
        "warning",
        "scale_far_from_one",
    ),
    "one temperature point": (
        lambda g: some_rows(g, g["temp"].to_numpy() < -3),
        "warning",
        "single_temperature",
    ),
}


def write(good_table, build, path):
    made = build(good_table)
    if made == "truncate":
        pq.write_table(good_table, path)
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif isinstance(made, bytes):
        path.write_bytes(made)
    else:
        pq.write_table(made, path)


def no_nan(text: str) -> dict:
    def refuse(name):
        raise AssertionError(f"{name} in the calibration file")

    return json.loads(text, parse_constant=refuse)


def test_the_catalogue_has_thirty_kinds_or_more():
    assert len(KINDS) >= 30
    assert {code for _, outcome, code in KINDS.values() if outcome == "warning"} <= set(CODES)


@pytest.mark.parametrize("kind", list(KINDS))
def test_bad_input(kind, good, tmp_path, capsys):
    build, outcome, expected = KINDS[kind]
    log, out = tmp_path / "U001.parquet", tmp_path / "cal.json"
    write(good, build, log)
    status = main(["calibrate", str(log), "-o", str(out)])
    err = capsys.readouterr().err
    if outcome == "error":
        assert status == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"gyrocal: error: {log}: "), err
        assert re.search(expected, lines[0]), lines[0]
        assert not out.exists()
        return
    assert status == 0, err
    assert "Traceback" not in err
    cal = no_nan(out.read_text())
    codes = [w["code"] for w in cal["warnings"]]
    K = np.array(cal["grid"]["K"])
    plausible = np.all(np.abs(np.diagonal(K, axis1=1, axis2=2) - 1) < 0.1)
    assert plausible or "scale_far_from_one" in codes, "an implausible calibration, unflagged"
    if outcome == "ok":
        assert codes == [], cal["warnings"]
    else:
        assert expected in codes, codes
        for w in cal["warnings"]:
            assert set(w) == {"code", "message", "evidence"} and w["message"]
            assert f"gyrocal: warning: {w['code']}: " in err


# -- the manifest, the config and what reports show of them -------------------------------------


@pytest.mark.parametrize(
    "config, message",
    [
        ({"segmentaton": {}}, "segmentaton"),
        ({"model": {"terms": ["bias"], "interpolaton": "linear"}}, "interpolaton"),
        ({"spec": {"turntable": {"fail_on_warning": True}}}, "fail_on_warning"),
        ({"spec": {"turntable": {"fail_on_warnings": ["temperature_dropped"]}}}, "temperature_dropped"),
    ],
)
def test_a_misspelled_config_key_is_refused_by_name(tmp_path, config, message, capsys):
    import yaml

    from gyrocal.fleet.summary import FleetSettings
    from gyrocal.io.errors import ConfigError

    if "spec" in config:  # the fleet stage's settings
        with pytest.raises(ConfigError, match=message):
            FleetSettings.from_dict(config)
        return
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    status = main(
        ["calibrate", str(tmp_path / "none.parquet"), "--config", str(path), "-o", str(tmp_path / "c.json")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("gyrocal: error: ") and message in err[0], err


HOSTILE = "<img src=x onerror=alert(1)>"


def test_reports_escape_every_string_from_data(good, tmp_path):
    """A batch name, an error text and a warning's message from a hostile log reach the unit
    report and the fleet summary as text, never as markup."""
    from gyrocal.fleet.summary import write_fleet_report
    from gyrocal.pipeline.chain import run
    from gyrocal.protocols import registry
    from gyrocal.report.unit import UnitResults, write_unit_report

    log = tmp_path / "U001.parquet"
    pq.write_table(some_rows(good, good["ref_rate"].to_numpy() >= 0), log)  # a warning too
    result = run(log, batch=HOSTILE, session="2026-01-01")
    result.calibration.extra["warnings"][0]["message"] += HOSTILE
    page = tmp_path / "unit.html"
    write_unit_report(UnitResults.from_run(result), page, registry.get("turntable"))
    html = page.read_text()
    assert 'id="warnings"' in html and "protocol_unbalanced" in html  # at the top of the report
    assert html.index('id="warnings"') < html.index('id="verdict"')
    assert "<img" not in html and html.count("&lt;img src=x onerror=alert(1)&gt;") >= 2
    failed = {
        "device": "U2",
        "batch": HOSTILE,
        "session": "2026-01-01",
        "protocol": "turntable",
        "report": "x.html",
        "status": "failed",
        "stage": "segment",
        "error": HOSTILE,
        "internal": False,
    }
    ok = {
        "device": "U3",
        "batch": HOSTILE,
        "session": "2026-01-01",
        "protocol": "turntable",
        "report": "y.html",
        "status": "ok",
        "span": (0.0, 40.0),
        "params": {},
        "noise": None,
        "summary": {"validation_rms": 1e-3, "excess": 1.0, "excess_over_expected": 1.0},
        "missing": "nothing",
        "warnings": result.calibration.extra["warnings"],
    }
    fleet = tmp_path / "index.html"
    write_fleet_report({"rows": [failed, ok], "ok": [ok], "fleet": None, "servo_vs_turntable": []}, fleet)
    html = fleet.read_text()
    assert "<img" not in html and html.count("&lt;img src=x onerror=alert(1)&gt;") >= 3
    assert "1 with plausibility warnings" in html and "1 warning: protocol_unbalanced" in html


@pytest.mark.parametrize(
    "stats, hold, outcome",
    [
        # the catalogue's log (100 Hz, 32 min, holds of 6 s) as it is: nothing to say
        ({"nominal_dt": 0.01, "duration_s": 1898.0}, 5.8, None),
        # a slow thermal logger: 1 sample/s over ten days
        ({"nominal_dt": 1.0, "duration_s": 10 * 86400.0}, None, None),
        # a 1 kHz log in ms: samples 1 s apart (a slow logger's), but holds of 5.6 h and 108
        # days of it: t in ms
        ({"nominal_dt": 1.0, "duration_s": 9.4e6}, 20000.0, "error ms"),
        # one odd figure only: samples 10 s apart in a 28-hour session of 2-minute holds
        ({"nominal_dt": 10.0, "duration_s": 1.0e5}, 120.0, "warning ms"),
        # a month and a half of a 100 Hz log: long, and no unit explains it
        ({"nominal_dt": 0.01, "duration_s": 45 * 86400.0}, 30.0, "warning"),
    ],
)
def test_the_time_base_against_what_rigs_record(stats, hold, outcome):
    """Errors where the figures are what no rig records and one unit factor explains them
    all, warnings where one figure is odd; the factor is named where it explains it."""
    from gyrocal.io.plausibility import time_base

    error, warning = time_base({"rows": 1000, **stats}, hold)
    if outcome is None:
        assert error is None and warning is None
    elif outcome.startswith("error"):
        assert warning is None and "in milliseconds" in error and '{"t": "ms"}' in error
    else:
        assert error is None and warning["code"] == "time_base_implausible"
        assert ("in milliseconds" in warning["message"]) == outcome.endswith("ms")


def test_every_kind_is_in_the_documented_table():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "inputs.md").read_text()
    rows = {
        line.split(" | ")[0].removeprefix("| ")
        for line in doc.splitlines()
        if line.startswith("| ") and " | " in line
    }
    assert set(KINDS) <= rows, sorted(set(KINDS) - rows)
