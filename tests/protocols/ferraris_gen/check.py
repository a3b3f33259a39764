"""Checks of the synthetic Ferraris generator against its own physics, a tiny reference Ferraris
calibration, and the real recording.  Run:  .venv/bin/python tests/protocols/ferraris_gen/check.py [--seed S]

1. Kinematics: (a) integrating the analytic body rate with the exponential map reproduces the
   closed-form end attitude of every turn and handling move; (b) the rectangle sum of the true
   hand rate at the log's own sample times equals its Gauss-Legendre integral to < 1e-6 deg, and
   that equals the recorded truth; (c) with wobble off, the integral is exactly angle_deg times the
   tilted turn axis; with wobble on, the (second-order) difference is shown.
2. A reference Ferraris calibration (bias = mean of the six face means; column j of K = integrated
   (w - b) over turn j / its angle) recovers K and b within the noise-propagated sigma on `clean`;
   the other calibrate kinds are shown too (gsens removes G estimated from opposite faces).
3. Realism: the same motion detector applied to the real session and to synthetic ones.
4. The bad kinds show their defect in the data; the same seed gives the same bytes.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generate as gen  # noqa: E402

REAL = Path("/work/shared/real/imucal-ferraris")
AX = "xyz"
OK = {True: "ok  ", False: "FAIL"}
failures = []


def report(ok, msg):
    print(f"  [{OK[bool(ok)]}] {msg}")
    if not ok:
        failures.append(msg)


# ----------------------------------------------------------------------------- 1. kinematics
def chain(mats):
    """Ordered product M0 @ M1 @ ... by pairwise batched reduction (fast, order-preserving)."""
    while len(mats) > 1:
        if len(mats) % 2:
            mats = np.concatenate([mats, np.eye(3)[None]])
        mats = mats[0::2] @ mats[1::2]
    return mats[0]


def attitude_error_deg(seg, h=2e-5):
    """Integrate R' = R [w]x with midpoint exponential-map steps; angle to the closed-form R(t1)."""
    n = int(np.ceil((seg.t1 - seg.t0) / h))
    h = (seg.t1 - seg.t0) / n
    tm = seg.t0 + (np.arange(n) + 0.5) * h
    _, w = gen.kinematics(seg, tm)
    R = gen.kinematics(seg, np.array([seg.t0]))[0][0] @ chain(Rotation.from_rotvec(w * h).as_matrix())
    R1 = gen.kinematics(seg, np.array([seg.t1]))[0][0]
    return np.degrees(Rotation.from_matrix(R1.T @ R).magnitude())


def check_kinematics(sess):
    tr = sess.truth
    turns = [s for s in sess.segs if isinstance(s, gen.Turn)]
    moves = [s for s in sess.segs if isinstance(s, gen.Move)]
    err_t = max(attitude_error_deg(s) for s in turns)
    err_m = max(attitude_error_deg(s) for s in moves)
    report(err_t < 1e-6 and err_m < 1e-6,
           f"{sess.kind}: exp-map integral of body rate vs closed-form attitude: turns {err_t:.1e} deg, "
           f"moves {err_m:.1e} deg")
    worst_sum = worst_gl = worst_truth = worst_flat = 0.0
    cone = []
    for name, seg in zip(tr["ordering"][-3:], turns):
        iv = tr["turns"][name]

        def hand(t, wob=True):
            return np.degrees(gen.kinematics(seg, t, wob)[1])

        gl = gen.gauss_integral(hand, seg.t0, seg.t1, breaks=seg.breaks)
        gl2 = gen.gauss_integral(hand, seg.t0, seg.t1, panels=128, order=12, breaks=seg.breaks, per_s=60)
        m = (sess.t > seg.t0 - 0.5) & (sess.t < seg.t1 + 0.5)
        rect = hand(sess.t[m]).sum(0) / sess.cfg.fs
        hand_truth = np.array(iv["theta_body_deg"]) - np.array(iv["theta_earth_deg"])
        flat = gen.gauss_integral(lambda t: hand(t, False), seg.t0, seg.t1, breaks=seg.breaks)
        worst_gl = max(worst_gl, np.abs(gl - gl2).max())
        worst_sum = max(worst_sum, np.abs(rect - gl).max())
        worst_truth = max(worst_truth, np.abs(hand_truth - gl).max())
        worst_flat = max(worst_flat, np.abs(flat - iv["angle_deg"] * np.array(iv["axis_body"])).max())
        cone.append(np.linalg.norm(gl) - abs(iv["angle_deg"]))
    report(worst_sum < 1e-6, f"{sess.kind}: sample-rate rectangle sum of true turn rate vs its integral: "
                             f"max {worst_sum:.1e} deg (Gauss 25/s x10 vs 60/s x12: {worst_gl:.1e})")
    report(worst_truth < 1e-9, f"{sess.kind}: recorded theta_body (hand part) vs recomputed: {worst_truth:.1e} deg")
    report(worst_flat < 1e-9, f"{sess.kind}: wobble off -> integral = angle_deg * turn axis: {worst_flat:.1e} deg; "
                              f"wobble on: |theta| - |angle| = {', '.join(f'{c:+.1e}' for c in cone)} deg")


