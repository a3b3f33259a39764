"""Static logs as labs record them, read by the sweep and static protocols, on recordings
from the generator in ``chamber/`` (written from the log contract and the physics without
reading gyrocal): a thermal-vacuum chamber's 5-s bursts every 5 minutes, imported with a
map alone and calibrated with the default settings; a host-stamped consumer IMU whose noise
comes out with the defaults and agrees with allantools; what bursts let the diagnosis judge.
And the pieces: stalls told from gaps, the temperature points of a short sweep."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from gyrocal.io.stamps import sampling
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings
from gyrocal.protocols.sweep.protocol import auto_point_span
from gyrocal.run import cli

from .chamber.generator import NoiseModel, chamber_burst_log, host_stamped_log, write_contract, write_raw
from .conftest import needs

try:
    import allantools
except ImportError:  # pragma: no cover - a test dependency
    allantools = None

CHAMBER_MAP = """\
format: csv
time: {column: time_ms, unit: ms}
gyro: {x: gx, y: gy, z: gz, unit: counts, sensitivity: %r}
temp: {column: temp_raw, unit: counts, sensitivity: 340, offset: -12420.2}
ref_rate: {value: 0}
"""


def run(capsys, *args) -> tuple[int, str, str]:
    status = cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


# --- time stamps ------------------------------------------------------------------------------


def test_stalls_made_up_by_bunches_are_no_gaps_and_a_pause_is_one():
    rate = 100.0
    sample = np.arange(60_000) / rate
    # a host stalls 0.4 s, then delivers what fell due in a bunch 1 ms apart
    stamps = sample.copy()
    stall = (sample >= 100.0) & (sample < 100.4)
    stamps[stall] = 100.4 + 0.001 * np.arange(stall.sum())
    stamps = np.maximum.accumulate(stamps + 1e-9 * np.arange(len(stamps)))
    s = sampling(stamps)
    assert len(s.run_starts) == 1 and s.stalls == 1
    assert s.longest_stall_s == pytest.approx(0.4, abs=0.02)
    assert s.rate == pytest.approx(rate, rel=1e-3)
    assert s.bursty and "stalls" in s.warning()
    # a logger that pauses for a minute: two runs, the rate from within them
    paused = np.r_[sample[:30_000], sample[30_000:] + 60.0]
    p = sampling(paused)
    assert list(p.run_starts) == [0, 30_000] and p.stalls == 0
    assert p.rate == pytest.approx(rate, rel=1e-9) and p.warning() is None


@pytest.mark.parametrize("rate_hz", [100.0, 200.0])
def test_a_faster_host_and_packets_are_one_run_at_the_sensors_rate(rate_hz):
    """Arrivals in bunches make the median interval the bunch's spacing (1 ms); the rate is
    read over spans of samples, so neither a 200-Hz host nor packets of two split the log."""
    t = host_stamped_log(2, duration_s=300.0, rate_hz=rate_hz).raw["t"].to_numpy(float)
    s = sampling(t - t[0])
    assert len(s.run_starts) == 1 and s.rate == pytest.approx(rate_hz, rel=1e-3)
    k = np.arange(60_000)
    packets = (k // 2) * 0.02 + (k % 2) * 1e-3
    p = sampling(packets)
    assert len(p.run_starts) == 1 and p.rate == pytest.approx(100.0, rel=1e-3)


def test_slow_sweeps_and_pauses_keep_their_windows_and_their_count():
    from gyrocal.io.log import RigLog
    from gyrocal.protocols.sweep.windows import sweep_windows

    def log(t):
        n = len(t)
        rng = np.random.default_rng(1)
        batch = {
            "t": t,
            "temp": -10 + 0.01 * t,
            "ref_rate": np.zeros(n),
            **{f"gyro_{a}": rng.normal(0, 0.02, n) for a in "xyz"},
        }
        return RigLog("x", (batch,), n, 0)

    slow = sweep_windows(log(np.arange(3600.0)), window_s=5.0, min_span=0.5)  # 1 Hz: 5 a window
    assert len(slow) == 720
    t = np.arange(0, 3600, 0.1)
    paused = sweep_windows(log(t[(t < 1200) | (t >= 3000)]), min_span=0.5)
    # the 30-min pause lost 90 windows, and they count as such (the fleet's hold share)
    assert len(paused) == 90 and paused.attrs["windows_total"] == 180
    assert paused.attrs["dropped"]["incomplete"] == 90


def test_bursts_are_runs_with_the_rate_of_their_samples():
    t = (np.arange(25)[:, None] * 300.0 + np.arange(250)[None, :] / 50.0).ravel()
    s = sampling(t)
    assert len(s.run_starts) == 25 and s.stalls == 0
    assert s.rate == pytest.approx(50.0, rel=1e-9)


def test_a_short_sweep_gets_narrow_temperature_points():
    assert auto_point_span(np.linspace(-40, 85, 50)) == 10.0
    assert auto_point_span(np.linspace(10, 22, 25)) == 1.0
    assert auto_point_span(np.full(5, 25.0)) == 0.5


# --- a chamber's burst log ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def chamber(tmp_path_factory):
    """The recording as the lab's script dumped it, its map, and the imported log."""
    rec = chamber_burst_log(1)
    folder = tmp_path_factory.mktemp("chamber")
    files = write_raw(rec, folder)
    factor = rec.truth["raw"]["driver_factor"]
    (folder / "map.yaml").write_text(CHAMBER_MAP % (np.pi / 180.0 * factor))
    log = folder / "chamber.parquet"
    assert cli.main(["import", str(files["csv"]), "--map", str(folder / "map.yaml"), "-o", str(log)]) == 0
    return rec, folder, log


