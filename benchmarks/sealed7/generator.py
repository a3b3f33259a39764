"""Seventh sealed benchmark: a simulator of `turntable` rig logs of a three-axis MEMS gyro.

SEALED: whoever works on the diagnosis does not read this file.

Each unit is one physical gyro written as three sessions (new power-on, new noise, its own
orders of set points, mounts and rates).  The unit follows

    w = K(T_die) . w_s + B(T_die) + b_on + b_BI(t) + n(t) + a * delta(t)

with w_s the true body rate in the sensor frame, and delta one effect family's signature at
unit amplitude (zero for complete units).  The amplitude a is fixed from the effect's
residual after the standard calibration (session 0 -> session 2) so that its strength is a
chosen multiple of the unit's reference floor, bounded by a physical cap.
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

MASTER_SEED = 20261130
D2R = math.pi / 180.0
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
RATE_MAGS = (0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 150, 200, 250, 300, 400)

# ----------------------------------------------------------------------------- families
# reads/acts/reasons use the judge's words only.  `carried`: a sensor term can carry it.
FAMILIES = {
    "F01": dict(reads={"rate", "temperature"}, acts={"scale"}, reasons=[], carried=True,
                cap=0.01),       # odd rate nonlinearity whose strength depends on temperature
    "F02": dict(reads={"rate"}, acts={"scale"}, reasons=[], carried=True,
                cap=0.6),        # low-rate threshold (dead band)
    "F03": dict(reads={"rate"}, acts={"cross-axis", "bias"}, reasons=[], carried=True,
                cap=0.5),        # rate-squared coupling into the other axes
    "F04": dict(reads={"accel", "mount", "temperature"}, acts={"bias"}, reasons=[],
                carried=True, cap=0.2),   # specific-force sensitivity changing with temperature
    "F05": dict(reads=set(), acts={"scale"}, reasons=["lab"], carried=False,
                cap=0.005),      # rig: table rate wrong in one session
    "F06": dict(reads={"mount"}, acts={"cross-axis"}, reasons=["mounting"], carried=False,
                cap=0.01),       # fixture: a face seated on debris in one session
    "F07": dict(reads=set(), acts={"cross-axis"}, reasons=["unit changed"], carried=False,
                cap=0.005),      # package relaxation after the first session
    "F08": dict(reads={"temperature"}, acts={"bias"}, reasons=["between points"],
                carried=False, cap=1.0),  # narrow feature in temperature between points
    "F09": dict(reads={"thermal"}, acts={"scale"}, reasons=["direction of approach"],
                carried=True, cap=0.005),  # thermal hysteresis of the scale factor
    "F10": dict(reads={"time"}, acts={"scale"}, reasons=[], carried=True,
                cap=0.005),      # scale creep after power-on
    "F11": dict(reads={"rate", "thermal", "time"}, acts={"bias"}, reasons=[], carried=True,
                cap=0.5),        # heat from the table drive: gradient through the package
    "F12": dict(reads={"time"}, acts={"bias"}, reasons=["slow noise"], carried=False,
                cap=0.5),        # two-level bias switching
}


def lu(rng, a, b):
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


# ----------------------------------------------------------------------------- plan
def plan(units_per_family=3, seed=MASTER_SEED, quick=False):
    rng = np.random.default_rng(seed)
    specs = []
    for fam in FAMILIES:
        for k in range(units_per_family):
            specs.append(dict(family=fam, tier=k % 3))
    for k in range(4):
        specs.append(dict(family=None, tier=0))
    order = rng.permutation(len(specs))
    specs = [specs[i] for i in order]
    for i, s in enumerate(specs):
        s["uid"] = f"U7{i:02d}"
        s["seed"] = int(rng.integers(1, 2**31 - 1))
    if quick:
        picked, fams = [], set()
        for s in specs:
            if s["family"] is None and not any(p["family"] is None for p in picked):
                picked.append(s)
            elif s["family"] is not None and s["family"] not in fams and \
                    sum(p["family"] is not None for p in picked) < 3:
                picked.append(s)
                fams.add(s["family"])
            if len(picked) == 4:
                break
        specs = picked
    return specs


# ----------------------------------------------------------------------------- unit
def _rot_to_up(axis, sign):
    v = np.zeros(3)
    v[axis] = sign
    r, _ = Rotation.align_vectors([[0, 0, 1.0]], [v])
    return r


def draw_unit(rng, family):
    u = {}
    u["arw"] = lu(rng, 0.003, 0.025) * rng.uniform(0.8, 1.25, 3)
    u["k_bi"] = lu(rng, 0.2, 2.0)
    u["tau_bi"] = lu(rng, 30, 5000)
    u["k_rep"] = lu(rng, 1, 4)
    # K(T), B(T)
    u["K0"] = np.eye(3) + np.diag(rng.normal(0, 0.01, 3)) + \
        (1 - np.eye(3)) * rng.normal(0, 0.004, (3, 3))
    u["K1"] = np.diag(rng.choice([-1, 1], 3) * [lu(rng, 30e-6, 300e-6) for _ in range(3)]) + \
        (1 - np.eye(3)) * rng.normal(0, 5e-6, (3, 3))
    u["K2"] = np.diag(rng.choice([-1, 1], 3) * [lu(rng, 50e-6, 1000e-6) for _ in range(3)]) / 3600
    u["B0"] = rng.normal(0, 0.4, 3)
    u["B1"] = rng.choice([-1, 1], 3) * np.array([lu(rng, 0.002, 0.03) for _ in range(3)])
    u["B2"] = rng.choice([-1, 1], 3) * np.array([lu(rng, 0.003, 0.15) for _ in range(3)]) / 3600
    u["B3"] = rng.choice([-1, 1], 3) * np.array([lu(rng, 0.001, 0.04) for _ in range(3)]) / 216000
    # thermal
    u["tau_air"] = lu(rng, 20, 80)
    u["kp"] = rng.uniform(0.5, 2.5)
    u["ti"] = lu(rng, 80, 500)
    u["lim"] = rng.uniform(25, 60)
    u["sp_rate"] = rng.uniform(1, 4) / 60.0
    u["ripple"] = lu(rng, 0.01, 0.12)
    u["tau_rip"] = lu(rng, 30, 300)
    u["tau_door"] = lu(rng, 30, 600)
    u["tau_case"] = lu(rng, 150, 900)
    u["tau_die"] = lu(rng, 5, 90) if rng.random() < 0.6 else 0.0
    u["sh_case"] = rng.uniform(0.3, 3.5)
    u["sh_die"] = rng.uniform(0.2, 1.5) if u["tau_die"] > 0 else 0.0
    u["conv"] = 0.0 if rng.random() < 0.3 else rng.uniform(0.1, 0.6)
    u["hand_w"] = rng.uniform(0, 0.4)
    mode = rng.choice(["die", "lag", "lead"], p=[0.3, 0.35, 0.35])
    u["sens_mode"] = str(mode)
    u["sens_tau"] = lu(rng, 3, 90)
    u["sens_kappa"] = rng.uniform(0.1, 0.5)
    u["sens_off"] = rng.normal(0, 1.2)
    u["sens_gain"] = 1 + rng.normal(0, 0.008)
    u["sens_noise"] = lu(rng, 0.005, 0.1)
    u["sens_q"] = float(rng.choice([1 / 256, 1 / 64, 1 / 16]))
    u["sens_upd"] = float(rng.choice([0.0, 1.0, 2.0]))
    u["seat"] = lu(rng, 2e-6, 25e-6)
    u["radius"] = rng.uniform(0, 0.07)
    u["accel"] = bool(rng.random() < 0.45)
    u["acc_bias"] = rng.normal(0, 0.01, 3)
    u["acc_scale"] = 1 + rng.normal(0, 0.005, 3)
    # protocol constants of the unit (the rig's recipe for this product)
    top = float(rng.choice([100, 200, 300, 400], p=[0.2, 0.3, 0.2, 0.3]))
    below = [m for m in RATE_MAGS if m < top]
    nm = int(rng.integers(2, 5))
    mags = sorted(set(rng.choice(below, nm, replace=False).tolist()) | {top})
    if family == "F02":   # a threshold needs slow holds to exist in the recipe
        slow = [m for m in below if m <= 2]
        mags = sorted(set(mags) | set(rng.choice(slow, 2, replace=False).tolist()))
    u["top"] = top
    u["mags"] = [float(m) for m in mags]
    u["zero"] = bool(rng.random() < 0.65)
    u["n_mounts"] = 3 if rng.random() < 0.55 else 6
    if u["n_mounts"] == 3:
        u["mount_set"] = [f"{'+' if rng.random() < 0.5 else '-'}{a}" for a in "xyz"]
    else:
        u["mount_set"] = list(MOUNTS)
    u["H"] = rng.uniform(20, 45)
    lo = 5 * round(rng.uniform(-40, -5) / 5)
    hi = 5 * round(rng.uniform(40, 70) / 5)
    n0 = int(rng.integers(3, 6))
    pts = np.linspace(lo, hi, n0)
    pts[1:-1] += rng.uniform(-2, 2, n0 - 2)
    u["sp0"] = [float(round(p, 1)) for p in pts]
    u["quant"] = bool(rng.random() < 0.5)
    u["family"] = family
    u["fam"] = draw_family(rng, family, u)
    return u


def draw_family(rng, family, u):
    f = {}
    sgn = lambda n: rng.choice([-1.0, 1.0], n)  # noqa: E731
    if family == "F01":
        f["ax"] = sgn(3) * rng.uniform(0.5, 1.5, 3)
        f["tauT"] = rng.uniform(25, 60)
    elif family == "F02":
        f["ax"] = rng.uniform(0.5, 1.5, 3)
        f["wth"] = lu(rng, 0.5, 3.0)
    elif family == "F03":
        C = rng.normal(0, 1, (3, 3)) * (1 - np.eye(3))
        f["C"] = C / np.sqrt((C ** 2).sum() / 6)
    elif family == "F04":
        G = rng.normal(0, 1, (3, 3))
        f["G"] = G / np.sqrt((G ** 2).sum() / 9)
        f["Tz"] = rng.uniform(u["sp0"][0] + 10, u["sp0"][-1] - 10)
    elif family == "F05":
        f["sign"] = float(sgn(1)[0])
    elif family == "F06":
        k = 1 if rng.random() < 0.6 else 2
        f["faces"] = [str(m) for m in rng.choice(u["mount_set"], k, replace=False)]
        f["az"] = [float(a) for a in rng.uniform(0, 2 * math.pi, k)]
    elif family == "F07":
        D = rng.normal(0, 1, (3, 3)) * (1 - np.eye(3))
        f["D"] = D / np.sqrt((D ** 2).sum() / 6)
        f["more"] = rng.uniform(1.0, 1.4)
    elif family == "F08":
        sp = u["sp0"]
        j = int(rng.integers(0, len(sp) - 1))
        f["Tc"] = 0.5 * (sp[j] + sp[j + 1]) + rng.uniform(-1, 1)
        f["w"] = rng.uniform(1.2, 2.5)
        v = rng.normal(0, 1, 3)
        f["v"] = v / np.linalg.norm(v) * math.sqrt(3)
    elif family == "F09":
        f["hw"] = rng.uniform(1.5, 5.0)
        s0 = sgn(1)[0]
        f["ax"] = s0 * rng.uniform(0.5, 1.5, 3) * np.where(rng.random(3) < 0.85, 1, -1)
    elif family == "F10":
        f["ax"] = sgn(1)[0] * rng.uniform(0.5, 1.5, 3)
        f["tau"] = lu(rng, 900, 5400)
    elif family == "F11":
        f["tau"] = lu(rng, 200, 1200)
        f["beta"] = sgn(1)[0] * rng.uniform(0.6, 1.4, 3)
        f["p"] = rng.uniform(1.5, 2.5)
    elif family == "F12":
        v = np.zeros(3)
        v[int(rng.integers(0, 3))] = 1.0
        v += rng.normal(0, 0.2, 3)
        f["v"] = v / np.linalg.norm(v) * math.sqrt(3)
        f["dwell"] = (lu(rng, 600, 4000), lu(rng, 600, 4000))
    return f


def K_of(u, T):
    d = (np.asarray(T) - 25.0)[..., None, None]
    return u["K0"] + u["K1"] * d + u["K2"] * d * d


def B_of(u, T):
    d = (np.asarray(T) - 25.0)[..., None]
    return u["B0"] + u["B1"] * d + u["B2"] * d * d + u["B3"] * d ** 3


# ----------------------------------------------------------------------------- session plan
def session_points(u, s, rng):
    sp0 = u["sp0"]
    if s == 0:
        pts = list(sp0)
    else:
        mode = rng.choice(["same", "mid", "shift"], p=[0.3, 0.35, 0.35])
        if u["family"] == "F08":
            mode = "mid"
        if mode == "same":
            pts = [p + rng.uniform(-1, 1) for p in sp0]
        elif mode == "mid":
            pts = [0.5 * (a + b) for a, b in zip(sp0[:-1], sp0[1:])]
            if len(pts) < 3:
                pts = [sp0[0] + 1.0] + pts + [sp0[-1] - 1.0]
            if u["family"] == "F08":
                Tc = u["fam"]["Tc"]
                k = int(np.argmin([abs(p - Tc) for p in pts]))
                pts[k] = Tc + rng.uniform(-0.8, 0.8)
        else:
            fr = rng.uniform(0.2, 0.8)
            pts = [a + fr * (b - a) for a, b in zip(sp0[:-1], sp0[1:])]
            if len(pts) < 3:
                pts = [sp0[0]] + pts
        pts = [float(np.clip(p, sp0[0], sp0[-1])) for p in pts]
    pts = sorted(round(p, 1) for p in pts)
    # temperature order: never plainly ascending
    kind = rng.choice(["desc", "room_down_up", "room_up_down", "zigzag", "shuffle"])
    n = len(pts)
    if kind == "desc":
        order = pts[::-1]
    elif kind in ("room_down_up", "room_up_down"):
        k = int(np.argmin([abs(p - 23) for p in pts]))
        down = pts[:k + 1][::-1]
        up = pts[k + 1:]
        if kind == "room_down_up":
            order = down + up
        else:
            up = pts[k:]
            down = pts[:k][::-1]
            order = up + down
    elif kind == "zigzag":
        order, lo, hi, t = [], 0, n - 1, 0
        while lo <= hi:
            if t % 2 == 0:
                order.append(pts[lo]); lo += 1
            else:
                order.append(pts[hi]); hi -= 1
            t += 1
    else:
        order = list(rng.permutation(pts))
    if list(order) == sorted(order):
        order = list(order[1:]) + [order[0]]
        if list(order) == sorted(order):
            order = order[::-1]
    return [float(p) for p in order], str(kind)


def rate_order(u, rng, kind):
    mags = u["mags"]
    rates = [m for m in mags] + [-m for m in mags]
    if kind == "asc":
        out = sorted(rates, key=lambda r: (abs(r), r < 0))
    elif kind == "desc":
        out = sorted(rates, key=lambda r: (-abs(r), r < 0))
    elif kind == "shuffle":
        out = list(rng.permutation(rates))
    elif kind == "high_first":
        rest = [r for r in rates if abs(r) != u["top"]]
        out = [u["top"], -u["top"]] + list(rng.permutation(rest))
    elif kind == "zigzag":
        out = []
        for m in mags[::-1] if rng.random() < 0.5 else mags:
            out += [m, -m]
    else:  # sweep
        out = sorted(m for m in mags) + sorted((-m for m in mags), key=lambda r: -r)
    out = [float(r) for r in out]
    if u["zero"]:
        out.insert(int(rng.integers(0, len(out) + 1)), 0.0)
    return out


def build_schedule(u, s, rng):
    """Segments on a continuous time line (s).  Each: kind, t0, t1 and fields."""
    pts, tkind = session_points(u, s, rng)
    revisit = rng.random() < 0.3
    rkind = str(rng.choice(["asc", "desc", "shuffle", "high_first", "zigzag", "sweep"]))
    mkind = str(rng.choice(["fixed", "serpentine", "random"]))
    base_mounts = list(rng.permutation(u["mount_set"]))
    n_rates = len(u["mags"]) * 2 + (1 if u["zero"] else 0)
    H = u["H"]
    per_mount = n_rates * (H + 6) + 120
    # keep the session at about <= 5.5 h
    soak_min = float(np.clip(rng.uniform(4, 7) * u["tau_case"], 900, 3000))
    est = len(pts) * (soak_min + u["n_mounts"] * per_mount)
    if est > 19800:
        H = max(15.0, H * 19800 / est)
        soak_min = max(900.0, soak_min * 19800 / est)
    seg = []
    t = 0.0
    room = rng.uniform(19, 26)
    cur_mount = base_mounts[0]
    cur_place = 0
    seg.append(dict(kind="insert", t0=t, t1=t + rng.uniform(15, 40), mount=cur_mount,
                    place=cur_place, sp=None, door=True))
    t = seg[-1]["t1"]
    visits = [(p, None) for p in pts]
    if revisit:
        p = float(rng.choice(pts[:-1])) if len(pts) > 1 else pts[0]
        nm = u["n_mounts"] if rng.random() < 0.4 else int(rng.integers(1, 3))
        visits.append((p, nm))
    prev_T = room
    for k, (p, nm) in enumerate(visits):
        ramp_t = abs(p - prev_T) / u["sp_rate"]
        soak = ramp_t + soak_min
        logged = "full" if rng.random() < 0.5 else "tail"
        tail = rng.uniform(180, 600)
        seg.append(dict(kind="soak", t0=t, t1=t + soak, mount=cur_mount, place=cur_place,
                        sp=p, logged=logged, tail=tail))
        t += soak
        prev_T = p
        if mkind == "fixed":
            mo = list(base_mounts)
        elif mkind == "serpentine":
            mo = list(base_mounts) if k % 2 == 0 else list(base_mounts[::-1])
        else:
            mo = list(rng.permutation(u["mount_set"]))
        if nm is not None:
            mo = mo[:nm]
        for m in mo:
            if m != cur_mount:
                d = rng.uniform(25, 70)
                seg.append(dict(kind="handle", t0=t, t1=t + d, mount=m, frm=cur_mount,
                                frm_place=cur_place, place=cur_place + 1, sp=p,
                                still=rng.uniform(2, 8), lift=rng.uniform(2, 6),
                                close=rng.uniform(3, 20)))
                t += d
                cur_mount = m
                cur_place += 1
            w = rng.uniform(5, lu(rng, 15, 240))
            seg.append(dict(kind="wait", t0=t, t1=t + w, mount=cur_mount, place=cur_place, sp=p))
            t += w
            r_prev = 0.0
            for r in rate_order(u, rng, rkind):
                a_pk = u["acc_pk"]
                T = max(0.6, math.pi * abs(r - r_prev) / (2 * a_pk))
                if r != r_prev:
                    seg.append(dict(kind="ramp", t0=t, t1=t + T, r0=r_prev, r1=r,
                                    mount=cur_mount, place=cur_place, sp=p))
                    t += T
                seg.append(dict(kind="hold", t0=t, t1=t + H, rate=r, mount=cur_mount,
                                place=cur_place, sp=p, spi=float(p)))
                t += H
                r_prev = r
            if r_prev != 0:
                T = max(0.6, math.pi * abs(r_prev) / (2 * u["acc_pk"]))
                seg.append(dict(kind="ramp", t0=t, t1=t + T, r0=r_prev, r1=0.0,
                                mount=cur_mount, place=cur_place, sp=p))
                t += T
            seg.append(dict(kind="wait", t0=t, t1=t + rng.uniform(2, 6), mount=cur_mount,
                            place=cur_place, sp=p))
            t = seg[-1]["t1"]
    meta = dict(points=pts, temp_order=tkind, rate_order=rkind, mount_order=mkind,
                revisit=bool(revisit), room=room, H=H)
    return seg, meta


# ----------------------------------------------------------------------------- simulation
def _gm(rng, n, dt, tau, sigma):
    a = math.exp(-dt / tau)
    e = rng.normal(0, sigma * math.sqrt(1 - a * a), n)
    e[0] = rng.normal(0, sigma)
    return lfilter([1.0], [1.0, -a], e)


def simulate(u, s, rng):
    seg, meta = build_schedule(u, s, rng)
    # sample rate: 20 Hz when the session stays under ~300k rows, else 10 Hz
    fs = 20.0 if seg[-1]["t1"] * 20 <= 300000 else 10.0
    dt = 1.0 / fs
    T_end = seg[-1]["t1"]
    n = int(T_end * fs)
    t = np.arange(n) * dt
    idx = lambda a: min(n, int(round(a * fs)))  # noqa: E731
    ref = np.zeros(n)
    door = np.zeros(n, bool)
    hand = np.zeros(n, bool)
    logged = np.ones(n, bool)
    hold_id = np.full(n, -1, np.int32)
    place_id = np.zeros(n, np.int32)
    mount_lab = np.empty(n, object)
    sp_tgt = np.full(n, np.nan)
    w_hand = np.zeros((n, 3))      # handling body rate (deg/s, sensor frame)
    up_hand = np.full((n, 3), np.nan)
    holds = []
    # placements: rotation sensor->rig per placement
    places = {}

    def placement(pid, m):
        if pid not in places:
            axis = "xyz".index(m[1])
            sign = 1.0 if m[0] == "+" else -1.0
            R0 = _rot_to_up(axis, sign)
            seat = Rotation.from_rotvec(rng.normal(0, u["seat"], 3))
            az = Rotation.from_euler("z", rng.uniform(0, 2 * math.pi))
            places[pid] = dict(R=az * seat * R0, mount=m, axis=axis, sign=sign)
        return places[pid]

    for g in seg:
        i0, i1 = idx(g["t0"]), idx(g["t1"])
        placement(g["place"], g["mount"])
        place_id[i0:i1] = g["place"]
        mount_lab[i0:i1] = g["mount"]
        if g.get("sp") is not None:
            sp_tgt[i0:i1] = g["sp"]
        k = g["kind"]
        if k == "insert":
            door[i0:i1] = True
        elif k == "soak":
            if g["logged"] == "tail":
                logged[i0:max(i0, i1 - int(g["tail"] * fs))] = False
        elif k == "ramp":
            tt = (t[i0:i1] - g["t0"]) / (g["t1"] - g["t0"])
            ref[i0:i1] = g["r0"] + (g["r1"] - g["r0"]) * (1 - np.cos(np.pi * tt)) / 2
        elif k == "hold":
            ref[i0:i1] = g["rate"]
            hold_id[i0:i1] = len(holds)
            p = places[g["place"]]
            holds.append(dict(i0=i0, i1=i1, rate=g["rate"], axis=p["axis"], sign=p["sign"],
                              sp=g["sp"], mount=g["mount"]))
        elif k == "handle":
            pa_ = placement(g["frm_place"], g["frm"])
            pb = placement(g["place"], g["mount"])
            ta = g["t0"] + g["still"]
            door[idx(ta):i1] = True
            tl = ta + g["lift"]
            tp = g["t1"] - g["close"]
            if tp - tl < 6:
                tp = tl + 6
            il, ip = idx(tl), idx(min(tp, g["t1"]))
            hand[il:ip] = True
            mount_lab[i0:ip] = g["frm"]
            place_id[i0:ip] = g["frm_place"]
            # orientation path: A -> R1 -> R2 -> B, four moves with pauses
            RA, RB = pa_["R"], pb["R"]
            mids = [RA * Rotation.from_rotvec(rng.normal(0, 0.8, 3)),
                    RB * Rotation.from_rotvec(rng.normal(0, 0.6, 3))]
            path = [RA] + mids + [RB]
            L = ip - il
            moves = len(path) - 1
            bounds = np.linspace(il, ip, moves + 1).astype(int)
            for j in range(moves):
                v = (path[j].inv() * path[j + 1]).as_rotvec()
                b0, b1 = bounds[j], bounds[j + 1]
                span = b1 - b0
                mv = max(2, int(span * rng.uniform(0.3, 0.7)))
                st = b0 + int(rng.uniform(0, 1) * (span - mv))
                tt = np.arange(mv) / mv
                sdot = (np.pi / 2) * np.sin(np.pi * tt) / (mv * dt)
                w_hand[st:st + mv] = (v[None, :] * sdot[:, None]) / D2R
                sv = (1 - np.cos(np.pi * tt)) / 2
                Rt = path[j] * Rotation.from_rotvec(sv[:, None] * v[None, :])
                up_hand[st:st + mv] = Rt.inv().apply([0, 0, 1.0])
                up_hand[b0:st] = path[j].inv().apply([0, 0, 1.0])
                up_hand[st + mv:b1] = path[j + 1].inv().apply([0, 0, 1.0])
            trem = lu(rng, 0.3, 3.0)
            e = rng.normal(0, 1, (L, 3))
            a = math.exp(-dt / 0.08)
            w_hand[il:ip] += lfilter([1 - a], [1, -a], e, axis=0) * trem / math.sqrt(
                (1 - a) / (1 + a))
    # sensor-frame rate, up, centripetal
    Rs = {pid: p["R"] for pid, p in places.items()}
    w_s = np.zeros((n, 3))
    up_s = np.zeros((n, 3))
    rad_s = np.zeros((n, 3))
    for pid, R in Rs.items():
        m = place_id == pid
        up = R.inv().apply([0, 0, 1.0])
        ur = R.inv().apply([1.0, 0, 0])      # radial direction (table frame) in sensor frame
        w_s[m] = ref[m, None] * up[None, :]
        up_s[m] = up
        rad_s[m] = ur
    hm = hand | ~np.isnan(up_hand[:, 0])
    w_s += w_hand
    up_s[hm & ~np.isnan(up_hand[:, 0])] = up_hand[hm & ~np.isnan(up_hand[:, 0])]
    # ---- thermal path on a 1 s grid
    ng = int(T_end) + 2
    tg = np.arange(ng, dtype=float)
    gi = np.minimum((tg * fs).astype(int), n - 1)
    spg = sp_tgt[gi]
    spg = np.where(np.isnan(spg), meta["room"], spg)
    doorg = door[gi]
    handg = hand[gi]
    omg = np.abs(ref[gi])
    rip = _gm(rng, ng, 1.0, u["tau_rip"], u["ripple"])
    room = meta["room"]
    air = case = die = room
    spr = room
    integ = 0.0
    a_air = 1 - math.exp(-1 / u["tau_air"])
    a_case = 1 - math.exp(-1 / u["tau_case"])
    a_die = 1 - math.exp(-1 / u["tau_die"]) if u["tau_die"] > 0 else 1.0
    a_door = 1 - math.exp(-1 / u["tau_door"])
    Tair = np.empty(ng); Tcase = np.empty(ng); Tdie = np.empty(ng)
    for k in range(ng):
        tgt = spg[k]
        stp = u["sp_rate"]
        spr = spr + float(np.clip(tgt - spr, -stp, stp))
        e = spr - air
        uu = spr + u["kp"] * e + integ
        lo_, hi_ = spr - u["lim"], spr + u["lim"]
        if lo_ < uu < hi_:
            integ += u["kp"] * e / u["ti"]
        uu = min(max(uu, lo_), hi_)
        air += (uu - air) * a_air
        if doorg[k]:
            air += (room - air) * a_door
        env = air + rip[k]
        if handg[k]:
            env = (1 - u["hand_w"]) * env + u["hand_w"] * 32.0
        shc = u["sh_case"] / (1 + u["conv"] * omg[k] / 300.0)
        case += (env + shc - case) * a_case
        die += (case + u["sh_die"] - die) * a_die
        Tair[k], Tcase[k], Tdie[k] = air, case, die
    T_die = np.interp(t, tg, Tdie)
    T_case = np.interp(t, tg, Tcase)
    if u["sens_mode"] == "die":
        node = Tdie
    elif u["sens_mode"] == "lag":
        a = 1 - math.exp(-1 / u["sens_tau"])
        node = lfilter([a], [1, -(1 - a)], Tdie - Tdie[0]) + Tdie[0]
    else:
        node = Tdie + u["sens_kappa"] * (Tcase - Tdie)
    ts = np.interp(t, tg, node)
    if u["sens_upd"] > 0:
        tq = np.floor(t / u["sens_upd"]) * u["sens_upd"]
        ts = np.interp(tq, tg, node)
    temp_log = u["sens_gain"] * ts + u["sens_off"] + rng.normal(0, u["sens_noise"], n)
    temp_log = np.round(temp_log / u["sens_q"]) * u["sens_q"]
    # ---- gyro output (effect-free)
    K = K_of(u, T_die)
    B = B_of(u, T_die)
    wf = white_floor(u, meta["H"])
    out = np.einsum("nij,nj->ni", K, w_s) + B
    out += rng.normal(0, u["k_rep"] * wf, 3)[None, :]
    sbi = u["k_bi"] * wf
    for j in range(3):
        out[:, j] += _gm(rng, n, dt, u["tau_bi"], sbi * rng.uniform(0.7, 1.3))
    out += rng.normal(0, 1, (n, 3)) * (u["arw"] * math.sqrt(fs))[None, :]
    # specific force (g): gravity + centripetal (toward the axis)
    cen = (ref * D2R) ** 2 * u["radius"] / 9.80665
    f_s = up_s - cen[:, None] * rad_s
    sim = dict(t=t, ref=ref, w_s=w_s, up_s=up_s, f_s=f_s, T_die=T_die, T_case=T_case,
               temp=temp_log, out=out, fs=fs, K=K, door=door, hand=hand, logged=logged,
               hold_id=hold_id, mount=mount_lab, holds=holds, meta=meta, place_id=place_id,
               places={pid: dict(axis=p["axis"], sign=p["sign"], mount=p["mount"],
                                 R=p["R"]) for pid, p in places.items()})
    return sim


def white_floor(u, H):
    return float(math.sqrt(np.mean(u["arw"] ** 2) / (H - 2.0)))


# ----------------------------------------------------------------------------- effects
def family_delta(u, sim, s):
    """The family's signature at unit amplitude, deg/s, (n, 3)."""
    fam, f = u["family"], u["fam"]
    w = sim["w_s"]
    n = w.shape[0]
    T = sim["T_die"]
    K = sim["K"]
    if fam is None:
        return np.zeros((n, 3))
    if fam == "F01":
        q = np.exp(-(T - 25.0) / f["tauT"])[:, None]
        return q * f["ax"][None, :] * w * (w / u["top"]) ** 2
    if fam == "F02":
        return -f["ax"][None, :] * w * np.exp(-(np.abs(w) / f["wth"]) ** 2)
    if fam == "F03":
        return ((w / u["top"]) ** 2) @ f["C"].T
    if fam == "F04":
        return (sim["f_s"] @ f["G"].T) * ((T - f["Tz"]) / 40.0)[:, None]
    if fam == "F05":
        if s != 0:
            return np.zeros((n, 3))
        wt = sim["ref"][:, None] * sim["up_s"]
        wt[sim["hand"]] = 0
        return f["sign"] * np.einsum("nij,nj->ni", K, wt)
    if fam == "F06":
        d = np.zeros((n, 3))
        if s != 0:
            return d
        for face, az in zip(f["faces"], f["az"]):
            for pid, p in sim["places"].items():
                if p["mount"] != face:
                    continue
                m = (sim["place_id"] == pid) & ~sim["hand"]
                nrig = np.array([math.cos(az), math.sin(az), 0.0])
                ns = p["R"].inv().apply(nrig)
                d[m] = -np.einsum("nij,nj->ni", K[m], np.cross(ns[None, :], w[m]))
        return d
    if fam == "F07":
        if s == 0:
            return np.zeros((n, 3))
        return (f["more"] if s == 2 else 1.0) * (w @ f["D"].T)
    if fam == "F08":
        return np.exp(-0.5 * ((T - f["Tc"]) / f["w"]) ** 2)[:, None] * f["v"][None, :]
    if fam == "F09":
        hw = f["hw"]
        y = T[0]
        x = np.empty(n)
        step = max(1, int(sim["fs"]))
        Tg = T[::step]
        xg = np.empty(Tg.size)
        for k, Tk in enumerate(Tg):
            y = min(max(y, Tk - hw), Tk + hw)
            xg[k] = (Tk - y) / hw
        x = np.repeat(xg, step)[:n]
        return x[:, None] * f["ax"][None, :] * w
    if fam == "F10":
        g = 1 - np.exp(-sim["t"] / f["tau"])
        return g[:, None] * f["ax"][None, :] * w
    if fam == "F11":
        Q = (np.abs(sim["ref"]) / u["top"]) ** f["p"]
        a = math.exp(-(1.0 / sim["fs"]) / f["tau"])
        g = lfilter([1 - a], [1, -a], Q)
        return g[:, None] * f["beta"][None, :] * np.abs(sim["up_s"])
    if fam == "F12":
        rng = np.random.default_rng([int(u["seed"]), s, 12])
        st = np.zeros(n)
        t = 0.0
        state = int(rng.random() < 0.5)
        tt = sim["t"]
        while t < tt[-1]:
            d = rng.exponential(f["dwell"][state])
            st[(tt >= t) & (tt < t + d)] = state
            t += d
            state = 1 - state
        return st[:, None] * f["v"][None, :]
    raise ValueError(fam)


