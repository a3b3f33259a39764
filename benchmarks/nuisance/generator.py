"""Open nuisance benchmark: complete turntable units under every realistic nuisance.

Each unit is one physical three-axis MEMS gyro that follows the standard model exactly,

    w = K(T_die) . w_true + B(T_die) + (turn-on bias) + (bias instability) + (white noise),

K (3x3) and B (3) smooth polynomials of the die temperature, and is written as three
`turntable` rig logs (sessions 0, 1, 2) that follow /work/shared/spec/log-format.md.
Nothing beyond the standard model acts on the sensor; everything else is nuisance of the
rig, the chamber, the operator and the logger (see README.md for the full list and ranges).

Public functions:
    draw_unit(master_seed, index)  -> unit parameters (JSON-able dict)
    build_unit(params)             -> {"sessions": [session dict x3], "trace": {...}}
    write_unit(built, folder)      -> [path0, path1, path2]
    standard_calibration(session)  -> the reference calibration (grid, K, B) of one session
    standard_error(cal, session)   -> RMS hold-mean error (deg/s) of a calibration on a session
    reference_floor(built)         -> dict(white, standard, floor, ...)
    validate_log(path)             -> list of contract problems (empty when the log is fine)
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation as Rot

T_REF = 25.0            # polynomial reference (die temperature, degC)
T_HAND = 32.0           # a hand / the operator's glove
G0 = 9.80665
RATE_MENU = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 75.0, 100.0, 150.0,
             200.0, 250.0, 300.0, 400.0)
MOUNTS6 = ("+x", "-x", "+y", "-y", "+z", "-z")
ROW_BUDGET = 300_000    # logged rows per session at most (the sample rate is chosen to fit)
TRIM = 1.0              # s trimmed at each end of a hold for hold means
DT_TH = 1.0             # thermal / slow-process grid step (s)


# ============================================================================ helpers
def _lu(rng, a, b):
    """log-uniform draw in [a, b]"""
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def _sgn(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


def _choice(rng, items, p=None):
    i = rng.choice(len(items), p=p)
    return items[int(i)]


def mount_vec(m):
    v = np.zeros(3)
    v["xyz".index(m[1])] = 1.0 if m[0] == "+" else -1.0
    return v


def _lowpass(x, tau, dt, y0):
    """exact first-order lag (zero-order hold input) on a uniform grid"""
    if tau <= 1e-9:
        return np.asarray(x, float).copy()
    a = math.exp(-dt / tau)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * y0])
    return y


def _gm(rng, n, tau, sigma, dt):
    """stationary Gauss-Markov process (first-order), n samples at step dt"""
    a = math.exp(-dt / tau)
    e = rng.normal(0.0, sigma * math.sqrt(1.0 - a * a), n)
    e[0] = rng.normal(0.0, sigma)
    y, _ = lfilter([1.0], [1.0, -a], e, zi=[0.0])
    return y


# ============================================================================ unit draw
def _kb_model(rng):
    """K(T), B(T) polynomial coefficients (in the die temperature, T - T_REF)."""
    # bias: offset, slope, curvature, cubic (deg/s)
    b0 = rng.normal(0.0, 0.5, 3)
    b1 = np.array([_sgn(rng) * _lu(rng, 0.002, 0.04) for _ in range(3)])
    b2 = np.array([_sgn(rng) * _lu(rng, 0.003, 0.2) for _ in range(3)]) / 60.0 ** 2
    b3 = np.array([_sgn(rng) * _lu(rng, 0.001, 0.05) for _ in range(3)]) / 60.0 ** 3
    # scale factor and cross-axis (dimensionless)
    k0 = np.eye(3) + np.diag(rng.normal(0.0, 0.01, 3))
    off = ~np.eye(3, dtype=bool)
    k0[off] = rng.normal(0.0, 0.004, 6)
    k1 = np.zeros((3, 3))
    k2 = np.zeros((3, 3))
    for i in range(3):
        k1[i, i] = _sgn(rng) * _lu(rng, 30e-6, 400e-6)
        k2[i, i] = _sgn(rng) * _lu(rng, 50e-6, 1500e-6) / 60.0 ** 2
    k1[off] = [_sgn(rng) * _lu(rng, 0.5e-6, 20e-6) for _ in range(6)]
    k2[off] = [_sgn(rng) * _lu(rng, 1e-6, 100e-6) / 60.0 ** 2 for _ in range(6)]
    return {"b": [b0.tolist(), b1.tolist(), b2.tolist(), b3.tolist()],
            "k": [k0.tolist(), k1.tolist(), k2.tolist()]}


def K_of(model, T):
    """K at die temperatures T (array (n,)) -> (n, 3, 3)"""
    d = np.asarray(T, float)[:, None, None] - T_REF
    k0, k1, k2 = (np.asarray(a) for a in model["k"])
    return k0[None] + k1[None] * d + k2[None] * d * d


def B_of(model, T):
    d = np.asarray(T, float)[:, None] - T_REF
    b0, b1, b2, b3 = (np.asarray(a) for a in model["b"])
    return b0[None] + b1[None] * d + b2[None] * d ** 2 + b3[None] * d ** 3


def _points0(rng):
    n = int(rng.integers(3, 8))
    lo = float(5 * round(rng.uniform(-40, 0) / 5))
    hi = float(5 * round(rng.uniform(40, 85) / 5))
    pts = np.linspace(lo, hi, n)
    jit = rng.uniform(-2, 2, n)
    jit[0] = jit[-1] = 0.0
    return [float(round(p)) for p in pts + jit]


def _points_other(rng, p0, mode):
    p0 = sorted(p0)
    lo, hi = p0[0], p0[-1]
    if mode == "same":
        pts = [p + float(rng.integers(-1, 2)) for p in p0]
    elif mode == "mid":
        pts = [0.5 * (a + b) for a, b in zip(p0[:-1], p0[1:])]
        if len(pts) < 3:
            pts = [lo + 1.0] + pts + [hi - 1.0]
    else:   # "shift": every point moved a fraction of the local spacing up, kept in range
        u = rng.uniform(0.2, 0.8)
        pts = [a + u * (b - a) for a, b in zip(p0[:-1], p0[1:])]
        pts = [lo + rng.uniform(0.5, 3.0)] + pts
        if len(pts) < 3:
            pts.append(hi - rng.uniform(0.5, 3.0))
    pts = sorted({float(round(min(max(p, lo), hi))) for p in pts})
    while len(pts) < 3:                  # never fewer than three points
        pts = sorted(set(pts) | {float(round(rng.uniform(lo, hi)))})
    return pts


def _temp_order(rng, pts, kind, room):
    asc = sorted(pts)
    n = len(asc)
    if kind == "descending":
        out = asc[::-1]
    elif kind in ("room_down_up", "room_up_down"):
        i = int(np.argmin([abs(p - room) for p in asc]))
        if kind == "room_down_up":
            out = asc[i::-1] + asc[i + 1:]
        else:
            out = asc[i:] + asc[:i][::-1]
    elif kind == "zigzag":
        out = []
        lo, hi = 0, n - 1
        while lo <= hi:
            out.append(asc[lo])
            if hi != lo:
                out.append(asc[hi])
            lo, hi = lo + 1, hi - 1
    else:
        out = list(rng.permutation(asc))
    if [float(x) for x in out] == asc:   # never plainly ascending
        out = asc[1:] + asc[:1] if rng.random() < 0.5 else asc[::-1]
    return [float(x) for x in out]


def _rate_list(rng, kind, mags, zero):
    mags = sorted(mags)
    if kind == "ascending":
        seq = [s * m for m in mags for s in (1, -1)]
        return ([0.0] if zero else []) + seq
    if kind == "descending":
        seq = [s * m for m in mags[::-1] for s in (1, -1)]
        return seq + ([0.0] if zero else [])
    if kind == "high_first":
        top = mags[-1]
        rest = [s * m for m in mags[:-1] for s in (1, -1)]
        rng.shuffle(rest)
        return [top, -top] + rest + ([0.0] if zero else [])
    if kind == "zigzag":
        a = [(1 if i % 2 == 0 else -1) * m for i, m in enumerate(mags)]
        return ([0.0] if zero else []) + a + [-x for x in a]
    if kind == "sweep":
        return ([0.0] if zero else []) + list(mags) + [-m for m in mags[::-1]]
    seq = [s * m for m in mags for s in (1, -1)] + ([0.0] if zero else [])
    return [float(x) for x in rng.permutation(seq)]


def draw_unit(master_seed, index):
    """All of one unit's random choices (physics, rig, protocol, sessions) -> dict."""
    rng = np.random.default_rng([int(master_seed), int(index), 1])
    P = {"uid": f"N{index:03d}", "master_seed": int(master_seed), "index": int(index)}
    P["model"] = _kb_model(rng)

    # ---- protocol shared by the unit's sessions (one rig set-up)
    six = rng.random() < 0.45
    if six:
        mounts = list(MOUNTS6)
    else:
        mounts = [(_choice(rng, ["+", "-"], p=[0.7, 0.3]) if rng.random() < 0.5 else "+") + a
                  for a in "xyz"]
    rmax = float(_choice(rng, [50.0, 100.0, 200.0, 300.0, 400.0], p=[0.1, 0.2, 0.25, 0.15, 0.3]))
    menu = [m for m in RATE_MENU if m < rmax]
    n_mag = int(rng.integers(2, 9))
    zero = bool(rng.random() < 0.65)
    n_pts_max = 6    # a typical session (3..7 points, a revisit adds one)
    while True:      # keep the hold count per session modest
        n_holds = n_pts_max * len(mounts) * (2 * n_mag + zero)
        if n_holds <= 400 or n_mag <= 2:
            break
        n_mag -= 1
    mags = sorted([float(x) for x in rng.choice(menu, n_mag - 1, replace=False)] + [rmax])
    H = float(round(rng.uniform(20.0, 60.0)))
    H = float(max(15.0, min(H, round(14000.0 / n_holds))))
    P["protocol"] = {"mounts": mounts, "rmax": rmax, "mags": mags, "zero": zero, "hold_s": H,
                     "accel": _lu(rng, 20.0, 200.0),
                     "settle_after_remount": [5.0, _lu(rng, 15.0, 600.0)],
                     "ref_noise_rel": 0.0 if rng.random() < 0.5 else _lu(rng, 1e-6, 1e-4)}

    # ---- sensor noise
    arw = _lu(rng, 0.003, 0.03)
    arw_ax = (arw * rng.uniform(0.75, 1.3, 3)).tolist()
    white_floor = math.sqrt(float(np.mean(np.square(arw_ax))) / (H - 2 * TRIM))
    k_bi = _lu(rng, 0.1, 2.5)
    bi_kind = _choice(rng, ["gm", "flicker"])
    if bi_kind == "gm":
        taus = [_lu(rng, 20.0, 20000.0)]
    else:
        lo, hi = _lu(rng, 10.0, 60.0), _lu(rng, 2000.0, 30000.0)
        taus = np.geomspace(lo, hi, 5).tolist()
    P["noise"] = {"arw": arw_ax, "white_floor": white_floor, "k_bi": k_bi, "bi_kind": bi_kind,
                  "bi_taus": taus, "bi_sigma": k_bi * white_floor,
                  "bi_axis": rng.uniform(0.7, 1.3, 3).tolist(),
                  "k_rep": _lu(rng, 1.0, 5.0)}
    P["noise"]["rep_sigma"] = P["noise"]["k_rep"] * white_floor
    # output quantisation: 16-bit over the smallest range that holds the top rate, unless the
    # per-sample noise would not dither it (then a finer, 20-bit-like step)
    rng_fs = float(next(r for r in (125.0, 250.0, 500.0, 1000.0, 2000.0) if r >= 1.25 * rmax * 1.05))
    P["noise"]["range"] = rng_fs
    P["noise"]["lsb16"] = rng_fs / 32768.0
    P["noise"]["quantise"] = bool(rng.random() < 0.75)

    # ---- thermal path
    two = rng.random() < 0.6
    tau_case = _lu(rng, 120.0, 1200.0)
    th = {"room": rng.uniform(19.0, 26.0), "two_stage": bool(two), "tau_case": tau_case,
          "tau_die": _lu(rng, 5.0, 120.0) if two else 0.0,
          "sh_case": rng.uniform(0.3, 5.0), "sh_die": rng.uniform(0.2, 2.0) if two else 0.0,
          "conv": 0.0 if rng.random() < 0.3 else rng.uniform(0.1, 0.8),
          "hand_mix": rng.uniform(0.0, 0.5),
          "m_soak": rng.uniform(4.0, 8.0), "ramp_rate": rng.uniform(1.0, 5.0) / 60.0,
          # chamber: air lag, PI controller, actuator limit, door exchange, ripple
          "tau_air": _lu(rng, 20.0, 90.0), "kp": rng.uniform(0.5, 3.0),
          "ti": _lu(rng, 60.0, 600.0), "umax": rng.uniform(25.0, 60.0),
          "tau_door": _lu(rng, 15.0, 1000.0),
          "ripple_sigma": _lu(rng, 0.01, 0.2), "ripple_tau": _lu(rng, 30.0, 300.0)}
    smode = _choice(rng, ["on_die", "lag", "lead"], p=[0.3, 0.35, 0.35])
    th["sensor"] = {"mode": smode,
                    "tau": _lu(rng, 3.0, 120.0) if smode == "lag" else 0.5,
                    "kappa": rng.uniform(0.1, 0.6) if smode == "lead" else 0.0,
                    "offset": rng.normal(0.0, 1.5), "gain": 1.0 + rng.normal(0.0, 0.01),
                    "noise": _lu(rng, 0.005, 0.15),
                    "lsb": float(_choice(rng, [1 / 256, 1 / 64, 1 / 16, 1 / 8])),
                    "update_s": float(_choice(rng, [0.0, 1.0, 2.0], p=[0.5, 0.3, 0.2]))}
    P["thermal"] = th

    # ---- handling, fixture, power
    P["handling"] = {"dur": [15.0, _lu(rng, 25.0, 90.0)], "door_extra": [2.0, rng.uniform(5.0, 25.0)],
                     "tremor": _lu(rng, 0.3, 5.0), "seat_urad": _lu(rng, 1.0, 30.0),
                     "power_cycle": _choice(rng, ["never", "remount", "setpoint"], p=[0.6, 0.2, 0.2])}

    # ---- logging / file format
    P["log"] = {"time": _choice(rng, ["float0", "float_epoch", "timestamp_ns", "timestamp_us"],
                                p=[0.4, 0.25, 0.2, 0.15]),
                "mount_col": _choice(rng, ["none", "string", "dictionary"], p=[0.4, 0.3, 0.3]),
                "accel": bool(rng.random() < 0.4), "radius": rng.uniform(0.0, 0.08),
                "rad": bool(rng.random() < 0.15), "float32": bool(rng.random() < 0.5),
                "nan_rows": int(rng.integers(1, 6)) if rng.random() < 0.15 else 0,
                "soak_log": _choice(rng, ["tail", "full"], p=[0.7, 0.3]),
                "soak_tail": [3.0 * 60, _lu(rng, 4.0 * 60, 15.0 * 60)]}

    # ---- sessions
    p0 = _points0(rng)
    sess = []
    for s in range(3):
        pts = p0 if s == 0 else _points_other(
            rng, p0, _choice(rng, ["same", "mid", "shift"], p=[0.3, 0.35, 0.35]))
        shift_mode = "base" if s == 0 else None
        if s > 0:
            shift_mode = ("same" if all(any(abs(a - b) <= 1 for b in p0) for a in pts)
                          else "between")
        tkind = _choice(rng, ["descending", "room_down_up", "room_up_down", "zigzag", "shuffled"])
        order = _temp_order(rng, pts, tkind, th["room"])
        revisit = None
        if rng.random() < 0.35:
            cand = [p for p in order[:-1]]
            rp = float(_choice(rng, cand))
            nm = len(mounts) if rng.random() < 0.5 else int(rng.integers(1, 3))
            revisit = {"point": rp, "mounts": [str(m) for m in rng.permutation(mounts)[:nm]]}
        sess.append({
            "points": pts, "shift": shift_mode, "temp_kind": tkind, "order": order,
            "revisit": revisit,
            "mount_policy": _choice(rng, ["fixed", "serpentine", "random"]),
            "rate_kind": _choice(rng, ["ascending", "descending", "shuffled", "high_first",
                                       "zigzag", "sweep"]),
            "n_pauses": int(_choice(rng, [0, 0, 1, 2, 3])),
            "power_on": _choice(rng, ["at_insert", "late"], p=[0.5, 0.5]),
            "warmup_s": _lu(rng, 180.0, 1800.0),
            "day": [0, int(rng.integers(1, 31)), int(rng.integers(30, 181))][s],
            "seed": int(rng.integers(0, 2 ** 31 - 1)),
        })
    P["sessions"] = sess
    return P


