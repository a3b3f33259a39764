"""Ninth sealed benchmark: simulator of `turntable` rig logs, the standard calibration (the
reference floor) and a contract validator.

NOT TO BE READ by whoever works on the diagnosis: this file holds the effect families, their
physics, shapes and magnitudes.

Each unit is one physical three-axis MEMS gyro, written as three sessions (a new power-on, new
noise, its own order of chamber set points, mounts and table rates).  Everything is simulated
on a common time line: a 1 s grid for the thermal path and the slow states, the sample rate
(10/20/25/50 Hz) for the outputs.  The sensor model is

    w = K(T_die) . w_body + B(T_die) + b_on + b_BI(t) + n(t) + a * g_family(t)

with `g_family` the pattern of the unit's effect (zero on complete units) and `a` its
amplitude, chosen so that the standard calibration of session 0 misses on session 2 by a
chosen multiple of the reference floor, capped by the family's physical bound.
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

MASTER_SEED = 20261202
DEG = math.pi / 180.0
G0 = 9.80665
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
MVEC = {
    "+x": np.array([1.0, 0, 0]),
    "-x": np.array([-1.0, 0, 0]),
    "+y": np.array([0, 1.0, 0]),
    "-y": np.array([0, -1.0, 0]),
    "+z": np.array([0, 0, 1.0]),
    "-z": np.array([0, 0, -1.0]),
}
MAGS = (0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 30, 50, 75, 100, 150, 200, 250, 300, 400)
LEVEL_LO, LEVEL_HI = 1.5, 50.0
ROW_CAP = 300_000

# ----------------------------------------------------------------------------- families
# reads: the input kinds the effect depends on; acts: what it acts on; carried: a sensor term
# can carry it; reasons: the judge's reason words that are right for it (no_sensor_term);
# fix_ok: whether a fix (reading the same kinds) can be right for an effect no sensor term
# carries; bound: the physical bound on the amplitude (units per family, see _pattern).
FAMILIES = {
    "sf_square": dict(reads=("rate",), acts=("scale",), carried=True, reasons=(), bound=1e-2),
    "sf_asym": dict(reads=("rate",), acts=("scale",), carried=True, reasons=(), bound=5e-3),
    "xax_rate": dict(reads=("rate",), acts=("cross-axis",), carried=True, reasons=(), bound=5e-3),
    "g_sens": dict(reads=("accel", "mount"), acts=("bias",), carried=True, reasons=(), bound=0.3),
    "offcentre": dict(reads=("accel", "rate"), acts=("bias",), carried=True, reasons=(), bound=0.2),
    "dTdt_bias": dict(reads=("thermal",), acts=("bias",), carried=True, reasons=(), bound=0.6),
    "xax_temp": dict(reads=("temperature",), acts=("cross-axis",), carried=True, reasons=(), bound=4e-3),
    "warmup": dict(reads=("time",), acts=("bias",), carried=True, reasons=(), bound=1.5),
    "hysteresis": dict(
        reads=("thermal",),
        acts=("bias",),
        carried=False,
        fix_ok=True,
        reasons=("direction of approach",),
        bound=0.5,
    ),
    "fixture": dict(
        reads=("mount",),
        acts=("cross-axis",),
        carried=False,
        fix_ok=True,
        reasons=("mounting",),
        bound=6e-3,
    ),
    "debris": dict(
        reads=("mount",), acts=None, carried=False, fix_ok=False, reasons=("mounting",), bound=6e-3
    ),
    "relax": dict(
        reads=("time",), acts=None, carried=False, fix_ok=False, reasons=("unit changed",), bound=0.3
    ),
    "crossing": dict(
        reads=("temperature",),
        acts=("bias",),
        carried=False,
        fix_ok=True,
        reasons=("between points",),
        bound=0.8,
    ),
    "popcorn": dict(
        reads=("time",), acts=None, carried=False, fix_ok=False, reasons=("slow noise",), bound=0.2
    ),
    "table_scale": dict(
        reads=("rate",), acts=None, carried=False, fix_ok=False, reasons=("lab",), bound=3e-3
    ),
}
# physical dependence and action of every family (descriptive truth; the scoring fields above
# leave out what a fix may not claim)
PHYSICS = {
    "sf_square": (("rate",), ("scale",)),
    "sf_asym": (("rate",), ("scale",)),
    "xax_rate": (("rate",), ("cross-axis",)),
    "g_sens": (("accel", "mount"), ("bias",)),
    "offcentre": (("accel", "rate", "mount"), ("bias",)),
    "dTdt_bias": (("thermal",), ("bias",)),
    "xax_temp": (("temperature",), ("cross-axis",)),
    "warmup": (("time",), ("bias",)),
    "hysteresis": (("thermal", "temperature"), ("bias",)),
    "fixture": (("mount",), ("cross-axis", "scale")),
    "debris": (("mount",), ("cross-axis", "scale")),
    "relax": (("time", "temperature"), ("bias", "scale")),
    "crossing": (("temperature",), ("bias",)),
    "popcorn": (("time",), ("bias",)),
    "table_scale": (("rate",), ("scale",)),
}


def lu(rng, a, b):
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def _first_order(x, tau, dt=1.0, y0=None):
    """Exact first-order lag of a piecewise-constant input on a uniform grid."""
    a = math.exp(-dt / max(tau, 1e-9))
    y0 = x[0] if y0 is None else y0
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * y0])
    return y


def _gauss_markov(rng, n, sigma, tau, dt=1.0):
    a = math.exp(-dt / tau)
    e = rng.standard_normal(n) * sigma * math.sqrt(1 - a * a)
    y, _ = lfilter([1.0], [1, -a], e, zi=[a * rng.standard_normal() * sigma])
    return y


def _unit_vec(rng):
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _perp(rng, u):
    v = np.cross(u, _unit_vec(rng))
    return v / np.linalg.norm(v)


# ----------------------------------------------------------------------------- the unit
def draw_unit(rng, family):
    """One physical gyro: sensor, thermal path, fixture and protocol parameters."""
    u = {}
    u["arw"] = lu(rng, 0.003, 0.03) * rng.uniform(0.75, 1.3, 3)
    top = float(rng.choice([50, 100, 200, 300, 400], p=[0.1, 0.2, 0.25, 0.15, 0.3]))
    u["top"] = top
    # K(T) = K0 + K1 x + K2 x^2, x = (T - 25)/60 ; B(T) cubic in x
    sgn = lambda n: rng.choice([-1.0, 1.0], n)  # noqa: E731
    K0 = np.eye(3) + np.diag(rng.normal(0, 0.01, 3))
    off = rng.normal(0, 0.004, (3, 3))
    np.fill_diagonal(off, 0)
    K0 += off
    K1 = np.diag(sgn(3) * [lu(rng, 30e-6, 400e-6) * 60 for _ in range(3)])
    K2 = np.diag(sgn(3) * [lu(rng, 50e-6, 1500e-6) for _ in range(3)])
    o1 = np.array([[lu(rng, 0.5e-6, 20e-6) * 60 for _ in range(3)] for _ in range(3)]) * sgn((3, 3))
    o2 = np.array([[lu(rng, 1e-6, 100e-6) for _ in range(3)] for _ in range(3)]) * sgn((3, 3))
    np.fill_diagonal(o1, 0)
    np.fill_diagonal(o2, 0)
    u["K"] = (K0, K1 + o1, K2 + o2)
    b0 = rng.normal(0, 0.5, 3)
    b1 = sgn(3) * [lu(rng, 0.002, 0.04) * 60 for _ in range(3)]
    b2 = sgn(3) * [lu(rng, 0.003, 0.2) for _ in range(3)]
    b3 = sgn(3) * [lu(rng, 0.001, 0.05) for _ in range(3)]
    u["B"] = np.array([b0, b1, b2, b3])
    # noise
    n_h = rng.uniform(20, 60)
    u["H"] = n_h
    u["bi_kind"] = "gm" if rng.uniform() < 0.5 else "flicker"
    u["k_bi"] = lu(rng, 0.1, 2.5) * rng.uniform(0.7, 1.3, 3)
    u["bi_tau"] = lu(rng, 20, 20000)
    u["bi_band"] = (lu(rng, 10, 60), lu(rng, 2000, 30000))
    u["k_rep"] = lu(rng, 1, 5)
    # output word
    u["quant"] = rng.uniform() < 0.75
    rngs = [r for r in (125, 250, 500, 1000, 2000) if r >= 1.31 * top]
    u["range"] = float(rngs[0] if rng.uniform() < 0.7 else rngs[min(1, len(rngs) - 1)])
    # thermal path
    u["room"] = rng.uniform(19, 26)
    u["tau_air"] = lu(rng, 20, 90)
    # PI on the air (plant tau_air, loss to the room): damping 0.5-1, i.e. some overshoot
    u["Kp"] = rng.uniform(2, 8)
    zeta = rng.uniform(0.5, 1.0)
    wn = (1 + u["Kp"]) / (2 * zeta * u["tau_air"])
    u["Ti"] = u["Kp"] / (u["tau_air"] * wn * wn)
    u["u_lim"] = rng.uniform(75, 110)
    u["ramp"] = rng.uniform(1, 5) / 60.0  # degC/s
    u["ripple"] = (lu(rng, 0.01, 0.2), lu(rng, 30, 300))
    u["tau_door"] = lu(rng, 30, 1000)
    u["tau_case"] = lu(rng, 200, 1500)
    u["two_stage"] = rng.uniform() < 0.6
    u["tau_die"] = lu(rng, 5, 120)
    u["sh_case"] = rng.uniform(0.3, 5)
    u["sh_die"] = rng.uniform(0.2, 2) if u["two_stage"] else 0.0
    u["cool_c"] = 0.0 if rng.uniform() < 0.3 else rng.uniform(0.1, 0.8)
    u["hand_w"] = rng.uniform(0, 0.5)
    mode = rng.choice(["die", "lag", "lead"], p=[0.3, 0.35, 0.35])
    u["ts_mode"] = str(mode)
    u["ts_tau"] = lu(rng, 3, 120)
    u["ts_kappa"] = rng.uniform(0.1, 0.6)
    u["ts_off"] = rng.normal(0, 1.5)
    u["ts_gain"] = rng.normal(0, 0.01)
    u["ts_noise"] = lu(rng, 0.005, 0.15)
    u["ts_q"] = float(rng.choice([1 / 256, 1 / 64, 1 / 16, 1 / 8]))
    u["ts_upd"] = int(rng.choice([0, 1, 2]))  # 0: every sample, else every 1 or 2 s
    # rig, fixture, operator
    u["seat_sigma"] = lu(rng, 1e-6, 30e-6)
    u["acc_peak"] = lu(rng, 20, 200)
    u["ref_jitter"] = 0.0 if rng.uniform() < 0.5 else lu(rng, 1e-6, 1e-4)
    u["radius"] = rng.uniform(0, 0.08)
    u["accel"] = rng.uniform() < 0.4
    u["acc_bias"] = rng.normal(0, 0.01, 3)
    u["acc_scale"] = 1 + rng.normal(0, 0.005, 3)
    u["acc_noise"] = lu(rng, 0.0005, 0.005)
    u["tremor"] = lu(rng, 0.3, 5)
    u["cycling"] = str(rng.choice(["never", "remount", "setpoint"], p=[0.6, 0.2, 0.2]))
    # protocol of the unit
    u["n_mounts"] = 3 if rng.uniform() < 0.55 else 6
    below = [m for m in MAGS if m < top]
    k = int(rng.integers(2, 9))
    u["mags"] = sorted({top, *rng.choice(below, size=min(k, len(below)), replace=False).tolist()})
    u["zero"] = rng.uniform() < 0.65
    # set points of session 0
    lo = 5 * round(rng.uniform(-40, 0) / 5)
    hi = 5 * round(rng.uniform(40, 85) / 5)
    n = int(rng.integers(3, 8))
    pts = np.linspace(lo, hi, n)
    if n > 2:
        pts[1:-1] += rng.uniform(-2, 2, n - 2)
    u["sp0"] = [float(p) for p in pts]
    # family needs
    if family == "fixture":
        u["n_mounts"] = 6
    if family in ("g_sens", "offcentre"):
        u["accel"] = True
    if family == "offcentre":
        u["radius"] = rng.uniform(0.12, 0.3)
        u["mags"] = sorted(set(u["mags"]) | {top, [m for m in MAGS if m <= top / 2][-1]})
    if family in ("sf_square", "sf_asym", "xax_rate") and len(u["mags"]) < 3:
        u["mags"] = sorted(set(u["mags"]) | {below[len(below) // 2]})
    return u


def session_plan(rng, u, s, family):
    """Set points, orders, logger and file-format choices of session s."""
    p = {}
    sp0 = u["sp0"]
    if s == 0:
        pts = list(sp0)
    else:
        kind = rng.choice(["same", "mid", "shift"], p=[0.3, 0.35, 0.35])
        if family in ("xax_temp", "crossing"):
            kind = "mid" if family == "crossing" else rng.choice(["mid", "shift"])
        if kind == "same":
            pts = [x + (rng.uniform(-1, 1) if rng.uniform() < 0.5 else 0) for x in sp0]
        elif kind == "mid":
            pts = [(a + b) / 2 for a, b in zip(sp0[:-1], sp0[1:], strict=True)]
            if len(pts) < 3:
                pts.append(sp0[0] if rng.uniform() < 0.5 else sp0[-1])
        else:
            f = rng.uniform(0.2, 0.8)
            pts = [a + f * (b - a) for a, b in zip(sp0[:-1], sp0[1:], strict=True)]
            if len(pts) < 3:
                pts.append(sp0[-1])
        p["sp_kind"] = str(kind)
        pts = [float(min(max(x, sp0[0]), sp0[-1])) for x in pts]
    # temperature order: never plainly ascending
    pts = sorted(pts)
    room = u["room"]
    while True:
        okind = rng.choice(["desc", "room_down_up", "room_up_down", "zigzag", "shuffle"])
        i0 = int(np.argmin([abs(x - room) for x in pts]))
        if okind == "desc":
            order = pts[::-1]
        elif okind == "room_down_up":
            order = pts[i0::-1] + pts[i0 + 1 :]
        elif okind == "room_up_down":
            order = pts[i0:] + pts[:i0][::-1]
        elif okind == "zigzag":
            order, lo_, hi_ = [], 0, len(pts) - 1
            while lo_ <= hi_:
                order.append(pts[lo_])
                if hi_ != lo_:
                    order.append(pts[hi_])
                lo_, hi_ = lo_ + 1, hi_ - 1
        else:
            order = [pts[i] for i in rng.permutation(len(pts))]
        if order != pts:
            break
    p["order"] = [float(x) for x in order]
    p["torder"] = str(okind)
    # mounts
    if u["n_mounts"] == 6:
        base = list(MOUNTS)
    else:
        if "m3" not in u:
            u["m3"] = [f"{'+' if rng.uniform() < 0.5 else '-'}{a}" for a in "xyz"]
        base = list(u["m3"])
    base = [base[i] for i in rng.permutation(len(base))]
    p["mount_kind"] = str(rng.choice(["fixed", "serpentine", "random"]))
    p["rate_kind"] = str(rng.choice(["asc", "desc", "shuffle", "highfirst", "zigzag", "sweep"]))
    p["base_mounts"] = base
    p["revisit"] = rng.uniform() < 0.35
    p["revisit_all"] = rng.uniform() < 0.5
    p["power_on"] = "at_insert" if rng.uniform() < 0.5 else "late"
    p["late_s"] = lu(rng, 180, 1800)
    p["logging"] = "tail" if rng.uniform() < 0.6 else "full"
    p["tail_s"] = 60 * rng.uniform(3, lu(rng, 4, 15))
    p["n_pauses"] = int(rng.integers(0, 4))
    p["time"] = str(rng.choice(["float0", "epoch", "ts_ns", "ts_us", "ts_ns_tz"]))
    p["f32"] = rng.uniform() < 0.5
    p["mount_col"] = str(rng.choice(["none", "string", "dict"], p=[0.3, 0.35, 0.35]))
    p["rad"] = rng.uniform() < 0.15
    p["nan_rows"] = int(rng.integers(1, 6)) if rng.uniform() < 0.15 else 0
    p["extra"] = str(rng.choice(["sample", "chamber_sp", "none"]))
    p["soak_m"] = rng.uniform(4, 8)
    p["epoch0"] = 1.76e9 + 86400 * (0, rng.integers(1, 31), rng.integers(30, 181))[s] + rng.uniform(0, 3600)
    return p


def _rate_order(rng, kind, mags, zero):
    pos = sorted(mags)
    if kind == "asc":
        r = [-m for m in pos[::-1]] + ([0.0] if zero else []) + pos
    elif kind == "desc":
        r = pos[::-1] + ([0.0] if zero else []) + [-m for m in pos]
    elif kind == "shuffle":
        r = pos + [-m for m in pos] + ([0.0] if zero else [])
        r = [r[i] for i in rng.permutation(len(r))]
    elif kind == "highfirst":
        r = [pos[-1], -pos[-1]] + [x for m in pos[-2::-1] for x in (m, -m)] + ([0.0] if zero else [])
    elif kind == "zigzag":
        r = ([0.0] if zero else []) + [x for m in pos for x in (m, -m)]
    else:  # sweep: all positive up, all negative down
        r = ([0.0] if zero else []) + pos + [-m for m in pos[::-1]]
    return [float(x) for x in r]


# ----------------------------------------------------------------------------- schedule
def build_schedule(rng, u, p):
    """Segments on the time line: soaks, remounts (handling), table transitions and holds."""
    H = u["H"]
    n_r = len(u["mags"]) * 2 + (1 if u["zero"] else 0)
    n_pts = len(p["order"]) + (1 if p["revisit"] else 0)
    # keep the holds of one session within ~4 h
    H = min(H, max(15.0, 4 * 3600 / (n_pts * u["n_mounts"] * n_r) - 6))
    n_rm = n_pts * u["n_mounts"]
    w_hi = min(lu(rng, 15, 600), max(15.0, 2 * 5400 / n_rm))
    tau_slow = u["tau_case"] + (u["tau_die"] if u["two_stage"] else 0) + u["tau_air"]
    segs, holds, doors, offs, hand, moves, sp_events, pauses = [], [], [], [], [], [], [], []
    t = 0.0
    doors.append((0.0, rng.uniform(10, 40)))
    pts = list(p["order"])
    plan = [(x, list(p["base_mounts"])) for x in pts]
    for k in range(len(plan)):
        if p["mount_kind"] == "serpentine" and k % 2 == 1:
            plan[k] = (plan[k][0], plan[k][1][::-1])
        elif p["mount_kind"] == "random":
            m = plan[k][1]
            plan[k] = (plan[k][0], [m[i] for i in rng.permutation(len(m))])
    if p["revisit"]:
        x = pts[int(rng.integers(0, len(pts) - 1))]
        ms = list(p["base_mounts"])
        if not p["revisit_all"]:
            ms = ms[: int(rng.integers(1, 3))]
        plan.append((x, ms))
    cur_m = plan[0][1][0]
    placements = [(0.0, cur_m, _seat(rng, u, cur_m))]
    prev_sp = u["room"]
    pause_at = set(rng.choice(np.arange(1, 40), size=p["n_pauses"], replace=False).tolist())
    n_remount = 0
    for k, (T_sp, mounts) in enumerate(plan):
        ramp_s = abs(T_sp - prev_sp) / u["ramp"]
        soak = float(np.clip(p["soak_m"] * tau_slow, 900, 6000)) + ramp_s
        if T_sp == prev_sp:
            soak = rng.uniform(300, 900)
        sp_events.append((t, T_sp))
        if u["cycling"] == "setpoint" and k > 0:
            t_off = t + rng.uniform(5, 30)
            offs.append((t_off, t_off + rng.uniform(5, 60)))
        segs.append(("soak", t, t + soak))
        t += soak
        prev_sp = T_sp
        for m in mounts:
            if m != cur_m:
                n_remount += 1
                if n_remount in pause_at:
                    dp = 60 * rng.uniform(1, 20)
                    pauses.append((t, t + dp))
                    segs.append(("idle", t, t + dp))
                    t += dp
                still = rng.uniform(2, 10)
                t_open = t + still
                t_lift = t_open + rng.uniform(2, 8)
                dur = rng.uniform(15, lu(rng, 25, 90))
                t_place = t_lift + dur
                t_close = t_place + rng.uniform(2, rng.uniform(5, 25))
                t_end = t_place + rng.uniform(5, w_hi)
                t_end = max(t_end, t_close + 3)
                doors.append((t_open, t_close))
                hand.append((t_lift, t_place))
                moves.append((t_lift, t_place, cur_m, m))
                if u["cycling"] == "remount":
                    offs.append((t_lift + 0.2 * dur, t_lift + 0.8 * dur))
                segs.append(("handle", t, t_end))
                placements.append((t_place, m, _seat(rng, u, m)))
                cur_m = m
                t = t_end
            cur_r = 0.0
            for r in _rate_order(rng, p["rate_kind"], u["mags"], u["zero"]):
                if r != cur_r:
                    d = math.pi * abs(r - cur_r) / (2 * u["acc_peak"])
                    segs.append(("trans", t, t + d, cur_r, r))
                    t += d + rng.uniform(0.5, 2)
                segs.append(("hold", t, t + H, r, m))
                holds.append(dict(t0=t, t1=t + H, rate=r, mount=m, point=T_sp))
                t += H
                cur_r = r
            if cur_r != 0:
                d = math.pi * abs(cur_r) / (2 * u["acc_peak"])
                segs.append(("trans", t, t + d, cur_r, 0.0))
                t += d
            t += rng.uniform(1, 5)
    t_end = t + rng.uniform(5, 30)
    # power-on late: the unit is switched on some minutes before the first hold
    if p["power_on"] == "late":
        t_on = max(0.0, holds[0]["t0"] - p["late_s"])
        if t_on > 1:
            offs.insert(0, (0.0, t_on))
    return dict(
        segs=segs,
        holds=holds,
        doors=doors,
        offs=offs,
        hand=hand,
        moves=moves,
        sp_events=sp_events,
        pauses=pauses,
        placements=placements,
        T=t_end,
        H=H,
    )


def _seat(rng, u, m):
    """A placement: the up vector in the sensor frame (micro-radian re-seating) and the
    in-plane radial direction (random azimuth on the fixture)."""
    e = MVEC[m]
    up = e + np.cross(rng.normal(0, u["seat_sigma"], 3), e)
    up = up / np.linalg.norm(up)
    rad = _perp(rng, up)
    return dict(up=up, radial=rad, tilt=_perp(rng, e))


# ----------------------------------------------------------------------------- thermal
def simulate_thermal(rng, u, sch):
    n = int(math.ceil(sch["T"])) + 2
    tg = np.arange(n, dtype=float)
    # chamber set point, ramped
    sp = np.full(n, u["room"])
    cur = u["room"]
    ev = sch["sp_events"] + [(sch["T"] + 10, None)]
    for (t0, T), (t1, _) in zip(ev[:-1], ev[1:], strict=True):
        i0, i1 = int(t0), min(n, int(t1) + 1)
        dur = np.arange(i1 - i0, dtype=float)
        step = np.sign(T - cur) * np.minimum(dur * u["ramp"], abs(T - cur))
        sp[i0:i1] = cur + step
        cur = T
    door = np.zeros(n)
    for a, b in sch["doors"]:
        door[int(a) : int(b) + 1] = 1.0
    power = np.ones(n)
    for a, b in sch["offs"]:
        power[int(math.ceil(a)) : int(b) + 1] = 0.0
    handw = np.zeros(n)
    for a, b in sch["hand"]:
        handw[int(a) : int(b) + 1] = u["hand_w"]
    spin = np.zeros(n)
    for s in sch["segs"]:
        if s[0] == "hold":
            spin[int(s[1]) : int(s[2])] = abs(s[3])
    # air: PI controller with anti-windup, door exchange with the room
    Kp, Ki, lim, tau, room = u["Kp"], u["Kp"] / u["Ti"], u["u_lim"], u["tau_air"], u["room"]
    tdo = u["tau_door"]
    air = np.empty(n)
    T, integ = room, 0.0
    spl, dl = sp.tolist(), door.tolist()
    for i in range(n):
        e = spl[i] - T
        v = Kp * e + integ
        vs = min(lim, max(-lim, v))
        if vs == v or (v > lim and e < 0) or (v < -lim and e > 0):
            integ += Ki * e
        T += ((room - T) + vs) / tau + dl[i] * (room - T) / tdo
        air[i] = T
    air = air + _gauss_markov(rng, n, *u["ripple"])
    env = (1 - handw) * air + handw * 32.0
    cool = 1.0 / (1.0 + u["cool_c"] * spin / 300.0)
    case = _first_order(env + u["sh_case"] * power * cool, u["tau_case"], y0=room)
    two = u["two_stage"]
    die = _first_order(case + u["sh_die"] * power, u["tau_die"], y0=room) if two else case.copy()
    if u["ts_mode"] == "die":
        node = die
    elif u["ts_mode"] == "lag":
        node = _first_order(die, u["ts_tau"], y0=room)
    else:
        node = die + u["ts_kappa"] * (case - die)
    return dict(tg=tg, air=air, case=case, die=die, node=node, power=power, sp=sp)


# ----------------------------------------------------------------------------- session
def simulate_session(rng, u, p, family, fam):
    """All sample-rate arrays of one session: base output (no effect), the effect's pattern
    per unit amplitude, logged temperature, reference rate, accelerometer, masks."""
    sch = build_schedule(rng, u, p)
    th = simulate_thermal(rng, u, sch)
    T_end = sch["T"]
    # sample rate: the largest keeping the logged rows within the cap
    t1 = np.arange(0, T_end, 1.0)
    on1 = np.interp(t1, th["tg"], th["power"]) > 0.5
    for a, b in sch["pauses"]:
        on1 &= ~((t1 >= a) & (t1 < b))
    tails = np.ones_like(on1)
    for s in sch["segs"]:
        if s[0] == "soak":
            tails &= ~((t1 >= s[1]) & (t1 < s[2] - p["tail_s"]))
    logged = float((on1 & tails).sum() if p["logging"] == "tail" else on1.sum())
    if logged * 10 > ROW_CAP and p["logging"] == "full":
        p["logging"] = "tail"
        logged = float((on1 & tails).sum())
    fs = 10
    for f in (50, 25, 20, 10):
        if logged * f <= ROW_CAP and rng.uniform() < 0.6:
            fs = f
            break
    t = np.arange(0, T_end, 1.0 / fs)
    ns = t.size
    # table
    ref = np.zeros(ns)
    alpha = np.zeros(ns)
    for s in sch["segs"]:
        i0, i1 = np.searchsorted(t, [s[1], s[2]])
        if s[0] == "hold":
            ref[i0:i1] = s[3]
        elif s[0] == "trans":
            d = s[2] - s[1]
            x = (t[i0:i1] - s[1]) / d
            ref[i0:i1] = s[3] + (s[4] - s[3]) * (1 - np.cos(np.pi * x)) / 2
            alpha[i0:i1] = (s[4] - s[3]) * np.pi / (2 * d) * np.sin(np.pi * x)
            # after the transition, until the next hold, the table sits at the new rate
            j1 = np.searchsorted(t, s[2] + 2.0)
            ref[i1:j1] = s[4]
    rate_true = ref.copy()
    ref_log = ref * (1 + u["ref_jitter"] * rng.standard_normal(ns) * (ref != 0))
    # placements: up vector per sample
    pl = sch["placements"]
    tp = np.array([x[0] for x in pl])
    idx = np.clip(np.searchsorted(tp, t, side="right") - 1, 0, len(pl) - 1)
    ups = np.array([x[2]["up"] for x in pl])
    rads = np.array([x[2]["radial"] for x in pl])
    up = ups[idx]
    radial = rads[idx]
    mount_name = np.array([x[1] for x in pl])[idx]
    handling = np.zeros(ns, bool)
    body = rate_true[:, None] * up
    grav = up.copy()
    for a, b, m_old, m_new in sch["moves"]:
        i0, i1 = np.searchsorted(t, [a, b])
        handling[i0:i1] = True
        tt = t[i0:i1]
        w = np.zeros((i1 - i0, 3))
        starts = np.sort(rng.uniform(a, b - 2.0, 4))
        for st in starts:
            d = rng.uniform(0.4, 2.0)
            ang = rng.uniform(30, 180)
            x = (tt - st) / d
            on = (x >= 0) & (x <= 1)
            w[on] += np.outer((ang / d) * (1 - np.cos(2 * np.pi * x[on])), _unit_vec(rng))
        for ax in range(3):
            w[:, ax] += _gauss_markov(rng, i1 - i0, u["tremor"], 0.3 * fs)
        body[i0:i1] = w
        fr = np.clip((tt - a) / (b - a), 0, 1)[:, None]
        g = (1 - fr) * MVEC[m_old] + fr * MVEC[m_new] + 0.05 * rng.standard_normal((i1 - i0, 3))
        grav[i0:i1] = g / np.linalg.norm(g, axis=1, keepdims=True)
    # specific force (g): gravity along the rig axis, centripetal toward the axis, tangential
    om = rate_true * DEG
    tang = np.cross(up, radial)
    acc = (
        grav - (om**2 * u["radius"] / G0)[:, None] * radial + (alpha * DEG * u["radius"] / G0)[:, None] * tang
    )
    acc[handling] += 0.05 * rng.standard_normal((handling.sum(), 3))
    # temperatures at the samples
    die = np.interp(t, th["tg"], th["die"])
    case = np.interp(t, th["tg"], th["case"])
    node = np.interp(t, th["tg"], th["node"])
    power = np.interp(t, th["tg"], th["power"]) > 0.5
    # power-on indices: a new turn-on bias and a new clock at each power-on
    on_edges = np.flatnonzero(np.diff(np.r_[0, power.astype(int)]) == 1)
    pidx = np.cumsum(np.isin(np.arange(ns), on_edges)) - 1
    pidx = np.maximum(pidx, 0)
    t_on = t - t[on_edges][pidx] if on_edges.size else t.copy()
    # K(T), B(T) of the die
    x = (die - 25.0) / 60.0
    K0, K1, K2 = u["K"]
    Kt = K0[None] + K1[None] * x[:, None, None] + K2[None] * (x**2)[:, None, None]
    Bc = u["B"]
    Bt = Bc[0][None] + np.outer(x, Bc[1]) + np.outer(x**2, Bc[2]) + np.outer(x**3, Bc[3])
    out = np.einsum("nij,nj->ni", Kt, body) + Bt
    # noise: white, bias instability, turn-on repeatability
    wf = math.sqrt(float(np.mean(u["arw"] ** 2)) / (sch["H"] - 2))
    out += rng.standard_normal((ns, 3)) * (u["arw"] * math.sqrt(fs))[None]
    n1 = int(math.ceil(T_end)) + 2
    bi = np.zeros((n1, 3))
    for ax in range(3):
        sig = u["k_bi"][ax] * wf
        if u["bi_kind"] == "gm":
            bi[:, ax] = _gauss_markov(rng, n1, sig, u["bi_tau"])
        else:
            taus = np.geomspace(*u["bi_band"], 5)
            for tau in taus:
                bi[:, ax] += _gauss_markov(rng, n1, sig / math.sqrt(5), tau)
    out += np.stack([np.interp(t, np.arange(n1), bi[:, a]) for a in range(3)], axis=1)
    n_on = max(1, on_edges.size)
    b_on = rng.normal(0, u["k_rep"] * wf, (n_on, 3))
    out += b_on[pidx]
    # logged temperature (the unit's own sensor)
    tl = 25 + (node - 25) * (1 + u["ts_gain"]) + u["ts_off"] + rng.normal(0, u["ts_noise"], ns)
    if u["ts_upd"]:
        k = np.floor(t / u["ts_upd"]).astype(np.int64)
        first = np.r_[0, np.flatnonzero(np.diff(k)) + 1]
        tl = tl[first][np.searchsorted(first, np.arange(ns), side="right") - 1]
    tl = np.round(tl / u["ts_q"]) * u["ts_q"]
    st = dict(
        t=t,
        fs=fs,
        out=out,
        ref=ref_log,
        rate_true=rate_true,
        body=body,
        up=up,
        acc=acc,
        die=die,
        case=case,
        tl=tl,
        x=x,
        Kt=Kt,
        t_on=t_on,
        power=power,
        handling=handling,
        mount=mount_name,
        idx_place=idx,
        sch=sch,
        wf=wf,
        tg=th["tg"],
        die_g=th["die"],
        sp_g=th["sp"],
    )
    return st


# ----------------------------------------------------------------------------- effects
def draw_effect(rng, family, u):
    """The effect's fixed parameters (per unit, the same in every session)."""
    e = {}
    v = _unit_vec(rng) * rng.choice([-1, 1])
    e["v"] = v * rng.uniform(0.6, 1.0, 3) / np.max(np.abs(v))
    if family in ("sf_square", "sf_asym"):
        e["k"] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.4, 1.0, 3)
    elif family == "xax_rate":
        M = rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.2, 1.0, (3, 3))
        np.fill_diagonal(M, 0)
        e["M"] = M / np.abs(M).max()
    elif family in ("g_sens", "offcentre"):
        G = rng.normal(0, 0.35, (3, 3)) + np.diag(rng.choice([-1.0, 1.0], 3) * rng.uniform(0.5, 1, 3))
        e["G"] = G / np.abs(G).max()
    elif family == "dTdt_bias":
        e["tau_g"] = lu(rng, 10, 120)  # gradient build-up across the die
    elif family == "xax_temp":
        M = rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.3, 1.0, (3, 3))
        np.fill_diagonal(M, 0)
        e["M"] = M / np.abs(M).max()
        e["P"] = rng.uniform(45, 110)
        e["phi"] = rng.uniform(0, 2 * np.pi, (3, 3))
    elif family == "warmup":
        e["tau"] = lu(rng, 600, 3600)
    elif family == "hysteresis":
        e["w"] = rng.uniform(3, 10)
        e["y0"] = rng.uniform(-1, 1)
    elif family == "fixture":
        e["faces"] = {m: rng.normal(0, 1, 3) / math.sqrt(3) for m in MOUNTS}
    elif family == "relax":
        e["off"] = rng.normal(0, 0.5, 3)
        e["slope"] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.4, 1.0, 3)
        e["sf"] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.4, 1.0, 3)
    elif family == "crossing":
        e["width"] = rng.uniform(1.5, 4.0)
    elif family == "popcorn":
        e["dwell"] = (lu(rng, 60, 1200), lu(rng, 60, 1200))
    elif family == "table_scale":
        # the rate reference of each session's table (encoder/servo setting): session 0 near
        # nominal, the later sessions on a reference off by its own amount
        c0 = rng.uniform(-0.3, 0.3)
        e["c"] = [c0] + [float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0)) for _ in range(2)]
    return e


