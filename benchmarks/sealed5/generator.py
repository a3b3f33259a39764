"""Fifth sealed benchmark: simulator of `turntable` rig logs with hidden effects.

SEALED: whoever works on the diagnosis must not read this file (see README.md).

Each unit is one physical three-axis MEMS gyro written as three sessions (new power-on, new
noise, own order of set points, mounts and table rates). The sensor, the chamber air, the
unit's thermal path, the table and the person re-mounting the unit are simulated on a common
sample grid.  The sensor output is

    w = K(T_die) . w_body + B(T_die) + b_on + b_BI(t) + n(t)  +  a * e(state)

where the last term is the unit's effect (absent on complete units), linear in its amplitude
`a`.  `a` is solved so that the standard calibration of session 0 (K, B per set point, linear
interpolation in the logged temperature) misses session 2 by a drawn multiple of the reference
floor.  The reference floor is computed for the same unit, noise, nuisances and protocol with
a = 0.
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.optimize import brentq
from scipy.signal import lfilter

MASTER_SEED = 20260517
D2R = math.pi / 180.0
G0 = 9.80665
MOUNT_WORDS = ("+x", "-x", "+y", "-y", "+z", "-z")
RATE_SET = (0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 30, 50, 75, 100, 150, 200, 250, 300, 400)
LOW_RATES = (0.1, 0.2, 0.5, 1, 2)
ROW_BUDGET = 260_000          # a session stays below ~300 000 rows
MAG_BINS = ((1.6, 4.0), (4.0, 15.0), (15.0, 50.0))   # ratio to the reference floor on session 2

# --------------------------------------------------------------------------------- families
# Truth per family: the judge's words.  `carried`: a sensor calibration term is needed (a
# no_sensor_term answer is then never a success).  `reads` / `acts`: what a right fix reads and
# acts on; empty where no fix is right.  Per unit the shape may narrow `acts`.
FAMILIES = {
    "g_sensitivity": dict(reasons=(), reads=("accel",), acts=("bias",), carried=True,
                          shapes=("linear", "anisoelastic", "mixed")),
    "rate_scale": dict(reasons=(), reads=("rate",), acts=("scale",), carried=True,
                       shapes=("knee", "tanh", "deadband")),
    "rate_cross": dict(reasons=(), reads=("rate",), acts=("cross-axis",), carried=True,
                       shapes=("square", "bump", "kink")),
    "thermal_gradient": dict(reasons=(), reads=("thermal",), acts=("bias",), carried=True,
                             shapes=("flux", "ddt_die", "ddt_case")),
    "warmup": dict(reasons=(), reads=("time",), acts=("bias",), carried=True,
                   shapes=("exp", "two_exp", "power")),
    "thermal_hysteresis": dict(reasons=("direction of approach",), reads=("thermal",),
                               acts=("bias", "scale"), carried=False,
                               shapes=("play_bias", "play_scale", "play_wide")),
    "temp_feature": dict(reasons=("between points",), reads=("temperature",),
                         acts=("bias", "scale"), carried=False,
                         shapes=("gauss", "step", "lorentz_scale")),
    "unit_change": dict(reasons=("unit changed",), reads=(), acts=(), carried=False,
                        shapes=("between", "within", "between")),
    "slow_noise": dict(reasons=("slow noise",), reads=(), acts=(), carried=False,
                       shapes=("telegraph", "random_walk", "gm_long")),
    "lab_reference": dict(reasons=("lab",), reads=(), acts=(), carried=False,
                          shapes=("scale_s0", "servo_tail", "scale_s0")),
    "fixture": dict(reasons=("mounting",), reads=(), acts=(), carried=False,
                    shapes=("debris_s0", "clamp_slip", "loose_seat")),
}


# --------------------------------------------------------------------------------- helpers
def _lu(rng, lo, hi, size=None):
    return np.exp(rng.uniform(np.log(lo), np.log(hi), size))


def _sgn(rng, size=None):
    return rng.choice([-1.0, 1.0], size)


def rotx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def roty(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rotz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotvec(v):
    """Rotation matrix of rotation vector v (rad)."""
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * Kx + (1 - math.cos(th)) * Kx @ Kx


def axis_angle(R):
    """Axis (unit) and angle of rotation matrix R."""
    c = max(-1.0, min(1.0, (np.trace(R) - 1) / 2))
    th = math.acos(c)
    if th < 1e-9:
        return np.array([0.0, 0.0, 1.0]), 0.0
    if math.pi - th < 1e-6:
        M = (R + np.eye(3)) / 2
        i = int(np.argmax(np.diag(M)))
        k = M[:, i] / math.sqrt(max(M[i, i], 1e-12))
        return k / np.linalg.norm(k), th
    k = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * math.sin(th))
    return k / np.linalg.norm(k), th


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


R_MOUNT = {"+z": np.eye(3), "-z": rotx(math.pi), "+x": roty(-math.pi / 2),
           "-x": roty(math.pi / 2), "+y": rotx(math.pi / 2), "-y": rotx(-math.pi / 2)}


def mount_vec(m):
    e = np.zeros(3)
    e["xyz".index(m[1])] = 1.0 if m[0] == "+" else -1.0
    return e


def perp_unit(rng, e):
    """Random unit vector perpendicular to e."""
    v = rng.normal(size=3)
    v -= v.dot(e) * e
    return v / np.linalg.norm(v)


def smoothstep(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def gm_process(rng, n, tau, dt=1.0):
    """Unit-variance Gauss-Markov sequence on a grid of step dt (stationary start)."""
    phi = math.exp(-dt / tau)
    x0 = rng.normal()
    return lfilter([math.sqrt(1 - phi * phi)], [1, -phi], rng.normal(size=n),
                   zi=[phi * x0])[0]


def lowpass(x, tau, dt):
    """Exact first-order lag of a sampled signal (starts settled at x[0])."""
    if tau <= 0:
        return x.copy()
    phi = math.exp(-dt / tau)
    return lfilter([1 - phi], [1, -phi], x, zi=[phi * x[0]])[0]


def lag_to(x, tau, dt, x0):
    phi = math.exp(-dt / tau)
    return lfilter([1 - phi], [1, -phi], x, zi=[phi * x0])[0]


# --------------------------------------------------------------------------------- plan
def _balanced(rng, options, n):
    out = [options[i % len(options)] for i in range(n)]
    rng.shuffle(out)
    return out


def plan(effect_units=28, seed=MASTER_SEED, n_complete=4, quick=False):
    """The seeded list of unit specs (uid, family, shape, magnitude bin, protocol variant)."""
    rng = np.random.default_rng([seed, 11])
    fams = list(FAMILIES)
    rng.shuffle(fams)
    counts = {f: effect_units // len(fams) + (1 if i < effect_units % len(fams) else 0)
              for i, f in enumerate(fams)}
    units = []
    for f in fams:
        n = counts[f]
        bins = list(rng.permutation(len(MAG_BINS)))
        while len(bins) < n:
            bins += list(rng.permutation(len(MAG_BINS)))
        shapes = list(FAMILIES[f]["shapes"])
        for i in range(n):
            units.append(dict(family=f, shape=shapes[i % len(shapes)], mag_bin=int(bins[i])))
    for i in range(n_complete):
        units.append(dict(family=None, shape=None, mag_bin=None))
    order = rng.permutation(len(units))
    units = [units[i] for i in order]
    n = len(units)
    feats = dict(
        n_mounts=_balanced(rng, [3, 4, 6], n),
        mount_col=_balanced(rng, ["none", "string", "dict"], n),
        accel=_balanced(rng, [True, False], n),
        time_kind=_balanced(rng, ["float0", "epoch", "ts_ns", "ts_us_utc"], n),
        dtype=_balanced(rng, ["f32", "f64", "f64"], n),
        rad=_balanced(rng, [True, False, False, False], n),
        pauses=_balanced(rng, [0, 1, 2, 3], n),
        nan_rows=_balanced(rng, [True, False, False], n),
        extra=_balanced(rng, ["sample", "chamber_sp", "none"], n),
        soak_log=_balanced(rng, ["tail", "tail", "full"], n),
        stop_between=_balanced(rng, [False, False, True], n),
        revisit=_balanced(rng, [True, False], n),
    )
    specs = []
    n_comp = 0
    for i, u in enumerate(units):
        v = {k: feats[k][i] for k in feats}
        v = {k: (x.item() if hasattr(x, "item") else x) for k, x in v.items()}
        f, sh = u["family"], u["shape"]
        # protocol constraints that make an effect exist on the protocol at all
        if f == "g_sensitivity" and sh != "linear":
            v["accel"] = True
        if f == "fixture" and sh == "debris_s0" and v["n_mounts"] == 3:
            v["n_mounts"] = 6
        v["hurried"] = None
        if f == "thermal_gradient":
            v["hurried"] = "strong"
        if f is None:
            v["hurried"] = "mild" if n_comp == 1 else None
            n_comp += 1
        specs.append(dict(uid=f"S5U{i + 1:02d}", index=i, seed=int(seed), family=f, shape=sh,
                          mag_bin=u["mag_bin"], variant=v))
    if quick:
        # a wiring check: one complete unit and three effect units of different families
        comp = [s for s in specs if s["family"] is None][:1]
        eff, seen = [], set()
        for s in specs:
            if s["family"] and s["family"] not in seen and len(eff) < 3:
                eff.append(s)
                seen.add(s["family"])
        specs = sorted(comp + eff, key=lambda s: s["index"])
    return specs


# --------------------------------------------------------------------------------- unit
def draw_unit(rng, v, clean=False):
    """Sensor, thermal, rig and logger parameters of one physical unit."""
    U = {}
    U["arw"] = float(_lu(rng, 0.004, 0.02)) * rng.uniform(0.8, 1.25, 3)   # deg/s/sqrt(Hz)
    U["H"] = float(rng.uniform(22, 45))                                     # hold length, s
    U["wf"] = float(np.sqrt(np.mean(U["arw"] ** 2) / (U["H"] - 2.0)))
    # bias vs die temperature (dT = T - 25 degC)
    U["b0"] = rng.normal(0, 0.3, 3)
    U["b1"] = _sgn(rng, 3) * _lu(rng, 0.002, 0.02, 3)
    U["b2"] = _sgn(rng, 3) * _lu(rng, 0.003, 0.05, 3) * (0 if clean else 1)
    U["b3"] = _sgn(rng, 3) * _lu(rng, 0.001, 0.02, 3) * (0 if clean else 1)
    K0 = np.eye(3) + np.diag(rng.normal(0, 0.005, 3))
    off = ~np.eye(3, dtype=bool)
    K0[off] += rng.normal(0, 0.003, 6)
    K1 = np.zeros((3, 3))
    K1[~off] = _sgn(rng, 3) * _lu(rng, 20e-6, 200e-6, 3)
    K1[off] = _sgn(rng, 6) * _lu(rng, 0.5e-6, 10e-6, 6)
    K2 = np.zeros((3, 3))
    K2[~off] = _sgn(rng, 3) * _lu(rng, 30e-6, 500e-6, 3)
    K2[off] = _sgn(rng, 6) * _lu(rng, 1e-6, 50e-6, 6)
    U["K0"], U["K1"], U["K2"] = K0, K1, K2 * (0 if clean else 1)
    # noise beyond white
    U["bi_kind"] = str(rng.choice(["gm", "flicker"]))
    U["bi_tau"] = float(_lu(rng, 100, 3000))
    U["bi_sigma"] = float(_lu(rng, 0.1, 0.8)) * U["wf"] * rng.uniform(0.7, 1.3, 3) * (0 if clean else 1)
    U["rep_sigma"] = float(_lu(rng, 0.5, 2.0)) * U["wf"] * (0 if clean else 1)
    # chamber and thermal path
    U["room"] = float(rng.uniform(20, 25))
    U["tau_air"] = float(_lu(rng, 20, 60))
    U["Kp"] = float(rng.uniform(0.8, 2.5))
    U["Ti"] = float(_lu(rng, 100, 400))
    U["u_lim"] = float(rng.uniform(25, 50))
    U["ramp"] = float(rng.uniform(1.0, 3.0))                  # degC/min
    U["ripple_sigma"] = float(_lu(rng, 0.01, 0.06)) * (0 if clean else 1)
    U["ripple_tau"] = float(_lu(rng, 30, 200))
    U["tau_door"] = float(_lu(rng, 150, 800)) if not clean else 1e12
    U["tau_case"] = float(_lu(rng, 150, 700))
    U["tau_die"] = float(_lu(rng, 3, 60))
    U["sh_case"] = float(rng.uniform(0.2, 1.5)) * (0 if clean else 1)
    U["sh_die"] = float(rng.uniform(0.05, 0.6)) * (0 if clean else 1)
    U["w_hand"] = float(rng.uniform(0, 0.3)) * (0 if clean else 1)
    # the unit's own temperature sensor
    U["ts_node"] = "die" if (clean or rng.uniform() < 0.4) else "lag"
    U["ts_tau"] = float(_lu(rng, 5, 60))
    U["ts_off"] = float(rng.normal(0, 1.0))
    U["ts_gain"] = float(1 + rng.normal(0, 0.005))
    U["ts_noise"] = float(_lu(rng, 0.01, 0.08))
    U["ts_q"] = float(rng.choice([1 / 16, 1 / 64, 1 / 256]))
    U["ts_update"] = str(rng.choice(["sample", "1s"]))
    # fixture, table, accelerometer
    U["seat_sigma"] = float(_lu(rng, 1e-6, 8e-6)) * (0 if clean else 1)  # rad
    U["radius"] = float(rng.uniform(0.0, 0.06))                          # m
    U["a_peak"] = float(_lu(rng, 30, 200))                               # deg/s^2
    U["ref_jitter"] = float(_lu(rng, 1e-6, 2e-5)) if rng.uniform() < 0.5 else 0.0
    U["acc_bias"] = rng.normal(0, 0.005, 3)
    U["acc_scale"] = 1 + rng.normal(0, 0.003, 3)
    U["acc_noise"] = float(_lu(rng, 0.0005, 0.003))
    # rate list (same magnitudes in every session: the lab's protocol)
    top = int(rng.choice([100, 200, 300, 400], p=[0.2, 0.3, 0.2, 0.3]))
    below = [r for r in RATE_SET if r < top]
    n_mag = int(rng.integers(2, 4)) if v["n_mounts"] == 6 else int(rng.integers(3, 6))
    lows = [r for r in below if r in LOW_RATES]
    mags = {top, float(rng.choice(lows))}
    rest = [r for r in below if r not in mags]
    while len(mags) < n_mag + 1 and rest:
        r = rest.pop(int(rng.integers(len(rest))))
        mags.add(r)
    U["top"] = float(top)
    U["mags"] = sorted(float(m) for m in mags)
    U["zero_hold"] = bool(rng.uniform() < 0.6)
    # output quantisation
    rng_ = [r for r in (125, 250, 500, 1000, 2000) if r >= 1.3 * top][0]
    U["range"] = float(rng_)
    U["quant"] = bool(rng.uniform() < 0.7) and not clean
    return U


def set_points(rng):
    lo = 5 * round(rng.uniform(-40, -10) / 5)
    hi = 5 * round(rng.uniform(40, 70) / 5)
    n = int(rng.integers(3, 7))
    pts = np.linspace(lo, hi, n)
    pts[1:-1] += rng.uniform(-2, 2, n - 2)
    return [float(round(p, 1)) for p in pts]


def later_points(rng, p0, scheme):
    """Set points of sessions 1 and 2, derived from session 0's (sorted)."""
    p0 = sorted(p0)
    lo, hi = p0[0], p0[-1]
    if scheme == "same":
        pts = [p + rng.uniform(-1, 1) for p in p0]
    elif scheme == "mid":
        pts = [(a + b) / 2 + rng.uniform(-1, 1) for a, b in zip(p0[:-1], p0[1:])]
        if len(pts) < 3:
            pts.append(float(rng.choice([lo, hi])))
        if len(pts) < 3:
            pts.append(hi if pts[-1] == lo else lo)
    else:  # shift
        f = rng.uniform(0.2, 0.8)
        pts = [a + f * (b - a) for a, b in zip(p0[:-1], p0[1:])]
        pts.append(lo if rng.uniform() < 0.5 else hi)
        if len(pts) < 3:
            pts.append(hi if pts[-1] == lo else lo)
    pts = sorted(set(round(float(np.clip(p, lo, hi)), 1) for p in pts))
    return pts


