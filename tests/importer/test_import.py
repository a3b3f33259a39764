"""gyrocal import: tables, ROS 2 bags and MCAP files written here with the libraries' own
writers from known signals, imported, and compared with the truth; calibrate on an imported
turntable log against the original; the real imucal session; the one-line errors."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from gyrocal import __version__
from gyrocal.importer import bags, import_log, sink, tabular
from gyrocal.io.errors import LogFormatError
from gyrocal.run import cli

from .conftest import needs

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "data" / "real" / "imucal-ferraris"
G0 = 9.80665
T0_NS = 1_700_000_000_123_456_789  # an epoch start, not a round number
IMU_TOPIC, TEMP_TOPIC, RATE_TOPIC = "/imu/data", "/imu/temp", "/table/rate"


def run(capsys, *args) -> tuple[int, str, str]:
    status = cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def columns(path) -> dict[str, np.ndarray]:
    table = pq.read_table(path)
    return {
        name: (
            table[name].to_numpy()
            if name not in ("mount", "section")
            else np.array(table[name].to_pylist(), dtype=object)
        )
        for name in table.column_names
    }


def provenance(path) -> dict:
    return json.loads(pq.ParquetFile(path).metadata.metadata[b"gyrocal.import"])


def write_csv(path, data: dict, delimiter=","):
    pacsv.write_csv(pa.table(data), path, write_options=pacsv.WriteOptions(delimiter=delimiter))


# --- tables ---------------------------------------------------------------------------------


def test_a_csv_in_rig_units_becomes_the_contract_log_in_its_units(tmp_path, monkeypatch):
    """ms, rad/s, mg, K and mdps converted; mount labels kept; small blocks, so the file
    crosses many batches (time order and sections are checked across their edges)."""
    monkeypatch.setattr(tabular, "BLOCK_BYTES", 1 << 14)
    monkeypatch.setattr(sink, "ROW_GROUP_ROWS", 300)
    rng = np.random.default_rng(1)
    n = 4000
    t_ms = np.cumsum(rng.uniform(4.0, 6.0, n)) + 1e6
    rad = rng.normal(0, 0.5, (n, 3))
    mg = rng.normal(0, 300, (n, 3)) + [0, 0, 1000]
    kelvin = 298.15 + np.linspace(0, 5, n)
    mdps = rng.normal(0, 5e4, n)
    mounts = np.array(["+x", "-y", "+z", ""])[np.arange(n) * 4 // n]
    src = tmp_path / "rig.csv"
    write_csv(
        src,
        {
            "time_ms": t_ms,
            "wx": rad[:, 0],
            "wy": rad[:, 1],
            "wz": rad[:, 2],
            "ax": mg[:, 0],
            "ay": mg[:, 1],
            "az": mg[:, 2],
            "T": kelvin,
            "table": mdps,
            "pose": mounts,
            "unused": np.zeros(n),
        },
    )
    (tmp_path / "rig.yaml").write_text(
        "time: {column: time_ms, unit: ms}\n"
        "gyro: {x: wx, y: wy, z: wz, unit: rad/s}\n"
        "accel: {x: ax, y: ay, z: az, unit: mg}\n"
        "temp: {column: T, unit: K}\n"
        "ref_rate: {column: table, unit: mdps}\n"
        "mount: {column: pose}\n"
        "sections: sections.json\n"
    )
    spans = {"x_p": {"start": 100, "end": 1500}, "z_rot": {"start": 2990, "end": 3999}}
    (tmp_path / "sections.json").write_text(json.dumps(spans))
    out = tmp_path / "log.parquet"
    summary = import_log(src, out, tmp_path / "rig.yaml")
    got = columns(out)
    assert summary.rows == n and pq.ParquetFile(out).metadata.num_row_groups > 5
    assert list(got) == [
        "t",
        "gyro_x",
        "gyro_y",
        "gyro_z",
        "temp",
        "ref_rate",
        "accel_x",
        "accel_y",
        "accel_z",
        "mount",
        "section",
    ]
    np.testing.assert_allclose(got["t"], t_ms * 1e-3, rtol=1e-15)
    np.testing.assert_allclose(
        np.c_[got["gyro_x"], got["gyro_y"], got["gyro_z"]], np.degrees(rad), rtol=1e-14
    )
    np.testing.assert_allclose(np.c_[got["accel_x"], got["accel_y"], got["accel_z"]], mg / 1000, rtol=1e-15)
    np.testing.assert_allclose(got["temp"], kelvin - 273.15, atol=1e-12)
    np.testing.assert_allclose(got["ref_rate"], mdps / 1000, rtol=1e-15)
    assert list(got["mount"]) == [m or None for m in mounts]
    truth = np.full(n, None, dtype=object)
    truth[100:1500], truth[2990:3999] = "x_p", "z_rot"
    assert list(got["section"]) == list(truth)
    record = provenance(out)
    assert record["source"] == {
        "name": "rig.csv",
        "format": "csv",
        "sha256": hashlib.sha256(src.read_bytes()).hexdigest(),
    }
    assert record["gyrocal"] == __version__ and record["map"]["gyro"]["unit"] == "rad/s"
    assert record["map"]["sections"] == {
        "file": "sections.json",
        "spans": {"x_p": [100, 1500], "z_rot": [2990, 3999]},
    }
    again = tmp_path / "again.parquet"
    import_log(src, again, tmp_path / "rig.yaml")
    assert again.read_bytes() == out.read_bytes()  # nothing in the file changes between runs


def test_a_tsv_of_counts_with_a_sample_rate_and_an_imucal_csv_section_list(tmp_path, capsys):
    """counts / sensitivity after a per-axis offset, °F, t = row number / --sample-rate,
    and the CSV form of imucal's section list given with --sections."""
    n = 1000
    rng = np.random.default_rng(2)
    counts = rng.integers(-30000, 30000, (n, 3))
    accel = rng.integers(-5000, 5000, (n, 3))
    fahrenheit = np.linspace(32, 212, n)
    src = tmp_path / "dump.tsv"
    write_csv(
        src,
        {
            "gx": counts[:, 0],
            "gy": counts[:, 1],
            "gz": counts[:, 2],
            "ax": accel[:, 0],
            "ay": accel[:, 1],
            "az": accel[:, 2],
            "tf": fahrenheit,
        },
        delimiter="\t",
    )
    (tmp_path / "map.yaml").write_text(
        "gyro: {x: gx, y: gy, z: gz, unit: counts, sensitivity: 131.0, offset: [10, -20, 5]}\n"
        "accel: {x: ax, y: ay, z: az, unit: counts, sensitivity: 4096}\n"
        "temp: {column: tf, unit: degF}\n"
    )
    (tmp_path / "sections.csv").write_text(",start,end\ny_a,10,20\nx_rot,500,1000\n")
    out = tmp_path / "log.parquet"
    status, stdout, _ = run(
        capsys,
        "import",
        src,
        "-o",
        out,
        "--map",
        tmp_path / "map.yaml",
        "--sample-rate",
        200,
        "--sections",
        tmp_path / "sections.csv",
    )
    assert status == 0
    assert stdout.startswith(f"1000 rows -> {out}: t 0 to 4.995 s")
    assert "t = row number / 200 Hz" in stdout and "section from sections.csv (2 labels)" in stdout
    got = columns(out)
    np.testing.assert_array_equal(got["t"], np.arange(n) / 200)
    np.testing.assert_allclose(got["gyro_y"], (counts[:, 1] + 20) / 131.0, rtol=1e-15)
    np.testing.assert_allclose(got["accel_z"], accel[:, 2] / 4096, rtol=1e-15)
    np.testing.assert_allclose(got["temp"], np.linspace(0, 100, n), atol=1e-12)
    assert (got["section"][10:20] == "y_a").all() and (got["section"][500:] == "x_rot").all()
    assert set(got["section"][:10]) == {None}