def effect_pattern(rng, family, e, u, st, s, p):
    """The effect's contribution to the output (deg/s, n x 3) per unit amplitude."""
    ns = st["t"].size
    body = st["body"]
    top = u["top"]
    if family == "sf_square":
        return e["k"][None] * body * np.abs(body) / top
    if family == "sf_asym":
        return e["k"][None] * np.abs(body) / 2
    if family == "xax_rate":
        return (body * np.abs(body) / top) @ e["M"].T
    if family in ("g_sens", "offcentre"):
        return st["acc"] @ e["G"].T
    if family == "dTdt_bias":
        # thermal gradient across the die: the die's rate of change, built up with a lag
        dT = np.gradient(st["die_g"]) * 60.0  # degC/min
        grad = _first_order(dT, e["tau_g"])
        return np.interp(st["t"], st["tg"], grad)[:, None] * e["v"][None]
    if family == "xax_temp":
        T = st["die"]
        f = np.sin(2 * np.pi * (T[:, None, None] - 25) / e["P"] + e["phi"][None]) - np.sin(e["phi"])[None]
        dK = e["M"][None] * f
        return np.einsum("nij,nj->ni", dK, body)
    if family == "warmup":
        return np.exp(-st["t_on"] / e["tau"])[:, None] * e["v"][None]
    if family == "hysteresis":
        T = st["die_g"]
        w = e["w"]
        y = np.empty_like(T)
        c = T[0] + w * e["y0"] if s == 0 else T[0] + w * rng.uniform(-1, 1)
        for i, Ti in enumerate(T.tolist()):
            c = min(Ti + w, max(Ti - w, c))
            y[i] = c
        h = (T - y) / w
        return np.interp(st["t"], st["tg"], h)[:, None] * e["v"][None]
    if family == "fixture":
        tilt = np.array([e["faces"][m] for m in MOUNTS])
        mi = np.array([MOUNTS.index(m) for m in st["mount"]])
        d = np.cross(tilt[mi], st["up"]) * st["rate_true"][:, None]
        d[st["handling"]] = 0
        return np.einsum("nij,nj->ni", st["Kt"], d)
    if family == "debris":
        pl = st["sch"]["placements"]
        tilt = np.array([x[2]["tilt"] * rng.normal(0, 1) for x in pl])
        d = np.cross(tilt[st["idx_place"]], st["up"]) * st["rate_true"][:, None]
        d[st["handling"]] = 0
        return np.einsum("nij,nj->ni", st["Kt"], d)
    if family == "relax":
        if s == 0:
            return np.zeros((ns, 3))
        x = st["x"]
        return (e["off"] + np.outer(x, e["slope"])) + e["sf"][None] * body / top
    if family == "crossing":
        T = st["die"]
        return np.exp(-0.5 * ((T - e["Tc"]) / e["width"]) ** 2)[:, None] * e["v"][None]
    if family == "popcorn":
        n1 = st["tg"].size
        out = np.zeros((n1, 3))
        for ax in range(3):
            state = int(rng.integers(0, 2))
            i = 0
            while i < n1:
                d = int(rng.exponential(e["dwell"][state])) + 1
                out[i : i + d, ax] = state
                i += d
                state = 1 - state
        out -= 0.5
        return np.stack([np.interp(st["t"], st["tg"], out[:, a]) for a in range(3)], 1) * e["v"][None]
    if family == "table_scale":
        d = st["up"] * (e["c"][s] * st["rate_true"])[:, None]
        d[st["handling"]] = 0
        return np.einsum("nij,nj->ni", st["Kt"], d)
    raise KeyError(family)