# ----------------------------------------------------------------------------- standard calibration
def hold_means(sim, data):
    H = []
    fs = 1.0 / (sim["t"][1] - sim["t"][0])
    trim = int(round(fs))
    for h in sim["holds"]:
        a, b = h["i0"] + trim, h["i1"] - trim
        H.append((data[a:b].mean(axis=0), sim["temp"][a:b].mean()))
    return H


def _design(sim):
    X = []
    for h in sim["holds"]:
        e = np.zeros(3)
        e[h["axis"]] = h["sign"]
        X.append(h["rate"] * e)
    return np.array(X)


def std_fit(sim, data):
    hm = hold_means(sim, data)
    X = _design(sim)
    W = np.array([m for m, _ in hm])
    Tl = np.array([T for _, T in hm])
    sps = np.array([h["sp"] for h in sim["holds"]])
    pts = []
    for p in sorted(set(sps.tolist())):
        m = sps == p
        A = np.hstack([X[m], np.ones((m.sum(), 1))])
        P, *_ = np.linalg.lstsq(A, W[m], rcond=None)
        pts.append((Tl[m].mean(), P[:3].T, P[3]))
    pts.sort(key=lambda z: z[0])
    return pts


def _interp(pts, T):
    Ts = np.array([p[0] for p in pts])
    Ks = np.array([p[1] for p in pts])
    Bs = np.array([p[2] for p in pts])
    K = np.empty((3, 3))
    B = np.empty(3)
    for i in range(3):
        B[i] = np.interp(T, Ts, Bs[:, i])
        for j in range(3):
            K[i, j] = np.interp(T, Ts, Ks[:, i, j])
    return K, B


