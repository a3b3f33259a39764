"""Check the generator's own claims with numpy alone; prints the figures, exits 1 on failure.

    /work/main/.venv/bin/python tests/protocols/chamber/selfcheck.py      (a few seconds)

Allan-deviation tolerance: an estimate from K = floor(N/m) clusters has a relative 1-sigma
error of about 1/sqrt(2(K-1)) (the usual non-overlapping figure; the overlapping estimator
used here is no worse).  Averaging the Allan variance of A independent axes (or bursts)
divides it by sqrt(A).  A check passes within 3 sigma.
"""
from __future__ import annotations

import hashlib
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

try:
    from . import generator as g
except ImportError:                                   # run as a script
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import generator as g

FAILS: list[str] = []


def check(name: str, ok: bool, figures: str) -> None:
    print(f"[{'ok' if ok else 'FAIL'}] {name}: {figures}")
    if not ok:
        FAILS.append(name)


def rel_sigma(n: int, m: int, pooled: int) -> float:
    """1-sigma relative error of an ADEV estimate (see module docstring)."""
    k = n // m
    return 1.0 / np.sqrt(2.0 * max(k - 1, 1) * pooled)


def avar_sums(y: np.ndarray, m: int) -> tuple[float, int]:
    """Sum of squared overlapping Allan differences (in rate units * m) and their count."""
    th = np.concatenate(([0.0], np.cumsum(y - y.mean())))
    d = th[2 * m:] - 2 * th[m:-m] + th[:-2 * m]
    return float(np.sum(d ** 2)), d.size


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_all(out: Path, seed_c: int, seed_h: int) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for rec in (g.chamber_burst_log(seed_c), g.host_stamped_log(seed_h)):
        files.update({f"{rec.kind}.{k}": p for k, p in g.write_raw(rec, out).items()})
        files[f"{rec.kind}.contract"] = g.write_contract(rec, out / f"{rec.stem}_contract.parquet")
        files[f"{rec.kind}.contract_rad"] = g.write_contract(
            rec, out / f"{rec.stem}_contract_rad.parquet", units="rad/s")
    return files