# ============================================================================ timeline
class _Timeline:
    """Physical time line of one session: table segments, events, placements."""

    def __init__(self):
        self.t = 0.0
        self.segs = []        # (t0, t1, r0, r1): table rate, linear-in-cosine between r0 and r1
        self.holds = []       # dicts
        self.sp_knots = []    # (t, setpoint)
        self.doors = []       # (t0, t1)
        self.handles = []     # dicts (t0, t1, moves...)
        self.power_off = []   # (t0, t1)
        self.log_off = []     # (t0, t1)
        self.power_on_times = []
        self.places = []      # (t, mount, R body->table, u_body)
        self.rate = 0.0

    def static(self, d):
        self.t += d

    def ramp_to(self, r, accel):
        if r == self.rate:
            return
        d = max(0.3, math.pi * abs(r - self.rate) / (2.0 * accel))
        self.segs.append((self.t, self.t + d, self.rate, r))
        self.t += d
        self.rate = r

    def hold(self, r, d, **kw):
        self.segs.append((self.t, self.t + d, r, r))
        self.holds.append(dict(t0=self.t, t1=self.t + d, rate=r, **kw))
        self.t += d


def _placement(rng, m, seat_rad):
    u = mount_vec(m)
    ez = np.array([0.0, 0.0, 1.0])
    c = np.cross(u, ez)
    if np.linalg.norm(c) < 1e-9:
        R0 = Rot.identity() if u[2] > 0 else Rot.from_rotvec([math.pi, 0.0, 0.0])
    else:
        R0 = Rot.from_rotvec(c / np.linalg.norm(c) * math.acos(float(np.clip(u @ ez, -1, 1))))
    Rz = Rot.from_rotvec([0.0, 0.0, rng.uniform(0, 2 * math.pi)])
    Rs = Rot.from_rotvec(rng.normal(0.0, seat_rad, 3))
    R = Rs * Rz * R0                      # body -> table frame
    u_body = R.inv().apply(ez)
    return R, u_body