def order_points(rng, pts, style, room):
    asc = sorted(pts)
    if style == "desc":
        out = asc[::-1]
    elif style in ("room_down_up", "room_up_down"):
        i = int(np.argmin([abs(p - room) for p in asc]))
        below, above = asc[:i][::-1], asc[i + 1:]
        out = [asc[i]] + (below + above if style == "room_down_up" else above + below)
    elif style == "zigzag":
        out, a, b = [], 0, len(asc) - 1
        while a <= b:
            out.append(asc[a])
            if a != b:
                out.append(asc[b])
            a, b = a + 1, b - 1
    else:
        out = list(rng.permutation(asc))
    out = [float(x) for x in out]
    if out == asc:
        out = out[::-1]
    return out


def order_rates(rng, mags, zero, style):
    if style == "desc":
        vals = sorted([m for m in mags] + [-m for m in mags] + ([0.0] if zero else []))[::-1]
    elif style == "zigzag":
        s = float(_sgn(rng))
        vals = []
        for m in mags:
            vals += [s * m, -s * m]
        if zero:
            vals.insert(int(rng.integers(len(vals) + 1)), 0.0)
    elif style == "high_first":
        s = float(_sgn(rng))
        rest = [m for m in mags[:-1]] + [-m for m in mags[:-1]] + ([0.0] if zero else [])
        rest = list(rng.permutation(rest))
        vals = [s * mags[-1], -s * mags[-1]] + [float(x) for x in rest]
    elif style == "sweep":
        vals = sorted(mags)[::-1] + ([0.0] if zero else []) + [-m for m in sorted(mags)]
    elif style == "outside_in":
        s = float(_sgn(rng))
        vals = []
        for m in sorted(mags)[::-1]:
            vals += [s * m, -s * m]
        if zero:
            vals.append(0.0)
    else:
        vals = [m for m in mags] + [-m for m in mags] + ([0.0] if zero else [])
        vals = [float(x) for x in rng.permutation(vals)]
    return [float(x) for x in vals]