# ----------------------------------------------------------------------------- 2. reference Ferraris
def ferraris(df, tr, remove_g=False, margin_s=0.2):
    """Textbook Ferraris on the log, with the truth's intervals as the segmentation."""
    fs = tr["sample_rate_hz"]
    gy = df[[f"gyro_{a}" for a in AX]].to_numpy(float)
    faces = {f: slice(*iv["samples"]) for f, iv in tr["faces"].items()}
    means = {f: gy[s].mean(0) for f, s in faces.items()}
    b = np.mean(list(means.values()), axis=0)
    G = fcal = None
    if remove_g:                                    # G and accel from opposite faces (Ferraris eqs.)
        ac = df[[f"accel_{a}" for a in AX]].to_numpy(float)
        am = {f: ac[s].mean(0) for f, s in faces.items()}
        G = np.column_stack([(means[a + "_p"] - means[a + "_a"]) / 2 for a in AX])
        Ka = np.column_stack([(am[a + "_p"] - am[a + "_a"]) / 2 for a in AX])
        ba = np.mean(list(am.values()), axis=0)
        fcal = (ac - ba) @ np.linalg.inv(Ka).T
    W = np.zeros((3, 3))
    for name, iv in tr["turns"].items():
        j = AX.index(name[0])
        i0, i1 = iv["samples"]
        s = slice(max(0, i0 - int(margin_s * fs)), i1 + int(margin_s * fs))
        x = gy[s] - b - (fcal[s] @ G.T if remove_g else 0)
        W[:, j] = x.sum(0) / fs
    Theta = np.column_stack([tr["turns"][f"{a}_rot"]["theta_body_deg"] for a in AX])
    ref = np.array([tr["turns"][f"{a}_rot"]["sign"] * 360.0 for a in AX])
    return b, W @ np.linalg.inv(Theta), W / ref


def check_ferraris(path, tr, strict):
    df = pq.read_table(path).to_pandas()
    b, K_th, K_nom = ferraris(df, tr, remove_g=tr["G"] is not None)
    zb = (b - np.array(tr["b_expected"])) / np.array(tr["b_sigma"])
    zK = (K_th - np.array(tr["K"])) / np.array(tr["K_sigma"])
    zN = (K_nom - np.array(tr["K_nominal"])) / np.array(tr["K_sigma"])
    db = np.abs(b - np.array(tr["b"])).max()
    dnom = np.abs(np.array(tr["K_nominal"]) - np.array(tr["K"])).max()
    msg = (f"{tr['kind']:13s} |z| max: b {np.abs(zb).max():4.1f}  K(true angles) {np.abs(zK).max():4.1f}  "
           f"K(360 deg) vs K_nominal {np.abs(zN).max():4.1f}   |b-b_true| {db:.4f} dps  "
           f"|K_nominal-K| {dnom:.4f}  K_sigma~{np.median(tr['K_sigma']):.1e}")
    tol = tr["suggested_tolerance"]
    within = (np.abs(K_nom - np.array(tr["K_nominal"])) <= np.array(tol["K_vs_K_nominal"])).all() and \
        (np.abs(b - np.array(tr["b_expected"])) <= np.array(tol["b_vs_b_expected"])).all()
    msg += f"  within suggested_tolerance: {within}"
    if strict:
        report(np.abs(zb).max() < 4 and np.abs(zK).max() < 4 and np.abs(zN).max() < 4 and within, msg)
    else:
        report(within, msg)