def _handling_moves(rng, R_old, R_new, t0, dur):
    """A few constant-axis moves (body frame) taking the unit from R_old to R_new."""
    def tilt(lo, hi):
        ax = rng.normal(size=3)
        ax /= np.linalg.norm(ax)
        return Rot.from_rotvec(ax * math.radians(rng.uniform(lo, hi)))
    mid = Rot.from_quat(np.vstack([R_old.as_quat(), R_new.as_quat()]))
    from scipy.spatial.transform import Slerp
    Rm = Slerp([0.0, 1.0], mid)([0.5])[0]
    way = [R_old, R_old * tilt(10, 30), Rm * tilt(20, 60), R_new * tilt(5, 15), R_new]
    n = len(way) - 1
    ds = rng.uniform(0.4, 2.0, n)
    ds *= min(1.0, 0.8 * dur / ds.sum())
    rest = dur - ds.sum()
    gaps = rng.dirichlet(np.ones(n + 1)) * rest
    moves = []
    t = t0 + gaps[0]
    for i in range(n):
        phi = (way[i].inv() * way[i + 1]).as_rotvec()     # body-frame rotation vector
        moves.append((t, t + ds[i], way[i], phi))
        t += ds[i] + gaps[i + 1]
    return moves


def _build_timeline(P, s, rng):
    pr, th, hd, lg = P["protocol"], P["thermal"], P["handling"], P["log"]
    S = P["sessions"][s]
    tl = _Timeline()
    room = th["room"]
    seat = hd["seat_urad"] * 1e-6
    soak = float(np.clip(th["m_soak"] * max(th["tau_case"], th["tau_die"]), 15 * 60, 100 * 60))
    tail = rng.uniform(*lg["soak_tail"])
    accel = pr["accel"]
    mounts = list(pr["mounts"])

    # the sequence of (setpoint, mounts) visits
    visits = []
    perm = [str(m) for m in rng.permutation(mounts)]
    for j, sp in enumerate(S["order"]):
        if S["mount_policy"] == "fixed":
            ms = perm
        elif S["mount_policy"] == "serpentine":
            ms = perm if j % 2 == 0 else perm[::-1]
        else:
            ms = [str(m) for m in rng.permutation(mounts)]
        visits.append((sp, ms))
    if S["revisit"]:
        visits.append((S["revisit"]["point"], list(S["revisit"]["mounts"])))
    n_total_mounts = sum(len(v[1]) for v in visits)
    pauses = set(rng.choice(np.arange(1, n_total_mounts), size=min(S["n_pauses"], n_total_mounts - 1),
                            replace=False).tolist()) if n_total_mounts > 1 else set()

    # insertion: chamber preconditioned at the first set point, unit at room temperature
    sp0 = visits[0][0]
    tl.sp_knots.append((0.0, sp0))
    cur_mount = visits[0][1][0]
    R, u = _placement(rng, cur_mount, seat)
    tl.places.append((0.0, cur_mount, R, u))
    tl.doors.append((0.0, rng.uniform(15.0, 40.0)))
    presoak = soak
    if S["power_on"] == "at_insert":
        tl.power_on_times.append(0.0)
        t_pon = 0.0
    else:
        t_pon = max(60.0, presoak - S["warmup_s"])
        tl.power_on_times.append(t_pon)
    tl.static(presoak)
    first_hold_wait = presoak - t_pon
    if lg["soak_log"] == "tail":
        tl.log_off.append((0.0, max(t_pon, presoak - tail)))
    else:
        tl.log_off.append((0.0, t_pon))

    mount_counter = 0
    cur_sp = sp0
    for j, (sp, ms) in enumerate(visits):
        if j > 0:
            # remount before the chamber moves if needed, then ramp, then soak
            t_start = tl.t
            if ms[0] != cur_mount:
                R, u = _remount(P, tl, rng, cur_mount, ms[0], R, seat, power_cycle=
                                hd["power_cycle"] in ("remount", "setpoint"))
                cur_mount = ms[0]
            elif hd["power_cycle"] == "setpoint":
                _power_cycle(tl, rng, tl.t + 2.0, rng.uniform(5.0, 30.0))
                tl.static(35.0)
            tl.sp_knots.append((tl.t, cur_sp))
            dur = abs(sp - cur_sp) / th["ramp_rate"]
            tl.static(dur)
            tl.sp_knots.append((tl.t, sp))
            tl.static(soak)
            cur_sp = sp
            if lg["soak_log"] == "tail":
                tl.log_off.append((t_start + 1.0, tl.t - tail))
        for k, m in enumerate(ms):
            if k > 0 or m != cur_mount:
                if mount_counter in pauses:       # logger paused while the operator waits
                    d = rng.uniform(60.0, 20 * 60.0)
                    tl.log_off.append((tl.t + 1.0, tl.t + 1.0 + d))
                    tl.static(d + 2.0)
                R, u = _remount(P, tl, rng, cur_mount, m, R, seat,
                                power_cycle=hd["power_cycle"] == "remount")
                cur_mount = m
                tl.static(rng.uniform(*pr["settle_after_remount"]))
            mount_counter += 1
            for r in _rate_list(rng, S["rate_kind"], pr["mags"], pr["zero"]):
                tl.ramp_to(r, accel)
                tl.hold(r, pr["hold_s"], mount=m, u_body=u.copy(), setpoint=float(sp), visit=j)
            tl.ramp_to(0.0, accel)
            tl.static(rng.uniform(3.0, 15.0))
    tl.static(5.0)
    tl.sp_knots.append((tl.t, cur_sp))
    return tl, first_hold_wait