def choose_mounts(rng, n):
    if n == 6:
        return list(MOUNT_WORDS)
    axes = list(rng.permutation(["x", "y", "z"]))
    ms = [str(_sgn_word(rng)) + a for a in axes]
    if n == 4:
        extra = ms[int(rng.integers(3))]
        ms.append(("-" if extra[0] == "+" else "+") + extra[1])
    return ms


def _sgn_word(rng):
    return "+" if rng.uniform() < 0.6 else "-"


def session_config(rng, U, v, p0, s, scheme):
    """Protocol of one session: set points and their order, mounts, rate orders, logger."""
    pts = p0 if s == 0 else later_points(rng, p0, scheme)
    style = str(rng.choice(["desc", "room_down_up", "room_up_down", "zigzag", "shuffle"]))
    order = order_points(rng, pts, style, U["room"])
    mounts = choose_mounts(rng, v["n_mounts"])
    mstyle = str(rng.choice(["fixed", "serpentine", "random"]))
    rstyle = str(rng.choice(["desc", "zigzag", "high_first", "sweep", "outside_in", "shuffle"]))
    visits = []
    for k, T in enumerate(order):
        if mstyle == "fixed":
            ms = list(mounts)
        elif mstyle == "serpentine":
            ms = list(mounts) if k % 2 == 0 else list(mounts)[::-1]
        else:
            ms = [str(x) for x in rng.permutation(mounts)]
        visits.append(dict(T=T, mounts=ms, revisit=False))
    if v["revisit"] and rng.uniform() < 0.7:
        T = float(rng.choice(order[:-1]))
        ms = list(mounts) if rng.uniform() < 0.5 else [str(x) for x in
                                                        rng.permutation(mounts)[:int(rng.integers(1, 3))]]
        visits.append(dict(T=T, mounts=ms, revisit=True))
    power = str(rng.choice(["never", "never", "never", "setpoint", "remount"]))
    return dict(session=s, scheme=scheme if s else "base", points=sorted(pts), order_style=style,
                soak_factor=(4.0, 7.0), wait=(60.0, 480.0),
                visits=visits, mount_style=mstyle, rate_style=rstyle, power=power,
                power_late=bool(rng.uniform() < 0.3), soak_log=v["soak_log"],
                pauses=int(v["pauses"]), stop_between=bool(v["stop_between"]))


# --------------------------------------------------------------------------------- timeline
def build_timeline(rng, U, C):
    """Continuous-time schedule of one session: segments, holds, handling, windows."""
    segs, holds, hands, places = [], [], [], []
    door, power_off, log_off, knots = [], [], [], []
    t = 0.0
    room = U["room"]
    knots.append((0.0, room))
    beta = rng.uniform(0, 2 * math.pi)           # fixture position on the table (radial dir)

    def place(m, k):
        R = rotvec(rng.normal(0, U["seat_sigma"], 3)) @ rotz(rng.uniform(0, 2 * math.pi)) @ R_MOUNT[m]
        places.append(dict(R=R, mount=m, visit=k, e=R.T @ np.array([0, 0, 1.0])))
        return len(places) - 1

    def handle(t0, p_old, p_new, power_cycle):
        D = float(rng.uniform(15, 45))
        hands.append(dict(t0=t0, t1=t0 + D, p_old=p_old, p_new=p_new))
        t_open = t0 + rng.uniform(0, 3)
        t_close = t0 + D + rng.uniform(2, 10)
        door.append((t_open, t_close))
        if power_cycle:
            power_off.append((t0 + 0.2 * D, t0 + 0.8 * D))
        return t_close

    cur_sp = room
    p_cur = place(C["visits"][0]["mounts"][0], 0)
    t = handle(0.0, None, p_cur, False) + rng.uniform(5, 30)
    segs.append(dict(kind="still", t0=0.0, t1=t, p=p_cur))
    n_rem_total = sum(len(vv["mounts"]) for vv in C["visits"]) - 1
    pause_at = set(rng.choice(max(n_rem_total, 1), size=min(C["pauses"], max(n_rem_total, 1)),
                              replace=False).tolist()) if C["pauses"] else set()
    rem_i = 0
    first_hold_t = None
    power_ons = [0.0]
    for k, vis in enumerate(C["visits"]):
        T = vis["T"]
        dur = abs(T - cur_sp) / U["ramp"] * 60.0
        knots.append((t, cur_sp))
        knots.append((t + dur, T))
        cur_sp = T
        soak = float(np.clip(rng.uniform(*C["soak_factor"]) * U["tau_case"], 300, 3600))
        if vis["revisit"]:
            soak = max(soak, 1500.0)
        if C["power"] == "setpoint" and k > 0:
            power_off.append((t, t + dur))
            power_ons.append(t + dur)
        t_end = t + dur + soak
        segs.append(dict(kind="still", t0=t, t1=t_end, p=p_cur))
        if C["soak_log"] == "tail":
            tail = float(rng.uniform(180, 900))
            log_off.append((t, t_end - tail))
        t = t_end
        for j, m in enumerate(vis["mounts"]):
            if m != places[p_cur]["mount"] or (j == 0 and k > 0 and rng.uniform() < 0.15):
                if rem_i in pause_at:
                    pz = float(rng.uniform(60, 900))
                    segs.append(dict(kind="still", t0=t, t1=t + pz + 5, p=p_cur))
                    log_off.append((t + 2, t + pz))
                    t += pz + 5
                rem_i += 1
                still = float(rng.uniform(2, 8))
                segs.append(dict(kind="still", t0=t, t1=t + still, p=p_cur))
                t += still
                p_new = place(m, k)
                cyc = C["power"] == "remount"
                t_close = handle(t, p_cur, p_new, cyc)
                if cyc:
                    power_ons.append(power_off[-1][1])
                h = hands[-1]
                segs.append(dict(kind="handle", t0=h["t0"], t1=h["t1"], p=-1))
                segs.append(dict(kind="still", t0=h["t1"], t1=t_close, p=p_new))
                t = t_close
                p_cur = p_new
                wait = float(rng.uniform(*C["wait"]))
            else:
                wait = float(rng.uniform(10, 40))
            segs.append(dict(kind="still", t0=t, t1=t + wait, p=p_cur))
            t += wait
            if first_hold_t is None:
                first_hold_t = t
            w_prev = 0.0
            for w in _rates_for(rng, U, C):
                if C["stop_between"] and w_prev != 0.0 and w != 0.0:
                    D = max(0.5, 1.5 * abs(w_prev) / U["a_peak"])
                    segs.append(dict(kind="ramp", t0=t, t1=t + D, w0=w_prev, w1=0.0, p=p_cur))
                    t += D
                    st = float(rng.uniform(2, 5))
                    segs.append(dict(kind="still", t0=t, t1=t + st, p=p_cur))
                    t += st
                    w_prev = 0.0
                D = max(0.5, 1.5 * abs(w - w_prev) / U["a_peak"])
                if w != w_prev:
                    segs.append(dict(kind="ramp", t0=t, t1=t + D, w0=w_prev, w1=w, p=p_cur))
                    t += D
                segs.append(dict(kind="hold", t0=t, t1=t + U["H"], w0=w, w1=w, p=p_cur))
                holds.append(dict(t0=t, t1=t + U["H"], w=w, w_from=w_prev, p=p_cur, mount=m,
                                  visit=k, T_set=T, revisit=vis["revisit"]))
                t += U["H"]
                w_prev = w
            if w_prev != 0.0:
                D = max(0.5, 1.5 * abs(w_prev) / U["a_peak"])
                segs.append(dict(kind="ramp", t0=t, t1=t + D, w0=w_prev, w1=0.0, p=p_cur))
                t += D
            st = float(rng.uniform(3, 10))
            segs.append(dict(kind="still", t0=t, t1=t + st, p=p_cur))
            t += st
    segs.append(dict(kind="still", t0=t, t1=t + 20.0, p=p_cur))
    t += 20.0
    knots.append((t, cur_sp))
    if C["power_late"] and C["power"] != "setpoint":
        t_on = max(first_hold_t - float(_lu(rng, 300, 1800)), 60.0)
        power_off.append((0.0, t_on))
        power_ons[0] = t_on
    return dict(T_end=t, segs=segs, holds=holds, hands=hands, places=places, door=door,
                power_off=power_off, power_ons=sorted(power_ons), log_off=log_off, knots=knots,
                beta=beta)


