"""Segmentation against the simulator's schedule: every hold, nothing from handling."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from gyrocal.io.errors import GyrocalError, SegmentationError
from gyrocal.io.holds import temperature_points
from gyrocal.io.log import read_log
from gyrocal.protocols.turntable.segment import LOG_COLUMNS, SegmentConfig, segment, segment_file
from gyrocal.simulate import load_truth
from gyrocal.simulate.unit import GyroUnit

from .conftest import TEMPS, make_log


def overlaps(a_start, a_end, b_start, b_end):
    return (a_start < b_end) & (a_end > b_start)


def match(obs, holds):
    """For each planned hold, the observations overlapping it."""
    return [obs[overlaps(obs.t_start, obs.t_end, h["t_start"], h["t_end"])] for h in holds]


@pytest.mark.parametrize("name", ["complete", "no_mount"])
def test_every_hold_found_with_the_right_mount_and_rate(logs, name):
    _, seg = segment_file(logs[name])
    truth = load_truth(logs[name])
    obs = seg.observations
    found = match(obs, truth["holds"])
    assert all(len(f) == 1 for f in found), "each planned hold is exactly one observation"
    assert len(obs) == len(truth["holds"]), "and no observation is extra"
    for planned, f in zip(truth["holds"], found, strict=False):
        row = f.iloc[0]
        assert row["mount"] == planned["mount"]
        assert row["ref_rate"] == pytest.approx(planned["rate"], abs=1e-3)
    # without a mount column the mounts came from the gyro or from neighbouring holds
    sources = set(obs["mount_source"])
    assert sources <= ({"data", "inherited"} if name == "no_mount" else {"column", "both"})


def test_each_hold_starts_at_the_table_angle_its_reference_rate_sums_to(logs):
    """The table's angle at a hold's start is the reference rate summed over the samples
    before it (what an effect fixed in the lab is seen through)."""
    log, seg = segment_file(logs["complete"])
    table = pq.read_table(logs["complete"], columns=["t", "ref_rate"])
    t, ref = (table[c].to_numpy().astype(float) for c in ("t", "ref_rate"))
    dt = float(np.median(np.diff(t)))
    angle = np.r_[0.0, np.cumsum(ref * dt)]
    obs = seg.observations
    start = np.searchsorted(t, obs["t_start"].to_numpy())
    expected = np.mod(angle[start], 360.0)
    # Equal but for the order of summation (by blocks there, by samples here).
    gap = np.abs((obs["table_angle"].to_numpy() - expected + 180.0) % 360.0 - 180.0)
    assert gap.max() < 1e-6, gap.max()


@pytest.mark.parametrize("name", ["complete", "no_mount"])
def test_nothing_from_handling_motion_which_is_reported(logs, name):
    _, seg = segment_file(logs[name])
    truth = load_truth(logs[name])
    obs = seg.observations
    for h in truth["handling"]:
        assert not overlaps(obs.t_start, obs.t_end, h["t_start"], h["t_end"]).any()
    motion = seg.rejected().query("reason == 'handling_motion'")
    # every handling episode is reported as rejected motion, and only those
    assert len(motion) == len(truth["handling"])
    for h in truth["handling"]:
        assert overlaps(motion.t_start, motion.t_end, h["t_start"], h["t_end"]).sum() == 1


def test_counts_per_temperature_and_mount(logs):
    _, seg = segment_file(logs["complete"])
    counts = seg.counts()
    assert list(counts.columns) == ["+x", "+y", "+z"]
    assert len(counts) == len(TEMPS)
    assert (counts.to_numpy() == 21).all()  # 0 and ±10 rates per mount and point
    np.testing.assert_allclose(counts.index, np.array(TEMPS) + 2.0, atol=0.1)  # self-heating


def drop_rows(path, out, mask_fn):
    table = pq.read_table(path)
    t = table.column("t").to_numpy()
    pq.write_table(table.filter(pa.array(~mask_fn(t))), out)
    return out


def test_a_short_logging_pause_inside_a_hold_does_not_interrupt_it(logs, tmp_path):
    truth = load_truth(logs["complete"])
    h = truth["holds"][40]
    mid = (h["t_start"] + h["t_end"]) / 2
    path = drop_rows(
        logs["complete"], tmp_path / "pause.parquet", lambda t: (t > mid - 0.3) & (t < mid + 0.3)
    )
    _, seg = segment_file(path)
    found = match(seg.observations, truth["holds"])
    assert all(len(f) == 1 for f in found)
    whole = match(segment_file(logs["complete"])[1].observations, truth["holds"])[40]
    assert found[40]["n"].iloc[0] < whole["n"].iloc[0]  # the paused samples are missing
    assert "gap" not in set(seg.segments["kind"])


def test_a_long_logging_gap_is_reported_and_costs_only_its_hold(logs, tmp_path):
    truth = load_truth(logs["complete"])
    h = truth["holds"][40]
    path = drop_rows(
        logs["complete"],
        tmp_path / "gap.parquet",
        lambda t: (t > h["t_start"] + 1.0) & (t < h["t_start"] + 4.0),
    )
    _, seg = segment_file(path)
    gaps = seg.segments[seg.segments["kind"] == "gap"]
    assert len(gaps) == 1
    assert gaps["t_start"].iloc[0] <= h["t_start"] + 1.0 and gaps["t_end"].iloc[0] >= h["t_start"] + 4.0
    found = match(seg.observations, truth["holds"])
    assert all(len(f) == 1 for i, f in enumerate(found) if i != 40)
    assert len(found[40]) <= 1  # what is left of it may or may not make a hold


def test_missing_hold_is_just_absent(logs, tmp_path):
    truth = load_truth(logs["complete"])
    gone = truth["holds"][30]
    path = drop_rows(
        logs["complete"],
        tmp_path / "miss.parquet",
        lambda t: (t >= gone["t_start"] - 1) & (t <= gone["t_end"] + 1),
    )
    _, seg = segment_file(path)
    found = match(seg.observations, truth["holds"])
    assert len(found[30]) == 0
    assert sum(len(f) == 1 for f in found) == len(truth["holds"]) - 1


def test_mount_column_that_contradicts_the_gyro_is_rejected(logs, tmp_path):
    truth = load_truth(logs["complete"])
    wrong = next(h for h in truth["holds"] if h["mount"] == "+x" and abs(h["rate"]) >= 50)
    table = pq.read_table(logs["complete"])
    t = table.column("t").to_numpy()
    mount = np.array(table.column("mount").to_pylist(), dtype=object)
    mount[(t >= wrong["t_start"]) & (t <= wrong["t_end"])] = "+y"
    table = table.set_column(table.schema.get_field_index("mount"), "mount", pa.array(mount.tolist()))
    path = tmp_path / "mislabel.parquet"
    pq.write_table(table, path)
    _, seg = segment_file(path)
    rejected = seg.rejected()
    hit = rejected[overlaps(rejected.t_start, rejected.t_end, wrong["t_start"], wrong["t_end"])]
    assert list(hit["reason"]) == ["mount_mismatch"]
    assert "mount column says +y, gyro says +x" in hit["detail"].iloc[0]


def test_scattered_missing_mount_labels_and_accelerometer_values_lose_nothing(logs, tmp_path):
    truth = load_truth(logs["complete"])
    table = pq.read_table(logs["complete"])
    rng = np.random.default_rng(0)
    n = table.num_rows
    mount = table.column("mount").to_pylist()
    for i in rng.choice(n, n // 100, replace=False):
        mount[i] = None  # a rig that sometimes omits the label
    table = table.set_column(table.schema.get_field_index("mount"), "mount", pa.array(mount))
    for c in ("accel_x", "accel_y", "accel_z"):
        values = table.column(c).to_numpy().copy()
        values[::2] = np.nan  # an accelerometer at half the rate
        table = table.set_column(table.schema.get_field_index(c), c, pa.array(values))
    path = tmp_path / "sparse.parquet"
    pq.write_table(table, path)
    log, seg = segment_file(path)
    assert log.rows_dropped == 0
    found = match(seg.observations, truth["holds"])
    assert all(len(f) == 1 for f in found)
    assert np.isfinite(seg.observations[["accel_x", "accel_y", "accel_z"]].to_numpy()).all()


def test_a_log_without_accelerometer_reads_the_specific_force_of_its_mounts(logs, tmp_path):
    """The turntable's axis points up (the log contract): a unit mounted with ``+a`` along it
    feels +1 g along ``a``. Where no accelerometer is logged each hold's specific force is
    its mount's, said so in ``accel_source``. The simulator's gravity is the mount's exactly,
    so where the accelerometer is logged its hold means differ from it by that sensor's
    noise over a hold alone (5 sigma of its 0.002 g a sample)."""
    table = pq.read_table(logs["complete"])
    logged = segment_file(logs["complete"])[1].observations
    assert "accel_source" not in logged
    path = tmp_path / "no_accel.parquet"
    pq.write_table(table.drop(["accel_x", "accel_y", "accel_z"]), path)
    obs = segment_file(path)[1].observations
    assert (obs["accel_source"] == "mount").all()
    force = obs[["accel_x", "accel_y", "accel_z"]].to_numpy()
    for mount, f in zip(obs["mount"].astype(str), force, strict=True):
        expected = np.zeros(3)
        expected["xyz".index(mount[1])] = 1.0 if mount[0] == "+" else -1.0
        assert np.array_equal(f, expected), (mount, f)
    same = logged.set_index("t_start").loc[obs["t_start"], ["accel_x", "accel_y", "accel_z"]].to_numpy()
    sigma = GyroUnit().accel_noise / np.sqrt(obs["n"].to_numpy(float))[:, None]
    assert np.all(np.abs(same - force) < 5 * sigma), np.abs(same - force).max()


def test_a_protocol_without_a_mount_still_segments(tmp_path):
    path = make_log(tmp_path, "two_mounts", mounts=("+x", "+z"), temperatures=(0.0, 20.0))
    _, seg = segment_file(path)
    assert set(seg.observations["mount"].astype(str)) == {"+x", "+z"}


def test_unstable_temperature_is_rejected(tmp_path):
    # the chamber keeps ramping: no soak, so early holds sit on a temperature transient
    path = make_log(tmp_path, "ramping", temperatures=(40.0,), soak_s=1.0, unit_tau_s=60.0)
    _, seg = segment_file(path)
    assert "unstable_temperature" in set(seg.rejected()["reason"])


def test_saturated_holds_are_rejected(tmp_path):
    from gyrocal.simulate import GyroUnit

    path = make_log(
        tmp_path,
        "clip",
        unit=GyroUnit.seed000(full_scale=300.0),
        temperatures=(20.0,),
        rates=(10.0, 100.0, 400.0),
    )
    _, seg = segment_file(path)
    rejected = seg.rejected()
    saturated = rejected[rejected["reason"] == "saturated"]
    assert len(saturated) == 6  # ±400 deg/s on three mounts
    assert (seg.observations["ref_rate"].abs() < 300).all()


def test_configured_full_scale_finds_the_same_saturation(tmp_path):
    from gyrocal.simulate import GyroUnit

    path = make_log(
        tmp_path,
        "clip",
        unit=GyroUnit.seed000(full_scale=300.0),
        temperatures=(20.0,),
        rates=(10.0, 100.0, 400.0),
    )
    _, seg = segment_file(path, SegmentConfig(full_scale=300.0))
    assert (seg.rejected()["reason"] == "saturated").sum() == 6
    _, seg = segment_file(path, SegmentConfig(full_scale=2000.0))  # a wider range: nothing clips
    assert "saturated" not in set(seg.rejected()["reason"])


@pytest.mark.parametrize(
    "values, message",
    [
        ({"block_s": None}, "segmentation.block_s must be a number"),
        ({"noise_cap": 0}, "segmentation.noise_cap must be at least 1"),
        ({"block_s": 0}, "segmentation.block_s must be more than 0"),
        ({"bogus": 1}, "unknown setting segmentation.bogus"),
        ({"trim_s": True}, "segmentation.trim_s must be a number"),
    ],
)
def test_bad_settings_are_refused_by_name(values, message):
    from gyrocal.io.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        SegmentConfig.from_dict(values)


def test_short_holds_get_shorter_blocks(tmp_path):
    path = make_log(tmp_path, "short", temperatures=(0.0, 20.0), hold_s=2.0, handling_s=3.0)
    log, seg = segment_file(path)
    truth = load_truth(path)
    found = match(seg.observations, truth["holds"])
    assert seg.info["block_samples"] < 50
    assert sum(len(f) == 1 for f in found) >= len(truth["holds"]) - 2 * 2  # at most the
    # rate-0 holds right after handling fall short of the settling margin


def test_too_short_log_is_refused(tmp_path):
    t = np.arange(20) * 0.01
    z = np.zeros(20, np.float32)
    path = tmp_path / "short.parquet"
    pq.write_table(pa.table({"t": t, "gyro_x": z, "gyro_y": z, "gyro_z": z, "temp": z, "ref_rate": t}), path)
    with pytest.raises(SegmentationError) as info:
        segment_file(path)
    assert str(path) in str(info.value)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@example(
    levels=[0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
    lengths=[1, 1, 1, 98, 150, 149, 1, 1],
    noise=0.0,
    jitter=0.0,
    seed=0,
    gap_at=0,
    mount=False,
)  # once crashed: no hold long enough
@given(
    levels=st.lists(st.floats(-500, 500, allow_nan=False), min_size=1, max_size=8),
    lengths=st.lists(st.integers(1, 400), min_size=8, max_size=8),
    noise=st.floats(0.0, 5.0),
    jitter=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**16),
    gap_at=st.integers(-1, 2000),
    mount=st.booleans(),
)
def test_any_log_segments_or_fails_cleanly(tmp_path, levels, lengths, noise, jitter, seed, gap_at, mount):
    rng = np.random.default_rng(seed)
    ref = np.concatenate([np.full(n, v) for v, n in zip(levels, lengths, strict=False)])
    n = len(ref)
    t = np.arange(n) * 0.01
    if 0 <= gap_at < n:
        t[gap_at:] += 5.0
    axis = rng.integers(0, 3)
    cols = {
        "t": t,
        "temp": (20 + rng.normal(0, jitter, n)).astype(np.float32),
        "ref_rate": ref + rng.normal(0, jitter * 1e-3, n),
    }
    for i, c in enumerate("xyz"):
        cols[f"gyro_{c}"] = ((ref if i == axis else 0) + rng.normal(0, noise, n)).astype(np.float32)
    if mount:
        cols["mount"] = pa.array(rng.choice(["+x", "-y", "+z"], n).tolist())
    path = tmp_path / "h.parquet"
    pq.write_table(pa.table(cols), path)
    try:
        seg = segment(read_log(path, optional=LOG_COLUMNS), SegmentConfig())
    except GyrocalError as exc:
        assert "\n" not in str(exc)
    else:
        obs = seg.observations
        assert len(obs) >= 1
        assert np.all(np.isfinite(obs[["gyro_x", "gyro_y", "gyro_z", "temp"]].to_numpy()))
        assert (obs["t_end"] > obs["t_start"]).all()


def test_temperature_points_chain_set_points_by_gap_and_cut_a_ramp_into_bins():
    """A turntable's set points are chains of holds each within the gap of the next,
    however far the chain reaches; a sweep's ramp is cut into bins aligned to 0 °C."""
    temp = np.array([19.0, 21.5, 20.2, 45.0, 44.0, 70.0, 23.4])
    by_gap = temperature_points(temp, gap=2.0)
    assert by_gap.point.tolist() == [0, 0, 0, 1, 1, 2, 0]  # 19 … 23.4 in steps under 2 °C
    assert by_gap.point_temp[0] == pytest.approx(np.mean([19.0, 21.5, 20.2, 23.4]), abs=1e-12)
    by_bin = temperature_points(temp, span=10.0)
    assert by_bin.point.tolist() == [0, 1, 1, 2, 2, 3, 1]  # [10, 20), [20, 30), [40, 50), [70, 80)
    assert by_bin.point_temp[1] == pytest.approx(np.mean([21.5, 20.2, 23.4]), abs=1e-12)
    with pytest.raises(ValueError):
        temperature_points(temp)