def test_a_static_chamber_log_with_temperature_in_counts_and_no_reference(tmp_path, capsys):
    """A static chamber test as recorded (issue 39): time in ms, the gyro in rad/s, the
    temperature in the sensor's counts (the MPU-6050's datasheet: °C = counts / 340 + 36.53,
    i.e. sensitivity 340 LSB/°C, offset -12420.2 counts) and no reference column: the map
    converts the counts and says the rig held 0 deg/s throughout."""
    n = 500
    celsius = np.linspace(22.0, 10.0, n)
    counts = np.round((celsius - 36.53) * 340.0)
    rng = np.random.default_rng(5)
    gyro = rng.normal(0.0, 1e-3, (n, 3))
    src = tmp_path / "tvac.csv"
    write_csv(
        src,
        {
            "ms": 1_000_000 + 20 * np.arange(n),
            "wx": gyro[:, 0],
            "wy": gyro[:, 1],
            "wz": gyro[:, 2],
            "tc": counts,
        },
    )
    (tmp_path / "map.yaml").write_text(
        "time: {column: ms, unit: ms}\n"
        "gyro: {x: wx, y: wy, z: wz, unit: rad/s}\n"
        "temp: {column: tc, unit: counts, sensitivity: 340, offset: -12420.2}\n"
        "ref_rate: {value: 0}\n"
    )
    out = tmp_path / "log.parquet"
    status, stdout, _ = run(capsys, "import", src, "-o", out, "--map", tmp_path / "map.yaml")
    assert status == 0, stdout
    assert "ref_rate 0 deg/s throughout (a static log)" in stdout and "temp from tc (counts)" in stdout
    got = columns(out)
    # within half a count of the datasheet's formula (the counts were rounded)
    np.testing.assert_allclose(got["temp"], counts / 340.0 + 36.53, atol=1e-9)
    assert np.max(np.abs(got["temp"] - celsius)) <= 0.5 / 340.0 + 1e-9
    np.testing.assert_array_equal(got["ref_rate"], np.zeros(n))
    np.testing.assert_allclose(got["gyro_z"], np.degrees(gyro[:, 2]), rtol=1e-12)


@pytest.mark.parametrize(
    "temp, message",
    [
        ("{column: tc, unit: counts}", "temp: unit counts needs sensitivity (LSB per degC)"),
        ("{column: tc, unit: degC, offset: 3}", "temp.sensitivity and temp.offset apply to unit counts only"),
    ],
)
def test_a_temperature_map_in_counts_says_what_it_lacks(tmp_path, capsys, temp, message):
    src = tmp_path / "t.csv"
    write_csv(
        src, {"t": np.arange(3.0), "gx": np.zeros(3), "gy": np.zeros(3), "gz": np.zeros(3), "tc": np.zeros(3)}
    )
    (tmp_path / "map.yaml").write_text(
        f"time: {{column: t, unit: s}}\ngyro: {{x: gx, y: gy, z: gz, unit: deg/s}}\ntemp: {temp}\n"
    )
    status, _, err = run(capsys, "import", src, "-o", tmp_path / "o.parquet", "--map", tmp_path / "map.yaml")
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_without_a_map_a_csv_in_contract_names_is_taken_as_it_is(tmp_path, capsys):
    n = 50
    src = tmp_path / "plain.csv"
    data = {
        "t": np.arange(n) * 0.01,
        "gyro_x": np.ones(n),
        "gyro_y": np.zeros(n),
        "gyro_z": -np.ones(n),
        "temp": np.full(n, 21.5),
        "extra": np.arange(n),
    }
    write_csv(src, data)
    status, stdout, _ = run(capsys, "import", src, "-o", tmp_path / "out.parquet")
    assert status == 0 and "temp from temp (degC)" in stdout
    got = columns(tmp_path / "out.parquet")
    assert list(got) == ["t", "gyro_x", "gyro_y", "gyro_z", "temp"]
    for name in got:
        np.testing.assert_array_equal(got[name], data[name])