def _power_cycle(tl, rng, t_off, d_off):
    tl.power_off.append((t_off, t_off + d_off))
    tl.power_on_times.append(t_off + d_off)


def _remount(P, tl, rng, m_old, m_new, R_old, seat, power_cycle):
    hd = P["handling"]
    tl.static(rng.uniform(2.0, 10.0))
    t_door = tl.t
    t_h0 = t_door + rng.uniform(2.0, 8.0)
    dur = rng.uniform(*hd["dur"])
    R_new, u_new = _placement(rng, m_new, seat)
    moves = _handling_moves(rng, R_old, R_new, t_h0, dur)
    tl.handles.append({"t0": t_h0, "t1": t_h0 + dur, "moves": moves, "R_end": R_new,
                       "tremor": hd["tremor"], "seed": int(rng.integers(0, 2 ** 31 - 1))})
    t_close = t_h0 + dur + rng.uniform(*hd["door_extra"])
    tl.doors.append((t_door, t_close))
    if power_cycle:
        _power_cycle(tl, rng, t_h0 + 0.2 * dur, 0.6 * dur)
    tl.places.append((t_h0 + dur, m_new, R_new, u_new))
    tl.t = t_close
    return R_new, u_new


def _in_intervals(t, ivs):
    m = np.zeros(t.shape, bool)
    for a, b in ivs:
        m |= (t >= a) & (t < b)
    return m


def _table_rate(tl, t):
    """table (encoder) rate at times t"""
    r = np.zeros_like(t)
    if not tl.segs:
        return r
    st = np.array([s[0] for s in tl.segs])
    en = np.array([s[1] for s in tl.segs])
    r0 = np.array([s[2] for s in tl.segs])
    r1 = np.array([s[3] for s in tl.segs])
    i = np.searchsorted(st, t, side="right") - 1
    ok = (i >= 0) & (t < en[np.clip(i, 0, None)])
    ii = i[ok]
    x = (t[ok] - st[ii]) / (en[ii] - st[ii])
    r[ok] = r0[ii] + (r1[ii] - r0[ii]) * 0.5 * (1.0 - np.cos(np.pi * x))
    return r


