"""Self-checks of the zoo generator: prints figures, asserts what the physics fixes.

    python -m benchmarks.zoo.selfcheck [--out DIR]

1. the pre-extension cases are byte-identical (SHA-256 recorded before the new effects);
2. every new effect writes byte-identical Parquet twice and runs on every protocol;
3. each new effect is fitted back from a written log with its true shape (numpy only; the
   shapes are re-implemented here, not imported) and its parameters recovered;
4. detectability: RMS of the hold-mean residual against the true base model over the
   hold-mean noise floor, seed 21 (turntable3 holds; sweep 20 s windows);
5. coloured noise on turntable6 and sweep: 20 s window means against the floor;
6. the on-axis IMU (imu_radius_m=0): accelerometer constant per mount, G recovered.

Light by design (5 Hz turntables, 1 Hz sweeps): about a minute on one core.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import os
import tempfile

import numpy as np
import pyarrow.parquet as pq

from benchmarks.zoo.generator import make_unit, simulate_session, write_session

NEW = ["die_lag_curved", "scale_warmup", "scale_temp_rate", "misalign_warp_tanh",
       "bias_bump_temp", "bias_tanh_temp", "scale_low_rate_tanh", "warmup_two_exp",
       "warmup_power_law", "bias_step_temp", "bias_step_time", "motor_heating_bias",
       "table_angle_bias"]

# (effect, protocol, noise, unit seed, session, session seed, rate_hz, overrides) -> SHA-256
# of the Parquet written before the effects above existed.
LEGACY = [
    ("none", "turntable3", "white", 1, 0, 1, 25.0, {},
     "e22b433e6aa7084d"),
    ("die_lag", "sweep", "white", 2, 0, 2, 5.0, {}, "e86cca75b7079e12"),
    ("die_lag", "sweep", "white", 2, 1, 2, 5.0, {"ramp_c_per_h": 60.0}, "87eb36af1f50aecd"),
    ("warmup", "turntable3", "white", 3, 0, 3, 5.0, {}, "daf4e3c5b23eed1c"),
    ("none", "turntable6", "coloured", 4, 0, 4, 5.0, {}, "e86ababacea08d73"),
    ("g_sensitivity+hysteresis+temp_rate", "sweep", "coloured", 5, 1, 9, 2.0,
     {"sweep_rate_dps": 10.0}, "17264b864a4b7793"),
    ("vibration_rectification+scale_cubic+run_to_run_bias", "servo", "white", 6, 2, 7, 25.0, {},
     "d963d9af8d9bc742"),
    ("bias_quadratic_temp+g_squared+cross_coupling+rate_dependent_bias_sat+scale_asymmetry"
     "+scale_quadratic+bias_ramp", "turntable6", "white", 8, 0, 1, 5.0,
     {"fixture_misalign_deg": 1.0}, "d4978bb9b6c37a45"),
]

SEED = 21
TT_HZ = 5.0
SW_HZ = 1.0


def sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


# ------------------------------------------------------------------ reading and residuals
def read(path):
    tb = pq.read_table(path)
    return {c: tb[c].to_numpy() for c in tb.column_names}


def axis_vec(label):
    v = np.zeros(3)
    v["xyz".index(label[1])] = 1.0 if label[0] == "+" else -1.0
    return v


def base_residual(cols, info):
    """Log minus the true base model K(T) w + B(T) at the logged temperature; mask of samples
    outside handling; the true body rate; the linear output u = K w."""
    b = info["base"]
    dT = (cols["temp"] - 25.0)[:, None]
    s = np.asarray(b["s0"]) + np.asarray(b["s1"]) * dT + np.asarray(b["s2"]) * dT ** 2
    B = np.asarray(b["b0"]) + np.asarray(b["b1"]) * dT + np.asarray(b["b2"]) * dT ** 2
    labels = cols["mount"].astype(str)
    ax = np.stack([axis_vec(x) for x in np.unique(labels)])
    ax = ax[np.searchsorted(np.unique(labels), labels)]
    w = cols["ref_rate"][:, None] * ax
    u = w + s * w + w @ np.asarray(b["M"]).T
    g = np.stack([cols["gyro_x"], cols["gyro_y"], cols["gyro_z"]], axis=1)
    keep = np.ones(len(w), bool)
    for ph in info["phases"]:
        if ph["kind"] == "handling":
            keep &= ~((cols["t"] >= ph["t_start"] - 1.0) & (cols["t"] < ph["t_end"] + 1.0))
    return g - u - B, keep, w, u


def lag(x, tau, dt):
    """tau y' = x - y, started at x[0], input linear between samples (plain loop)."""
    e = math.exp(-dt / tau)
    c = tau * (1 - e) / dt
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = e * y[k - 1] + (1 - c) * x[k] + (c - e) * x[k - 1]
    return y