# ----------------------------------------------------------------------------- calibration
def quantise(w, u):
    if not u["quant"]:
        return np.clip(w, -u["range"], u["range"])
    q = u["range"] / 32768.0
    if float(np.min(u["arw"])) * math.sqrt(10) < q:  # 16 bits would not be dithered: 20 bits
        q = u["range"] / 2.0**19
    return np.clip(np.round(w / q) * q, -u["range"], u["range"] - q)


def hold_means(st, arr):
    """Means of arr over every hold (1 s trimmed at each end) -> (n_holds, ...)."""
    t = st["t"]
    out = []
    for h in st["sch"]["holds"]:
        i0, i1 = np.searchsorted(t, [h["t0"] + 1.0, h["t1"] - 1.0])
        out.append(arr[i0:i1].mean(axis=0))
    return np.array(out)


def hold_table(st):
    hs = st["sch"]["holds"]
    u = np.array([h["rate"] * MVEC[h["mount"]] for h in hs])
    pt = np.array([h["point"] for h in hs])
    tl = hold_means(st, st["tl"])
    return u, pt, tl


def standard_fit(u0, pt0, tl0, w0):
    """K, B (12 parameters) at every set point of session 0, least squares on hold means."""
    temps, Ks, Bs = [], [], []
    for p in sorted(set(pt0.tolist())):
        sel = pt0 == p
        X = np.c_[u0[sel], np.ones(sel.sum())]
        beta, *_ = np.linalg.lstsq(X, w0[sel], rcond=None)
        Ks.append(beta[:3].T)
        Bs.append(beta[3])
        temps.append(float(tl0[sel].mean()))
    o = np.argsort(temps)
    return np.array(temps)[o], np.array(Ks)[o], np.array(Bs)[o]