def test_the_real_imucal_session_imports_with_its_sections(tmp_path, capsys):
    out = tmp_path / "ferraris.parquet"
    status, stdout, _ = run(capsys, "import", REAL / "session.csv", "--map", REAL / "import.yaml", "-o", out)
    assert status == 0 and stdout.startswith("10376 rows")
    got = columns(out)
    assert len(got["t"]) == 10376 and got["t"][-1] == pytest.approx(10375 / 102.4)
    assert got["t"][-1] == pytest.approx(101.3, abs=0.1)
    spans = json.loads((REAL / "sections.json").read_text())
    labels, counts = np.unique(got["section"][got["section"] != None], return_counts=True)  # noqa: E711
    assert dict(zip(labels, counts, strict=False)) == {k: v["end"] - v["start"] for k, v in spans.items()}
    assert len(labels) == 9
    raw = pacsv.read_csv(REAL / "session.csv")
    np.testing.assert_array_equal(got["gyro_y"], raw["gyr_y"].to_numpy())
    for label in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        rest = got["section"] == label  # lying still on a face: gravity alone, about 1 g
        norm = np.sqrt(sum(got[f"accel_{a}"][rest] ** 2 for a in "xyz"))
        assert abs(np.median(norm) - 1.0) < 0.1, label
        axis = "xyz".index(label[0])
        assert np.median(got[f"accel_{'xyz'[axis]}"][rest]) * (1 if label[2] == "p" else -1) > 0.9
    assert set(got) >= {"accel_x", "accel_y", "accel_z"} and "temp" not in got


@needs({"imucal": importlib.util.find_spec("imucal") is not None}, "pip install -e '.[test]'")
def test_the_section_column_holds_the_samples_imucal_reads_for_each_section(tmp_path):
    """imucal's own reading of the section list (ferraris_regions_from_section_list) picks
    the same samples as the imported log's section labels."""
    import imucal
    import pandas as pd

    out = tmp_path / "ferraris.parquet"
    import_log(REAL / "session.csv", out, REAL / "import.yaml")
    got = columns(out)
    data = pd.read_csv(REAL / "session.csv", index_col=0)
    section_list = pd.read_json(REAL / "sections.json").T
    regions = imucal.ferraris_regions_from_section_list(data, section_list)
    for label in json.loads((REAL / "sections.json").read_text()):
        rows = got["section"] == label
        gyro = np.c_[got["gyro_x"][rows], got["gyro_y"][rows], got["gyro_z"][rows]]
        accel = np.c_[got["accel_x"][rows], got["accel_y"][rows], got["accel_z"][rows]]
        np.testing.assert_array_equal(gyro, getattr(regions, f"gyr_{label}"))
        np.testing.assert_allclose(accel * G0, getattr(regions, f"acc_{label}"), rtol=1e-15)


def european(source: Path, out: Path) -> list[int]:
    """``source`` (a plain CSV) as a rig in much of the world writes it: ``;`` between the
    columns, a decimal comma, two comment lines before the header and one among the rows,
    and a row of units under the header. Returns the file line of each data row."""
    lines = source.read_text().splitlines()
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    units = {
        "acc_x": "m/s²",
        "acc_y": "m/s²",
        "acc_z": "m/s²",
        "gyr_x": "°/s",
        "gyr_y": "[deg/s]",
        "gyr_z": "dps",
    }
    text = [
        "# exported by the rig's own tool",
        "# unit 0042, operator 7",
        ";".join(header),
        ";".join(units.get(name, "") for name in header),
    ]
    where = []
    for k, row in enumerate(rows):
        if k == len(rows) // 2:
            text.append("  # the operator paused here")
        text.append(";".join(cell.replace(".", ",") for cell in row))
        where.append(len(text))
    out.write_text("\n".join(text) + "\n", encoding="utf-8")
    return where


EUROPEAN_MAP = """\
delimiter: ";"
decimal: ","
comment: "#"
units_row: true
"""


def test_decimal_commas_comments_and_a_units_row_give_the_same_log(tmp_path, monkeypatch):
    """The real session in imucal's labelled form, written as rigs in much of the world write
    a table, imports to the log the plain file gives, value for value and label for label,
    across many small blocks (a comment line inside one); an error's line number counts
    every line of the file, comments and units row included."""
    from ..protocols.test_ferraris import LABELLED_MAP, labelled_session

    monkeypatch.setattr(tabular, "BLOCK_BYTES", 1 << 14)
    plain = labelled_session(tmp_path)
    (tmp_path / "plain.yaml").write_text(LABELLED_MAP)
    (tmp_path / "eu.yaml").write_text(EUROPEAN_MAP + LABELLED_MAP)
    eu = tmp_path / "eu.csv"
    lines = european(plain, eu)
    import_log(plain, tmp_path / "plain.parquet", tmp_path / "plain.yaml")
    summary = import_log(eu, tmp_path / "eu.parquet", tmp_path / "eu.yaml")
    assert summary.rows == len(lines) == 4382
    assert pq.read_table(tmp_path / "eu.parquet").equals(pq.read_table(tmp_path / "plain.parquet"))
    text = eu.read_text().splitlines()
    k = len(lines) * 3 // 4  # past the comment among the rows
    cells = text[lines[k] - 1].split(";")
    cells[6] = "0,5.1"
    text[lines[k] - 1] = ";".join(cells)
    eu.write_text("\n".join(text) + "\n")
    with pytest.raises(
        LogFormatError, match=rf"eu\.csv: line {lines[k]}, column gyr_y: '0,5\.1' is not a number$"
    ):
        import_log(eu, tmp_path / "bad.parquet", tmp_path / "eu.yaml")


