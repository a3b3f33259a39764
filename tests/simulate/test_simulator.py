"""The simulator: deterministic, follows the contract, physics as documented."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq

from gyrocal.io.log import read_log
from gyrocal.simulate import GyroUnit, TurntableProtocol, load_truth, simulate
from gyrocal.simulate.unit import SEED000_B25, SEED000_K25


def test_same_seed_same_bytes_other_seed_other_data(tmp_path):
    rig = TurntableProtocol.quick(temperatures=(0.0, 20.0), rates=(10.0, 100.0))
    a = simulate(tmp_path / "a", rig=rig, units=2, seed=5).parent
    b = simulate(tmp_path / "b", rig=rig, units=2, seed=5).parent
    c = simulate(tmp_path / "c", rig=rig, units=1, seed=6).parent
    for name in ("U001.parquet", "U002.parquet", "U001.truth.json", "devices.tsv"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert (a / "U001.parquet").read_bytes() != (c / "U001.parquet").read_bytes()
    assert (a / "U001.truth.json").read_text() != (a / "U002.truth.json").read_text()


def test_log_follows_the_contract_and_the_manifest_points_at_it(tmp_path):
    rig = TurntableProtocol.quick(temperatures=(0.0, 20.0), rates=(10.0,))
    manifest = simulate(tmp_path, rig=rig, units=1, seed=1, batch="B7", session="2026-02-03")
    header, row = [line.split("\t") for line in manifest.read_text().splitlines()]
    assert header == ["device", "batch", "session", "protocol", "path"]
    assert row == ["U001", "B7", "2026-02-03", "turntable", "U001.parquet"]
    schema = pq.read_schema(tmp_path / "U001.parquet")
    assert {"t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "mount"} <= set(schema.names)
    log = read_log(tmp_path / "U001.parquet")
    assert log.rows_dropped == 0 and np.all(np.diff(log.column("t")) > 0)


def test_seed000_unit_reproduces_eq23_at_25_degrees():
    unit = GyroUnit.seed000()
    np.testing.assert_allclose(unit.K(25.0), SEED000_K25, rtol=1e-12)
    np.testing.assert_allclose(unit.B(25.0), SEED000_B25, rtol=1e-12)
    # The large x/y package term seed 000 reports, about ±0.0188.
    assert abs(unit.K(25.0)[0, 1] + 0.0188) < 1e-12 and abs(unit.K(25.0)[1, 0] - 0.0187) < 1e-12


def test_schedule_has_every_hold_forward_and_reverse(tmp_path):
    rig = TurntableProtocol.quick(temperatures=(0.0, 20.0), rates=(1.0, 10.0))
    simulate(tmp_path, rig=rig, units=1, seed=1)
    truth = load_truth(tmp_path / "U001.parquet")
    holds = truth["holds"]
    assert len(holds) == 2 * 3 * (1 + 2 * 2)  # points x mounts x (0, ±1, ±10)
    rates = sorted({h["rate"] for h in holds})
    assert rates == [-10.0, -1.0, 0.0, 1.0, 10.0]
    assert len(truth["handling"]) == 2 * 2  # between mounts, zig-zag across points
    assert json.loads((tmp_path / "U001.truth.json").read_text())["format"] == "gyrocal.truth/1"


def test_output_is_quantised_and_saturates_at_full_scale(tmp_path):
    unit = GyroUnit.seed000(full_scale=150.0)
    rig = TurntableProtocol.quick(temperatures=(20.0,), rates=(100.0, 200.0))
    simulate(tmp_path, rig=rig, unit=unit, units=1, seed=1)
    g = read_log(tmp_path / "U001.parquet").column("gyro_x").astype(np.float64)
    assert g.max() <= 150.0 + 1e-3 and g.min() >= -150.0 - 1e-3
    steps = g / unit.lsb
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)


def test_temperature_sensor_lags_the_chamber_with_self_heating(tmp_path):
    rig = TurntableProtocol.quick(temperatures=(40.0,), rates=(10.0,), soak_s=40.0)
    simulate(tmp_path, rig=rig, units=1, seed=1)
    log = read_log(tmp_path / "U001.parquet")
    t, temp = log.column("t"), log.column("temp").astype(float)
    # Right after the set-point jump the die is still near room temperature...
    assert temp[t < 0.5].mean() < rig.room_temp + 3.0
    # ...and it settles at the set point plus the self-heating.
    late = temp[t > t[-1] - 5.0].mean()
    np.testing.assert_allclose(late, 40.0 + rig.self_heating, atol=0.05)