def _table_accel(tl, t):
    """table angular acceleration (deg/s^2) at times t"""
    a = np.zeros_like(t)
    for t0, t1, r0, r1 in tl.segs:
        if r0 == r1:
            continue
        m = (t >= t0) & (t < t1)
        x = (t[m] - t0) / (t1 - t0)
        a[m] = (r1 - r0) * 0.5 * np.pi * np.sin(np.pi * x) / (t1 - t0)
    return a


# ============================================================================ physics
def _thermal(P, tl, rng, t_end):
    th = P["thermal"]
    n = int(math.ceil(t_end / DT_TH)) + 2
    g = np.arange(n) * DT_TH
    kt = np.array([k[0] for k in tl.sp_knots])
    kv = np.array([k[1] for k in tl.sp_knots])
    sp = np.interp(g, kt, kv)
    door = _in_intervals(g, tl.doors)
    hand = _in_intervals(g, [(h["t0"], h["t1"]) for h in tl.handles])
    power = np.zeros(n, bool)
    ons = sorted(tl.power_on_times)
    power |= g >= ons[0]
    power &= ~_in_intervals(g, tl.power_off)
    om = np.abs(_table_rate(tl, g))

    # chamber air: first-order plant, PI controller with actuator limit, door air exchange
    room, tau_a, kp, ti, umax, tau_d = (th["room"], th["tau_air"], th["kp"], th["ti"],
                                        th["umax"], th["tau_door"])
    air = np.empty(n)
    T = float(sp[0])
    I = 0.0
    spl = sp.tolist()
    dl = door.tolist()
    for k in range(n):
        e = spl[k] - T
        u = spl[k] + kp * e + I
        lo, hi = T - umax, T + umax
        if u > hi:
            u = hi
        elif u < lo:
            u = lo
        else:
            I += kp * e * DT_TH / ti
        dT = (u - T) / tau_a
        if dl[k]:
            dT += (room - T) / tau_d
        T += DT_TH * dT
        air[k] = T
    air += _gm(rng, n, th["ripple_tau"], th["ripple_sigma"], DT_TH)

    h = th["hand_mix"] * hand
    env = air * (1 - h) + T_HAND * h
    q_case = th["sh_case"] * power / (1.0 + th["conv"] * om / 300.0)
    case = _lowpass(env + q_case, th["tau_case"], DT_TH, room)
    die = _lowpass(case + th["sh_die"] * power, th["tau_die"], DT_TH, room)
    sn = th["sensor"]
    sens = _lowpass(die + sn["kappa"] * (case - die), sn["tau"], DT_TH, room)
    return {"g": g, "sp": sp, "air": air, "case": case, "die": die, "sens": sens,
            "door": door, "power": power}


def _bias_instability(P, rng, n):
    nz = P["noise"]
    taus = nz["bi_taus"]
    out = np.zeros((n, 3))
    for ax in range(3):
        sig = nz["bi_sigma"] * nz["bi_axis"][ax] / math.sqrt(len(taus))
        for tau in taus:
            out[:, ax] += _gm(rng, n, tau, sig, DT_TH)
    return out


def _handling_signals(tl, t, accel_on):
    """body rate (deg/s) during handling, and the gravity direction in the body frame"""
    w = np.zeros((t.size, 3))
    grav = None
    for h in tl.handles:
        m = (t >= h["t0"]) & (t < h["t1"])
        if not m.any():
            continue
        idx = np.nonzero(m)[0]
        tt = t[idx]
        hr = np.random.default_rng(h["seed"])
        # tremor: band-limited random body rate
        trem = hr.normal(0.0, 1.0, (idx.size, 3))
        if idx.size > 3:
            trem = lfilter([0.3], [1.0, -0.7], trem, axis=0) / 0.42
        w[idx] += h["tremor"] * trem
        for (a, b, R_a, phi) in h["moves"]:
            mm = (tt >= a) & (tt < b)
            x = (tt[mm] - a) / (b - a)
            sd = 0.5 * np.pi * np.sin(np.pi * x) / (b - a)
            w[idx[mm]] += np.degrees(phi)[None, :] * sd[:, None]
    if accel_on:
        grav = np.zeros((t.size, 3))
        # orientation piecewise: at rest between moves the last orientation holds
        for h in tl.handles:
            m = (t >= h["t0"]) & (t < h["t1"])
            if not m.any():
                continue
            idx = np.nonzero(m)[0]
            tt = t[idx]
            rot = np.empty((idx.size, 3))
            rot[:] = np.nan
            for (a, b, R_a, phi) in h["moves"]:
                before = tt >= b
                Rend = R_a * Rot.from_rotvec(phi)
                rot[before] = Rend.inv().apply([0.0, 0.0, 1.0])
                mm = (tt >= a) & (tt < b)
                if mm.any():
                    x = (tt[mm] - a) / (b - a)
                    s_ = 0.5 * (1.0 - np.cos(np.pi * x))
                    Rs = R_a * Rot.from_rotvec(s_[:, None] * phi[None, :])
                    rot[mm] = Rs.inv().apply([0.0, 0.0, 1.0])
            first = h["moves"][0]
            nanm = np.isnan(rot[:, 0])
            rot[nanm] = first[2].inv().apply([0.0, 0.0, 1.0])
            grav[idx] = rot
    return w, grav


