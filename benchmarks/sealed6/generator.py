"""Sixth sealed benchmark: simulator of `turntable` rig logs of three-axis MEMS gyros.

SEALED: whoever works on the diagnosis must not read this file.

Each unit is one physical gyro written as three sessions (new power-on, new noise, own order of
set points, mounts and rates).  The sensor output is

    w = K(T_die) . w_true + B(T_die) + b_on + b_BI(t) + n(t) + a * e(t)

with e the unit's effect (zero for complete units) at unit amplitude and a chosen so that the
standard calibration of session 0 (K, B per set point, linear interpolation) misses session 2
by a target multiple of the reference floor.  Everything is deterministic given the spec.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

MASTER_SEED = 20260706
MOUNT_WORDS = ("+x", "-x", "+y", "-y", "+z", "-z")
EYE = np.eye(3)

# ---------------------------------------------------------------------------- families
# reads / acts / reasons use the judge's words only.  carried: a sensor term can carry it.
FAMILIES = {
    "gsens":     dict(reads=("accel", "mount"), acts=("bias",), reasons=(), carried=True, cap=25.0),
    "rate_knee": dict(reads=("rate",), acts=("scale",), reasons=(), carried=True, cap=300.0),
    "xrate_nl":  dict(reads=("rate",), acts=("cross-axis",), reasons=(), carried=True, cap=300.0),
    "dtdt":      dict(reads=("thermal",), acts=("bias",), reasons=(), carried=True, cap=60.0),
    "warmup":    dict(reads=("time",), acts=("bias",), reasons=(), carried=True, cap=100.0),
    "seat":      dict(reads=(), acts=(), reasons=("mounting",), carried=False, cap=20.0),
    "table":     dict(reads=(), acts=(), reasons=("lab",), carried=False, cap=100.0),
    "changed":   dict(reads=(), acts=(), reasons=("unit changed",), carried=False, cap=150.0),
    "slow":      dict(reads=(), acts=(), reasons=("slow noise",), carried=False, cap=60.0),
    "between":   dict(reads=(), acts=(), reasons=("between points",), carried=False, cap=150.0),
    "hyst":      dict(reads=("thermal",), acts=("bias",), reasons=("direction of approach",),
                      carried=False, cap=60.0),
}
BANDS = ((1.6, 3.0), (3.0, 12.0), (12.0, 50.0))


def _lu(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _unit(v):
    return v / np.linalg.norm(v)


def _rot(theta):
    """small-rotation matrix for rotation vector theta (rad)."""
    th = np.linalg.norm(theta)
    if th < 1e-15:
        return EYE.copy()
    k = theta / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return EYE + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def _mvec(word):
    v = np.zeros(3)
    v["xyz".index(word[1])] = 1.0 if word[0] == "+" else -1.0
    return v


# ---------------------------------------------------------------------------- planning
def plan(units_per_family=3, seed=MASTER_SEED, quick=False, n_complete=4):
    rng = np.random.default_rng(seed)
    specs = []
    for fam in FAMILIES:
        for k in range(units_per_family):
            specs.append(dict(family=fam, k=k, band=BANDS[k % len(BANDS)]))
    for k in range(n_complete):
        specs.append(dict(family=None, k=k, band=None))
    if quick:
        fams = list(FAMILIES)
        pick = rng.choice(len(fams), 3, replace=False)
        specs = [dict(family=fams[i], k=1, band=BANDS[1]) for i in pick] + \
                [dict(family=None, k=0, band=None)]
    order = rng.permutation(len(specs))
    out = []
    for j, i in enumerate(order):
        s = dict(specs[i])
        s["seed"] = int(rng.integers(1, 2 ** 31 - 1))
        s["uid"] = f"S6U{j:02d}"
        out.append(s)
    return out


# ---------------------------------------------------------------------------- the unit
def draw_unit(rng, fam, k):
    u = {}
    arw = _lu(rng, 0.004, 0.025) * rng.uniform(0.8, 1.25, 3)
    u["arw"] = arw
    # K(T), B(T): smooth temperature dependence
    u["K0"] = EYE * (1 + rng.normal(0, 0.01, 3)) + (1 - EYE) * rng.normal(0, 0.004, (3, 3))
    u["K1"] = EYE * rng.choice([-1, 1], 3) * np.array([_lu(rng, 30e-6, 300e-6) for _ in range(3)]) + \
        (1 - EYE) * rng.normal(0, 5e-6, (3, 3))
    u["K2"] = EYE * rng.normal(0, 0.2e-6, 3) + (1 - EYE) * rng.normal(0, 0.01e-6, (3, 3))
    u["B0"] = rng.normal(0, 0.4, 3)
    u["B1"] = rng.choice([-1, 1], 3) * np.array([_lu(rng, 0.002, 0.03) for _ in range(3)])
    u["B2"] = rng.normal(0, 3e-5, 3)
    u["B3"] = rng.normal(0, 2e-7, 3)
    u["k_rep"] = _lu(rng, 0.8, 3.0)
    u["k_bi"] = _lu(rng, 0.2, 1.5)
    u["tau_bi"] = _lu(rng, 30, 3000)
    # thermal path
    u["tau_case"] = _lu(rng, 200, 900)
    u["tau_die"] = _lu(rng, 8, 60)
    u["sh_case"] = rng.uniform(0.5, 3.0)
    u["sh_die"] = rng.uniform(0.1, 1.0)
    u["conv"] = rng.uniform(0.0, 0.6)
    u["sens_off"] = rng.normal(0, 1.2)
    u["sens_gain"] = 1 + rng.normal(0, 0.008)
    u["sens_tau"] = _lu(rng, 2, 60)
    u["sens_noise"] = _lu(rng, 0.005, 0.08)
    u["sens_q"] = float(rng.choice([1 / 256, 1 / 64, 1 / 16]))
    u["seat_urad"] = _lu(rng, 2, 25)
    # accelerometer
    u["acc_bias"] = rng.normal(0, 0.01, 3)
    u["acc_scale"] = 1 + rng.normal(0, 0.005, 3)
    u["radius"] = rng.uniform(0.0, 0.06)
    return u


def draw_protocol(rng, fam, k):
    p = {}
    nm = int(rng.choice([3, 4, 6], p=[0.45, 0.25, 0.30]))
    axes = rng.permutation(3)
    if nm == 3:
        mounts = [("+" if rng.random() < 0.6 else "-") + "xyz"[a] for a in axes]
    elif nm == 4:
        mounts = ["+" + "xyz"[a] for a in axes] + ["-" + "xyz"[axes[0]]]
    else:
        mounts = list(MOUNT_WORDS)
    p["mounts"] = mounts
    top = float(rng.choice([100, 200, 300, 400], p=[0.2, 0.3, 0.2, 0.3]))
    pool = [m for m in (0.5, 1, 2, 5, 10, 20, 30, 50, 75, 100, 150, 200, 250, 300) if m < top]
    nmag = int(rng.integers(3, 7 if nm < 6 else 5))
    mags = sorted(set(rng.choice(pool, min(nmag - 1, len(pool)), replace=False).tolist()) | {top})
    if fam in ("rate_knee", "xrate_nl") and len(mags) < 4:
        mags = sorted(set(mags) | {top * 0.5, top * 0.75})
    p["mags"] = mags
    p["top"] = top
    p["zero_hold"] = bool(rng.random() < 0.5)
    p["acc"] = _lu(rng, 30, 200)
    # temperature grid of session 0
    npt = int(rng.integers(3, 6))
    lo = 5 * round(rng.uniform(-40, -10) / 5)
    hi = 5 * round(rng.uniform(40, 70) / 5)
    if fam == "between":
        npt = int(rng.integers(3, 5))
    pts = np.linspace(lo, hi, npt)
    pts[1:-1] += rng.uniform(-2, 2, npt - 2)
    p["pts0"] = [float(x) for x in np.round(pts, 1)]
    nholds = nm * (2 * len(mags) + p["zero_hold"])
    H = rng.uniform(20, 45)
    H = min(H, 4.0 * 3600 / (nholds * npt * 1.2))
    p["H"] = float(max(H, 12.0))
    p["fs"] = 10.0 if nholds * npt * p["H"] * 20 > 200000 else float(rng.choice([10.0, 20.0]))
    # file variants
    p["mount_col"] = str(rng.choice(["none", "string", "dict"]))
    p["accel"] = bool(rng.random() < 0.45) or (fam == "gsens" and k != 1)
    p["time"] = str(rng.choice(["float0", "epoch", "ts_ns", "ts_us"]))
    p["dtype"] = str(rng.choice(["float32", "float64"]))
    p["rad"] = bool(rng.random() < 0.2)
    p["extra"] = bool(rng.random() < 0.5)
    p["nan_rows"] = int(rng.integers(1, 5)) if rng.random() < 0.3 else 0
    return p


def session_points(rng, p, s, fam):
    pts0 = p["pts0"]
    if s == 0:
        pts = list(pts0)
    else:
        mids = [(a + b) / 2 for a, b in zip(pts0[:-1], pts0[1:])]
        if fam == "between":
            pts = [pts0[0]] + mids + [pts0[-1]]
        else:
            mode = rng.choice(["same", "mid", "shift"], p=[0.4, 0.3, 0.3])
            if mode == "same":
                pts = [x + rng.uniform(-1, 1) for x in pts0]
            elif mode == "mid":
                pts = [pts0[0]] + mids + [pts0[-1]] if len(mids) < 3 else mids
            else:
                f = rng.uniform(0.2, 0.8)
                pts = [a + f * (b - a) for a, b in zip(pts0[:-1], pts0[1:])]
                if len(pts) < 3:
                    pts = [pts0[0]] + pts + [pts0[-1]]
    pts = sorted(round(float(x), 1) for x in pts)
    # order: never plainly ascending
    n = len(pts)
    room = 23.0
    if fam == "hyst":
        kinds = {0: "desc", 1: "zigzag", 2: "asc_rev"}
        kind = kinds[s]
    else:
        kind = str(rng.choice(["desc", "room_down_up", "room_up_down", "zigzag", "shuffle"]))
    if kind == "desc":
        order = list(range(n))[::-1]
    elif kind == "asc_rev":     # coldest first, then up, last one taken from above
        order = list(range(n - 1)) + [n - 1]
        order = order[:-2] + [n - 1, n - 2]
    elif kind == "zigzag":
        order, lo_, hi_ = [], 0, n - 1
        while lo_ <= hi_:
            order.append(lo_)
            if hi_ != lo_:
                order.append(hi_)
            lo_, hi_ = lo_ + 1, hi_ - 1
    elif kind in ("room_down_up", "room_up_down"):
        c = int(np.argmin([abs(x - room) for x in pts]))
        down = list(range(c, -1, -1))
        up = list(range(c + 1, n))
        order = down + up if kind == "room_down_up" else ([c] + up + list(range(c - 1, -1, -1)))
    else:
        order = list(rng.permutation(n))
    if order == sorted(order):
        order = order[::-1]
    seq = [pts[i] for i in order]
    revisit = None
    if rng.random() < 0.35 and fam not in ("hyst",):
        revisit = float(seq[int(rng.integers(0, n - 1))])
    return seq, revisit


def rate_sequence(rng, p):
    mags = p["mags"]
    kind = rng.choice(["shuffle", "desc", "asc", "altsign", "highfirst", "sweep"])
    if kind == "shuffle":
        rs = [s * m for m in mags for s in (1, -1)]
        rs = [rs[i] for i in rng.permutation(len(rs))]
    elif kind == "desc":
        rs = [s * m for m in mags[::-1] for s in (1, -1)]
    elif kind == "asc":
        rs = [s * m for m in mags for s in (-1, 1)]
    elif kind == "altsign":
        ms = [mags[i] for i in rng.permutation(len(mags))]
        rs = [s * m for m in ms for s in (1, -1)]
    elif kind == "highfirst":
        rest = [s * m for m in mags[:-1] for s in (1, -1)]
        rs = [mags[-1], -mags[-1]] + [rest[i] for i in rng.permutation(len(rest))]
    else:
        rs = [m for m in mags] + [-m for m in mags[::-1]]
    if p["zero_hold"]:
        rs.insert(int(rng.integers(0, len(rs) + 1)), 0.0)
    return [float(r) for r in rs], bool(rng.random() < 0.5)


# ---------------------------------------------------------------------------- a session
def simulate_session(rng, u, p, s, fam, fx):
    """Timeline, thermal path, motion; returns sample arrays and hold list."""
    fs = p["fs"]
    dt = 1.0 / fs
    seq, revisit = session_points(rng, p, s, fam)
    plan_pts = [(T, list(p["mounts"])) for T in seq]
    if revisit is not None:
        ms = list(p["mounts"]) if rng.random() < 0.5 else \
            list(rng.choice(p["mounts"], int(rng.integers(1, 3)), replace=False))
        plan_pts.append((revisit, ms))
    mount_mode = rng.choice(["fixed", "serpentine", "random"])
    room = rng.uniform(19, 26)
    ramp_rate = rng.uniform(1, 4) / 60.0       # degC/s
    door_tau = _lu(rng, 30, 600)
    hand_w = rng.uniform(0, 0.4)

    # --- build timeline of segments
    segs = []   # dicts: kind, t0, dur, logged, + payload
    t = 0.0
    sp_events = []      # (t, target setpoint)
    doors = []          # (t0, t1)
    hands = []
    cur_T = room
    cur_mount = None
    pause_left = int(rng.integers(0, 4))
    for ip, (T, ms) in enumerate(plan_pts):
        if mount_mode == "serpentine" and ip % 2:
            ms = ms[::-1]
        elif mount_mode == "random":
            ms = [ms[i] for i in rng.permutation(len(ms))]
        ramp = abs(T - cur_T) / ramp_rate
        sp_events.append((t, cur_T, T, ramp))
        soak = ramp + float(np.clip(rng.uniform(4, 7) * u["tau_case"], 900, 4800))
        tail = rng.uniform(180, 600)
        if cur_mount is None:
            cur_mount = ms[0]
            segs.append(dict(kind="place", t0=t, mount=cur_mount))
        segs.append(dict(kind="rest", t0=t, dur=soak - tail, logged=False, mount=cur_mount))
        segs.append(dict(kind="rest", t0=t + soak - tail, dur=tail, logged=True, mount=cur_mount))
        t += soak
        cur_T = T
        for m in ms:
            if m != cur_mount or (ip > 0 and rng.random() < 0.1):
                if pause_left and rng.random() < 0.3:
                    d = rng.uniform(60, 600)
                    segs.append(dict(kind="rest", t0=t, dur=d, logged=False, mount=cur_mount))
                    t += d
                    pause_left -= 1
                still = rng.uniform(2, 8)
                segs.append(dict(kind="rest", t0=t, dur=still, logged=True, mount=cur_mount))
                t += still
                dur = rng.uniform(15, 45)
                d_open = rng.uniform(2, 6)
                doors.append((t + d_open, t + dur + rng.uniform(2, 15)))
                hands.append((t + d_open + 2, t + dur))
                segs.append(dict(kind="handle", t0=t, dur=dur, logged=True, frm=cur_mount, to=m))
                t += dur
                cur_mount = m
                segs.append(dict(kind="place", t0=t, mount=m))
                w = rng.uniform(10, _lu(rng, 20, 240))
                segs.append(dict(kind="rest", t0=t, dur=w, logged=True, mount=m))
                t += w
            rates, stops = rate_sequence(rng, p)
            r_prev = 0.0
            for r in rates:
                if stops and r_prev != 0.0:
                    d = max(0.6, 1.5 * abs(r_prev) / p["acc"])
                    segs.append(dict(kind="ramp", t0=t, dur=d, r0=r_prev, r1=0.0, mount=m))
                    t += d
                    segs.append(dict(kind="rest", t0=t, dur=rng.uniform(1, 4), logged=True, mount=m))
                    t += segs[-1]["dur"]
                    r_prev = 0.0
                d = max(0.6, 1.5 * abs(r - r_prev) / p["acc"]) + rng.uniform(0.5, 2.0)
                segs.append(dict(kind="ramp", t0=t, dur=d, r0=r_prev, r1=r, mount=m))
                t += d
                segs.append(dict(kind="hold", t0=t, dur=p["H"], r=r, mount=m, T=T))
                t += p["H"]
                r_prev = r
            d = max(0.6, 1.5 * abs(r_prev) / p["acc"])
            segs.append(dict(kind="ramp", t0=t, dur=d, r0=r_prev, r1=0.0, mount=m))
            t += d
    t_end = t + 5.0
    segs.append(dict(kind="rest", t0=t, dur=5.0, logged=True, mount=cur_mount))

    # --- sample grid and motion
    place_u = {}
    ts, rr, body, mlab, hold_idx, upl, perp = [], [], [], [], [], [], []
    holds = []
    cur_u = None
    cur_perp = None
    for sg in segs:
        if sg["kind"] == "place":
            un = _mvec(sg["mount"])
            seat = rng.normal(0, u["seat_urad"] * 1e-6, 3)
            Rp = _rot(seat)
            cur_u = Rp @ un
            a = rng.uniform(0, 2 * np.pi)
            e1 = _unit(np.cross(un, [0.3, 0.5, 0.8] if abs(un[2]) < 0.9 else [1.0, 0.2, 0.0]))
            e2 = np.cross(un, e1)
            cur_perp = np.cos(a) * e1 + np.sin(a) * e2
            tilt = fx.get("seat_tilt")
            if tilt is not None:
                th = rng.normal(0, 1.0, 3)
                th -= th.dot(un) * un
                sg["dtilt"] = np.cross(th * 1e-3, cur_u)
            place_u[id(sg)] = cur_u
            cur_dtilt = sg.get("dtilt", np.zeros(3))
            continue
        if not sg.get("logged", True):
            continue
        n = max(1, int(np.floor(sg["dur"] * fs)))
        tt = sg["t0"] + np.arange(n) * dt
        ts.append(tt)
        if sg["kind"] == "rest":
            r = np.zeros(n)
            b = np.zeros((n, 3))
        elif sg["kind"] == "ramp":
            x = np.clip((tt - sg["t0"]) / (sg["dur"] - 0.3 if sg["dur"] > 0.6 else sg["dur"]), 0, 1)
            r = sg["r0"] + (sg["r1"] - sg["r0"]) * (1 - np.cos(np.pi * x)) / 2
            b = r[:, None] * cur_u[None, :]
        elif sg["kind"] == "hold":
            r = np.full(n, sg["r"])
            b = r[:, None] * cur_u[None, :]
            holds.append(dict(i0=sum(len(a) for a in ts[:-1]), n=n, r=sg["r"], mount=sg["mount"],
                              T=sg["T"], u=cur_u, dtilt=cur_dtilt))
        else:   # handle: real motion, ref_rate 0
            r = np.zeros(n)
            b = np.zeros((n, 3))
            nmv = int(rng.integers(3, 6))
            for _ in range(nmv):
                c = rng.uniform(sg["t0"] + 3, sg["t0"] + sg["dur"] - 2)
                w = rng.uniform(0.4, 2.0)
                pk = _lu(rng, 20, 250)
                ax = _unit(rng.normal(size=3))
                sh = np.where(np.abs(tt - c) < w / 2, np.cos(np.pi * (tt - c) / w), 0.0)
                b += pk * sh[:, None] * ax[None, :]
            trem = rng.normal(0, 1, (n, 3))
            k = max(1, int(fs / 4))
            trem = np.apply_along_axis(lambda v: np.convolve(v, np.ones(k) / k, "same"), 0, trem)
            b += _lu(rng, 0.3, 4) * trem * np.sqrt(k)
        rr.append(r)
        body.append(b)
        mlab.append(np.full(n, MOUNT_WORDS.index(sg.get("mount", sg.get("to", "+z")))))
        upl.append(np.repeat(cur_u[None, :], n, 0) if cur_u is not None else np.zeros((n, 3)))
        perp.append(np.repeat(cur_perp[None, :], n, 0))
    t = np.concatenate(ts)
    ref = np.concatenate(rr)
    w_true = np.concatenate(body)
    mount_i = np.concatenate(mlab)
    uvec = np.concatenate(upl)
    pvec = np.concatenate(perp)
    # the ramps overlap holds by < 1 sample at most; enforce strict order
    keep = np.concatenate([[True], np.diff(t) > 1e-6])
    if not keep.all():
        raise RuntimeError("timeline overlap")

    # --- thermal path on a 1 s grid
    g = np.arange(0.0, t_end + 2.0, 1.0)
    sp = np.full(g.size, room)
    for (t0, T0, T1, rd) in sp_events:
        m = g >= t0
        x = np.clip((g[m] - t0) / max(rd, 1.0), 0, 1)
        sp[m] = T0 + (T1 - T0) * x
    door = np.zeros(g.size, bool)
    for a, b_ in doors:
        door[(g >= a) & (g < b_)] = True
    hand = np.zeros(g.size, bool)
    for a, b_ in hands:
        hand[(g >= a) & (g < b_)] = True
    absr = np.interp(g, t, np.abs(ref))
    tau_air = _lu(rng, 20, 90)
    Kp, Ti, lim = rng.uniform(0.5, 3), _lu(rng, 60, 600), rng.uniform(25, 60)
    rip = np.zeros(g.size)
    rs, rt = _lu(rng, 0.01, 0.1), _lu(rng, 30, 300)
    ar = np.exp(-1 / rt)
    e = rng.normal(0, rs * np.sqrt(1 - ar * ar), g.size)
    for i in range(1, g.size):
        rip[i] = ar * rip[i - 1] + e[i]
    air = np.empty(g.size)
    case = np.empty(g.size)
    die = np.empty(g.size)
    A, C, D, I = room, room, room, 0.0
    tc, td = u["tau_case"], u["tau_die"]
    shc, shd, conv = u["sh_case"], u["sh_die"], u["conv"]
    for i in range(g.size):
        err = sp[i] - A
        I = float(np.clip(I + err / Ti, -lim, lim))
        uu = float(np.clip(sp[i] + Kp * err + I, sp[i] - lim, sp[i] + lim))
        A += (uu - A) / tau_air
        if door[i]:
            A += (room - A) / door_tau
        Aeff = A + rip[i]
        env = (1 - hand_w) * Aeff + hand_w * 32.0 if hand[i] else Aeff
        C += (env + shc / (1 + conv * absr[i] / 300.0) - C) / tc
        D += (C + shd - D) / td
        air[i], case[i], die[i] = A, C, D
    # sensor node lags the die
    sn = np.empty(g.size)
    a_s = np.exp(-1 / u["sens_tau"])
    x = die[0]
    for i in range(g.size):
        x = a_s * x + (1 - a_s) * die[i]
        sn[i] = x
    Td = np.interp(t, g, die)
    Tsens = u["sens_gain"] * np.interp(t, g, sn) + u["sens_off"] + rng.normal(0, u["sens_noise"], t.size)
    Tsens = np.round(Tsens / u["sens_q"]) * u["sens_q"]

    # --- sensor model (base)
    dT = Td - 25.0
    K = u["K0"][None] + u["K1"][None] * dT[:, None, None] + u["K2"][None] * (dT ** 2)[:, None, None]
    B = u["B0"] + u["B1"] * dT[:, None] + u["B2"] * dT[:, None] ** 2 + u["B3"] * dT[:, None] ** 3
    w_base = np.einsum("nij,nj->ni", K, w_true) + B
    wf = float(np.sqrt(np.mean(u["arw"] ** 2) / (p["H"] - 2.0)))
    b_on = rng.normal(0, u["k_rep"] * wf, 3)
    # bias instability: Gauss-Markov on the 1 s grid
    sig_bi = u["k_bi"] * wf
    ab = np.exp(-1 / u["tau_bi"])
    bi = np.zeros((g.size, 3))
    eb = rng.normal(0, sig_bi * np.sqrt(1 - ab * ab), (g.size, 3))
    bi[0] = rng.normal(0, sig_bi, 3)
    for i in range(1, g.size):
        bi[i] = ab * bi[i - 1] + eb[i]
    bi_t = np.stack([np.interp(t, g, bi[:, j]) for j in range(3)], 1)
    white = rng.normal(0, 1, (t.size, 3)) * (u["arw"] * np.sqrt(fs))[None, :]
    w_base = w_base + b_on + bi_t + white

    # specific force (g) in the sensor frame
    cen = (np.deg2rad(ref) ** 2) * u["radius"] / 9.80665
    f = uvec + cen[:, None] * pvec
    hmask = np.all(uvec == 0, 1)
    f[hmask] = np.array([0, 0, 1.0])
    handle = np.abs(w_true).sum(1) > 0
    handle &= ref == 0
    if handle.any():
        f[handle] = f[handle] + rng.normal(0, 0.05, (int(handle.sum()), 3))

    env = dict(t=t, ref=ref, w_true=w_true, K=K, Td=Td, dT_grid=(g, die), f=f, mount_i=mount_i,
               uvec=uvec, fs=fs, holds=holds, s=s, pts=sorted(set(x for x, _ in plan_pts)),
               sp_grid=(g, sp))
    eff = effect_unit(fam, fx, env, rng)
    return dict(t=t, ref=ref, temp=Tsens, w_base=w_base, eff=eff, mount_i=mount_i, f=f,
                holds=holds, handle=handle, wf=wf, t_end=t_end)


# ---------------------------------------------------------------------------- effects
def draw_effect(rng, fam, k, u, p):
    fx = dict(variant=int(k % 3))
    if fam == "gsens":
        G = rng.normal(0, 0.3, (3, 3)) + EYE * rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.0, 3)
        fx["G"] = G * 0.01           # deg/s/g
    elif fam == "rate_knee":
        fx["knee"] = rng.uniform(0.3, 0.65)
        fx["sgn"] = rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.0, 3)
    elif fam == "xrate_nl":
        C = rng.normal(0, 1, (3, 3))
        np.fill_diagonal(C, 0)
        fx["C"] = C
    elif fam == "dtdt":
        fx["v"] = rng.normal(0, 1, 3) * 0.01
        fx["g0"] = rng.uniform(0.05, 0.4) / 60.0       # degC/s
        fx["lag"] = _lu(rng, 20, 200)
    elif fam == "warmup":
        fx["v"] = rng.normal(0, 1, 3) * 0.01
        fx["tau1"] = rng.uniform(15, 40) * 60
        fx["tau2"] = rng.uniform(70, 200) * 60
        fx["mix"] = rng.uniform(0.2, 0.8)
    elif fam == "seat":
        fx["seat_tilt"] = True
    elif fam == "table":
        fx["eps"] = rng.choice([-1, 1]) * 1e-4
    elif fam == "changed":
        dK = np.zeros((3, 3))
        if fx["variant"] == 0:
            i = int(rng.integers(0, 3))
            dK[i, i] = rng.choice([-1, 1]) * 1e-4
        elif fx["variant"] == 1:
            i, j = rng.choice(3, 2, replace=False)
            dK[i, j] = rng.choice([-1, 1]) * 1e-4
            dK[j, i] = rng.normal(0, 0.5e-4)
        else:
            dK = EYE * rng.normal(0, 0.7e-4, 3)
        fx["dK"] = dK
        fx["dB"] = rng.normal(0, 0.004, 3)
    elif fam == "slow":
        fx["tau"] = rng.uniform(20, 90) * 60
        fx["sig"] = 0.01
    elif fam == "between":
        pts = p["pts0"]
        spacing = (pts[-1] - pts[0]) / (len(pts) - 1)
        j = int(rng.integers(0, len(pts) - 1))
        fx["Tc"] = (pts[j] + pts[j + 1]) / 2
        fx["sig"] = spacing / 9.0
        fx["v"] = rng.normal(0, 1, 3) * 0.01
        fx["on_scale"] = fx["variant"] == 2
    elif fam == "hyst":
        fx["v"] = rng.normal(0, 1, 3) * 0.01
        fx["w"] = rng.uniform(1.5, 5.0)
    return fx


def effect_unit(fam, fx, env, rng):
    t, ref, wt, K, Td = env["t"], env["ref"], env["w_true"], env["K"], env["Td"]
    n = t.size
    z = np.zeros((n, 3))
    if fam is None:
        return z
    v = fx["variant"]
    if fam == "gsens":
        f = env["f"]
        if v == 1:
            return (fx["G"] @ (f * np.abs(f)).T).T
        if v == 2:   # saturating response to specific force
            return (fx["G"] @ np.tanh(f / 0.7).T).T
        return (fx["G"] @ f.T).T
    if fam == "rate_knee":
        top = max(np.abs(ref).max(), 1.0)
        wk = fx["knee"] * top
        a = np.abs(wt)
        if v == 2:   # smooth cubic compression
            ex = (a / top) ** 3 * top
        else:
            ex = np.maximum(a - wk, 0.0) ** 2 / top
        out = -np.sign(wt) * ex * fx["sgn"][None, :] * 1e-4
        if v == 1:   # only one turning direction compresses
            out = np.where(wt > 0, out * 2, 0.0)
        return out
    if fam == "xrate_nl":
        top = max(np.abs(ref).max(), 1.0)
        q = wt * np.abs(wt) / top
        if v == 1:   # coupling that sets in above a threshold
            q = np.sign(wt) * np.maximum(np.abs(wt) - 0.4 * top, 0) ** 2 / top * 2
        return (fx["C"] @ q.T).T * 1e-4
    if fam == "dtdt":
        g, die = env["dT_grid"]
        rate = np.gradient(die, g)
        a = np.exp(-1 / fx["lag"])
        lag = np.empty_like(rate)
        x = 0.0
        for i in range(rate.size):
            x = a * x + (1 - a) * rate[i]
            lag[i] = x
        r = np.interp(t, g, lag)
        s = np.tanh(r / fx["g0"])
        if v == 1:   # only warming drives it (one-sided gradient)
            s = np.maximum(s, 0)
        return s[:, None] * fx["v"][None, :]
    if fam == "warmup":
        tt = t - t[0] + 60.0
        if v == 2:
            sh = 1.0 / (1.0 + tt / fx["tau1"])
        else:
            sh = fx["mix"] * np.exp(-tt / fx["tau1"]) + (1 - fx["mix"]) * np.exp(-tt / fx["tau2"])
        return sh[:, None] * fx["v"][None, :] * 2
    if fam == "seat":
        return z     # filled in build_unit from each placement's tilt
    if fam == "table":
        if env["s"] != 0:
            return z
        top = max(np.abs(ref).max(), 1.0)
        if v == 0:
            sh = ref * fx["eps"]
        elif v == 1:   # droop at high rates (motor torque limit)
            sh = -abs(fx["eps"]) * ref * (np.abs(ref) / top) ** 2 * 2
        else:          # one direction only (encoder direction error)
            sh = np.where(ref > 0, ref * fx["eps"] * 1.5, 0.0)
        return np.einsum("nij,nj->ni", K, sh[:, None] * env["uvec"])
    if fam == "changed":
        if env["s"] == 0:
            return z
        return (fx["dK"] @ wt.T).T + fx["dB"][None, :]
    if fam == "slow":
        g = np.arange(t[0], t[-1] + 2, 5.0)
        a = np.exp(-5.0 / fx["tau"])
        x = np.zeros((g.size, 3))
        x[0] = rng.normal(0, fx["sig"], 3)
        e = rng.normal(0, fx["sig"] * np.sqrt(1 - a * a), (g.size, 3))
        for i in range(1, g.size):
            x[i] = a * x[i - 1] + e[i]
        if v == 1:    # random walk component as well
            x += np.cumsum(rng.normal(0, fx["sig"] * np.sqrt(5.0 / fx["tau"]), (g.size, 3)), 0)
        return np.stack([np.interp(t, g, x[:, j]) for j in range(3)], 1)
    if fam == "between":
        bump = np.exp(-0.5 * ((Td - fx["Tc"]) / fx["sig"]) ** 2)
        if fx["on_scale"]:
            return bump[:, None] * wt * fx["v"][None, :] * 0.01
        return bump[:, None] * fx["v"][None, :]
    if fam == "hyst":
        g, die = env["dT_grid"]
        st = np.empty_like(die)
        x = 0.0
        for i in range(1, die.size):
            x = min(1.0, max(-1.0, x + (die[i] - die[i - 1]) / fx["w"]))
            st[i] = x
        st[0] = 0.0
        return np.interp(t, g, st)[:, None] * fx["v"][None, :]
    return z


# ---------------------------------------------------------------------------- calibration
def hold_means(sess, w):
    out = []
    for h in sess["holds"]:
        i0, n = h["i0"], h["n"]
        k = max(1, int(round(1.0 / (sess["t"][1] - sess["t"][0]))))
        sl = slice(i0 + k, i0 + n - k) if n > 2 * k + 2 else slice(i0, i0 + n)
        out.append(w[sl].mean(0))
    return np.array(out)


def hold_temps(sess):
    return np.array([sess["temp"][h["i0"]:h["i0"] + h["n"]].mean() for h in sess["holds"]])


def standard_cal(sess, hm):
    ht = hold_temps(sess)
    X = np.array([h["r"] * _mvec(h["mount"]) for h in sess["holds"]])
    pts = {}
    for i, h in enumerate(sess["holds"]):
        pts.setdefault(h["T"], []).append(i)
    grid = []
    for T, idx in pts.items():
        A = np.hstack([X[idx], np.ones((len(idx), 1))])
        sol, *_ = np.linalg.lstsq(A, hm[idx], rcond=None)
        grid.append((ht[idx].mean(), sol[:3].T, sol[3]))
    grid.sort(key=lambda g: g[0])
    return grid


def apply_cal(grid, sess, hm):
    ht = hold_temps(sess)
    Ts = np.array([g[0] for g in grid])
    Ks = np.array([g[1] for g in grid])
    Bs = np.array([g[2] for g in grid])
    errs = []
    for i, h in enumerate(sess["holds"]):
        T = float(np.clip(ht[i], Ts[0], Ts[-1]))
        j = int(np.clip(np.searchsorted(Ts, T) - 1, 0, len(Ts) - 2))
        a = (T - Ts[j]) / (Ts[j + 1] - Ts[j]) if Ts[j + 1] > Ts[j] else 0.0
        Km = (1 - a) * Ks[j] + a * Ks[j + 1]
        Bm = (1 - a) * Bs[j] + a * Bs[j + 1]
        est = np.linalg.solve(Km, hm[i] - Bm)
        errs.append(est - h["r"] * _mvec(h["mount"]))
    return float(np.sqrt(np.mean(np.square(errs))))


def std_rms(s0, s2, hm0, hm2):
    return apply_cal(standard_cal(s0, hm0), s2, hm2)


# ---------------------------------------------------------------------------- build
def build_unit(spec, max_tries=6):
    fam = spec["family"]
    for attempt in range(max_tries):
        rng = np.random.default_rng(spec["seed"] + 7919 * attempt)
        u = draw_unit(rng, fam, spec["k"])
        p = draw_protocol(rng, fam, spec["k"])
        fx = draw_effect(rng, fam, spec["k"], u, p) if fam else {"variant": 0}
        sessions = []
        for s in range(3):
            ss = simulate_session(np.random.default_rng(rng.integers(1, 2 ** 31)), u, p, s, fam, fx)
            ss["fs"] = p["fs"]
            if fam == "seat":
                # tilt of each placement (mrad at unit amplitude): true rate off the nominal axis
                e = np.zeros_like(ss["w_base"])
                for h in ss["holds"]:
                    sl = slice(h["i0"], h["i0"] + h["n"])
                    e[sl] = h["r"] * h["dtilt"][None, :]
                ss["eff"] = e
            sessions.append(ss)
        hb = [hold_means(ss, ss["w_base"]) for ss in sessions]
        he = [hold_means(ss, ss["eff"]) for ss in sessions]
        wf = sessions[2]["wf"]
        base = std_rms(sessions[0], sessions[2], hb[0], hb[2])
        floor = max(wf, base)
        a = 0.0
        strength = base / floor
        if fam is not None:
            rng_t = np.random.default_rng(spec["seed"] + 1)
            target = _lu(rng_t, *spec["band"])

            def S(a_):
                return std_rms(sessions[0], sessions[2], hb[0] + a_ * he[0], hb[2] + a_ * he[2]) / floor
            cap = FAMILIES[fam]["cap"]
            if S(cap) < target:
                if attempt < max_tries - 1:
                    continue
                target = S(cap)
            lo, hi = cap * 1e-6, cap       # geometric bisection: S(lo) ~ base/floor < target
            for _ in range(45):
                mid = float(np.sqrt(lo * hi))
                if S(mid) >= target:
                    hi = mid
                else:
                    lo = mid
            a = hi
            strength = S(a)
        for ss in sessions:
            ss["gyro"] = ss["w_base"] + a * ss["eff"]
        F = FAMILIES.get(fam) if fam else None
        truth = dict(family=fam, complete=fam is None, floor=floor, threshold=1.2 * floor,
                     white_floor=wf, standard=base, strength=float(strength), amplitude=float(a),
                     reads=set(F["reads"]) if F else set(), acts=set(F["acts"]) if F else set(),
                     reasons=set(F["reasons"]) if F else set(),
                     carried=bool(F["carried"]) if F else True, attempt=attempt,
                     variant=fx.get("variant"))
        if fam == "gsens" and u["radius"] * np.deg2rad(p["top"]) ** 2 / 9.80665 > 0.1:
            truth["reads"].add("rate")
        if fam == "rate_knee" and fx["variant"] == 1:
            truth["acts"].add("bias")
        return dict(spec=spec, unit=u, protocol=p, sessions=sessions, truth=truth)
    raise RuntimeError("unreachable")


# ---------------------------------------------------------------------------- writing
def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    p = built["protocol"]
    rng = np.random.default_rng(built["spec"]["seed"] + 99)
    paths = []
    epoch0 = 1.76e9 + rng.uniform(0, 1e7)
    for s, ss in enumerate(built["sessions"]):
        n = ss["t"].size
        dt_ = np.float32 if p["dtype"] == "float32" else np.float64
        gy = ss["gyro"].copy()
        ref = ss["ref"].copy()
        if p["rad"]:
            gy = np.deg2rad(gy)
            ref = np.deg2rad(ref)
        cols = {}
        t = ss["t"]
        t0 = epoch0 + 86400 * (0, rng.integers(1, 30), rng.integers(30, 180))[s]
        if p["time"] == "float0":
            cols["t"] = pa.array(t, pa.float64())
        elif p["time"] == "epoch":
            cols["t"] = pa.array(t + t0, pa.float64())
        elif p["time"] == "ts_ns":
            cols["t"] = pa.array(np.round((t + t0) * 1e9).astype("int64"), pa.timestamp("ns"))
        else:
            cols["t"] = pa.array(np.round((t + t0) * 1e6).astype("int64"), pa.timestamp("us"))
        if p["nan_rows"]:
            idx = np.flatnonzero(ss["handle"])
            if idx.size:
                gy[rng.choice(idx, min(p["nan_rows"], idx.size), replace=False), 0] = np.nan
        for j, c in enumerate("xyz"):
            cols[f"gyro_{c}"] = pa.array(gy[:, j].astype(dt_))
        cols["temp"] = pa.array(ss["temp"].astype(dt_))
        cols["ref_rate"] = pa.array(ref.astype(dt_))
        words = np.array(MOUNT_WORDS)[ss["mount_i"]]
        if p["mount_col"] == "string":
            cols["mount"] = pa.array(words.tolist(), pa.string())
        elif p["mount_col"] == "dict":
            cols["mount"] = pa.array(words.tolist(), pa.string()).dictionary_encode()
        if p["accel"]:
            u = built["unit"]
            acc = ss["f"] * u["acc_scale"] + u["acc_bias"] + rng.normal(0, 0.002, (n, 3))
            for j, c in enumerate("xyz"):
                cols[f"accel_{c}"] = pa.array(acc[:, j].astype(dt_))
        if p["extra"]:
            cols["sample"] = pa.array(np.arange(n, dtype=np.int64))
        tab = pa.table(cols)
        if p["rad"]:
            md = dict(tab.schema.metadata or {})
            md[b"gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()
            tab = tab.replace_schema_metadata(md)
        path = os.path.join(folder, f"session{s}.parquet")
        pq.write_table(tab, path)
        paths.append(path)
    return paths


def validate_log(path):
    """Problems of one log against the contract (empty list = fine)."""
    probs = []
    tab = pq.read_table(path)
    sch = tab.schema
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in sch.names:
            probs.append(f"missing {c}")
    if probs:
        return probs
    tt = sch.field("t").type
    if pa.types.is_timestamp(tt):
        tv = tab.column("t").cast(pa.int64()).to_numpy().astype(np.float64)
    elif tt == pa.float64():
        tv = tab.column("t").to_numpy()
    else:
        probs.append(f"t type {tt}")
        tv = None
    if tv is not None and not np.all(np.diff(tv) > 0):
        probs.append("t not strictly increasing")
    fl = (pa.float32(), pa.float64())
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y", "accel_z"):
        if c in sch.names and sch.field(c).type not in fl:
            probs.append(f"{c} type {sch.field(c).type}")
    if any(c in sch.names for c in ("accel_x", "accel_y", "accel_z")) and \
            not all(c in sch.names for c in ("accel_x", "accel_y", "accel_z")):
        probs.append("partial accel")
    if "mount" in sch.names:
        mt = sch.field("mount").type
        if not (pa.types.is_string(mt) or pa.types.is_dictionary(mt)):
            probs.append(f"mount type {mt}")
        vals = set(tab.column("mount").cast(pa.string()).to_pylist()) if pa.types.is_dictionary(mt) \
            else set(tab.column("mount").to_pylist())
        if not vals <= set(MOUNT_WORDS):
            probs.append(f"mount words {sorted(vals - set(MOUNT_WORDS))}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            d = json.loads(md[b"gyrocal.units"])
            if not set(d.values()) <= {"rad/s", "deg/s"}:
                probs.append("units metadata values")
        except ValueError:
            probs.append("units metadata not JSON")
    if tab.num_rows > 320000:
        probs.append(f"{tab.num_rows} rows")
    return probs