def test_a_label_column_is_checked_as_a_section_list_is(tmp_path):
    """Labels land on their rows, an empty cell is outside every section, and the labels of
    rows out of time order are ordered with them."""
    (tmp_path / "rig.csv").write_text(
        "n,a,b,c,part\n3,1,2,3,y_p\n0,1,2,3,x_p\n1,1,2,3,x_p\n2,1,2,3, \n4,1,2,3,y_p\n"
    )
    (tmp_path / "map.yaml").write_text(
        "time: {column: n, sample_rate: 10, sort: true}\n"
        "gyro: {x: a, y: b, z: c, unit: deg/s}\n"
        "sections: {column: part}\n"
    )
    summary = import_log(tmp_path / "rig.csv", tmp_path / "out.parquet", tmp_path / "map.yaml")
    got = columns(tmp_path / "out.parquet")
    assert list(got["t"]) == [0.0, 0.1, 0.2, 0.3, 0.4]
    assert list(got["section"]) == ["x_p", "x_p", None, "y_p", "y_p"]
    assert summary.labels == ("x_p", "y_p")
    assert provenance(tmp_path / "out.parquet")["map"]["sections"] == {"column": "part"}


# --- bags and MCAP --------------------------------------------------------------------------


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _stamp(store, ns):
    return store.types["builtin_interfaces/msg/Time"](sec=int(ns // 10**9), nanosec=int(ns % 10**9))


def imu_msg(store, ns, gyro, accel, no_accel=False):
    T = store.types
    header = T["std_msgs/msg/Header"](stamp=_stamp(store, ns), frame_id="imu")
    cov = np.zeros(9)
    acc_cov = cov.copy()
    if no_accel:
        acc_cov[0] = -1.0
    return T["sensor_msgs/msg/Imu"](
        header=header,
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=cov,
        angular_velocity=T["geometry_msgs/msg/Vector3"](*map(float, gyro)),
        angular_velocity_covariance=cov,
        linear_acceleration=T["geometry_msgs/msg/Vector3"](*map(float, accel)),
        linear_acceleration_covariance=acc_cov,
    )


def temp_msg(store, ns, value):
    T = store.types
    return T["sensor_msgs/msg/Temperature"](
        header=T["std_msgs/msg/Header"](stamp=_stamp(store, ns), frame_id="imu"),
        temperature=float(value),
        variance=0.0,
    )


def rate_msg(store, ns, value):
    T = store.types
    return T["geometry_msgs/msg/Vector3Stamped"](
        header=T["std_msgs/msg/Header"](stamp=_stamp(store, ns), frame_id="table"),
        vector=T["geometry_msgs/msg/Vector3"](0.0, 0.0, float(value)),
    )


def write_bag(path, events, storage="sqlite3", extra_topics=()):
    """events: (log_ns, topic, msgtype, message) in any order; written in log-time order,
    as a recorder does."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _typestore()
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for topic, kind in sorted({(e[1], e[2]) for e in events} | set(extra_topics)):
            conns[topic] = writer.add_connection(topic, kind, typestore=store)
        for log_ns, topic, kind, msg in sorted(events, key=lambda e: e[0]):
            writer.write(conns[topic], log_ns, store.serialize_cdr(msg, kind))


def signals(n=1000, rate=200.0, seed=3):
    """A known IMU session: IMU stamps, rates (rad/s) and accelerations (m/s²), a
    temperature at 2 Hz starting 0.3 s late and published 0.2 s after its stamp (samples
    have to wait for it), and a table rate at 50 Hz."""
    rng = np.random.default_rng(seed)
    stamps = T0_NS + np.round(np.arange(n) / rate * 1e9).astype(np.int64)
    gyro = rng.normal(0, 1.0, (n, 3))
    accel = rng.normal(0, 0.2, (n, 3)) + [0, 0, G0]
    temp_stamps = stamps[0] + 300_000_000 + np.arange(0, int(n / rate * 2)) * 500_000_000
    temps = 20 + 0.1 * np.arange(len(temp_stamps))
    rate_stamps = stamps[0] + np.arange(0, int(n / rate * 50)) * 20_000_000
    rates = np.sin(np.arange(len(rate_stamps)) / 10)
    return dict(
        stamps=stamps,
        gyro=gyro,
        accel=accel,
        temp_stamps=temp_stamps,
        temps=temps,
        rate_stamps=rate_stamps,
        rates=rates,
    )


def held_truth(sample_stamps, value_stamps, values):
    """The last value stamped at or before each sample, None before the first (a loop)."""
    out, j = [], -1
    for s in sample_stamps:
        while j + 1 < len(value_stamps) and value_stamps[j + 1] <= s:
            j += 1
        out.append(values[j] if j >= 0 else None)
    return out


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_ros2_bag_gives_deg_s_g_and_held_temperature_and_rate(tmp_path, capsys, monkeypatch, storage):
    monkeypatch.setattr(bags, "BATCH", 64)  # many batches: samples wait for the late topic
    s = signals()
    store = _typestore()
    events = [
        (int(ns) + 1_000_000, IMU_TOPIC, "sensor_msgs/msg/Imu", imu_msg(store, ns, g, a))
        for ns, g, a in zip(s["stamps"], s["gyro"], s["accel"], strict=False)
    ]
    events += [
        (int(ns) + 200_000_000, TEMP_TOPIC, "sensor_msgs/msg/Temperature", temp_msg(store, ns, v))
        for ns, v in zip(s["temp_stamps"], s["temps"], strict=False)
    ]
    events += [
        (int(ns) + 500_000, RATE_TOPIC, "geometry_msgs/msg/Vector3Stamped", rate_msg(store, ns, v))
        for ns, v in zip(s["rate_stamps"], s["rates"], strict=False)
    ]
    bag = tmp_path / "session_bag"
    write_bag(bag, events, storage, extra_topics={("/imu/other", "sensor_msgs/msg/Imu")})
    (tmp_path / "map.yaml").write_text(
        f"topics:\n  imu: {IMU_TOPIC}\n  temperature: {TEMP_TOPIC}\n"
        f"  ref_rate: {{topic: {RATE_TOPIC}, field: vector.z, unit: rad/s}}\n"
    )
    out = tmp_path / "log.parquet"
    status, stdout, err = run(capsys, "import", bag, "-o", out, "--map", tmp_path / "map.yaml")
    assert status == 0, err
    temp = held_truth(s["stamps"], s["temp_stamps"], s["temps"])
    keep = np.array([v is not None for v in temp])
    assert err.strip() == (
        f"gyrocal: note: {int((~keep).sum())} IMU samples before the first temp "
        f"message on {TEMP_TOPIC} dropped"
    )
    got = columns(out)
    kept = s["stamps"][keep]
    assert stdout.startswith(f"{keep.sum()} rows -> {out}")
    np.testing.assert_allclose(got["t"], (kept - kept[0]) / 1e9, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        np.c_[got["gyro_x"], got["gyro_y"], got["gyro_z"]], np.degrees(s["gyro"][keep]), rtol=1e-14
    )
    np.testing.assert_allclose(
        np.c_[got["accel_x"], got["accel_y"], got["accel_z"]], s["accel"][keep] / G0, rtol=1e-14
    )
    np.testing.assert_array_equal(got["temp"], np.array(temp)[keep].astype(float))
    rate = np.degrees(np.array(held_truth(kept, s["rate_stamps"], s["rates"]), dtype=float))
    np.testing.assert_allclose(got["ref_rate"], rate, rtol=1e-14)
    record = provenance(out)
    assert record["time_origin_ns"] == int(kept[0]) and record["imu_topic"] == IMU_TOPIC
    assert record["source"]["format"] == "ros2" and len(record["source"]["sha256"]) == 64
    again = tmp_path / "again.parquet"
    assert run(capsys, "import", bag, "-o", again, "--map", tmp_path / "map.yaml")[0] == 0
    assert again.read_bytes() == out.read_bytes()


def test_a_rigs_own_message_type_is_read_from_the_definition_in_the_bag(tmp_path, capsys):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_types_from_msg

    store = _typestore()
    store.register(get_types_from_msg("float64 rate_dps\nuint8 mode", "rig_msgs/msg/TableState"))
    state = store.types["rig_msgs/msg/TableState"]
    bag = tmp_path / "bag"
    with Writer(bag, version=9) as writer:
        imu = writer.add_connection(IMU_TOPIC, "sensor_msgs/msg/Imu", typestore=store)
        table = writer.add_connection(RATE_TOPIC, "rig_msgs/msg/TableState", typestore=store)
        for i in range(20):
            ns = T0_NS + i * 10**7
            writer.write(
                table, ns, store.serialize_cdr(state(rate_dps=10.0 * i, mode=1), "rig_msgs/msg/TableState")
            )
            writer.write(
                imu,
                ns + 1,
                store.serialize_cdr(imu_msg(store, ns, (0, 0, 1), (0, 0, G0)), "sensor_msgs/msg/Imu"),
            )
    (tmp_path / "map.yaml").write_text(
        f"topics: {{ref_rate: {{topic: {RATE_TOPIC}, field: rate_dps, unit: deg/s}}}}\n"
    )
    out = tmp_path / "log.parquet"
    status, _, err = run(capsys, "import", bag, "-o", out, "--map", tmp_path / "map.yaml")
    assert status == 0, err
    np.testing.assert_array_equal(columns(out)["ref_rate"], 10.0 * np.arange(20))


def test_a_plain_mcap_file_read_with_mcap_ros2(tmp_path, capsys):
    """Written with mcap_ros2's own writer; log (receive) time as the time base, a
    Float32 reference in deg/s, and an IMU without accelerometer (covariance[0] = -1)."""
    from mcap_ros2.writer import Writer

    store = _typestore()
    s = signals(n=400, seed=4)
    schemas = {}
    path = tmp_path / "robot.mcap"
    log_imu = s["stamps"] + 3_000_000
    log_rate = s["rate_stamps"] + 1_000_000
    with open(path, "wb") as fh:
        writer = Writer(fh)
        for kind in ("sensor_msgs/msg/Imu", "std_msgs/msg/Float32"):
            schemas[kind] = writer.register_msgdef(kind, store.generate_msgdef(kind, ros_version=2)[0])
        events = [(int(t), 0, i) for i, t in enumerate(log_imu)] + [
            (int(t), 1, i) for i, t in enumerate(log_rate)
        ]
        for log_ns, which, i in sorted(events):
            if which == 0:
                ns = int(s["stamps"][i])
                msg = {
                    "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": "imu"},
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    "orientation_covariance": [0.0] * 9,
                    "angular_velocity": dict(zip("xyz", map(float, s["gyro"][i]), strict=False)),
                    "angular_velocity_covariance": [0.0] * 9,
                    "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "linear_acceleration_covariance": [-1.0] + [0.0] * 8,
                }
                writer.write_message(IMU_TOPIC, schemas["sensor_msgs/msg/Imu"], msg, log_time=log_ns)
            else:
                writer.write_message(
                    RATE_TOPIC,
                    schemas["std_msgs/msg/Float32"],
                    {"data": float(s["rates"][i])},
                    log_time=log_ns,
                )
        writer.finish()
    (tmp_path / "map.yaml").write_text(
        f"time: {{source: log}}\ntopics: {{ref_rate: {{topic: {RATE_TOPIC}, unit: deg/s}}}}\n"
    )
    out = tmp_path / "log.parquet"
    status, stdout, err = run(capsys, "import", path, "-o", out, "--map", tmp_path / "map.yaml")
    assert status == 0, err
    got = columns(out)
    assert list(got) == ["t", "gyro_x", "gyro_y", "gyro_z", "ref_rate"]  # no accelerometer
    np.testing.assert_allclose(got["t"], (log_imu - log_imu[0]) / 1e9, atol=1e-12)
    np.testing.assert_allclose(got["gyro_z"], np.degrees(s["gyro"][:, 2]), rtol=1e-14)
    truth = np.array(held_truth(log_imu, log_rate, s["rates"].astype(np.float32)), dtype=float)
    np.testing.assert_array_equal(got["ref_rate"], truth)
    assert provenance(out)["source"]["format"] == "mcap" and err == ""


# --- calibrate on an imported turntable log ------------------------------------------------


@pytest.fixture(scope="module")
def turntable(tmp_path_factory):
    """A quick simulated turntable log and its calibration."""
    d = tmp_path_factory.mktemp("turntable")
    log = d / "sim.parquet"
    assert (
        cli.main(
            [
                "simulate",
                "--protocol",
                "turntable",
                "--preset",
                "quick",
                "--sample-rate",
                "25",
                "--log",
                str(log),
            ]
        )
        == 0
    )
    assert cli.main(["calibrate", str(log), "-o", str(d / "cal.json")]) == 0
    return log, json.loads((d / "cal.json").read_text())


def calibrate(log, out) -> dict:
    assert cli.main(["calibrate", str(log), "-o", str(out)]) == 0
    return json.loads(Path(out).read_text())


def test_calibrate_gives_the_same_calibration_from_an_imported_csv(tmp_path, turntable, capsys):
    """Exported as a rig would write it (rad/s, m/s², a sample index), imported back: the
    same parameters to float rounding."""
    log, original = turntable
    table = pq.read_table(log)
    col = {name: table[name].to_numpy().astype(np.float64) for name in table.column_names if name != "mount"}
    src = tmp_path / "rig.csv"
    write_csv(
        src,
        {
            "sample": np.arange(table.num_rows),
            **{f"w{a}": np.radians(col[f"gyro_{a}"]) for a in "xyz"},
            **{f"f{a}": col[f"accel_{a}"] * G0 for a in "xyz"},
            "temp_c": col["temp"],
            "table_rad_s": np.radians(col["ref_rate"]),
            "mount": table["mount"].cast(pa.string()),
        },
    )
    (tmp_path / "map.yaml").write_text(
        "time: {column: sample, sample_rate: 25}\n"
        "gyro: {x: wx, y: wy, z: wz, unit: rad/s}\naccel: {x: fx, y: fy, z: fz, unit: m/s^2}\n"
        "temp: {column: temp_c, unit: degC}\nref_rate: {column: table_rad_s, unit: rad/s}\n"
        "mount: {column: mount}\n"
    )
    imported = tmp_path / "imported.parquet"
    assert run(capsys, "import", src, "-o", imported, "--map", tmp_path / "map.yaml")[0] == 0
    np.testing.assert_allclose(columns(imported)["t"], col["t"], atol=1e-9)
    cal = calibrate(imported, tmp_path / "cal.json")
    for key in ("temperature", "K", "B"):
        np.testing.assert_allclose(cal["grid"][key], original["grid"][key], rtol=1e-9, atol=1e-12)


def test_calibrate_accepts_a_turntable_log_imported_from_a_bag(tmp_path, turntable, capsys):
    """The same session as a robot logs it: Imu messages, the chamber's temperature every
    fifth sample (held in between), the table's rate as a TwistStamped, no mount column.
    Parameters agree to within 1 % of their stated standard errors with those of the same log
    holding its temperature as the bag does."""
    log, original = turntable
    table = pq.read_table(log)
    col = {name: table[name].to_numpy().astype(np.float64) for name in table.column_names if name != "mount"}
    store = _typestore()
    T = store.types
    stamps = T0_NS + np.round(col["t"] * 1e9).astype(np.int64)
    gyro = np.radians(np.c_[col["gyro_x"], col["gyro_y"], col["gyro_z"]])
    accel = np.c_[col["accel_x"], col["accel_y"], col["accel_z"]] * G0
    rate = np.radians(col["ref_rate"])
    events = []
    for i, ns in enumerate(stamps):
        ns = int(ns)
        events.append((ns, IMU_TOPIC, "sensor_msgs/msg/Imu", imu_msg(store, ns, gyro[i], accel[i])))
        twist = T["geometry_msgs/msg/TwistStamped"](
            header=T["std_msgs/msg/Header"](stamp=_stamp(store, ns), frame_id="table"),
            twist=T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0),
                angular=T["geometry_msgs/msg/Vector3"](0.0, 0.0, rate[i]),
            ),
        )
        events.append((ns, RATE_TOPIC, "geometry_msgs/msg/TwistStamped", twist))
        if i % 5 == 0:
            events.append(
                (ns, TEMP_TOPIC, "sensor_msgs/msg/Temperature", temp_msg(store, ns, col["temp"][i]))
            )
    bag = tmp_path / "bag"
    write_bag(bag, events, "mcap")
    (tmp_path / "map.yaml").write_text(
        f"topics:\n  temperature: {TEMP_TOPIC}\n  ref_rate: {{topic: {RATE_TOPIC}, field: twist.angular.z}}\n"
    )
    imported = tmp_path / "imported.parquet"
    status, _, err = run(capsys, "import", bag, "-o", imported, "--map", tmp_path / "map.yaml")
    assert status == 0 and err == ""
    got = columns(imported)
    np.testing.assert_allclose(got["ref_rate"], col["ref_rate"], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(got["temp"], np.repeat(col["temp"][::5], 5)[: len(col["t"])])
    cal = calibrate(imported, tmp_path / "cal.json")
    # Each hold is fitted at its own mean temperature: the reference is the same log with
    # the temperature the bag carries (held between its messages).
    held = table.set_column(
        table.column_names.index("temp"), "temp", pa.array(got["temp"], type=table.schema.field("temp").type)
    )
    pq.write_table(held, tmp_path / "held.parquet")
    original = calibrate(tmp_path / "held.parquet", tmp_path / "held.json")
    assert cal["grid"]["temperature"] == pytest.approx(original["grid"]["temperature"], abs=0.01)
    for name, values in original["grid"]["coefficients"].items():
        stderr = np.array(original["grid"]["stderr"][name])
        diff = np.abs(np.array(cal["grid"]["coefficients"][name]) - values)
        assert (diff <= 0.01 * stderr).all(), (name, diff / stderr)


# --- errors ----------------------------------------------------------------------------------


def _csv(tmp_path, text, name="rig.csv"):
    (tmp_path / name).write_text(text)
    (tmp_path / "map.yaml").write_text("time: {column: n, unit: s}\ngyro: {x: a, y: b, z: c, unit: deg/s}\n")
    return [tmp_path / name, "--map", tmp_path / "map.yaml"]


def _labelled(tmp_path, text, map_extra="sections: {column: part}\n", time="{column: n, unit: s}"):
    (tmp_path / "rig.csv").write_text(text)
    (tmp_path / "map.yaml").write_text(f"time: {time}\ngyro: {{x: a, y: b, z: c, unit: deg/s}}\n" + map_extra)
    return [tmp_path / "rig.csv", "--map", tmp_path / "map.yaml"]


def _map(tmp_path, text):
    (tmp_path / "rig.csv").write_text("n,a,b,c\n0,1,2,3\n")
    (tmp_path / "bad.yaml").write_text(text)
    return [tmp_path / "rig.csv", "--map", tmp_path / "bad.yaml"]


def _small_bag(tmp_path, extra=()):
    store = _typestore()
    events = [
        (
            T0_NS + i * 10**7,
            IMU_TOPIC,
            "sensor_msgs/msg/Imu",
            imu_msg(store, T0_NS + i * 10**7, (0, 0, 0), (0, 0, G0)),
        )
        for i in range(10)
    ]
    events += [
        (T0_NS + i * 10**7, RATE_TOPIC, "std_msgs/msg/Float64", store.types["std_msgs/msg/Float64"](data=1.0))
        for i in range(10)
    ]
    for topic in extra:
        events += [(T0_NS + 5, topic, "sensor_msgs/msg/Imu", imu_msg(store, T0_NS, (0, 0, 0), (0, 0, 0)))]
    write_bag(tmp_path / "bag", events)
    return tmp_path / "bag"


def _with_map(tmp_path, args, text):
    (tmp_path / "bag.yaml").write_text(text)
    return [*args, "--map", tmp_path / "bag.yaml"]


def _truncated(path, keep):
    data = path.read_bytes()
    path.write_bytes(data[:keep])
    return path


def _binary(d):
    args = _csv(d, "")
    (d / "rig.csv").write_bytes(b"\xff\xfe\x00garbage\x80\x81\n1,2\n")
    return args


def _json(d, value):
    (d / "sections.json").write_text(json.dumps(value))
    return d / "sections.json"


def _mcap_copy(d):
    from mcap_ros2.writer import Writer

    with open(d / "robot.mcap", "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("std_msgs/msg/Float64", "float64 data")
        for i in range(100):
            writer.write_message("/x", schema, {"data": float(i)}, log_time=i)
        writer.finish()
    return d / "robot.mcap"


ERRORS = {
    "missing file": (lambda d: [d / "nope.csv"], r"nope\.csv: no such file or directory$"),
    "missing map": (
        lambda d: [_csv(d, "n,a,b,c\n")[0], "--map", d / "none.yaml"],
        r"none\.yaml: no such map file$",
    ),
    "not a CSV": (
        lambda d: _csv(d, "n,a,b,c\n0,1,2,3\n1,2\n"),
        r"rig\.csv: not a readable CSV file \(CSV parse error: Expected 4 columns, got 2: 1,2\)$",
    ),
    "not text": (_binary, r"rig\.csv: not a UTF-8 text file"),
    "column not in the file": (
        lambda d: _csv(d, "n,a,bb,c\n0,1,2,3\n"),
        r"rig\.csv: column 'b' \(gyro\.y in map\.yaml\) is not in the file; its columns: n, a, bb, c$",
    ),
    "value not a number": (
        lambda d: _csv(d, "n,a,b,c\n0,1,2,3\n1,2,n/a?,4\n"),
        r"rig\.csv: line 3, column b: 'n/a\?' is not a number$",
    ),
    "time not increasing": (
        lambda d: _csv(d, "n,a,b,c\n0,1,2,3\n1,1,2,3\n1,1,2,3\n"),
        r"rig\.csv: time is not strictly increasing: line 4 has t=1\.0 s after t=1\.0 s$",
    ),
    "empty result": (lambda d: _csv(d, "n,a,b,c\n"), r"rig\.csv: no samples to import$"),
    "rows grouped by label": (
        lambda d: _labelled(d, "n,a,b,c,part\n5,1,2,3,x_a\n6,1,2,3,x_a\n0,1,2,3,x_p\n"),
        r"rig\.csv: time is not strictly increasing: line 4 has t=0\.0 s after t=6\.0 s; if the file "
        r"lists its rows in another order \(grouped by label, say\), sort: true under time in "
        r"map\.yaml orders them by n$",
    ),
    "equal times, sorted": (
        lambda d: _labelled(
            d, "n,a,b,c\n1,1,2,3\n0,1,2,3\n0,1,2,3\n", "", "{column: n, unit: s, sort: true}"
        ),
        r"rig\.csv: time is not strictly increasing: line 4 has t=0\.0 s after t=0\.0 s$",
    ),
    "unknown section label": (
        lambda d: _labelled(d, "n,a,b,c,part\n0,1,2,3,x_p\n1,1,2,3,x_rotation\n"),
        r"rig\.csv: line 3: section 'x_rotation' is not one of x_p x_a y_p y_a z_p z_a x_rot y_rot "
        r"z_rot \(or an empty cell\)$",
    ),
    "a section in two stretches": (
        lambda d: _labelled(d, "n,a,b,c,part\n0,1,2,3,x_p\n1,1,2,3,x_p\n2,1,2,3,y_p\n3,1,2,3,x_p\n"),
        r"rig\.csv: line 5: section x_p starts again after other rows \(it ran from line 2 to line "
        r"3\); a section is one stretch of samples in time order$",
    ),
    "units row against the map": (
        lambda d: _labelled(d, "n,a,b,c\ns,rad/s,rad/s,rad/s\n0,1,2,3\n", "units_row: true\n"),
        r"rig\.csv: the units row gives 'rad/s' for column 'a', which map\.yaml maps as gyro\.x in "
        r"deg/s: correct the map's unit \(or the column\)$",
    ),
    "sort with a section list": (
        lambda d: _labelled(
            d, "n,a,b,c\n0,1,2,3\n", "sections: s.json\n", "{column: n, unit: s, sort: true}"
        ),
        r"map\.yaml: a section list counts the file's rows as they stand; with time\.sort give the "
        r"annotation as a label column \(sections: \{column: NAME\}\)$",
    ),
    "decimal comma, comma delimiter": (
        lambda d: _labelled(d, "n,a,b,c\n0,1,2,3\n", "decimal: ','\n"),
        r"map\.yaml: decimal and delimiter are both ',': a file with decimal commas separates its "
        r'columns with another character \(delimiter: ";"\)$',
    ),
    "unknown key": (
        lambda d: _map(
            d, "time: {column: n, unit: s}\ngyro: {x: a, y: b, z: c, unit: deg/s}\ntemperature: {column: t}\n"
        ),
        r"bad\.yaml: unknown key 'temperature' in the map; expected one of format, ",
    ),
    "unknown unit": (
        lambda d: _map(d, "time: {column: n, unit: s}\ngyro: {x: a, y: b, z: c, unit: dps}\n"),
        r"bad\.yaml: gyro\.unit: unknown value 'dps'; expected one of deg/s, rad/s, mdps, counts$",
    ),
    "counts without sensitivity": (
        lambda d: _map(d, "time: {column: n, unit: s}\ngyro: {x: a, y: b, z: c, unit: counts}\n"),
        r"bad\.yaml: gyro: unit counts needs sensitivity \(LSB per deg/s\)$",
    ),
    "missing gyro axis": (
        lambda d: _map(d, "time: {column: n, unit: s}\ngyro: {x: a, y: b, unit: deg/s}\n"),
        r"bad\.yaml: gyro lacks axis z: map x, y and z to columns$",
    ),
    "section past the end": (
        lambda d: [
            *_csv(d, "n,a,b,c\n0,1,2,3\n1,1,2,3\n"),
            "--sections",
            _json(d, {"x_p": {"start": 0, "end": 5}}),
        ],
        r"sections\.json: section x_p ends at sample 5, past the source's 2 samples$",
    ),
    "corrupt bag": (
        lambda d: [_truncated(next(_small_bag(d).glob("*.db3")), 3000).parent],
        r"bag: not a readable ROS 2 bag \(",
    ),
    "corrupt MCAP": (lambda d: [_truncated(_mcap_copy(d), 600)], r"robot\.mcap: not a readable MCAP file \("),
    "topic not in the bag": (
        lambda d: _with_map(d, [_small_bag(d)], "topics: {temperature: /imu/temp}\n"),
        r"bag: topic /imu/temp \(temp\) is not in the file; its topics: /imu/data \(sensor_msgs/msg/Imu\), "
        r"/table/rate \(std_msgs/msg/Float64\)$",
    ),
    "wrong message type": (
        lambda d: _with_map(d, [_small_bag(d)], "topics: {imu: /table/rate}\n"),
        r"bag: topic /table/rate carries std_msgs/msg/Float64, expected sensor_msgs/msg/Imu$",
    ),
    "no such field": (
        lambda d: _with_map(d, [_small_bag(d)], "topics: {ref_rate: {topic: /table/rate, field: data.x}}\n"),
        r"bag: topic /table/rate: std_msgs/msg/Float64 has no field data\.x$",
    ),
    "two IMU topics": (
        lambda d: [_small_bag(d, extra=("/imu/raw",))],
        r"bag: 2 sensor_msgs/msg/Imu topics \(/imu/data, /imu/raw\): name one as topics\.imu",
    ),
}


@pytest.mark.parametrize("case", list(ERRORS))
def test_bad_input_is_one_line_naming_the_file_and_exit_status_2(tmp_path, capsys, case):
    import re

    make, pattern = ERRORS[case]
    out = tmp_path / "out.parquet"
    status, stdout, err = run(capsys, "import", *make(tmp_path), "-o", out)
    assert status == 2 and len(err.splitlines()) == 1, err
    assert re.search(pattern, err.removeprefix("gyrocal: error: ").strip()), err
    assert not out.exists() and not list(tmp_path.glob(".out.parquet.*"))


def test_a_bad_import_through_the_installed_command_is_one_line_and_status_2(tmp_path):
    args = _csv(tmp_path, "n,a,b,c\n0,1,2,3\n1,2,oops,4\n")
    proc = subprocess.run(
        [sys.executable, "-m", "gyrocal", "import", *map(str, args), "-o", str(tmp_path / "o.parquet")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().endswith("rig.csv: line 3, column b: 'oops' is not a number")
    assert "Traceback" not in proc.stderr and len(proc.stderr.splitlines()) == 1


def test_the_bag_libraries_load_only_for_a_bag():
    """calibrate does not pay for rosbags and mcap: a CSV import does not load them either."""
    probe = (
        "import sys, gyrocal.run.cli, gyrocal.importer, gyrocal.importer.tabular; "
        "print(sorted(m for m in ('rosbags', 'mcap', 'mcap_ros2') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