def std_error(sim0, data0, sim2, data2):
    pts = std_fit(sim0, data0)
    X = _design(sim2)
    err = []
    for (w, T), x in zip(hold_means(sim2, data2), X):
        K, B = _interp(pts, T)
        err.append(np.linalg.solve(K, w - B) - x)
    return float(np.sqrt(np.mean(np.square(err))))


def effect_residual(sim0, d0, sim2, d2):
    """Linear: the standard calibration's error from the effect alone."""
    pts = std_fit(sim0, d0)
    X = _design(sim2)
    err = []
    for (w, T), x in zip(hold_means(sim2, d2), X):
        K, B = _interp(pts, T)
        err.append(w - K @ x - B)
    return float(np.sqrt(np.mean(np.square(err))))


# ----------------------------------------------------------------------------- build
TIERS = ((1.6, 4.0), (4.0, 14.0), (14.0, 50.0))


def build_unit(spec):
    rng = np.random.default_rng(spec["seed"])
    fam = spec["family"]
    u = draw_unit(rng, fam)
    u["seed"] = spec["seed"]
    u["acc_pk"] = lu(rng, 20, 200)
    target = lu(rng, *TIERS[spec["tier"]])
    F = FAMILIES.get(fam)
    best = None
    for attempt in range(4):
        prng = np.random.default_rng(spec["seed"] + 7919 * (attempt + 1))
        sims = []
        for s in range(3):
            srng = np.random.default_rng(prng.integers(1, 2**31 - 1))
            sims.append(simulate(u, s, srng))
        deltas = [family_delta(u, sims[s], s) for s in range(3)]
        wf = white_floor(u, sims[2]["meta"]["H"])
        std = std_error(sims[0], sims[0]["out"], sims[2], sims[2]["out"])
        floor = max(wf, std)
        if fam is None:
            best = (sims, deltas, 0.0, floor, wf, std, 0.0)
            break
        e1 = effect_residual(sims[0], deltas[0], sims[2], deltas[2])
        amp = target * floor / max(e1, 1e-12)
        cand = (sims, deltas, min(amp, F["cap"]), floor, wf, std, e1)
        if amp <= F["cap"]:
            best = cand
            break
        if best is None or cand[2] * cand[6] > best[2] * best[6]:
            best = cand
    sims, deltas, amp, floor, wf, std, e1 = best
    for s in range(3):
        sims[s]["out"] = sims[s]["out"] + amp * deltas[s]
        sims[s]["out_clean"] = None
    with_eff = std_error(sims[0], sims[0]["out"], sims[2], sims[2]["out"])
    truth = dict(uid=spec["uid"], family=fam, complete=fam is None,
                 reads=set(F["reads"]) if F else set(), acts=set(F["acts"]) if F else set(),
                 reasons=list(F["reasons"]) if F else [], carried=bool(F["carried"]) if F else True,
                 floor=floor, white_floor=wf, standard=std, threshold=1.2 * floor,
                 target=target if F else 0.0, strength=(amp * e1 / floor) if F else 0.0,
                 amplitude=amp, standard_with_effect=with_eff,
                 capped=bool(F and amp >= F["cap"] * 0.999))
    return dict(unit=u, sessions=[_finish(u, sims[s], s, np.random.default_rng(
        spec["seed"] + 31 * s + 5)) for s in range(3)], truth=truth)