def _rates_for(rng, U, C):
    return order_rates(rng, U["mags"], U["zero_hold"], C["rate_style"])


# --------------------------------------------------------------------------------- physics
def _windows_mask(t, wins):
    m = np.zeros(t.shape, bool)
    for a, b in wins:
        i0, i1 = np.searchsorted(t, [a, b])
        m[i0:i1] = True
    return m


def thermal(rng, U, TL):
    """Chamber air (PI-controlled), case and die temperatures on a 1 s grid."""
    n = int(math.ceil(TL["T_end"])) + 2
    tg = np.arange(n, dtype=float)
    kt, kT = zip(*TL["knots"])
    sp = np.interp(tg, np.array(kt), np.array(kT))
    door = _windows_mask(tg, TL["door"]).astype(float)
    hand = _windows_mask(tg, [(h["t0"], h["t1"]) for h in TL["hands"]]).astype(float)
    power = 1.0 - _windows_mask(tg, TL["power_off"]).astype(float)
    room = U["room"]
    Ta, I = room, 0.0
    air = np.empty(n)
    tau_a, tau_d, Kp, Ti, lim = U["tau_air"], U["tau_door"], U["Kp"], U["Ti"], U["u_lim"]
    spl, dl = sp.tolist(), door.tolist()
    for k in range(n):
        s = spl[k]
        e = s - Ta
        u = s + Kp * e + I
        if u > s + lim:
            u = s + lim
        elif u < s - lim:
            u = s - lim
        else:
            I += e / Ti
        Ta += (u - Ta) / tau_a + dl[k] * (room - Ta) / tau_d
        air[k] = Ta
    air = air + U["ripple_sigma"] * gm_process(rng, n, U["ripple_tau"])
    env = (1 - U["w_hand"] * hand) * air + U["w_hand"] * hand * 32.0
    case = lag_to(env + U["sh_case"] * power, U["tau_case"], 1.0, room)
    die = lag_to(case + U["sh_die"] * power, U["tau_die"], 1.0, room)
    return dict(tg=tg, sp=sp, air=air, env=env, case=case, die=die, power=power)


def build_session(rng, U, C, v, epoch0):
    """Simulate one session: returns the state on logged samples, holds and writer info."""
    TL = build_timeline(rng, U, C)
    TH = thermal(rng, U, TL)
    # logged time and sample rate
    tg = TH["tg"]
    off1 = _windows_mask(tg, TL["log_off"] + TL["power_off"])
    logged_s = float((~off1).sum())
    allowed = [f for f in (20.0, 10.0, 5.0) if logged_s * f <= ROW_BUDGET] or [5.0]
    fs = float(allowed[0] if rng.uniform() < 0.5 else allowed[min(1, len(allowed) - 1)])
    N = int(math.floor(TL["T_end"] * fs))
    t_full = np.arange(N) / fs
    # table rate profile and placement index on the full grid
    w_tab = np.zeros(N)
    a_tab = np.zeros(N)
    pidx = np.full(N, -1, int)
    for sg in TL["segs"]:
        i0, i1 = int(math.ceil(sg["t0"] * fs)), int(math.ceil(sg["t1"] * fs))
        if i1 <= i0:
            continue
        if sg["kind"] != "handle":
            pidx[i0:i1] = sg["p"]
        if sg["kind"] == "hold":
            w_tab[i0:i1] = sg["w0"]
        elif sg["kind"] == "ramp":
            D = sg["t1"] - sg["t0"]
            u = (t_full[i0:i1] - sg["t0"]) / D
            dw = sg["w1"] - sg["w0"]
            w_tab[i0:i1] = sg["w0"] + dw * smoothstep(u)
            a_tab[i0:i1] = dw * 6 * u * (1 - u) / D
    for h in TL["hands"]:      # handling overrides whatever was painted
        i0, i1 = int(math.ceil(h["t0"] * fs)), int(math.ceil(h["t1"] * fs))
        pidx[i0:i1] = -1
        w_tab[i0:i1] = 0.0
    theta = np.cumsum(w_tab) / fs                                     # table angle, deg
    # logged samples
    keep = ~_windows_mask(t_full, TL["log_off"] + TL["power_off"])
    idx = np.nonzero(keep)[0]
    t = t_full[idx]
    n = len(t)
    p = pidx[idx]
    wt = w_tab[idx]
    at = a_tab[idx]
    E = np.array([pl["e"] for pl in TL["places"]])
    Rs = np.array([pl["R"] for pl in TL["places"]])
    placed = p >= 0
    e_rig = np.zeros((n, 3))
    e_rig[placed] = E[p[placed]]
    body_tab = wt[:, None] * e_rig
    # specific force (g): gravity + centripetal + tangential, in the sensor frame
    r = U["radius"]
    rh = np.array([math.cos(TL["beta"]), math.sin(TL["beta"]), 0.0])
    th_ = np.array([-rh[1], rh[0], 0.0])
    f_tab = np.zeros((n, 3))
    if placed.any():
        wr = wt[placed] * D2R
        ftab = (np.array([0, 0, 1.0])[None, :] - (wr ** 2 * r / G0)[:, None] * rh[None, :]
                + (at[placed] * D2R * r / G0)[:, None] * th_[None, :])
        f_tab[placed] = np.einsum("nji,nj->ni", Rs[p[placed]], ftab)
    # handling: motions of the operator's hand (ref_rate stays 0)
    body_hand = np.zeros((n, 3))
    for h in TL["hands"]:
        j0, j1 = np.searchsorted(t, [h["t0"], h["t1"]])
        if j1 <= j0:
            continue
        bh, fh = _handling(rng, TL, h, t[j0:j1], fs)
        body_hand[j0:j1] = bh
        f_tab[j0:j1] = fh
    # thermal state on logged samples
    die = np.interp(t, tg, TH["die"])
    case = np.interp(t, tg, TH["case"])
    env = np.interp(t, tg, TH["env"])
    # time since power-on, power segment index
    pons = np.array(TL["power_ons"])
    pseg = np.searchsorted(pons, t, side="right") - 1
    pseg = np.clip(pseg, 0, None)
    t_on = t - pons[pseg]
    # logged temperature
    node = TH["die"] if U["ts_node"] == "die" else lag_to(TH["die"], U["ts_tau"], 1.0, TH["die"][0])
    if U["ts_update"] == "1s":
        base = node[np.clip(np.floor(t).astype(int), 0, len(node) - 1)]
        nz = rng.normal(0, U["ts_noise"], len(node))[np.clip(np.floor(t).astype(int), 0, len(node) - 1)]
    else:
        base = np.interp(t, tg, node)
        nz = rng.normal(0, U["ts_noise"], n)
    temp = U["ts_off"] + U["ts_gain"] * base + nz
    temp = np.round(temp / U["ts_q"]) * U["ts_q"]
    # holds (logged sample windows, 1 s trimmed at each end)
    H = []
    for hd in TL["holds"]:
        j0, j1 = np.searchsorted(t, [hd["t0"] + 1.0, hd["t1"] - 1.0])
        H.append(dict(hd, j0=int(j0), j1=int(j1)))
    S = dict(C=C, TL=TL, TH=TH, fs=fs, t=t, n=n, p=p, w_tab=wt, a_tab=at, theta=theta[idx],
             e_rig=e_rig, body_tab=body_tab, body_hand=body_hand, f=f_tab, die=die, case=case,
             env=env, t_on=t_on, pseg=pseg, temp=temp, holds=H, epoch0=epoch0,
             mount_label=_mount_labels(TL, t))
    return S