def simulate_session(P, s):
    """One session's log (arrays) and its truth."""
    S = P["sessions"][s]
    rng = np.random.default_rng([P["master_seed"], P["index"], 100 + s, S["seed"]])
    tl, first_wait = _build_timeline(P, s, rng)
    t_end = tl.t
    thm = _thermal(P, tl, rng, t_end)
    fs = P["log"]["fs"]

    # logged sample times: the logger's grid minus pauses and power-off
    t = np.arange(0.0, t_end, 1.0 / fs)
    keep = ~_in_intervals(t, tl.log_off) & ~_in_intervals(t, tl.power_off)
    keep &= t >= min(tl.power_on_times)
    t = t[keep]
    n = t.size

    die = np.interp(t, thm["g"], thm["die"])
    sens = np.interp(t, thm["g"], thm["sens"])

    # true body rate: table rate about the current placement's rig axis + handling motion
    ref_true = _table_rate(tl, t)
    pt = np.array([p[0] for p in tl.places])
    pi_ = np.clip(np.searchsorted(pt, t, side="right") - 1, 0, None)
    U = np.array([p[3] for p in tl.places])[pi_]
    handling = _in_intervals(t, [(h["t0"], h["t1"]) for h in tl.handles])
    w_true = ref_true[:, None] * U
    w_true[handling] = 0.0
    w_h, grav_h = _handling_signals(tl, t, P["log"]["accel"])
    w_true += w_h

    # sensor output
    K = K_of(P["model"], die)
    B = B_of(P["model"], die)
    nz = P["noise"]
    w = np.einsum("nij,nj->ni", K, w_true) + B
    ons = np.array(sorted(tl.power_on_times))
    epoch = np.clip(np.searchsorted(ons, t, side="right") - 1, 0, None)
    b_on = rng.normal(0.0, nz["rep_sigma"], (ons.size, 3))
    w += b_on[epoch]
    bi = _bias_instability(P, rng, thm["g"].size)
    for ax in range(3):
        w[:, ax] += np.interp(t, thm["g"], bi[:, ax])
    w += rng.normal(0.0, 1.0, (n, 3)) * (np.asarray(nz["arw"]) * math.sqrt(fs))[None, :]
    if nz["quantise"]:
        lsb = nz["lsb16"]
        if min(nz["arw"]) * math.sqrt(fs) < 0.6 * lsb:
            lsb = nz["range"] / 2 ** 20
        w = np.round(w / lsb) * lsb
    w = np.clip(w, -nz["range"], nz["range"])

    # the unit's temperature sensor
    sn = P["thermal"]["sensor"]
    if sn["update_s"] > 0:
        tu = np.floor(t / sn["update_s"]) * sn["update_s"]
        sens_u = np.interp(tu, thm["g"], thm["sens"])
    else:
        sens_u = sens
    temp = T_REF + sn["offset"] + sn["gain"] * (sens_u - T_REF)
    temp = temp + rng.normal(0.0, sn["noise"], n)
    temp = np.round(temp / sn["lsb"]) * sn["lsb"]

    # encoder reference: exact at rest, small relative jitter when turning
    ref = ref_true + rng.normal(0.0, 1.0, n) * P["protocol"]["ref_noise_rel"] * np.abs(ref_true)

    # mount label: the placement in force
    mlabel = np.array([p[1] for p in tl.places])[pi_]

    # accelerometer (g): gravity + centripetal/tangential on the table; gravity + hand in handling
    acc = None
    if P["log"]["accel"]:
        Rb = [p[2] for p in tl.places]
        ez = np.array([0.0, 0.0, 1.0])
        rad = P["log"]["radius"]
        psi = rng.uniform(0, 2 * math.pi)
        rho = np.array([math.cos(psi), math.sin(psi), 0.0])
        tau_ = np.cross(ez, rho)
        om = np.radians(ref_true)
        al = np.radians(_table_accel(tl, t))
        f_tab = ez[None, :] + (-(om ** 2)[:, None] * rad * rho[None, :]
                               + al[:, None] * rad * tau_[None, :]) / G0
        acc = np.empty((n, 3))
        for i, R in enumerate(Rb):
            m = pi_ == i
            acc[m] = R.inv().apply(f_tab[m])
        acc[handling] = grav_h[handling] + rng.normal(0.0, 0.05, (int(handling.sum()), 3))
        ab = rng.normal(0.0, 0.01, 3)
        acc = acc @ (np.eye(3) + rng.normal(0.0, 0.003, (3, 3))).T + ab + rng.normal(0.0, 0.002, (n, 3))

    # NaN glitches outside holds
    if P["log"]["nan_rows"]:
        cand = np.nonzero(handling)[0] if handling.any() else np.arange(n)
        bad = rng.choice(cand, size=min(P["log"]["nan_rows"], cand.size), replace=False)
        w[bad, int(rng.integers(0, 3))] = np.nan

    # holds: logged means, truth
    holds = []
    for h in tl.holds:
        m = (t >= h["t0"] + TRIM) & (t <= h["t1"] - TRIM)
        if m.sum() > 3:     # temperature change across the hold (degC/min): die and logged
            tc = t[m] - t[m].mean()
            den = float(tc @ tc)
            d_die = float(tc @ (die[m] - die[m].mean())) / den * 60.0
            d_log = float(tc @ (temp[m] - temp[m].mean())) / den * 60.0
        else:
            d_die = d_log = 0.0
        holds.append({"t0": h["t0"], "t1": h["t1"], "rate": h["rate"], "mount": h["mount"],
                      "setpoint": h["setpoint"], "visit": h["visit"],
                      "w_mean": np.nanmean(w[m], axis=0) if m.any() else np.full(3, np.nan),
                      "temp_mean": float(np.mean(temp[m])) if m.any() else float("nan"),
                      "die_mean": float(np.mean(die[m])) if m.any() else float("nan"),
                      "u_body": h["u_body"], "n": int(m.sum()),
                      "ddie": d_die, "dlog": d_log})

    # door dips of the air, as a fraction of (room - set point)
    dips = []
    for a, b in tl.doors[1:]:
        m = (thm["g"] >= a) & (thm["g"] <= b + 600)
        spm = thm["sp"][m]
        d = np.max(np.abs(thm["air"][m] - spm)) if m.any() else 0.0
        den = abs(P["thermal"]["room"] - float(np.median(spm))) if m.any() else 0.0
        if den > 5.0:
            dips.append(d / den)
    return {"t": t, "gyro": w, "temp": temp, "ref": ref, "mount": mlabel, "accel": acc,
            "die": die, "holds": holds, "t_end": t_end, "first_wait": first_wait,
            "door_dips": dips, "n_power_on": int(ons.size),
            "sh_unsettled": _selfheat_unsettled(P, tl, first_wait)}


def _selfheat_unsettled(P, tl, first_wait):
    """degC of self-heating still to come at the first hold after power-on (first order)"""
    th = P["thermal"]
    a = th["sh_case"] * math.exp(-first_wait / th["tau_case"])
    if th["tau_die"] > 0:
        a += th["sh_die"] * math.exp(-first_wait / th["tau_die"])
    return a


def _choose_fs(P):
    """the largest logger rate that keeps session 0 within the row budget"""
    P["log"]["fs"] = 1.0
    sim_rng = np.random.default_rng([P["master_seed"], P["index"], 100, P["sessions"][0]["seed"]])
    tl, _ = _build_timeline(P, 0, sim_rng)
    t = np.arange(0.0, tl.t, 1.0)
    keep = ~_in_intervals(t, tl.log_off) & ~_in_intervals(t, tl.power_off)
    secs = float(keep.sum()) * 1.15       # other sessions can be a little longer
    for f in (50.0, 25.0, 20.0, 10.0):
        if secs * f <= ROW_BUDGET:
            return f, "ok"
    return 10.0, "over"