# ----------------------------------------------------------------------------- 3. realism
def motion_stats(t, gyro, fs):
    """Same detector for real and synthetic data: motion = |w - median still w| > 2 deg/s,
    runs merged across gaps < 0.3 s; stills = the gaps between motions (>= 1 s)."""
    g = gyro - np.median(gyro, axis=0)
    mov = np.linalg.norm(g, axis=1) > 2
    k = int(0.15 * fs)
    mov = np.convolve(mov, np.ones(2 * k + 1), "same") > 0
    edges = np.flatnonzero(np.diff(np.r_[0, mov.astype(int), 0])).reshape(-1, 2)
    durs = np.diff(edges, axis=1)[:, 0] / fs
    peaks = np.array([np.linalg.norm(g[a:b], axis=1).max() for a, b in edges])
    stills = (edges[1:, 0] - edges[:-1, 1]) / fs
    return durs, peaks, stills[stills >= 1]


def describe(name, fs, dur_total, noise_g, noise_a, durs, peaks, stills, face_durs, turn_info):
    q = lambda x: f"{np.min(x):5.2f}/{np.median(x):5.2f}/{np.max(x):5.2f}"
    print(f"  {name:22s} {fs:6.1f} Hz {dur_total:6.1f} s  gyro noise {np.round(noise_g, 3)} dps  "
          f"accel noise {np.round(noise_a, 4)} g")
    print(f"  {'':22s} motions n={len(durs):2d} dur min/med/max {q(durs)} s, peak {q(peaks / 100)} x100 dps; "
          f"stills {q(stills)} s; faces {q(face_durs)} s")
    print(f"  {'':22s} turns: {turn_info}")


def check_realism(out, truths):
    raw = pd.read_csv(REAL / "session.csv")
    sec = json.loads((REAL / "sections.json").read_text())
    fs = 102.4
    gy = raw[["gyr_x", "gyr_y", "gyr_z"]].to_numpy()
    ac = raw[["acc_x", "acc_y", "acc_z"]].to_numpy() / 9.81
    fc = [v for k, v in sec.items() if "rot" not in k]
    ng = np.mean([gy[v["start"]:v["end"]].std(0) for v in fc], axis=0)
    na = np.mean([ac[v["start"]:v["end"]].std(0) for v in fc], axis=0)
    info = []
    for k in ("x_rot", "y_rot", "z_rot"):
        v = sec[k]
        s = slice(v["start"], v["end"])
        j = "xyz".index(k[0])
        w = gy[s] - gy[fc[0]["start"]:fc[0]["end"]].mean(0)
        info.append(f"{k} {(v['end'] - v['start']) / fs:.1f}s pk{np.abs(w[:, j]).max():.0f} "
                    f"int{w[:, j].sum() / fs:+.0f}")
    print("  real session (imucal example):")
    describe("real", fs, len(gy) / fs, ng, na, *motion_stats(None, gy, fs),
             [(v["end"] - v["start"]) / fs for v in fc], "; ".join(info))
    for kind in ("steps", "clean", "fast"):
        tr = truths[kind]
        df = pq.read_table(out / f"{kind}.parquet").to_pandas()
        g = df[[f"gyro_{a}" for a in AX]].to_numpy(float)
        a = df[[f"accel_{x}" for x in AX]].to_numpy(float)
        fcs = [slice(*iv["samples"]) for iv in tr["faces"].values()]
        ng = np.mean([g[s].std(0) for s in fcs], axis=0)
        na = np.mean([a[s].std(0) for s in fcs], axis=0)
        info = "; ".join(f"{k} {iv['t_motion'][1] - iv['t_motion'][0]:.1f}s pk{iv['peak_rate_dps']:.0f} "
                         f"int{np.sum(g[slice(*iv['samples']), AX.index(k[0])] - tr['b'][AX.index(k[0])]) / tr['sample_rate_hz']:+.0f}"
                         for k, iv in tr["turns"].items())
        describe(f"synthetic {kind}", tr["sample_rate_hz"], tr["t_end"] - tr["t_start"], ng, na,
                 *motion_stats(None, g, tr["sample_rate_hz"]),
                 [np.diff(iv["t"])[0] for iv in tr["faces"].values()], info)