def _mount_labels(TL, t):
    """The mount word the rig operator has entered: switches when the unit is placed."""
    lab = np.empty(len(t), dtype=object)
    lab[:] = TL["places"][TL["hands"][0]["p_new"]]["mount"]
    for h in TL["hands"][1:]:
        j = np.searchsorted(t, h["t1"])
        lab[j:] = TL["places"][h["p_new"]]["mount"]
    return lab


def _handling(rng, TL, h, tt, fs):
    """Body rate (deg/s) and gravity (g) in the sensor frame while the unit is handled."""
    places = TL["places"]
    R_new = places[h["p_new"]]["R"]
    R_old = places[h["p_old"]]["R"] if h["p_old"] is not None else random_rotation(rng)
    R_a = rotvec(perp_unit(rng, np.array([0, 0, 1.0])) * rng.uniform(0.3, 1.0)) @ R_old
    R_b = random_rotation(rng)
    R_c = rotvec(rng.normal(size=3) / math.sqrt(3) * rng.uniform(0.2, 0.7)) @ R_new
    way = [R_old, R_a, R_b, R_c, R_new]
    D = h["t1"] - h["t0"]
    legs = rng.uniform(0.5, 2.0, 4)
    gaps = rng.dirichlet(np.ones(5)) * max(D - legs.sum(), 0.5)
    n = len(tt)
    body = np.zeros((n, 3))
    grav = np.zeros((n, 3))
    z = np.array([0, 0, 1.0])
    tau = tt - h["t0"]
    # orientation at each sample: piecewise
    tc = gaps[0]
    R_cur = R_old
    grav[:] = R_old.T @ z
    for i in range(4):
        Ra, Rb = way[i], way[i + 1]
        k, ang = axis_angle(Rb @ Ra.T)
        m_leg = (tau >= tc) & (tau < tc + legs[i])
        u = (tau[m_leg] - tc) / legs[i]
        phi = ang * smoothstep(u)
        dphi = ang * 6 * u * (1 - u) / legs[i]
        body[m_leg] = (Ra.T @ k)[None, :] * (dphi / D2R)[:, None]
        # gravity: Ra^T Rot(k, -phi) z
        c, s = np.cos(phi), np.sin(phi)
        kz = k.dot(z)
        vrot = (z[None, :] * c[:, None] + np.cross(-k, z)[None, :] * s[:, None]
                + (k * kz)[None, :] * (1 - c)[:, None])
        grav[m_leg] = vrot @ Ra
        after = tau >= tc + legs[i]
        grav[after] = Rb.T @ z
        tc += legs[i] + gaps[i + 1]
        R_cur = Rb
    # hand tremor (band-limited), while the unit is in the hand
    amp = float(_lu(rng, 0.3, 3.0))
    trem = lfilter([1 - math.exp(-2 * math.pi * 4 / fs)], [1, -math.exp(-2 * math.pi * 4 / fs)],
                   rng.normal(size=(n, 3)), axis=0)
    sd = trem.std() if n > 3 else 1.0
    inhand = (tau > gaps[0] * 0.5) & (tau < D - gaps[-1] * 0.5)
    body += amp * trem / max(sd, 1e-12) * inhand[:, None]
    return body, grav


def sensor_output(rng, U, S, ses_key):
    """Base gyro output (deg/s), without effect; and accelerometer (g)."""
    n, t = S["n"], S["t"]
    dT = S["die"] - 25.0
    body = S["body_tab"] + S["body_hand"]
    w = np.zeros((n, 3))
    q = (dT / 60.0) ** 2
    for i in range(3):
        for j in range(3):
            kij = U["K0"][i, j] + U["K1"][i, j] * dT + U["K2"][i, j] * q
            w[:, i] += kij * body[:, j]
        w[:, i] += (U["b0"][i] + U["b1"][i] * dT + U["b2"][i] * q
                    + U["b3"][i] * (dT / 60.0) ** 3)
    # turn-on bias: a new draw at every power-on
    n_on = int(S["pseg"].max()) + 1
    bon = rng.normal(0, 1, (n_on, 3)) * U["rep_sigma"]
    w += bon[S["pseg"]]
    # bias instability on a 1 s grid
    ng = int(math.ceil(t[-1])) + 2
    if U["bi_kind"] == "gm":
        bi = np.stack([gm_process(rng, ng, U["bi_tau"]) for _ in range(3)], 1)
    else:
        taus = np.geomspace(30, 20000, 5)
        bi = sum(np.stack([gm_process(rng, ng, tt) for _ in range(3)], 1) for tt in taus) / math.sqrt(5)
    bi = bi * U["bi_sigma"][None, :]
    for i in range(3):
        w[:, i] += np.interp(t, np.arange(ng, dtype=float), bi[:, i])
    w += rng.normal(size=(n, 3)) * (U["arw"] * math.sqrt(S["fs"]))[None, :]
    acc = (S["f"] * U["acc_scale"][None, :] + U["acc_bias"][None, :]
           + rng.normal(0, U["acc_noise"], (n, 3)))
    return w, acc


# --------------------------------------------------------------------------------- effects
def draw_effect(rng, fam, shape, U, sess_cfgs):
    P = dict(family=fam, shape=shape)
    top = U["top"]
    if fam == "g_sensitivity":
        G = rng.normal(size=(3, 3))
        P["G"] = G / np.linalg.norm(G) * (1.0 if shape != "anisoelastic" else 0.0)
        A = rng.normal(size=(3, 3))
        P["A"] = A / np.linalg.norm(A) * (0.0 if shape == "linear" else 1.0)
        if shape == "mixed":
            P["A"] *= rng.uniform(0.3, 1.0)
    elif fam == "rate_scale":
        P["s"] = rng.uniform(0.3, 1.0, 3)
        P["knee"] = rng.uniform(0.3, 0.7) * top
        P["R"] = rng.uniform(1.0, 2.0) * top
        P["w0"] = float(_lu(rng, 0.3, 3.0))
    elif fam == "rate_cross":
        c = np.zeros((3, 3))
        pairs = [(i, j) for i in range(3) for j in range(3) if i != j]
        for k in rng.choice(len(pairs), size=int(rng.integers(2, 5)), replace=False):
            c[pairs[k]] = rng.normal()
        P["c"] = c / np.abs(c).max()
        mids = [m for m in U["mags"] if m >= 5] or U["mags"]
        P["wc"] = float(rng.choice(mids))
        P["ws"] = float(rng.uniform(0.1, 0.3)) * P["wc"]
        P["wk"] = rng.uniform(0.3, 0.6) * top
    elif fam in ("thermal_gradient", "warmup", "thermal_hysteresis", "temp_feature", "slow_noise"):
        u = rng.normal(size=3)
        P["u"] = u / np.abs(u).max()
        if fam == "thermal_gradient":
            P["tau_f"] = float(_lu(rng, 30, 300))
        elif fam == "warmup":
            P["tau"] = float(_lu(rng, 8, 40)) * 60
            P["tau1"] = float(_lu(rng, 3, 10)) * 60
            P["tau2"] = float(_lu(rng, 30, 120)) * 60
            P["frac"] = float(rng.uniform(0.4, 0.7))
            P["ptau"] = float(_lu(rng, 2, 10)) * 60
        elif fam == "thermal_hysteresis":
            P["width"] = float(_lu(rng, 10, 25) if shape == "play_wide" else _lu(rng, 3, 9))
        elif fam == "temp_feature":
            P["sigma"] = float(_lu(rng, 1.5, 4.0))
            P["gamma"] = float(_lu(rng, 1.0, 3.0))
            P["wd"] = float(_lu(rng, 0.3, 1.5))
            # centre: near a point of session 2 that lies between session 0's points
            p0 = sorted(sess_cfgs[0]["points"])
            p2 = [x for x in sess_cfgs[2]["points"]
                  if min(abs(x - y) for y in p0) > 2.5]
            if not p2:
                p2 = [(p0[0] + p0[1]) / 2]
            c = float(rng.choice(p2))
            P["Tc"] = c + rng.uniform(-0.3, 0.3) * (P["sigma"] if shape != "step" else 1.0)
            if shape == "step":
                # a step between two of session 0's points, near a session-2 point
                P["Tc"] = c + rng.uniform(-1.0, 1.0)
        elif fam == "slow_noise":
            P["dwell"] = float(_lu(rng, 3, 40)) * 60
            P["gm_tau"] = float(_lu(rng, 1, 4)) * 3600
            P["axes"] = rng.uniform(size=3) < 0.6
            if not P["axes"].any():
                P["axes"][int(rng.integers(3))] = True
    elif fam == "unit_change":
        i = int(rng.integers(3))
        e = np.zeros(3)
        e[i] = 1
        dK = np.zeros((3, 3))
        dK[i] += perp_unit(rng, e)                       # one sensing axis tilts (rad)
        dK[np.diag_indices(3)] += rng.normal(0, 0.4, 3)  # scale changes (relative)
        P["dK"] = dK
        P["db"] = rng.normal(0, 0.2, 3) * top            # bias shift, per unit amplitude
    elif fam == "lab_reference":
        P["tau_s"] = float(_lu(rng, 2.0, 8.0))
    elif fam == "fixture":
        P["ws"] = rng.uniform(0.4, 0.8) * top
        P["debris_mount"] = None
    return P