def lsq(X, y):
    """Least squares; returns coefficients and the residual sum of squares."""
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    return beta, float(np.sum((y - X @ beta) ** 2))


def grid_fit(features, y, grid):
    """Variable projection: for each grid point, features(p) -> design (n,k); best by RSS."""
    best = None
    for p in grid:
        X = features(p)
        beta, rss = lsq(X, y)
        if best is None or rss < best[2]:
            best = (p, beta, rss)
    return best


def smooth_rate(t, T, win_s=301.0):
    """dT/dt from a noisy, quantised temperature: a local straight-line fit over win_s."""
    dt = float(np.median(np.diff(t)))
    n = int(win_s / dt) | 1
    k = np.arange(n) - n // 2
    w = k / np.sum(k * k * dt)
    d = np.convolve(T, w[::-1], mode="same")
    d[: n // 2] = np.nan
    d[-(n // 2):] = np.nan
    return d


# ------------------------------------------------------------------ 1-2: bytes
def check_legacy(tmp):
    print("\n== pre-extension cases, SHA-256 (first 16 hex) ==")
    ok = True
    for eff, prot, noise, us, sess, ss, hz, ov, want in LEGACY:
        p = os.path.join(tmp, "legacy.parquet")
        write_session(make_unit(eff, prot, noise, seed=us), p, session=sess, seed=ss, rate_hz=hz, **ov)
        got = sha(p)[:16]
        ok &= got == want
        print(f"  {eff[:40]:40s} {prot:10s} seed {us} {hz:4.0f} Hz {ov}: {got} "
              f"{'same' if got == want else 'DIFFERENT (was ' + want + ')'}")
    assert ok, "a pre-extension case changed"


def check_determinism(tmp):
    print("\n== new effects: every protocol runs, same seeds -> same bytes ==")
    for e in NEW:
        for prot, hz, ov in (("turntable3", 2.0, {}), ("turntable6", 1.0, {}),
                             ("sweep", 0.5, {"sweep_rate_dps": 50.0}), ("servo", 10.0, {})):
            u = make_unit(e, prot, "coloured", seed=SEED)
            a, b = os.path.join(tmp, "a.parquet"), os.path.join(tmp, "b.parquet")
            write_session(u, a, 0, 1, hz, **ov)
            write_session(u, b, 0, 1, hz, **ov)
            c = read(a)
            assert sha(a) == sha(b), (e, prot)
            assert all(np.all(np.isfinite(c[k])) for k in ("gyro_x", "gyro_y", "gyro_z", "temp"))
            assert np.all(np.diff(c["t"]) > 0)
    print(f"  {len(NEW)} effects x 4 protocols: identical bytes, finite, t increasing")


# ------------------------------------------------------------------ 4: detectability
def windows(info, t, protocol):
    if protocol.startswith("turntable"):
        return [(p["t_start"], p["t_end"]) for p in info["phases"] if p["kind"] == "hold"]
    t0 = t[0]
    n = int((t[-1] - t0) // 20.0)
    return [(t0 + 20.0 * i, t0 + 20.0 * (i + 1)) for i in range(n)]


def detectability(effect, protocol, hz, **ov):
    """RMS over windows and axes of the window-mean residual against the true base model,
    over the hold-mean noise floor (white noise).  For die_lag_curved the base is the same
    unit's curves felt at the sensor temperature (what the lag does)."""
    uE = make_unit(effect, protocol, "white", seed=SEED)
    cE, info = simulate_session(uE, 0, 1, hz, **ov)
    cN, _ = simulate_session(make_unit("none", protocol, "white", seed=SEED), 0, 1, hz, **ov)
    cC, _ = simulate_session(make_unit("none", protocol, "white", seed=SEED,
                                       arw_dps_rthz=[0.0, 0.0, 0.0]), 0, 1, hz, **ov)
    G = lambda c: np.stack([c["gyro_x"], c["gyro_y"], c["gyro_z"]], 1)        # noqa: E731
    noise = G(cN) - G(cC)
    if effect == "none":
        resid = noise
    elif effect == "die_lag_curved":
        uB = make_unit(effect, protocol, "white", seed=SEED, die_lag_curved__tau_die_s=1e-3)
        cB, _ = simulate_session(uB, 0, 1, hz, **ov)
        resid = G(cE) - G(cB) + noise
    else:
        resid = G(cE) - G(cC)
    t = cE["t"]
    means = [resid[(t >= a) & (t < b)].mean(0) for a, b in windows(info, t, protocol)]
    return float(np.sqrt(np.mean(np.square(means)))) / info["noise_floor_hint"]


def check_detectability():
    print(f"\n== detectability, seed {SEED}: window-mean residual RMS / floor ==")
    print("   (turntable3 holds at 5 Hz; sweep 30 degC/h with the rig at 100 deg/s, 20 s windows, 1 Hz)")
    out = {}
    for e in ["none"] + NEW:
        a = detectability(e, "turntable3", TT_HZ)
        b = detectability(e, "sweep", SW_HZ, sweep_rate_dps=100.0)
        out[e] = (a, b)
        print(f"  {e:22s} turntable3 {a:7.1f}x   sweep {b:7.1f}x")
    for soak in (120.0, 60.0):
        a = detectability("scale_temp_rate", "turntable3", TT_HZ, soak_s=soak)
        print(f"  scale_temp_rate        turntable3 with soak_s={soak:.0f}: {a:.1f}x "
              "(the first holds fall in the settling)")
    assert 0.8 < out["none"][0] < 1.25 and 0.8 < out["none"][1] < 1.25
    return out


# ------------------------------------------------------------------ 3: fits
def written(tmp, effect, protocol, hz, unit_kw=None, session=0, **ov):
    u = make_unit(effect, protocol, "white", seed=SEED, **(unit_kw or {}))
    p = os.path.join(tmp, f"{effect}_{protocol}_{session}.parquet")
    info = write_session(u, p, session=session, seed=1, rate_hz=hz, **ov)
    return read(p), info, info["effect_params"].get(effect, {})


def report(name, pairs):
    print(f"  {name}")
    for k, fit, true in pairs:
        f, tr = np.atleast_1d(np.asarray(fit, float)), np.atleast_1d(np.asarray(true, float))
        f2, tr2 = np.broadcast_arrays(f, tr)
        nz = np.abs(tr2) > 0
        err = np.max(np.abs(f2[nz] - tr2[nz]) / np.abs(tr2[nz])) if np.any(nz) else 0.0
        print(f"      {k:16s} fit {np.array2string(f, precision=5, suppress_small=False)}"
              f"   true {np.array2string(tr, precision=5, suppress_small=False)}"
              f"   max rel. error {100 * err:.2f} %")


def rel_ok(fit, true, tol):
    fit, true = np.asarray(fit, float), np.asarray(true, float)
    return bool(np.all(np.abs(fit - true) <= tol * np.maximum(np.abs(true), 1e-12)))


def fit_die_lag_curved(tmp):
    """Lag the logged temperature by a trial tau, regress the still sweep on a cubic of it
    (ramps 30 and 60 degC/h, same unit); then the scale curve from a sweep turning at 100."""
    res = {}
    for ramp in (30.0, 60.0):
        c, info, ep = written(tmp, "die_lag_curved", "sweep", SW_HZ, ramp_c_per_h=ramp)
        g = np.stack([c["gyro_x"], c["gyro_y"], c["gyro_z"]], 1)
        def feats(tau, T=c["temp"]):
            return np.vander(lag(T, tau, 1.0 / SW_HZ) - 25.0, 4, increasing=True)
        coarse = grid_fit(feats, g, np.arange(100.0, 1500.0, 20.0))[0]
        tau, beta, _ = grid_fit(feats, g, np.arange(coarse - 20.0, coarse + 20.0, 0.5))
        res[ramp] = (tau, beta)
        poly = np.array(info["effect_params"]["die_lag_curved"]["bias_poly_dps"])     # (4,3)
        report(f"die_lag_curved, still sweep at {ramp:.0f} degC/h",
               [("tau_d s", tau, ep["tau_die_s"]), ("b1 dps/C", beta[1], poly[1]),
                ("b2 dps/C2", beta[2], poly[2]), ("b3 dps/C3", beta[3], poly[3])])
        assert abs(tau - ep["tau_die_s"]) < 0.02 * ep["tau_die_s"]
        assert rel_ok(beta[2], poly[2], 0.05) and rel_ok(beta[1], poly[1], 0.05)
    # scale: the same unit turning at 100 deg/s; bias curve from the 30 degC/h fit removed
    tau, beta = res[30.0]
    c, info, ep = written(tmp, "die_lag_curved", "sweep", SW_HZ, sweep_rate_dps=100.0)
    x = lag(c["temp"], tau, 1.0 / SW_HZ) - 25.0
    gz = c["gyro_z"] - np.vander(x, 4, increasing=True) @ beta[:, 2]
    sc, _ = lsq(np.vander(x, 3, increasing=True) * 100.0, gz - 100.0)
    spoly = np.array(info["effect_params"]["die_lag_curved"]["scale_poly"])
    report("die_lag_curved, z scale from a sweep at 100 deg/s",
           [("s0,s1,s2", sc, spoly[:, 2])])
    assert rel_ok(sc[1], spoly[1, 2], 0.05)


def fit_scale_warmup(tmp):
    c, info, ep = written(tmp, "scale_warmup", "turntable3", TT_HZ)
    r, keep, w, u = base_residual(c, info)
    t = c["t"] - info["power_on_t"]
    s_fit = []
    taus = []
    for a in range(3):
        m = keep & (np.abs(w[:, a]) > 1.0)
        tau, beta, _ = grid_fit(lambda tau: (u[m, a] * np.exp(-t[m] / tau))[:, None], r[m, a],
                                np.arange(200.0, 3000.0, 5.0))
        s_fit.append(beta[0])
        taus.append(tau)
    report("scale_warmup, turntable3 own-axis holds",
           [("s", s_fit, ep["s"]), ("tau s", taus, ep["tau_s"])])
    assert rel_ok(s_fit, ep["s"], 0.1) and rel_ok(np.median(taus), ep["tau_s"], 0.1)


def fit_scale_temp_rate(tmp):
    q_fit, q_true = [], None
    for a, lab in enumerate(("+x", "+y", "+z")):
        c, info, ep = written(tmp, "scale_temp_rate", "sweep", SW_HZ, sweep_rate_dps=100.0, mount=lab)
        r, keep, w, u = base_residual(c, info)
        d = smooth_rate(c["t"], c["temp"]) * 60.0
        m = np.isfinite(d)
        beta, _ = lsq(np.stack([u[m, a] * d[m], np.ones(m.sum())], 1), r[m, a])
        q_fit.append(beta[0])
        q_true = ep["q_per_c_per_min"]
    report("scale_temp_rate, sweeps at 100 deg/s on +x, +y, +z (dT/dt from the logged temp)",
           [("q /(C/min)", q_fit, q_true)])
    assert rel_ok(q_fit, q_true, 0.1)


def fit_misalign_warp(tmp):
    Mfit = np.zeros((3, 3))
    grid = [(tg, W) for tg in np.arange(0.0, 55.0, 1.0) for W in np.arange(4.0, 25.0, 1.0)]
    tgs = []
    for a, lab in enumerate(("+x", "+y", "+z")):
        c, info, ep = written(tmp, "misalign_warp_tanh", "sweep", SW_HZ, sweep_rate_dps=100.0, mount=lab)
        r, keep, w, u = base_residual(c, info)
        others = [b for b in range(3) if b != a]
        y = r[:, others]
        p, beta, _ = grid_fit(lambda p: np.stack([w[:, a] * np.tanh((c["temp"] - p[0]) / p[1]),
                                                  np.ones(len(y))], 1), y, grid)
        Mfit[others, a] = beta[0]
        tgs.append(p)
    Mt = np.asarray(ep["Mw_rad"])
    report("misalign_warp_tanh, sweeps at 100 deg/s on +x, +y, +z",
           [("Mw (rows)", Mfit.ravel(), Mt.ravel()),
            ("T_g, W C", np.mean(tgs, 0), [ep["T_g_c"], ep["W_c"]])])
    off = ~np.eye(3, dtype=bool)
    assert rel_ok(Mfit[off], Mt[off], 0.1)


def fit_temperature_shape(tmp, effect, shape, grid, amp_key, names, tol=0.1):
    c, info, ep = written(tmp, effect, "sweep", SW_HZ)
    r, keep, w, u = base_residual(c, info)
    p, beta, _ = grid_fit(lambda p: np.stack([shape(c["temp"], p), np.ones(len(r))], 1), r, grid)
    report(f"{effect}, still sweep", [(amp_key, beta[0], ep[amp_key]),
                                      (",".join(names), p, [ep[n] for n in names])])
    assert rel_ok(beta[0], ep[amp_key], tol)
    return p, ep


def fit_bump(tmp):
    grid = [(tb, sg) for tb in np.arange(-10.0, 50.0, 0.5) for sg in np.arange(3.0, 12.0, 0.25)]
    p, ep = fit_temperature_shape(tmp, "bias_bump_temp",
                                  lambda T, p: np.exp(-0.5 * ((T - p[0]) / p[1]) ** 2), grid,
                                  "h_dps", ["T_b_c", "sigma_c"])
    assert abs(p[0] - ep["T_b_c"]) < 0.5 and abs(p[1] - ep["sigma_c"]) < 0.5


def fit_tanh(tmp):
    grid = [(tt, ww) for tt in np.arange(-10.0, 50.0, 0.5) for ww in np.arange(1.0, 12.0, 0.25)]
    p, ep = fit_temperature_shape(tmp, "bias_tanh_temp", lambda T, p: np.tanh((T - p[0]) / p[1]),
                                  grid, "a_dps", ["T_t_c", "w_c"])
    assert abs(p[0] - ep["T_t_c"]) < 0.5 and abs(p[1] - ep["w_c"]) < 0.5


def schmitt(T, p):
    """Switch state for centre p[0], dead band p[1]: the side of the last sample outside the
    band, else the side of the centre T[0] is on."""
    up, down = p[0] + p[1] / 2, p[0] - p[1] / 2
    outside = (T >= up) | (T <= down)
    last = np.maximum.accumulate(np.where(outside, np.arange(len(T)), -1))
    return np.where(last >= 0, T[np.maximum(last, 0)] >= up, T[0] >= p[0]).astype(float)


def fit_step_temp(tmp):
    grid = [(ts, hw) for ts in np.arange(-5.0, 50.0, 0.25) for hw in np.arange(0.5, 5.0, 0.25)]
    p, ep = fit_temperature_shape(tmp, "bias_step_temp", schmitt, grid, "step_dps",
                                  ["T_switch_c", "hysteresis_c"])
    assert abs(p[0] - ep["T_switch_c"]) < 0.3 and abs(p[1] - ep["hysteresis_c"]) < 0.3


def fit_low_rate_tanh(tmp):
    c, info, ep = written(tmp, "scale_low_rate_tanh", "turntable3", TT_HZ)
    r, keep, w, u = base_residual(c, info)
    a_fit, W_fit = [], []
    t = c["t"]
    holds = [(p["t_start"], p["t_end"]) for p in info["phases"] if p["kind"] == "hold"]
    for a in range(3):
        hm = [(u[(t >= s) & (t < e), a].mean(), r[(t >= s) & (t < e), a].mean()) for s, e in holds]
        hm = np.array(hm)
        W, beta, _ = grid_fit(lambda W: np.stack([np.tanh(hm[:, 0] / W), np.ones(len(hm))], 1),
                              hm[:, 1], np.arange(5.0, 150.0, 0.25))
        a_fit.append(beta[0])
        W_fit.append(W)
    report("scale_low_rate_tanh, turntable3 hold means", [("a dps", a_fit, ep["a_dps"]),
                                                          ("W dps", W_fit, ep["W_dps"])])
    assert rel_ok(a_fit, ep["a_dps"], 0.1) and rel_ok(W_fit, ep["W_dps"], 0.15)


def fit_time_shape(tmp, effect, shape, grid, amp_keys, names):
    c, info, ep = written(tmp, effect, "turntable3", TT_HZ)
    r, keep, w, u = base_residual(c, info)
    # 5 s means of the kept samples: white noise, so the same fit on 25x fewer rows
    n = int(keep.sum()) // 25 * 25
    t = (c["t"] - info["power_on_t"])[keep][:n].reshape(-1, 25).mean(1)
    y = r[keep][:n].reshape(-1, 25, 3).mean(1)
    p, beta, _ = grid_fit(lambda p: np.column_stack([*shape(t, p), np.ones(len(t))]), y, grid)
    pairs = [(k, beta[i], ep[k]) for i, k in enumerate(amp_keys)]
    pairs.append((",".join(names), p, [ep[n] for n in names]))
    report(f"{effect}, turntable3", pairs)
    return p, beta, ep


def fit_two_exp(tmp):
    grid = [(a, b) for a in np.arange(60.0, 600.0, 5.0) for b in np.arange(1000.0, 6000.0, 50.0)]
    p, beta, ep = fit_time_shape(tmp, "warmup_two_exp",
                                 lambda t, p: (np.exp(-t / p[0]), np.exp(-t / p[1])), grid,
                                 ["A1_dps", "A2_dps"], ["tau1_s", "tau2_s"])
    assert rel_ok(beta[0], ep["A1_dps"], 0.15) and rel_ok(p[0], ep["tau1_s"], 0.1)


def fit_power_law(tmp):
    grid = [(a, b) for a in np.arange(10.0, 300.0, 2.0) for b in np.arange(0.1, 1.2, 0.01)]
    p, beta, ep = fit_time_shape(tmp, "warmup_power_law", lambda t, p: ((1 + t / p[0]) ** -p[1],),
                                 grid, ["A_dps"], ["t0_s", "p"])
    assert rel_ok(beta[0], ep["A_dps"], 0.1) and abs(p[1] - ep["p"]) < 0.05


def fit_step_time(tmp):
    p, beta, ep = fit_time_shape(tmp, "bias_step_time", lambda t, p: ((t >= p[0]).astype(float),),
                                 [(x,) for x in np.arange(100.0, 5000.0, 1.0)], ["step_dps"], ["t_step_s"])
    # the step can only be placed between samples kept outside handling
    assert rel_ok(beta[0], ep["step_dps"], 0.1) and abs(p[0] - ep["t_step_s"]) < 30.0


def fit_motor_heating(tmp):
    c, info, ep = written(tmp, "motor_heating_bias", "turntable3", TT_HZ)
    r, keep, w, u = base_residual(c, info)
    P = (c["ref_rate"] / 400.0) ** 2
    feats = lambda tau: np.stack([lag(P, tau, 1 / TT_HZ)[keep], np.ones(keep.sum())], 1)  # noqa: E731
    coarse = grid_fit(feats, r[keep], np.arange(60.0, 1200.0, 20.0))[0]
    tau, beta, _ = grid_fit(feats, r[keep], np.arange(coarse - 20.0, coarse + 20.0, 1.0))
    report("motor_heating_bias, turntable3 (power from the logged ref_rate)",
           [("H dps", beta[0], ep["H_dps"]), ("tau s", tau, ep["tau_s"])])
    assert rel_ok(beta[0], ep["H_dps"], 0.1) and rel_ok(tau, ep["tau_s"], 0.1)


def fit_table_angle(tmp):
    c, info, ep = written(tmp, "table_angle_bias", "turntable3", TT_HZ)
    r, keep, w, u = base_residual(c, info)
    th = np.concatenate([[0.0], np.cumsum(0.5 * (c["ref_rate"][1:] + c["ref_rate"][:-1])
                                          * np.diff(c["t"]))]) * math.pi / 180
    amp = np.zeros(3)
    n = np.zeros(3)
    labels = c["mount"].astype(str)
    for lab in np.unique(labels):
        m = keep & (labels == lab)
        X = np.stack([np.cos(th[m]), np.sin(th[m]), np.ones(m.sum())], 1)
        for a in range(3):
            if a == "xyz".index(lab[1]):
                continue                      # the vertical axis sees no horizontal field
            beta, _ = lsq(X, r[m, a])
            amp[a] += math.hypot(beta[0], beta[1])
            n[a] += 1
    amp /= n
    report("table_angle_bias, turntable3 (angle from the logged ref_rate)",
           [("|S| dps", amp, np.abs(ep["S_dps"]))])
    assert rel_ok(amp, np.abs(ep["S_dps"]), 0.1)


def check_die_drives_effects(tmp):
    """With die_lag_curved, a temperature effect is felt at the die and the firmware step at the
    sensor: the combined log minus the die-only log (same noise) is the effect alone."""
    print("\n== die_lag_curved with other temperature effects: which temperature drives them ==")
    cD, iD, epD = written(tmp, "die_lag_curved", "sweep", SW_HZ)
    tau = epD["tau_die_s"]
    shapes = {
        "bias_bump_temp": ("h_dps", lambda T, e: np.exp(-0.5 * ((T - e["T_b_c"]) / e["sigma_c"]) ** 2)),
        "bias_step_temp": ("step_dps", lambda T, e: schmitt(T, (e["T_switch_c"], e["hysteresis_c"]))),
    }
    for other, (amp_key, shape) in shapes.items():
        c, info, _ = written(tmp, "die_lag_curved+" + other, "sweep", SW_HZ)
        e = info["effect_params"][other]
        d = np.stack([c[k] - cD[k] for k in ("gyro_x", "gyro_y", "gyro_z")], 1)
        amp = np.asarray(e[amp_key])
        # the logged temperature carries noise; its lag is the die's within tau/N
        rms = {}
        for lab, T in (("sensor", cD["temp"]), ("die", lag(cD["temp"], tau, 1.0 / SW_HZ))):
            rms[lab] = float(np.sqrt(np.mean((d - amp[None] * shape(T, e)[:, None]) ** 2)))
        print(f"  {other:16s} misfit if felt at the sensor {rms['sensor']:.5f} dps, at the die "
              f"{rms['die']:.5f} dps")
        if other == "bias_step_temp":
            assert rms["sensor"] < rms["die"]
        else:
            assert rms["die"] < 0.2 * rms["sensor"]


# ------------------------------------------------------------------ 5-6
def check_coloured(tmp):
    print("\n== coloured noise: std of 20 s window means over the floor (per axis) ==")
    for prot, hz in (("turntable6", TT_HZ), ("sweep", SW_HZ), ("turntable3", TT_HZ)):
        rat = []
        for s in (21, 22, 23, 24):
            cN, info = simulate_session(make_unit("none", prot, "coloured", seed=s), 0, 1, hz)
            cC, _ = simulate_session(make_unit("none", prot, "white", seed=s,
                                               arw_dps_rthz=[0.0, 0.0, 0.0]), 0, 1, hz)
            nz = np.stack([cN[k] - cC[k] for k in ("gyro_x", "gyro_y", "gyro_z")], 1)
            k = int(20.0 * hz)
            blocks = nz[: len(nz) // k * k].reshape(-1, k, 3).mean(1)
            rat.append(blocks.std(0) / np.asarray(info["noise_floor_detail"]["hold_mean_std_dps"]))
        rat = np.array(rat)
        print(f"  {prot:10s} seeds 21-24: {np.array2string(rat, precision=2)}  median {np.median(rat):.2f}")
        assert 0.7 < np.median(rat) < 1.5


def check_on_axis_imu(tmp):
    print("\n== g_sensitivity on turntable3 with the IMU on the rig axis (imu_radius_m=0) ==")
    for kw in ({}, {"imu_radius_m": 0.0}):
        c, info, ep = written(tmp, "g_sensitivity", "turntable3", TT_HZ, unit_kw=kw)
        acc = np.stack([c["accel_x"], c["accel_y"], c["accel_z"]], 1).astype(float)
        t = c["t"]
        holds = [p for p in info["phases"] if p["kind"] == "hold"]
        spread = 0.0
        G = np.zeros((3, 3))
        r, keep, w, u = base_residual(c, info)
        for lab in ("+x", "+y", "+z"):
            hm = np.array([acc[(t >= p["t_start"]) & (t < p["t_end"])].mean(0) for p in holds
                           if p["mount"] == lab])
            spread = max(spread, float(np.max(hm.max(0) - hm.min(0))))
            sel = np.zeros(len(t), bool)
            for p in holds:
                if p["mount"] == lab:
                    sel |= (t >= p["t_start"]) & (t < p["t_end"])
            G[:, "xyz".index(lab[1])] = r[sel].mean(0)
        print(f"  {str(kw) or 'default':22s} accel hold-mean spread within a mount: {spread:.4f} g")
        if kw:
            Gt = np.asarray(ep["G_dps_per_g"])
            report("G from the per-mount hold means (1 g on one axis per mount)",
                   [("G (rows)", G.ravel(), Gt.ravel())])
            n_holds = sum(p["mount"] == "+x" for p in holds)
            tol = 5.0 * info["noise_floor_hint"] / math.sqrt(n_holds)   # 5 sigma of a column mean
            print(f"      max |G - G_true| {np.max(np.abs(G - Gt)):.5f} dps/g, 5-sigma noise bound {tol:.5f}")
            assert spread < 0.01
            assert np.max(np.abs(G - Gt)) < tol


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="folder for the logs (default: a temporary one)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as td:
        tmp = a.out or td
        os.makedirs(tmp, exist_ok=True)
        check_legacy(tmp)
        check_determinism(tmp)
        print("\n== fitted back from written logs with the true shape ==")
        for f in (fit_die_lag_curved, fit_scale_warmup, fit_scale_temp_rate, fit_misalign_warp,
                  fit_bump, fit_tanh, fit_low_rate_tanh, fit_two_exp, fit_power_law, fit_step_temp,
                  fit_step_time, fit_motor_heating, fit_table_angle):
            f(tmp)
        check_die_drives_effects(tmp)
        check_coloured(tmp)
        check_on_axis_imu(tmp)
        check_detectability()
    print("\nall checks passed")


if __name__ == "__main__":
    main()