def test_a_chamber_burst_log_imports_with_a_map_and_calibrates_one_window_per_burst(chamber, capsys):
    rec, folder, log = chamber
    truth = rec.truth
    status, out, err = run(capsys, "calibrate", log, "--protocol", "sweep", "-o", folder / "cal.json")
    assert status == 0, err
    bursts = len(truth["bursts"]["die_c"])
    assert f"{bursts} holds" in out
    cal = json.loads((folder / "cal.json").read_text())
    noise = cal["noise"]
    assert noise["floor"] == "noise model of the static stretches"
    # 5-s bursts resolve the noise to a few seconds only, and the file says so
    assert noise["resolves"]["tau_max_s"] < 5.0 and "not measured" in noise["resolves"]["text"]
    # one window per burst: each starts at a burst's first sample and holds all of it
    t = pq.read_table(log, columns=["t"]).column("t").to_numpy()
    first = t[np.r_[0, np.flatnonzero(np.diff(t) > 1.0) + 1]]
    holds = segment_log(log, Settings().for_protocol("sweep"), "sweep").observations
    np.testing.assert_allclose(np.sort(holds["t_start"].to_numpy()), first, atol=1e-9)
    np.testing.assert_allclose(holds["t_end"] - holds["t_start"], 249 / 50.0, atol=1e-6)
    # compensated, each burst's mean is what a line through the true bias leaves: the truth's
    # curvature, within the noise of a 5-s mean and the wander between bursts (the truth's
    # Allan deviation at 100 s), five sigma
    assert cli.main(["apply", str(folder / "cal.json"), str(log), "-o", str(folder / "out.parquet")]) == 0
    comp = pq.read_table(folder / "out.parquet").to_pandas()
    burst = np.cumsum(np.r_[0, np.diff(comp["t"].to_numpy()) > 1.0])
    burst_mean = comp.groupby(burst)[["gyro_x", "gyro_y", "gyro_z"]].mean().to_numpy()
    temps = comp.groupby(burst)["temp"].mean().to_numpy()
    expected = np.asarray(truth["bursts"]["expected_deg_s"], float)
    design = np.column_stack([np.ones_like(temps), temps])
    line = design @ np.linalg.lstsq(design, expected, rcond=None)[0]
    allan = truth["allan"]
    sigma = np.hypot(
        np.asarray(allan["components_deg_h"]["white"])[0] / 3600 / np.sqrt(5.0),
        np.sqrt(2.0) * np.asarray(allan["adev_deg_s"])[2],
    )
    np.testing.assert_array_less(np.abs(burst_mean - (expected - line)), 5 * sigma)
    # without the map's conversions the bias would be off by the driver's factor of two
    assert np.abs(expected - line).max() < 0.1 * np.abs(np.diff(expected[[0, -1]], axis=0)).max()


def test_a_turntable_calibration_of_a_still_log_names_the_protocols_that_read_it(chamber, capsys):
    _, folder, log = chamber
    status, _, err = run(capsys, "calibrate", log, "-o", folder / "refused.json")
    assert status != 0 and "Traceback" not in err
    assert "the reference rate is 0 throughout" in err and "--protocol sweep" in err
    assert len(err.strip().splitlines()) == 1