def effect_unit(P, U, S, s, rng):
    """The effect's contribution to the gyro output at unit amplitude (deg/s), N x 3."""
    fam, shape = P["family"], P["shape"]
    n = S["n"]
    out = np.zeros((n, 3))
    body = S["body_tab"] + S["body_hand"]
    K0 = U["K0"]
    top = U["top"]
    if fam == "g_sensitivity":
        f = S["f"]
        out = f @ P["G"].T
        if shape != "linear":
            # anisoelastic / rectification: products of specific-force components
            ff = np.stack([f[:, 0] * f[:, 0], f[:, 1] * f[:, 1], f[:, 2] * f[:, 2]], 1)
            cross = np.stack([f[:, 1] * f[:, 2], f[:, 0] * f[:, 2], f[:, 0] * f[:, 1]], 1)
            out = out + ff @ P["A"].T + 0.5 * cross @ P["A"][::-1].T
    elif fam == "rate_scale":
        for i in range(3):
            x = body[:, i]
            if shape == "knee":
                g = np.sign(x) * np.maximum(np.abs(x) - P["knee"], 0) ** 2 / top
            elif shape == "tanh":
                g = x - P["R"] * np.tanh(x / P["R"])
            else:
                g = x * np.exp(-np.abs(x) / P["w0"])
            out[:, i] = -P["s"][i] * g
    elif fam == "rate_cross":
        for j in range(3):
            for k in range(3):
                if P["c"][j, k] == 0:
                    continue
                x = body[:, k]
                if shape == "square":
                    g = x * np.abs(x) / top
                elif shape == "bump":
                    g = x * np.exp(-(np.abs(x) - P["wc"]) ** 2 / (2 * P["ws"] ** 2))
                else:
                    g = np.sign(x) * np.maximum(np.abs(x) - P["wk"], 0)
                out[:, j] += P["c"][j, k] * g
    elif fam == "thermal_gradient":
        TH = S["TH"]
        if shape == "flux":
            q = lowpass(TH["env"] - TH["case"], P["tau_f"], 1.0)          # degC
        elif shape == "ddt_die":
            q = np.gradient(lowpass(TH["die"], 20.0, 1.0)) * 60.0          # degC/min
        else:
            q = lowpass(np.gradient(TH["case"]) * 60.0, P["tau_f"], 1.0)   # degC/min, lagged
        out = np.interp(S["t"], TH["tg"], q)[:, None] * P["u"][None, :]
    elif fam == "warmup":
        x = S["t_on"]
        if shape == "exp":
            g = np.exp(-x / P["tau"])
        elif shape == "two_exp":
            g = P["frac"] * np.exp(-x / P["tau1"]) + (1 - P["frac"]) * np.exp(-x / P["tau2"])
        else:
            g = (1 + x / P["ptau"]) ** -0.7
        out = g[:, None] * P["u"][None, :]
    elif fam == "thermal_hysteresis":
        TH = S["TH"]
        h = play_state(TH["die"], P["width"], S["TL"]["knots"][0][1])
        hs = np.interp(S["t"], TH["tg"], h)
        if shape == "play_scale":
            out = (hs[:, None] * P["u"][None, :]) * body / top
        else:
            out = hs[:, None] * P["u"][None, :]
    elif fam == "temp_feature":
        T = S["die"]
        if shape == "gauss":
            g = np.exp(-(T - P["Tc"]) ** 2 / (2 * P["sigma"] ** 2))
            out = g[:, None] * P["u"][None, :]
        elif shape == "step":
            g = 1.0 / (1.0 + np.exp(-(T - P["Tc"]) / P["wd"]))
            out = g[:, None] * P["u"][None, :]
        else:
            g = 1.0 / (1.0 + ((T - P["Tc"]) / P["gamma"]) ** 2)
            out = g[:, None] * P["u"][None, :] * body / top
    elif fam == "slow_noise":
        ng = int(math.ceil(S["t"][-1])) + 2
        if shape == "telegraph":
            x = np.stack([telegraph(rng, ng, P["dwell"]) for _ in range(3)], 1)
        elif shape == "random_walk":
            x = np.cumsum(rng.normal(size=(ng, 3)), 0) / math.sqrt(3600.0)   # per sqrt(h)
            x -= x.mean(0)
        else:
            x = np.stack([gm_process(rng, ng, P["gm_tau"]) for _ in range(3)], 1)
        x = x * (P["u"] * P["axes"])[None, :]
        tg = np.arange(ng, dtype=float)
        out = np.stack([np.interp(S["t"], tg, x[:, i]) for i in range(3)], 1)
    elif fam == "unit_change":
        m = np.ones(n) if s > 0 else np.zeros(n)
        if s == 0 and shape == "within":
            m = (S["t"] >= P["t_event"]).astype(float)
        out = (body @ (P["dK"]).T + P["db"][None, :]) * m[:, None]
    elif fam == "lab_reference":
        if shape == "scale_s0":
            if s == 0:
                out = S["body_tab"] @ K0.T            # the table turns (1 + a) x the logged rate
        else:
            # the table's rate loop overshoots each rate step and settles with a slow tail,
            # while the logged reference is the commanded (constant) rate
            dw = np.zeros(n)
            t = S["t"]
            for h in S["holds"]:
                j0, j1 = np.searchsorted(t, [h["t0"], h["t1"]])
                dw[j0:j1] = (h["w"] - h["w_from"]) * np.exp(-(t[j0:j1] - h["t0"]) / P["tau_s"])
            out = (dw[:, None] * S["e_rig"]) @ K0.T
    elif fam == "fixture":
        tilt = np.zeros((n, 3))
        places = S["TL"]["places"]
        if shape == "debris_s0":
            if s == 0:
                m = P["debris_mount"]
                v = P["debris_vec"]
                for pi, pl in enumerate(places):
                    if pl["mount"] == m:
                        tilt[S["p"] == pi] = v
        else:
            prng = np.random.default_rng(P["seed_sess"][s])
            for pi, pl in enumerate(places):
                vv = prng.normal(size=3)
                vv -= vv.dot(pl["e"]) * pl["e"]
                sel = S["p"] == pi
                if shape == "clamp_slip":
                    # the clamp gives at the first hold above the slip rate, until the next remount
                    hs = [h for h in S["holds"] if h["p"] == pi and abs(h["w"]) >= P["ws"]]
                    if not hs:
                        continue
                    sel = sel & (S["t"] >= hs[0]["t0"] - 0.5)
                tilt[sel] = vv
        # rate along the rig axis, turned by the extra tilt: (theta x e) * w
        dwv = np.cross(tilt, S["e_rig"]) * S["w_tab"][:, None]
        out = dwv @ K0.T
    return out