def build_unit(P):
    P = json.loads(json.dumps(P))            # private copy
    fs, st = _choose_fs(P)
    if st == "over" and P["log"]["soak_log"] == "full":
        P["log"]["soak_log"] = "tail"
        fs, st = _choose_fs(P)
    P["log"]["fs"] = fs
    sessions = [simulate_session(P, s) for s in range(3)]
    return {"params": P, "sessions": sessions, "trace": _trace(P, sessions)}


# ============================================================================ writing
def write_session(P, S, path, s):
    lg = P["log"]
    n = S["t"].size
    f = np.float32 if lg["float32"] else np.float64
    conv = math.pi / 180.0 if lg["rad"] else 1.0
    day0 = 1718000000.0 + 86400.0 * P["sessions"][s]["day"] + 3600.0 * 8
    cols = {}
    if lg["time"] == "float0":
        cols["t"] = pa.array(S["t"], pa.float64())
    elif lg["time"] == "float_epoch":
        cols["t"] = pa.array(S["t"] + day0, pa.float64())
    else:
        unit = "ns" if lg["time"] == "timestamp_ns" else "us"
        mult = 1e9 if unit == "ns" else 1e6
        ticks = np.round((S["t"] + day0) * mult).astype(np.int64)
        cols["t"] = pa.array(ticks, pa.timestamp(unit))
    for i, a in enumerate("xyz"):
        cols[f"gyro_{a}"] = pa.array((S["gyro"][:, i] * conv).astype(f))
    cols["temp"] = pa.array(S["temp"].astype(f))
    cols["ref_rate"] = pa.array((S["ref"] * conv).astype(f if lg["float32"] else np.float64))
    if lg["mount_col"] == "string":
        cols["mount"] = pa.array(S["mount"].tolist(), pa.string())
    elif lg["mount_col"] == "dictionary":
        cols["mount"] = pa.array(S["mount"].tolist(), pa.string()).dictionary_encode()
    if S["accel"] is not None:
        for i, a in enumerate("xyz"):
            cols[f"accel_{a}"] = pa.array(S["accel"][:, i].astype(f))
    cols["sample"] = pa.array(np.arange(n, dtype=np.int64))     # an extra column, carried along
    tab = pa.table(cols)
    meta = {b"gyrocal.generator": b"benchmarks/nuisance"}
    if lg["rad"]:
        meta[b"gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()
    tab = tab.replace_schema_metadata(meta)
    pq.write_table(tab, path, compression="zstd")
    return path


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    P = built["params"]
    return [write_session(P, S, os.path.join(folder, f"{P['uid']}_s{s}.parquet"), s)
            for s, S in enumerate(built["sessions"])]


# ============================================================================ reference
def standard_calibration(S):
    """K and B (12 parameters) per set point by least squares on the hold means; the grid
    temperature of a point is the mean logged temperature of its holds (revisits pooled)."""
    groups = {}
    for h in S["holds"]:
        if h["n"] < 2 or not np.all(np.isfinite(h["w_mean"])):
            continue
        groups.setdefault(h["setpoint"], []).append(h)
    grid, Ks, Bs = [], [], []
    for sp, hs in groups.items():
        X = np.array([np.r_[h["rate"] * mount_vec(h["mount"]), 1.0] for h in hs])
        Y = np.array([h["w_mean"] for h in hs])
        sol, *_ = np.linalg.lstsq(X, Y, rcond=None)        # (4, 3): Y = X @ sol
        Ks.append(sol[:3].T)
        Bs.append(sol[3])
        grid.append(float(np.mean([h["temp_mean"] for h in hs])))
    o = np.argsort(grid)
    return {"grid": np.array(grid)[o], "K": np.array(Ks)[o], "B": np.array(Bs)[o]}


def _interp_cal(cal, T):
    g = cal["grid"]
    K = np.empty((3, 3))
    B = np.empty(3)
    for i in range(3):
        B[i] = np.interp(T, g, cal["B"][:, i])
        for j in range(3):
            K[i, j] = np.interp(T, g, cal["K"][:, i, j])
    return K, B


def standard_error(cal, S):
    """RMS (over holds and the three axes) of the compensated hold mean minus the nominal
    reference vector (rate along the mount axis)."""
    err = []
    for h in S["holds"]:
        if h["n"] < 2 or not np.all(np.isfinite(h["w_mean"])):
            continue
        K, B = _interp_cal(cal, h["temp_mean"])
        wt = np.linalg.solve(K, h["w_mean"] - B)
        err.append(wt - h["rate"] * mount_vec(h["mount"]))
    e = np.array(err)
    return float(np.sqrt(np.mean(e ** 2)))


def reference_floor(built):
    P = built["params"]
    white = P["noise"]["white_floor"]
    cal = standard_calibration(built["sessions"][0])
    std = standard_error(cal, built["sessions"][2])
    return {"white": white, "standard": std, "floor": max(white, std)}


# ============================================================================ trace
def _oracle_interp_error(P, S0, S2):
    """error of linearly interpolating the TRUE K, B between session 0's points (at the true
    die temperature), evaluated at session 2's holds: the interpolation part of the floor"""
    model = P["model"]
    grp = {}
    for h in S0["holds"]:
        grp.setdefault(h["setpoint"], []).append(h["die_mean"])
    g = np.sort([np.mean(v) for v in grp.values()])
    Kg, Bg = K_of(model, g), B_of(model, g)
    cal = {"grid": g, "K": Kg, "B": Bg}
    err = []
    for h in S2["holds"]:
        T = h["die_mean"]
        K, B = _interp_cal(cal, T)
        Kt, Bt = K_of(model, [T])[0], B_of(model, [T])[0]
        v = h["rate"] * mount_vec(h["mount"])
        err.append(np.linalg.solve(K, Kt @ v + Bt - B) - v)
    return float(np.sqrt(np.mean(np.square(err))))


def _offpoint(P, S):
    """holds off their point's temperature: RMS over holds of the die temperature's departure
    from its point's median (degC), and its effect on the output (deg/s) through dK/dT, dB/dT"""
    model = P["model"]
    grp = {}
    for h in S["holds"]:
        grp.setdefault(h["setpoint"], []).append(h)
    dT, eff, trk = [], [], []
    for sp, hs in grp.items():
        dies = np.array([h["die_mean"] for h in hs])
        offs = np.array([h["temp_mean"] - h["die_mean"] for h in hs])
        med, omed = np.median(dies), np.median(offs)
        for h, d, o in zip(hs, dies, offs):
            v = h["rate"] * mount_vec(h["mount"])
            Kd = (K_of(model, [d])[0] - K_of(model, [med])[0]) @ v
            Bd = B_of(model, [d])[0] - B_of(model, [med])[0]
            dT.append(d - med)
            eff.append(np.linalg.norm(Kd + Bd) / math.sqrt(3))
            # what the logged temperature gets wrong about that departure
            trk.append(o - omed)
    return (float(np.sqrt(np.mean(np.square(dT)))), float(np.sqrt(np.mean(np.square(eff)))),
            float(np.sqrt(np.mean(np.square(trk)))))


def _trace(P, sessions):
    S0, S2 = sessions[0], sessions[2]
    wf = P["noise"]["white_floor"]
    off_dT0, off_eff0, trk0 = _offpoint(P, S0)
    off_dT2, off_eff2, trk2 = _offpoint(P, S2)
    # sensitivity of the output to a logged-temperature error (deg/s per degC) at the top rate
    model = P["model"]
    dK = (K_of(model, [T_REF + 0.5])[0] - K_of(model, [T_REF - 0.5])[0])
    dB = B_of(model, [T_REF + 0.5])[0] - B_of(model, [T_REF - 0.5])[0]
    rmax = P["protocol"]["rmax"]
    sens_top = float(np.linalg.norm(dK @ (rmax * np.ones(3) / math.sqrt(3)) + dB) / math.sqrt(3))
    dips = [d for S in sessions for d in S["door_dips"]]
    th, hd, pr, nz = P["thermal"], P["handling"], P["protocol"], P["noise"]
    sl0 = np.abs([h["ddie"] for h in S0["holds"]])
    sl0log = np.abs([h["dlog"] for h in S0["holds"]])
    return {
        "hold_drift_max": float(sl0.max()),           # degC/min, die, session 0
        "hold_drift_frac": float(np.mean(sl0 > 0.05)),  # share of session-0 holds drifting > 0.05 degC/min
        "hold_drift_frac_log": float(np.mean(sl0log > 0.05)),
        "arw": float(np.mean(nz["arw"])), "white_floor": wf,
        "k_bi": nz["k_bi"], "bi_kind": nz["bi_kind"], "bi_tau_max": float(max(nz["bi_taus"])),
        "k_rep": nz["k_rep"],
        "door_dip": float(max(dips)) if dips else 0.0,
        "tau_door": th["tau_door"], "room": th["room"],
        "tau_case": th["tau_case"], "tau_die": th["tau_die"], "two_stage": th["two_stage"],
        "self_heat": th["sh_case"] + th["sh_die"], "conv": th["conv"],
        "sh_unsettled": float(max(S["sh_unsettled"] for S in sessions)),
        "sensor_mode": th["sensor"]["mode"], "sensor_tau": th["sensor"]["tau"],
        "sensor_kappa": th["sensor"]["kappa"], "temp_lsb": th["sensor"]["lsb"],
        "temp_noise": th["sensor"]["noise"],
        "offpoint_dT": max(off_dT0, off_dT2),
        "offpoint_eff": max(off_eff0, off_eff2) / wf,
        "sensor_track": max(trk0, trk2),
        "sensor_track_eff": max(trk0, trk2) * sens_top / wf,
        "seat_urad": hd["seat_urad"],
        "seat_eff": hd["seat_urad"] * 1e-6 * rmax / wf,
        "power_cycle": hd["power_cycle"], "handle_s": hd["dur"][1], "tremor": hd["tremor"],
        "hand_mix": th["hand_mix"],
        "n_mounts": len(pr["mounts"]), "n_rates": len(pr["mags"]), "rmax": rmax,
        "hold_s": pr["hold_s"], "fs": P["log"]["fs"],
        "n_points0": len(P["sessions"][0]["points"]),
        "rate_kind0": P["sessions"][0]["rate_kind"],
        "rate_kind2": P["sessions"][2]["rate_kind"],
        "temp_kind0": P["sessions"][0]["temp_kind"],
        "shift2": P["sessions"][2]["shift"], "shift1": P["sessions"][1]["shift"],
        "revisit0": P["sessions"][0]["revisit"] is not None,
        "pauses0": P["sessions"][0]["n_pauses"],
        "power_on0": P["sessions"][0]["power_on"],
        "soak_log": P["log"]["soak_log"], "accel_cols": P["log"]["accel"],
        "rad_units": P["log"]["rad"], "time_kind": P["log"]["time"],
        "mount_col": P["log"]["mount_col"], "ref_noise": pr["ref_noise_rel"] > 0,
        "interp_eff": _oracle_interp_error(P, S0, S2) / wf,
        "rows": [int(S["t"].size) for S in sessions],
        "n_holds": [len(S["holds"]) for S in sessions],
    }


# ============================================================================ contract check
def validate_log(path, expect=None):
    """Problems of one log against log-format.md section 1 (empty list when fine)."""
    probs = []
    pf = pq.ParquetFile(path)
    sch = pf.schema_arrow
    tab = pf.read()
    names = set(sch.names)
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in names:
            probs.append(f"missing column {c}")
    if probs:
        return probs
    tt = sch.field("t").type
    if not (pa.types.is_float64(tt) or pa.types.is_timestamp(tt)):
        probs.append(f"t has type {tt}")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y", "accel_z"):
        if c in names and not (pa.types.is_float32(sch.field(c).type)
                               or pa.types.is_float64(sch.field(c).type)):
            probs.append(f"{c} has type {sch.field(c).type}")
    if any(c in names for c in ("accel_x", "accel_y", "accel_z")) and \
            not all(c in names for c in ("accel_x", "accel_y", "accel_z")):
        probs.append("partial accel columns")
    t = tab.column("t")
    if pa.types.is_timestamp(tt):
        tv = t.cast(pa.int64()).to_numpy().astype(np.float64)
    else:
        tv = t.to_numpy()
    if not np.all(np.diff(tv) > 0):
        probs.append("t not strictly increasing")
    if "mount" in names:
        mt = sch.field("mount").type
        if not (pa.types.is_string(mt) or pa.types.is_large_string(mt)
                or pa.types.is_dictionary(mt)):
            probs.append(f"mount has type {mt}")
        vals = set(tab.column("mount").to_pylist())
        if vals - set(MOUNTS6):
            probs.append(f"mount values {vals - set(MOUNTS6)}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        u = json.loads(md[b"gyrocal.units"])
        if set(u) - {"gyro", "ref_rate"} or set(u.values()) - {"rad/s", "deg/s"}:
            probs.append(f"bad units metadata {u}")
    return probs