def standard_error(cal, u2, tl2, w2):
    """RMS over session-2 holds and axes of K(T)^-1 (w - B(T)) - rate e_mount."""
    temps, Ks, Bs = cal
    errs = []
    for i in range(len(u2)):
        T = min(max(tl2[i], temps[0]), temps[-1])
        j = int(np.clip(np.searchsorted(temps, T) - 1, 0, len(temps) - 2)) if len(temps) > 1 else 0
        if len(temps) > 1:
            f = (T - temps[j]) / (temps[j + 1] - temps[j])
            K = (1 - f) * Ks[j] + f * Ks[j + 1]
            B = (1 - f) * Bs[j] + f * Bs[j + 1]
        else:
            K, B = Ks[0], Bs[0]
        errs.append(np.linalg.solve(K, w2[i] - B) - u2[i])
    return float(np.sqrt(np.mean(np.square(errs))))


# ----------------------------------------------------------------------------- plan
def plan(units_per_family=3, seed=MASTER_SEED, quick=False):
    rng = np.random.default_rng([seed, 9])
    levels = np.geomspace(LEVEL_LO, LEVEL_HI, units_per_family) if units_per_family > 1 else [8.7]
    specs = []
    for fam in FAMILIES:
        for lv in levels:
            specs.append(dict(family=fam, level=float(lv)))
    for _ in range(4):
        specs.append(dict(family=None, level=0.0))
    order = rng.permutation(len(specs))
    seeds = rng.integers(0, 2**31, len(specs))
    out = []
    for k, i in enumerate(order):
        s = dict(specs[i], uid=f"S9U{k + 1:02d}", seed=int(seeds[k]))
        out.append(s)
    if quick:
        fams = list(FAMILIES)
        pick = [fams[i] for i in rng.choice(len(fams), 3, replace=False)]
        want = list(zip(pick, [levels[-1], levels[len(levels) // 2], levels[0]], strict=True))
        q = []
        for fam, lv in want:
            q.append(next(s for s in out if s["family"] == fam and s["level"] == float(lv)))
        q.append(next(s for s in out if s["family"] is None))
        return sorted(q, key=lambda s: s["uid"])
    return out


def build_unit(spec, tries=6):
    """Three sessions of one unit, the effect's amplitude and the truth.  A unit whose effect,
    at its physical bound, cannot make session 2 miss by a telling multiple of its floor is
    not an effect unit: it is drawn again (another unit of the same family), up to `tries`
    times, keeping the strongest."""
    best = None
    for k in range(tries):
        b = _attempt(spec, k)
        tr = b["truth"]
        if tr["complete"]:
            return b
        lv = spec["level"]
        need = 0.9 * lv if lv <= 2 else max(1.5, 0.3 * lv)
        if best is None or tr["achieved"] > best["truth"]["achieved"]:
            best = b
        if tr["achieved"] >= need:
            return b
    return best


def _attempt(spec, k):
    fam = spec["family"]
    sd = [spec["seed"], k]
    rng = np.random.default_rng([*sd, 1])
    u = draw_unit(rng, fam)
    e = draw_effect(rng, fam, u) if fam else {}
    plans = [session_plan(np.random.default_rng([*sd, 10 + s]), u, s, fam) for s in range(3)]
    if fam == "crossing":
        # the feature sits at one of the later sessions' points that lies between session 0's
        sp0 = np.array(u["sp0"])
        cand = [x for x in plans[2]["order"] if np.min(np.abs(sp0 - x)) > 3 * e["width"]]
        if not cand:
            cand = [max(plans[2]["order"], key=lambda x: np.min(np.abs(sp0 - x)))]
        e["Tc"] = float(cand[int(rng.integers(0, len(cand)))] + rng.uniform(-1, 1) + u["sh_case"] * 0.5)
    sts, pats = [], []
    for s in range(3):
        r = np.random.default_rng([*sd, 20 + s])
        st = simulate_session(r, u, plans[s], fam, FAMILIES.get(fam))
        pats.append(effect_pattern(r, fam, e, u, st, s, plans[s]) if fam else None)
        sts.append(st)
    base = [quantise(st["out"], u) for st in sts]
    ht = [hold_table(st) for st in sts]
    wb = [hold_means(sts[s], base[s]) for s in range(3)]
    cal0 = standard_fit(ht[0][0], ht[0][1], ht[0][2], wb[0])
    std = standard_error(cal0, ht[2][0], ht[2][2], wb[2])
    wf = sts[2]["wf"]
    floor = max(wf, std)
    amp, capped, miss = 0.0, False, std
    if fam:
        wg = [hold_means(sts[s], pats[s]) for s in (0, 2)]
        target = spec["level"] * floor
        bound = FAMILIES[fam]["bound"]

        def miss_of(a):
            c = standard_fit(ht[0][0], ht[0][1], ht[0][2], wb[0] + a * wg[0])
            return standard_error(c, ht[2][0], ht[2][2], wb[2] + a * wg[1])

        grid = bound * np.geomspace(1e-5, 1.0, 41)
        vals = [miss_of(a) for a in grid]
        hit = next((i for i, v in enumerate(vals) if v >= target), None)
        if hit is None:
            amp, capped = float(bound), True
        elif hit == 0:
            amp = float(grid[0])
        else:
            amp = float(brentq(lambda a: miss_of(a) - target, grid[hit - 1], grid[hit], xtol=bound * 1e-9))
        miss = miss_of(amp)
    sessions = []
    for s, st in enumerate(sts):
        w = st["out"] + (amp * pats[s] if fam else 0.0)
        sessions.append(_finish(np.random.default_rng([*sd, 30 + s]), u, plans[s], st, quantise(w, u)))
    F = FAMILIES.get(fam) or {}
    reads, acts = PHYSICS.get(fam, ((), ()))
    fix_ok = bool(F.get("carried") or F.get("fix_ok"))
    truth = dict(
        uid=spec["uid"],
        family=fam,
        level=spec["level"],
        complete=fam is None,
        carried=bool(F.get("carried", False)),
        reasons=set(F.get("reasons", ())),
        reads=set(F.get("reads", ())) if fix_ok else set(),
        acts=set(F.get("acts") or ()) if fix_ok else set(),
        depends_on=sorted(reads),
        acts_physically=sorted(acts),
        amplitude=amp,
        bound=F.get("bound"),
        capped=capped,
        white_floor=wf,
        standard=std,
        floor=floor,
        threshold=1.2 * floor,
        miss=miss,
        achieved=miss / floor,
        n_mounts=u["n_mounts"],
        draw=k,
    )
    return dict(truth=truth, sessions=sessions, uid=spec["uid"])


def _finish(rng, u, p, st, gyro):
    """Rows as logged: power-offs, logger pauses, soak tails, NaN rows, file format."""
    t = st["t"]
    sch = st["sch"]
    keep = st["power"].copy()
    for a, b in sch["pauses"]:
        keep &= ~((t >= a) & (t < b))
    if p["logging"] == "tail":
        for s in sch["segs"]:
            if s[0] == "soak":
                keep &= ~((t >= s[1]) & (t < s[2] - p["tail_s"]))
    gyro = gyro.copy()
    nan_idx = np.flatnonzero(st["handling"] & keep)
    if p["nan_rows"] and nan_idx.size:
        pick = rng.choice(nan_idx, size=min(p["nan_rows"], nan_idx.size), replace=False)
        gyro[pick, int(rng.integers(0, 3))] = np.nan
    acc = st["acc"] * u["acc_scale"][None] + u["acc_bias"][None]
    acc = acc + rng.normal(0, u["acc_noise"], acc.shape)
    sp = np.interp(t, st["tg"], st["sp_g"])
    return dict(
        t=t[keep],
        gyro=gyro[keep],
        temp=st["tl"][keep],
        ref=st["ref"][keep],
        mount=st["mount"][keep],
        acc=acc[keep] if u["accel"] else None,
        sp=sp[keep],
        plan=p,
    )


# ----------------------------------------------------------------------------- writing
def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    paths = []
    for s, ss in enumerate(built["sessions"]):
        path = os.path.join(folder, f"{built['uid']}_s{s}.parquet")
        write_log(ss, path)
        paths.append(path)
    return paths


def write_log(ss, path):
    p = ss["plan"]
    ft = pa.float32() if p["f32"] else pa.float64()
    npf = np.float32 if p["f32"] else np.float64
    t = ss["t"]
    cols, names = [], []
    if p["time"] == "float0":
        cols.append(pa.array(t, pa.float64()))
    elif p["time"] == "epoch":
        cols.append(pa.array(t + p["epoch0"], pa.float64()))
    else:
        unit = "us" if p["time"] == "ts_us" else "ns"
        scale = 1e6 if unit == "us" else 1e9
        ticks = np.round((t + p["epoch0"]) * scale).astype(np.int64)
        tz = "UTC" if p["time"] == "ts_ns_tz" else None
        cols.append(pa.array(ticks, pa.timestamp(unit, tz=tz)))
    names.append("t")
    k = math.pi / 180 if p["rad"] else 1.0
    for a, c in enumerate("xyz"):
        cols.append(pa.array((ss["gyro"][:, a] * k).astype(npf), ft))
        names.append(f"gyro_{c}")
    cols.append(pa.array(ss["temp"].astype(npf), ft))
    names.append("temp")
    cols.append(pa.array((ss["ref"] * k).astype(npf), ft))
    names.append("ref_rate")
    if p["mount_col"] == "string":
        cols.append(pa.array(ss["mount"].tolist(), pa.string()))
        names.append("mount")
    elif p["mount_col"] == "dict":
        cols.append(pa.array(ss["mount"].tolist(), pa.string()).dictionary_encode())
        names.append("mount")
    if ss["acc"] is not None:
        for a, c in enumerate("xyz"):
            cols.append(pa.array(ss["acc"][:, a].astype(npf), ft))
            names.append(f"accel_{c}")
    if p["extra"] == "sample":
        cols.append(pa.array(np.arange(t.size, dtype=np.int64)))
        names.append("sample")
    elif p["extra"] == "chamber_sp":
        cols.append(pa.array(np.round(ss["sp"], 2), pa.float64()))
        names.append("chamber_sp")
    meta = {}
    if p["rad"]:
        meta[b"gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()
    table = pa.Table.from_arrays(cols, names=names).replace_schema_metadata(meta or None)
    pq.write_table(table, path)


# ----------------------------------------------------------------------------- validator
def validate_log(path):
    """Problems of one log against the contract (an empty list when it follows it)."""
    probs = []
    try:
        table = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        return [f"unreadable: {exc}"]
    sch = table.schema
    names = sch.names
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in names:
            probs.append(f"missing column {c}")
    if probs:
        return probs
    tt = sch.field("t").type
    if not (pa.types.is_float64(tt) or pa.types.is_timestamp(tt)):
        probs.append(f"t has type {tt}")
    floats = ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y", "accel_z")
    for c in floats:
        if c in names:
            ty = sch.field(c).type
            if not (pa.types.is_float32(ty) or pa.types.is_float64(ty)):
                probs.append(f"{c} has type {ty}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in names]
    if acc and len(acc) != 3:
        probs.append("partial accelerometer columns")
    if pa.types.is_timestamp(tt):
        tv = table.column("t").cast(pa.int64()).to_numpy().astype(np.float64)
    else:
        tv = table.column("t").to_numpy()
    if not np.all(np.isfinite(tv)):
        probs.append("non-finite t")
    elif tv.size < 2 or not np.all(np.diff(tv) > 0):
        probs.append("t not strictly increasing")
    if "mount" in names:
        ty = sch.field("mount").type
        if not (pa.types.is_string(ty) or pa.types.is_large_string(ty) or pa.types.is_dictionary(ty)):
            probs.append(f"mount has type {ty}")
        vals = set(table.column("mount").cast(pa.string()).to_pylist())
        if not vals <= set(MOUNTS):
            probs.append(f"mount words {sorted(map(str, vals - set(MOUNTS)))}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            un = json.loads(md[b"gyrocal.units"])
            if not isinstance(un, dict) or not set(un.values()) <= {"rad/s", "deg/s"}:
                probs.append("bad gyrocal.units")
        except ValueError:
            probs.append("gyrocal.units not JSON")
    g = np.stack([table.column(c).to_numpy(zero_copy_only=False) for c in ("gyro_x", "gyro_y", "gyro_z")], 1)
    bad = ~np.all(np.isfinite(g), axis=1)
    if bad.mean() > 0.01:
        probs.append(f"{int(bad.sum())} non-finite gyro rows")
    r = table.column("ref_rate").to_numpy(zero_copy_only=False)
    if not np.all(np.isfinite(r)):
        probs.append("non-finite ref_rate")
    return probs


if __name__ == "__main__":  # generate and validate every unit (no tool is run)
    import argparse
    import tempfile
    import time

    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=MASTER_SEED)
    ap.add_argument("--max-units", type=int, default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    root = a.out or tempfile.mkdtemp(prefix="sealed9_gen_")
    specs = plan(3, a.seed)[: a.max_units]
    t0 = time.time()
    for sp in specs:
        b = build_unit(sp)
        ps = write_unit(b, os.path.join(root, sp["uid"]))
        pr = [m for q in ps for m in validate_log(q)]
        print(sp["uid"], [int(s["t"].size) for s in b["sessions"]], pr or "ok", flush=True)
    print(f"{len(specs)} units in {time.time() - t0:.0f} s")