def play_state(T, width, T0):
    """Play (backlash) operator on the die temperature: +1 approached from below, -1 above."""
    y = T0
    h = np.empty(len(T))
    half = width / 2
    for k, x in enumerate(T.tolist()):
        if x - y > half:
            y = x - half
        elif y - x > half:
            y = x + half
        h[k] = (x - y) / half
    return h


def telegraph(rng, n, dwell):
    x = np.empty(n)
    k, s = 0, float(_sgn(rng))
    while k < n:
        d = int(max(1, rng.exponential(dwell)))
        x[k:k + d] = s
        s = -s
        k += d
    return x - x.mean()


# --------------------------------------------------------------------------------- standard
def hold_means(S, w):
    cs = np.vstack([np.zeros((1, w.shape[1])), np.cumsum(w, 0)])
    j0 = np.array([h["j0"] for h in S["holds"]])
    j1 = np.array([h["j1"] for h in S["holds"]])
    return (cs[j1] - cs[j0]) / (j1 - j0)[:, None]


def hold_table(S):
    hs = S["holds"]
    tm = hold_means(S, S["temp"][:, None])[:, 0]
    return dict(ref=np.array([h["w"] for h in hs]),
                e=np.array([mount_vec(h["mount"]) for h in hs]),
                T=tm, grp=np.array([h["T_set"] for h in hs]))


def standard_fit(h0, w0):
    """K (3x3) and B per set point of session 0 (12 parameters each), by least squares."""
    pts = []
    for g in sorted(set(h0["grp"].tolist())):
        m = h0["grp"] == g
        X = np.hstack([h0["ref"][m, None] * h0["e"][m], np.ones((m.sum(), 1))])
        coef, *_ = np.linalg.lstsq(X, w0[m], rcond=None)
        pts.append((float(h0["T"][m].mean()), coef[:3].T, coef[3]))
    pts.sort(key=lambda x: x[0])
    return pts


def standard_error(pts, h2, w2):
    Tp = np.array([p[0] for p in pts])
    Ks = np.array([p[1] for p in pts])
    Bs = np.array([p[2] for p in pts])
    err = np.empty_like(w2)
    for i in range(len(w2)):
        T = h2["T"][i]
        if T <= Tp[0]:
            K, B = Ks[0], Bs[0]
        elif T >= Tp[-1]:
            K, B = Ks[-1], Bs[-1]
        else:
            k = int(np.searchsorted(Tp, T)) - 1
            f = (T - Tp[k]) / (Tp[k + 1] - Tp[k])
            K = (1 - f) * Ks[k] + f * Ks[k + 1]
            B = (1 - f) * Bs[k] + f * Bs[k + 1]
        err[i] = np.linalg.solve(K, w2[i] - B) - h2["ref"][i] * h2["e"][i]
    return err


def standard_rms(h0, w0, h2, w2):
    e = standard_error(standard_fit(h0, w0), h2, w2)
    return float(np.sqrt(np.mean(e ** 2)))


# --------------------------------------------------------------------------------- build
def _unit_rng(spec, stream):
    return np.random.default_rng([spec["seed"], 5, spec["index"], stream])


def build_unit(spec, clean=False, with_tables=True):
    """Simulate one unit's three sessions; return tables, truth and private detail."""
    v = spec["variant"]
    fam, shape = spec["family"], spec["shape"]
    rng_u = _unit_rng(spec, 0)
    U = draw_unit(rng_u, v, clean=clean)
    p0 = set_points(rng_u)
    # session schemes: constraints that make some effects exist on the protocol
    schemes = [None, str(rng_u.choice(["same", "mid", "shift"])), str(rng_u.choice(["same", "mid", "shift"]))]
    if fam == "temp_feature":
        # both later sessions visit the middles between session 0's points
        schemes[1] = schemes[2] = "mid"
    hurried = {"strong": ((1.5, 3.0), (10.0, 60.0)), "mild": ((2.5, 4.0), (30.0, 150.0))}.get(
        v.get("hurried"))
    cfgs = []
    for s in range(3):
        rng_c = _unit_rng(spec, 10 + s)
        for attempt in range(50):
            C = session_config(rng_c, U, v, p0, s, schemes[s])
            if hurried:
                # the operator does not wait for the unit to settle (soak, after door openings)
                C["soak_factor"], C["wait"] = hurried
            if fam == "warmup" and s in (0, 2) and C["power"] == "never" and not C["power_late"]:
                C["power"] = "setpoint" if s == 0 else "remount"
            if fam == "thermal_hysteresis" and s > 0 and not _approach_differs(cfgs[0], C, U["room"]):
                continue
            if any([vv["T"] for vv in C["visits"]] == [vv["T"] for vv in c["visits"]] for c in cfgs):
                continue          # every session has its own order of set points
            break
        cfgs.append(C)
    rng_e = _unit_rng(spec, 30)
    P = draw_effect(rng_e, fam, shape, U, cfgs) if fam else None
    day2 = int(rng_u.integers(30, 181))
    days = [0, int(rng_u.integers(1, 31)), day2]
    base_epoch = 1767600000.0 + spec["index"] * 86400 * 3   # early 2026
    sessions = []
    for s in range(3):
        rng_s = _unit_rng(spec, 20 + s)
        epoch0 = base_epoch + days[s] * 86400 + float(rng_s.uniform(7, 10)) * 3600
        S = build_session(rng_s, U, cfgs[s], v, epoch0)
        w, acc = sensor_output(rng_s, U, S, s)
        S["w_base"], S["acc"] = w, acc
        sessions.append(S)
    if P is not None:
        _finish_effect(rng_e, P, U, sessions)
        for s, S in enumerate(sessions):
            S["w_eff"] = effect_unit(P, U, S, s, _unit_rng(spec, 40 + s))
    # standard calibration of session 0, judged on session 2
    h0, h2 = hold_table(sessions[0]), hold_table(sessions[2])
    w0b, w2b = hold_means(sessions[0], sessions[0]["w_base"]), hold_means(sessions[2], sessions[2]["w_base"])
    std0 = standard_rms(h0, w0b, h2, w2b)
    wf = float(np.sqrt(np.mean(U["arw"] ** 2) / (U["H"] - 2.0)))
    floor = max(wf, std0)
    amp, ratio, target = 0.0, std0 / floor, None
    if P is not None:
        lo, hi = MAG_BINS[spec["mag_bin"]]
        target = float(_lu(rng_e, lo, hi))
        d0 = hold_means(sessions[0], sessions[0]["w_eff"])
        d2 = hold_means(sessions[2], sessions[2]["w_eff"])

        def g(a):
            return standard_rms(h0, w0b + a * d0, h2, w2b + a * d2) / floor - target

        a_hi = 1e-9
        while g(a_hi) < 0:
            a_hi *= 4.0
            if a_hi > 1e9:
                raise RuntimeError(f"{spec['uid']}: effect cannot reach its target")
        a_lo = a_hi / 4.0 if a_hi > 1e-9 else 0.0
        amp = float(brentq(g, a_lo, a_hi, xtol=1e-14, rtol=1e-6))
        ratio = g(amp) + target
    F = FAMILIES.get(fam) if fam else None
    acts = tuple(F["acts"]) if F else ()
    if fam == "thermal_hysteresis":
        acts = ("scale",) if shape == "play_scale" else ("bias",)
    if fam == "temp_feature":
        acts = ("scale",) if shape == "lorentz_scale" else ("bias",)
    truth = dict(uid=spec["uid"], complete=fam is None, family=fam, shape=shape,
                 reads=set(F["reads"]) if F else set(), acts=set(acts),
                 reasons=set(F["reasons"]) if F else set(), carried=bool(F["carried"]) if F else False,
                 floor=floor, threshold=1.2 * floor, white_floor=wf, standard_no_effect=std0,
                 target_ratio=target, achieved_ratio=ratio, amplitude=amp,
                 physical=_physical(P, amp, U) if P else {})
    out = dict(truth=truth, U=U, cfgs=cfgs, sessions=sessions, amp=amp, P=P)
    if with_tables:
        out["tables"] = [to_table(spec, U, S, amp) for S in sessions]
    return out