# ----------------------------------------------------------------------------- writing
def _finish(u, sim, s, rng):
    """Apply the logger's choices; return the columns and metadata of the log."""
    out = sim["out"].copy()
    if u["quant"]:
        rng_top = u["top"] * 1.31
        full = next(r for r in (125, 250, 500, 1000, 2000, 4000) if r >= rng_top)
        q = full / 32768
        if q < float(np.min(u["arw"])) * math.sqrt(sim["fs"]):
            out = np.clip(np.round(out / q) * q, -full, full)
    logged = sim["logged"].copy()
    n = out.shape[0]
    t = sim["t"]
    cols = {}
    fmt_t = rng.choice(["zero", "epoch", "ns", "us"])
    day0 = 1780000000.0 + 86400.0 * (0 if s == 0 else (rng.integers(1, 31) if s == 1 else
                                                        rng.integers(31, 181)))
    t0 = day0 + rng.uniform(6, 10) * 3600
    dtype = np.float32 if rng.random() < 0.4 else np.float64
    radps = rng.random() < 0.15
    conv = D2R if radps else 1.0
    temp = sim["temp"].copy()
    gy = out.copy()
    if rng.random() < 0.15:
        hidx = np.flatnonzero(sim["hand"] & logged)
        if hidx.size:
            for i in rng.choice(hidx, int(rng.integers(1, 6)), replace=False):
                gy[i, int(rng.integers(0, 3))] = np.nan
    sel = logged
    tt = t[sel]
    if fmt_t == "zero":
        cols["t"] = pa.array(tt, pa.float64())
    elif fmt_t == "epoch":
        cols["t"] = pa.array(tt + t0, pa.float64())
    elif fmt_t == "ns":
        cols["t"] = pa.array(np.round((tt + t0) * 1e9).astype("int64"), pa.timestamp("ns"))
    else:
        cols["t"] = pa.array(np.round((tt + t0) * 1e6).astype("int64"), pa.timestamp("us"))
    for j, c in enumerate("xyz"):
        cols[f"gyro_{c}"] = pa.array((gy[sel, j] * conv).astype(dtype))
    cols["temp"] = pa.array(temp[sel].astype(dtype))
    cols["ref_rate"] = pa.array((sim["ref"][sel] * conv).astype(dtype))
    mk = rng.choice(["none", "string", "dict"], p=[0.3, 0.35, 0.35])
    if mk != "none":
        labs = sim["mount"][sel].astype(str)
        arr = pa.array(labs.tolist(), pa.string())
        cols["mount"] = arr.dictionary_encode() if mk == "dict" else arr
    if u["accel"]:
        acc = sim["f_s"] * u["acc_scale"][None, :] + u["acc_bias"][None, :] + \
            rng.normal(0, 0.002, (n, 3))
        for j, c in enumerate("xyz"):
            cols[f"accel_{c}"] = pa.array(acc[sel, j].astype(dtype))
    if rng.random() < 0.5:
        cols["sample"] = pa.array(np.flatnonzero(sel).astype("int64"))
    meta = {}
    if radps:
        meta["gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})
    return dict(cols=cols, meta=meta, t=tt, session=s, date_offset=float(day0))


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    paths = []
    for ss in built["sessions"]:
        tab = pa.table(ss["cols"])
        if ss["meta"]:
            tab = tab.replace_schema_metadata({**(tab.schema.metadata or {}),
                                               **{k.encode(): v.encode()
                                                  for k, v in ss["meta"].items()}})
        p = os.path.join(folder, f"session{ss['session']}.parquet")
        pq.write_table(tab, p)
        paths.append(p)
    return paths


# ----------------------------------------------------------------------------- validation
def validate_log(path):
    """Problems of one log against the contract (empty list: it follows it)."""
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
    ty = sch.field("t").type
    if not (pa.types.is_float64(ty) or pa.types.is_timestamp(ty)):
        probs.append(f"t has type {ty}")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y",
              "accel_z"):
        if c in names:
            ty = sch.field(c).type
            if not (pa.types.is_float32(ty) or pa.types.is_float64(ty)):
                probs.append(f"{c} has type {ty}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in names]
    if acc and len(acc) != 3:
        probs.append("partial accelerometer columns")
    t = tab.column("t")
    if pa.types.is_timestamp(t.type):
        tv = t.cast(pa.int64()).to_numpy().astype(float)
    else:
        tv = t.to_numpy()
    if not np.all(np.isfinite(tv)):
        probs.append("non-finite t")
    elif not np.all(np.diff(tv) > 0):
        probs.append("t not strictly increasing")
    if "mount" in names:
        ty = sch.field("mount").type
        if not (pa.types.is_string(ty) or pa.types.is_dictionary(ty)):
            probs.append(f"mount has type {ty}")
        vals = set(tab.column("mount").cast(pa.string()).to_pylist()) \
            if not pa.types.is_dictionary(ty) else \
            set(tab.column("mount").combine_chunks().dictionary.to_pylist())
        if vals - set(MOUNTS):
            probs.append(f"mount words {sorted(vals - set(MOUNTS))}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            d = json.loads(md[b"gyrocal.units"])
            if not set(d.values()) <= {"rad/s", "deg/s"}:
                probs.append("units metadata values")
        except ValueError:
            probs.append("units metadata not JSON")
    n = tab.num_rows
    if n < 1000:
        probs.append(f"only {n} rows")
    return probs