def main() -> int:
    tmp = Path(tempfile.mkdtemp(prefix="chamber_selfcheck_"))
    print(f"scratch files in {tmp} (removed at the end)\n")

    # ------------------------------------------------------------------ chamber log
    rec = g.chamber_burst_log(seed=1)
    tr, raw, smp = rec.truth, rec.raw, rec.samples
    paths = g.write_raw(rec, tmp / "a")
    csv = pd.read_csv(paths["csv"])
    par = pq.read_table(paths["parquet"]).to_pandas()
    same_csv = list(csv.columns) == list(raw.columns) and all(
        np.array_equal(csv[c].to_numpy(), raw[c].to_numpy()) for c in raw.columns)
    check("chamber CSV == Parquet == memory", same_csv and par.equals(raw),
          f"{len(raw)} rows, columns {list(raw.columns)}, dtypes "
          f"{dict(par.dtypes.astype(str))} (CSV values bit-equal)")

    b = tr["bursts"]
    tms = raw["time_ms"].to_numpy()
    starts = np.flatnonzero(np.r_[True, np.diff(tms) > 1000])        # gaps split bursts
    sizes = np.diff(np.r_[starts, tms.size])
    steps = np.diff(tms)[np.diff(tms) <= 1000]
    period = np.diff(tms[starts])
    check("burst layout",
          starts.size == b["n_bursts"] and np.all(sizes == b["samples_per_burst"])
          and np.all(steps == b["step_ms"]) and np.all(period == b["period_s"] * 1000)
          and np.array_equal(tms[starts], b["start_ms"]),
          f"{starts.size} bursts x {set(sizes.tolist())} samples, step {set(steps.tolist())} ms, "
          f"period {set(period.tolist())} ms, span {(tms[-1] - tms[0]) / 3.6e6:.3f} h")

    tc = tr["raw"]["temp_counts"]
    back = raw["temp_raw"].to_numpy() / tc["lsb_per_c"] + tc["offset_c"]
    exact = np.array_equal(raw["temp_raw"].to_numpy(),
                           np.round(tc["lsb_per_c"] * (smp["measured_c"] - tc["offset_c"])).astype(np.int16))
    err_q = np.abs(back - smp["measured_c"]).max()
    err_s = (back - smp["sensor_c"]).std()
    want_s = np.hypot(tr["temperature"]["sensor_noise_c"], 1 / tc["lsb_per_c"] / np.sqrt(12))
    check("counts <-> degC", exact and err_q <= 0.5 / tc["lsb_per_c"] + 1e-12
          and abs(err_s / want_s - 1) < 0.1,
          f"counts = round({tc['lsb_per_c']}*(T - {tc['offset_c']})), at 22 degC "
          f"{raw['temp_raw'].iloc[0]} counts; max |back - measured| {err_q:.5f} degC "
          f"(half LSB {0.5 / tc['lsb_per_c']:.5f}); sd(back - true) {err_s:.4f} vs {want_s:.4f}; "
          f"range {back.max():.2f} -> {back.min():.2f} degC")

    con = pq.read_table(g.write_contract(rec, tmp / "a" / "contract.parquet")).to_pandas()
    con_rad = g.to_contract(rec, "rad/s")
    gyro_deg = con[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    f = tr["raw"]["driver_factor"]
    algebra = np.allclose(np.radians(gyro_deg) * f, raw[["gx", "gy", "gz"]], rtol=1e-14, atol=0)
    # physics: regress raw burst means on the noise-free rate (rad/s); slope = driver factor
    clean = smp[["clean_x", "clean_y", "clean_z"]].to_numpy()
    n_b, L = b["n_bursts"], b["samples_per_burst"]
    rm = raw[["gx", "gy", "gz"]].to_numpy().reshape(n_b, L, 3).mean(1).ravel()
    cm = np.radians(clean.reshape(n_b, L, 3).mean(1)).ravel()
    slope = np.sum(rm * cm) / np.sum(cm * cm)
    check("driver factor", algebra and abs(slope / f - 1) < 0.02,
          f"raw = {f} x rad/s exactly in the contract conversion; fitted raw/true slope {slope:.4f}")
    check("contract form",
          list(con.columns) == ["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "burst"]
          and np.all(np.diff(con["t"]) > 0) and np.all(con["ref_rate"] == 0)
          and con_rad.schema.metadata[b"gyrocal.units"] == b'{"gyro": "rad/s", "ref_rate": "rad/s"}'
          and np.allclose(con_rad.column("gyro_x").to_numpy(), np.radians(con["gyro_x"]), rtol=1e-14),
          f"columns {list(con.columns)}, t {con['t'].iloc[0]:.3f} .. {con['t'].iloc[-1]:.3f} s")

    # noise within bursts: residual = contract rate - noise-free truth, pooled Allan variance
    res = (gyro_deg - clean).reshape(n_b, L, 3)
    fs = b["rate_hz"]
    model = g.NoiseModel.from_truth(tr)
    for tau in (0.2, 1.0, 2.0):
        m = int(round(tau * fs))
        sums = [avar_sums(res[i, :, a], m) for i in range(n_b) for a in range(3)]
        est = np.sqrt(sum(s for s, _ in sums) / sum(c for _, c in sums) / (2 * m ** 2)) * 3600
        want = model.adev(tau, fs) * 3600
        sig = rel_sigma(L, m, 3 * n_b)
        check(f"chamber ADEV tau={tau:g} s (in-burst, pooled)", abs(est / want - 1) < 3 * sig,
              f"{est:.2f} deg/h vs analytic {want:.2f} (ratio {est / want:.3f}, 1-sigma {sig:.3f})")

    earth = np.asarray(tr["earth"]["body_deg_s"])
    mean_res = np.nanmean(res, axis=1)                               # burst means - truth
    t_mid = np.asarray(b["t_mid_s"])
    gm_var = sum(s ** 2 for _, s in model.gm_terms())
    pred = np.sqrt((model.n_deg_rt_s ** 2 * fs + (model.lsb_deg_s or 0) ** 2 / 12) / L
                   + gm_var + model.k_deg_rt_s3 ** 2 * t_mid.mean())
    rms = np.sqrt(np.mean(mean_res ** 2))
    dT = np.asarray(b["die_c"]) - tr["bias"]["t_ref_c"]
    bm = gyro_deg.reshape(n_b, L, 3).mean(1) - earth
    fit = np.array([np.polyfit(dT, bm[:, a], 2)[::-1] for a in range(3)])  # b0, b1, b2
    check("burst means = bias(T) + Earth + noise", 0.2 < rms / pred < 3,
          f"rms(mean - truth) {rms * 1e3:.2f} mdeg/s vs predicted {pred * 1e3:.2f}; "
          f"quadratic fit b0 {np.round(fit[:, 0], 3).tolist()} (true {tr['bias']['b0_deg_s']}), "
          f"b1 {np.round(fit[:, 1], 4).tolist()} (true {tr['bias']['b1_deg_s_per_c']}), "
          f"b2 {np.round(fit[:, 2], 5).tolist()} (true {tr['bias']['b2_deg_s_per_c2']})")

    h = g.chamber_burst_log(seed=1, die_lag_s=600.0).samples
    t2 = h["t_s"].to_numpy().reshape(n_b, L)
    d2 = h["die_c"].to_numpy().reshape(n_b, L)
    s2 = h["sensor_c"].to_numpy().reshape(n_b, L)
    lhs = np.gradient(d2, axis=1) / np.gradient(t2, axis=1)
    rhs = (s2 - d2) / 600.0
    check("die lag obeys dTd/dt = (Ts - Td)/lag", np.allclose(lhs, rhs, atol=1e-6),
          f"max |residual| {np.abs(lhs - rhs).max():.1e} degC/s; die - sensor at 30 min "
          f"{(d2 - s2)[6, 0]:.3f} degC")

    hl = rec.hand
    check("hand log", len(hl) == 13 and hl["chamber_c"].iloc[0] == 22.0,
          f"{len(hl)} readings every {tr['hand_log']['period_s']:.0f} s: "
          f"{hl['chamber_c'].tolist()}")

    nrm = np.linalg.norm(earth) * 3600
    check("Earth rate", abs(nrm - 15.041) < 0.001 and tr["earth"]["up_axis"] == "+z"
          and abs(earth[2] * 3600 - 15.041 * np.sin(np.radians(48))) < 0.001,
          f"|w| {nrm:.4f} deg/h, body {np.round(earth * 3600, 4).tolist()} deg/h at 48 deg, up {tr['earth']['up_axis']}")

    # ------------------------------------------------------------------ host log
    hrec = g.host_stamped_log(seed=2)
    ht, hr, hs = hrec.truth, hrec.raw, hrec.samples
    st = ht["stamps"]
    step = np.diff(np.round(hr["t"].to_numpy() * 1000)).astype(int)
    gap_idx = np.asarray(st["stall_gap_index"]) - 1                  # step ending at a bunch
    big = np.flatnonzero(step > st["max_normal_step_ms"])
    lag_ms = (hs["t_stamp"] - hs["t_sample"]).to_numpy() * 1000
    check("host stamps", step.min() >= 1 and step.max() <= 500 and abs(step.mean() - 10) < 0.05
          and set(big) <= set(gap_idx) and lag_ms.min() >= -0.5,
          f"{len(hr)} samples over {(hr['t'].iloc[-1] - hr['t'].iloc[0]) / 60:.2f} min; step ms "
          f"min {step.min()} / p5 {np.percentile(step, 5):g} / median {np.median(step):g} / mean "
          f"{step.mean():.4f} / p95 {np.percentile(step, 95):g} / max {step.max()}; "
          f"normal steps <= {step[np.setdiff1d(np.arange(step.size), gap_idx)].max()} ms; "
          f"{len(st['stalls'])} stalls "
          f"({sum(s['n_bunched'] for s in st['stalls'])} samples bunched, gaps "
          f"{step[gap_idx].min()}..{step[gap_idx].max()} ms); stamp - sample "
          f"{lag_ms.min():.1f}..{lag_ms.max():.1f} ms")
    ts = hs["t_sample"].to_numpy()
    check("host sample clock regular", np.allclose(np.diff(ts), 1 / ht["true_sample_rate_hz"], atol=1e-6),
          f"{ht['true_sample_rate_hz']} Hz; stamps NOT regular: sd(step) {step.std():.2f} ms")
    check("host columns / contract", list(hr.columns) == ["t", "gyro_x", "gyro_y", "gyro_z", "temp"]
          and list(g.to_contract(hrec).column_names) == ["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"],
          f"raw {list(hr.columns)}, temp {hr['temp'].mean():.3f} +- {hr['temp'].std():.3f} degC")

    hfs = ht["true_sample_rate_hz"]
    hres = hr[["gyro_x", "gyro_y", "gyro_z"]].to_numpy() - hs[["clean_x", "clean_y", "clean_z"]].to_numpy()
    for tau, want in zip(ht["allan"]["tau_s"], ht["allan"]["adev_deg_h"]):
        est = np.sqrt(np.mean([g.overlapping_adev(hres[:, a], hfs, [tau])[0] ** 2 for a in range(3)])) * 3600
        sig = rel_sigma(len(hr), int(round(tau * hfs)), 3)
        check(f"host ADEV tau={tau:g} s (11 min, 3 axes)", abs(est / want - 1) < 3 * sig,
              f"{est:.2f} deg/h vs analytic {want:.2f} (ratio {est / want:.3f}, 1-sigma {sig:.3f})")

    # ------------------------------------------------------------------ long noise run
    fs_l, n_l = 10.0, int(24 * 3600 * 10)                            # 24 h at 10 Hz
    rng = np.random.default_rng(12345)
    nm = g.NoiseModel()
    y = np.round((0.8 + g.simulate_noise(np.arange(n_l) / fs_l, nm, fs_l, rng)) / nm.lsb_deg_s) * nm.lsb_deg_s
    for tau in (1.0, 10.0, 100.0, 1000.0):
        est = np.sqrt(np.mean([g.overlapping_adev(y[:, a], fs_l, [tau])[0] ** 2
                               for a in range(3)])) * 3600
        want = nm.adev(tau, fs_l) * 3600
        sig = rel_sigma(n_l, int(tau * fs_l), 3)
        comp = {k: round(float(np.sqrt(v) * 3600), 2) for k, v in nm.avar_components(tau, fs_l).items()}
        check(f"noise ADEV tau={tau:g} s (24 h, 3 axes)", abs(est / want - 1) < 3 * sig,
              f"{est:.3f} deg/h vs analytic {want:.3f} (ratio {est / want:.3f}, 1-sigma {sig:.3f}); "
              f"components {comp}")
    print(f"      analytic minimum {ht['allan']['adev_min_deg_h']:.2f} deg/h at tau "
          f"{ht['allan']['tau_at_min_s']:.0f} s; 0.664*B = {ht['noise']['bias_instability_plateau_deg_h']:.2f} deg/h")

    # ------------------------------------------------------------------ determinism
    f1, f2 = write_all(tmp / "d1", 1, 2), write_all(tmp / "d2", 1, 2)
    same = all(sha(f1[k]) == sha(f2[k]) for k in f1)
    f3 = write_all(tmp / "d3", 11, 12)
    differ = sha(f1["chamber_burst.csv"]) != sha(f3["chamber_burst.csv"])
    check("determinism", same and differ,
          f"{len(f1)} files byte-identical across two runs; another seed differs; "
          f"chamber csv sha256 {sha(f1['chamber_burst.csv'])[:16]}, "
          f"host csv {sha(f1['host_stamped.csv'])[:16]}")

    shutil.rmtree(tmp)                                 # scratch files only
    print(f"\n{'ALL OK' if not FAILS else 'FAILED: ' + ', '.join(FAILS)}")
    return 1 if FAILS else 0


if __name__ == "__main__":
    sys.exit(main())