def _approach_differs(C0, C, room):
    """True when some point of C is approached from the other side than the nearest of C0."""
    def dirs(Cx):
        prev, out = room, []
        for vis in Cx["visits"]:
            out.append((vis["T"], np.sign(vis["T"] - prev)))
            prev = vis["T"]
        return out
    d0 = dirs(C0)
    n_diff = 0
    dd = dirs(C)
    for T, sgn in dd:
        j = int(np.argmin([abs(T - x) for x, _ in d0]))
        n_diff += sgn != d0[j][1]
    return n_diff >= max(1, len(dd) // 3)


def _finish_effect(rng, P, U, sessions):
    """Effect parameters that depend on the simulated sessions."""
    if P["family"] == "unit_change" and P["shape"] == "within":
        hands = sessions[0]["TL"]["hands"][1:]
        h = hands[int(rng.integers(len(hands) // 3, max(len(hands) // 3 + 1, 2 * len(hands) // 3)))]
        P["t_event"] = float(h["t0"])
    if P["family"] == "fixture":
        P["seed_sess"] = [int(rng.integers(2 ** 31)) for _ in range(3)]
        if P["shape"] == "debris_s0":
            m0 = {h["mount"] for h in sessions[0]["holds"]}
            m2 = {h["mount"] for h in sessions[2]["holds"]}
            common = sorted(m0 & m2) or sorted(m0)
            P["debris_mount"] = str(rng.choice(common))
            P["debris_vec"] = perp_unit(rng, mount_vec(P["debris_mount"]))


def _physical(P, a, U):
    """The effect's size in physical units (private record only)."""
    fam, sh = P["family"], P["shape"]
    if fam == "g_sensitivity":
        return {"deg_s_per_g": a}
    if fam == "rate_scale":
        if sh == "deadband":
            return {"scale_deficit_at_0": a, "w0": P["w0"]}
        if sh == "knee":
            return {"deficit_at_top_deg_s": a * (U["top"] - P["knee"]) ** 2 / U["top"]}
        return {"deficit_at_top_deg_s": a * (U["top"] - P["R"] * math.tanh(U["top"] / P["R"]))}
    if fam == "rate_cross":
        return {"coef": a}
    if fam == "thermal_gradient":
        return {"deg_s_per_unit": a, "unit": "degC" if sh == "flux" else "degC/min"}
    if sh in ("play_scale", "lorentz_scale"):
        return {"relative_scale_peak": a / U["top"]}
    if fam in ("warmup", "thermal_hysteresis", "temp_feature", "slow_noise"):
        return {"deg_s_peak": a, "in_wf": a / U["wf"]}
    if fam == "unit_change":
        return {"tilt_rad": a}
    if fam == "lab_reference":
        return {"relative_scale" if sh == "scale_s0" else "overshoot_fraction": a}
    if fam == "fixture":
        return {"tilt_rad": a}
    return {}


# --------------------------------------------------------------------------------- writer
def to_table(spec, U, S, amp):
    v = spec["variant"]
    w = S["w_base"] + (amp * S["w_eff"] if "w_eff" in S and amp else 0.0)
    # output quantisation and range
    if U["quant"]:
        lsb = U["range"] / 32768.0
        if float(np.min(U["arw"])) * math.sqrt(S["fs"]) < lsb:
            lsb = U["range"] / 524288.0
        w = np.clip(np.round(w / lsb) * lsb, -U["range"], U["range"])
    ref = S["w_tab"].copy()
    if U["ref_jitter"]:
        rj = np.random.default_rng([spec["seed"], spec["index"], 77, S["C"]["session"]])
        ref = ref * (1 + U["ref_jitter"] * rj.normal(size=len(ref)))
    temp = S["temp"].copy()
    n = S["n"]
    if v["nan_rows"]:
        rj = np.random.default_rng([spec["seed"], spec["index"], 78, S["C"]["session"]])
        hmask = np.nonzero(S["p"] < 0)[0]
        if len(hmask):
            rows = rj.choice(hmask, size=min(int(rj.integers(1, 6)), len(hmask)), replace=False)
            w = w.copy()
            w[rows, int(rj.integers(3))] = np.nan
    conv = D2R if v["rad"] else 1.0
    fdt = pa.float32() if v["dtype"] == "f32" else pa.float64()
    tk = v["time_kind"]
    t = S["t"]
    if tk == "float0":
        tcol = pa.array(t, pa.float64())
    elif tk == "epoch":
        tcol = pa.array(S["epoch0"] + t, pa.float64())
    elif tk == "ts_ns":
        tcol = pa.array(np.round((S["epoch0"] + t) * 1e9).astype(np.int64), pa.timestamp("ns"))
    else:
        tcol = pa.array(np.round((S["epoch0"] + t) * 1e6).astype(np.int64), pa.timestamp("us", tz="UTC"))
    cols = {"t": tcol,
            "gyro_x": pa.array(w[:, 0] * conv, fdt), "gyro_y": pa.array(w[:, 1] * conv, fdt),
            "gyro_z": pa.array(w[:, 2] * conv, fdt),
            "temp": pa.array(temp, fdt), "ref_rate": pa.array(ref * conv, fdt)}
    if v["mount_col"] != "none":
        ma = pa.array(S["mount_label"].tolist(), pa.string())
        cols["mount"] = ma.dictionary_encode() if v["mount_col"] == "dict" else ma
    if v["accel"]:
        for i, a in enumerate("xyz"):
            cols[f"accel_{a}"] = pa.array(S["acc"][:, i], fdt)
    if v["extra"] == "sample":
        cols["sample"] = pa.array(np.round(t * S["fs"]).astype(np.int64), pa.int64())
    elif v["extra"] == "chamber_sp":
        cols["chamber_sp"] = pa.array(np.interp(t, S["TH"]["tg"], S["TH"]["sp"]), pa.float32())
    tab = pa.table(cols)
    if v["rad"]:
        tab = tab.replace_schema_metadata(
            {"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})})
    return tab


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    paths = []
    for s, tab in enumerate(built["tables"]):
        p = os.path.join(folder, f"session{s}.parquet")
        pq.write_table(tab, p)
        paths.append(p)
    return paths


# --------------------------------------------------------------------------------- contract
def validate_log(path):
    """Problems of one rig log against the contract (empty list: valid)."""
    probs = []
    try:
        tab = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        return [f"unreadable: {exc}"]
    sch = tab.schema
    names = set(sch.names)
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in names:
            probs.append(f"missing column {c}")
    if probs:
        return probs
    floats = (pa.float32(), pa.float64())
    tt = sch.field("t").type
    if not (tt == pa.float64() or pa.types.is_timestamp(tt)):
        probs.append(f"t has type {tt}")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y", "accel_z"):
        if c in names and sch.field(c).type not in floats:
            probs.append(f"{c} has type {sch.field(c).type}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in names]
    if acc and len(acc) != 3:
        probs.append("partial accelerometer columns")
    tv = tab.column("t")
    if pa.types.is_timestamp(tt):
        tn = tv.cast(pa.int64()).to_numpy().astype(float)
    else:
        tn = tv.to_numpy()
    if tab.num_rows < 100:
        probs.append("too few rows")
    if not np.all(np.isfinite(tn)):
        probs.append("t not finite")
    if np.any(np.diff(tn) <= 0):
        probs.append("t not strictly increasing")
    if "mount" in names:
        mt = sch.field("mount").type
        if not (pa.types.is_string(mt) or pa.types.is_large_string(mt) or pa.types.is_dictionary(mt)):
            probs.append(f"mount has type {mt}")
        vals = set(tab.column("mount").cast(pa.string()).to_pylist())
        if not vals <= set(MOUNT_WORDS):
            probs.append(f"mount words {sorted(map(str, vals - set(MOUNT_WORDS)))}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            u = json.loads(md[b"gyrocal.units"])
            if not set(u) <= {"gyro", "ref_rate"} or not set(u.values()) <= {"rad/s", "deg/s"}:
                probs.append(f"bad units metadata {u}")
        except ValueError:
            probs.append("units metadata not JSON")
    rr = tab.column("ref_rate").to_numpy(zero_copy_only=False)
    if not np.all(np.isfinite(rr)):
        probs.append("ref_rate not finite (allowed, but not written by this generator)")
    return probs