def test_points_too_thin_to_calibrate_alone_name_the_setting_that_widens_them(chamber, capsys, tmp_path):
    _, folder, log = chamber
    settings = json.dumps({"protocols": {"sweep": {"options": {"point_span": 0.001}}}})
    status, _, err = run(
        capsys,
        "calibrate",
        log,
        "--protocol",
        "sweep",
        "-o",
        tmp_path / "c.json",
        "--settings-json",
        settings,
    )
    assert status != 0 and len(err.strip().splitlines()) == 1
    assert str(log) in err and "point_span" in err and "Traceback" not in err


def test_bursts_let_the_diagnosis_judge_a_lag_and_say_when_wander_hides_the_rest(tmp_path, capsys):
    """With a quiet sensor, a die lagging the sensor 900 s is named, its time constant within
    its standard error's reach; without an effect, nothing is. With the datasheet's wander
    (bias instability 10 deg/h, random walk 30 deg/h/sqrt(h)) the bursts cannot rule out that
    the wander makes the scatter: said, not a name."""
    quiet = NoiseModel(bi_deg_h=2.0, rrw_deg_h_rt_h=2.0)
    cases = {
        "lag": dict(die_lag_s=900.0, b2=(0.0, 0.0, 0.0), noise=quiet),
        "none": dict(b2=(0.0, 0.0, 0.0), noise=quiet),
        "wander": dict(b2=(0.0, 0.0, 0.0)),
    }
    verdicts = {}
    for name, kw in cases.items():
        log = write_contract(chamber_burst_log(2, **kw), tmp_path / f"{name}.parquet")
        status, _, err = run(capsys, "diagnose", log, "--protocol", "sweep", "-o", tmp_path / f"{name}.json")
        assert status == 0, err
        verdicts[name] = json.loads((tmp_path / f"{name}.json").read_text())
    lag = verdicts["lag"]["best"]
    assert lag["term"] == "temp_lag"
    (profiled,) = lag["profiled"]
    tau, tau_se = profiled["value"], profiled["stderr"]
    assert abs(tau - 900.0) < 4 * tau_se + 0.05 * 900.0
    assert verdicts["none"]["best"] is None and verdicts["none"]["explains_the_data"]
    wander = verdicts["wander"]
    assert wander["best"] is None and wander["within_noise_uncertainty"]["explains"]


# --- a host-stamped static log ------------------------------------------------------------------


@needs({"allantools": allantools is not None}, "pip install allantools")
def test_a_host_stamped_static_log_gets_its_noise_with_the_defaults_as_allantools_does(tmp_path, capsys):
    rec = host_stamped_log(2)
    log = write_contract(rec, tmp_path / "host.parquet")
    status, out, err = run(capsys, "noise", log, "-o", tmp_path / "noise.json")
    assert status == 0, err
    noise = json.loads((tmp_path / "noise.json").read_text())
    assert noise["stretches"] == 1, "a stall of arrival stamps does not cut the stretch"
    t = pq.read_table(log, columns=["t"]).column("t").to_numpy()
    assert noise["static_seconds"] == pytest.approx(t[-1] - t[0], rel=0.01)
    allan = noise["session"]["allan"]
    tau, adev = np.asarray(allan["tau_s"]), np.asarray(allan["adev"])
    table = pq.read_table(log).to_pandas()
    rate = (len(t) - 1) / (t[-1] - t[0])  # samples over time, as allantools is given
    for k, axis in enumerate("xyz"):
        taus, ref, _, _ = allantools.oadev(
            table[f"gyro_{axis}"].to_numpy(), rate=rate, data_type="freq", taus=tau
        )
        np.testing.assert_allclose(adev[: len(ref), k], ref, rtol=0.10)
    # the angle random walk within three of its standard errors of the generator's
    terms = noise["session"]["terms"]
    arw_true = rec.truth["noise"]["model"]["arw_deg_rt_h"]
    assert np.all(
        np.abs(np.asarray(terms["arw"]) - arw_true) < 3 * np.asarray(terms["arw_stderr"]) + 0.02 * arw_true
    )
    # without a reference column it is read as still too
    table.drop(columns=["ref_rate"]).to_parquet(tmp_path / "noref.parquet")
    status, out, err = run(capsys, "noise", tmp_path / "noref.parquet")
    assert status == 0 and "1 static stretches" in out, err
    # calibrated as a still unit, the bursty stamps are said
    status, _, err = run(capsys, "calibrate", log, "--protocol", "static", "-o", tmp_path / "cal.json")
    assert status == 0, err
    warnings = json.loads((tmp_path / "cal.json").read_text())["warnings"]
    jitter = [w for w in warnings if w["code"] == "sample_jitter"]
    assert jitter and "stalls" in jitter[0]["message"] and "samples over time" in jitter[0]["message"]