# ----------------------------------------------------------------------------- 4. bad kinds, determinism
def check_bad(out, truths):
    for kind in ("half_turn", "two_turns"):
        tr = truths[kind]
        df = pq.read_table(out / f"{kind}.parquet").to_pandas()
        fs = tr["sample_rate_hz"]
        angs = {k: (df[f"gyro_{k[0]}"].to_numpy()[slice(*iv["samples"])] - tr["b"][AX.index(k[0])]).sum() / fs
                for k, iv in tr["turns"].items()}
        odd = [k for k, iv in tr["turns"].items() if iv["nominal_deg"] != 360]
        report(len(odd) == 1 and abs(abs(angs[odd[0]]) - tr["turns"][odd[0]]["nominal_deg"]) < 20,
               f"{kind}: integrated angles " + ", ".join(f"{k} {v:+.1f}" for k, v in angs.items()))
    tr = truths["missing_face"]
    df = pq.read_table(out / "missing_face.parquet").to_pandas()
    mf = tr["missing_face"]
    acc = df[[f"accel_{a}" for a in AX]].to_numpy()
    still = np.linalg.norm(df[[f"gyro_{a}" for a in AX]].to_numpy() - tr["b"], axis=1) < 0.5
    seen = (acc[still, AX.index(mf[0])] < -0.8).sum()
    report(seen == 0 and mf not in tr["faces"], f"missing_face: {mf} absent; still samples with that axis down: {seen}")
    for kind in ("no_accel", "sections_only"):
        cols = pq.read_schema(out / f"{kind}.parquet").names
        report(not any(c.startswith("accel") for c in cols), f"{kind}: columns {cols}")
    sch = pq.read_schema(out / "annotated.parquet")
    df = pq.read_table(out / "annotated.parquet").to_pandas()
    labs = df["section"].value_counts().to_dict()
    report(set(labs) == set(gen.FACES + gen.TURNS),
           f"annotated: section type {sch.field('section').type}, labels {dict(sorted(labs.items()))}, "
           f"null {df['section'].isna().sum()}")


def check_determinism():
    with tempfile.TemporaryDirectory() as d:
        h = []
        for i in range(2):
            p = Path(d) / f"{i}.parquet"
            gen.session("annotated", 7, p)
            h.append(hashlib.sha256(p.read_bytes()).hexdigest())
    report(h[0] == h[1], f"same seed, same bytes: {h[0][:16]} == {h[1][:16]}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds-ferraris", type=int, default=5, help="seeds for the clean-kind recovery check")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        gen.main(["--out", d, "--seed", str(a.seed)])
        truths = json.loads((out / "truth.json").read_text())["kinds"]
        print(f"\n1. kinematics (seed {a.seed})")
        for kind in ("clean", "steps", "shuffled", "two_turns"):
            check_kinematics(gen.build(kind, a.seed))
        print("\n2. reference Ferraris calibration (z = error / noise-propagated sigma)")
        for s in range(a.seed, a.seed + a.seeds_ferraris):
            tr = gen.session("clean", s, out / "c.parquet")
            check_ferraris(out / "c.parquet", tr, strict=True)
        print("   other calibrate kinds (not strict: Earth rate, bias walk, face tilt under G are not modelled here)")
        for kind, tr in truths.items():
            if tr["expect"] == "calibrate" and kind != "clean" and tr["accel"]["present"]:
                check_ferraris(out / f"{kind}.parquet", tr, strict=False)
        tr = truths["gsens"]
        df = pq.read_table(out / "gsens.parquet").to_pandas()
        _, _, Kn = ferraris(df, tr, remove_g=False)
        print(f"   gsens with G ignored: max |K - K_if_G_ignored| = "
              f"{np.abs(Kn - np.array(tr['K_if_G_ignored'])).max():.1e}, vs K_nominal "
              f"{np.abs(Kn - np.array(tr['K_nominal'])).max():.1e}")
        print("\n3. realism: real vs synthetic (same detector)")
        check_realism(out, truths)
        print("\n4. bad kinds and determinism")
        check_bad(out, truths)
        check_determinism()
    print("\nall checks passed" if not failures else f"\n{len(failures)} check(s) FAILED")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
