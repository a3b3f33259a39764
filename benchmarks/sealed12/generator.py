"""Twelfth sealed benchmark: a simulator of ``turntable`` rig logs, the standard calibration that
sets each unit's reference floor, and a contract validator.

SEALED: whoever works on the diagnosis does not read this file (see README.md).

Each unit is one physical three-axis MEMS gyro written as three sessions (a first session, a
second days later, a third weeks to months later), each with a new power-on, new noise, its own
chamber set points and their order, its own mount order and rate order.  An effect unit carries
one effect family on top of the standard model ``w = K(T) w_true + B(T)`` and every nuisance; a
complete unit carries the nuisances only.  The effect's amplitude is chosen so that the standard
calibration of session 0 misses on session 2 by a chosen multiple of the reference floor, capped
by a physical bound per family.

Interface used by ``run.py``: ``MASTER_SEED``, ``FAMILIES``, ``plan()``, ``build_unit(spec)``,
``write_unit(built, folder)``, ``validate_log(path)``.

    python benchmarks/sealed12/generator.py [jobs]     # build and validate every unit (no tool run)
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter

MASTER_SEED = 20271109
MAX_ROWS = 300_000
N_COMPLETE = 4
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
G0 = 9.80665
EARTH = 15.041067 / 3600.0  # deg/s
EZ = np.array([0.0, 0.0, 1.0])
MAGS = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 75.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)
TOPS = (75.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)
TOP_P = (0.08, 0.14, 0.12, 0.2, 0.1, 0.14, 0.22)
RANGES = (125.0, 250.0, 500.0, 1000.0, 2000.0)
STILL, HOLD, RAMP, HAND = 0, 1, 2, 3
EPOCH0 = 1_772_438_400  # 2026-03-02 08:00:00 UTC


# ------------------------------------------------------------------------------------ families
def _fam(reads, acts, reasons, carried, cap, unit, note):
    return dict(
        reads=tuple(sorted(reads)),
        acts=tuple(sorted(acts)),
        reasons=tuple(sorted(reasons)),
        carried=carried,
        cap=cap,
        unit=unit,
        note=note,
    )


# reads / acts / reasons in the judge's words; cap = the physical bound of the amplitude
FAMILIES = {
    "g_bias": _fam(
        {"accel", "mount"},
        {"bias"},
        (),
        True,
        0.15,
        "deg/s per g",
        "linear g-sensitivity of the bias: a 3x3 matrix times the specific force (gravity, and the "
        "centripetal and tangential force of the off-centre fixture)",
    ),
    "g_scale": _fam(
        {"accel", "mount"},
        {"scale"},
        (),
        True,
        2.0e-3,
        "relative per g",
        "each axis' scale factor modulated by the specific force along that axis (proof-mass sag "
        "changes the sense gap): dw_i = c_i f_i w_i",
    ),
    "rate_cubic": _fam(
        {"rate"},
        {"scale"},
        (),
        True,
        5.0e-3,
        "relative at the top rate",
        "odd cubic scale-factor nonlinearity (same-axis centrifugal spring softening, electrostatic "
        "pick-off nonlinearity): dw_i = c_i w_i^3 / top^2",
    ),
    "scale_asym": _fam(
        {"rate"},
        {"scale", "bias"},
        (),
        True,
        4.0e-3,
        "relative",
        "scale factor different for positive and negative rates: dw_i = c_i |w_i|",
    ),
    "centrifugal_cross": _fam(
        {"rate"},
        {"cross-axis", "bias"},
        (),
        True,
        2.0e-3,
        "relative at the top rate",
        "even cross-axis term: rotation about one axis softens the springs of the other axes' "
        "resonators and moves their quadrature into the output: dw_j = sum_i C_ji w_i^2 / top",
    ),
    "thermal_rate": _fam(
        {"thermal"},
        {"bias"},
        (),
        True,
        0.15,
        "deg/s per degC/min",
        "bias proportional to the die's heating rate (transient gradient across the package)",
    ),
    "warmup_charge": _fam(
        {"time"},
        {"bias"},
        (),
        True,
        0.3,
        "deg/s",
        "bias transient decaying with the time since each power-on, not thermal (dielectric "
        "charging of the electrodes), tau 15-120 min",
    ),
    "fixture_swap": _fam(
        {"mount"},
        {"cross-axis"},
        {"mounting"},
        False,
        5.0e-3,
        "rad",
        "the adapter plate was replaced after session 0: in sessions 1 and 2 the unit sits rotated "
        "by milliradians on the table",
    ),
    "table_clock": _fam(
        {"rate"},
        {"scale"},
        {"lab"},
        False,
        3.0e-3,
        "relative",
        "the rate table's reported rate carried a scale error in session 0 only (controller "
        "reference clock / encoder setting), corrected before session 1",
    ),
    "aging": _fam(
        {"time"},
        {"scale", "cross-axis"},
        {"unit changed"},
        False,
        4.0e-3,
        "relative",
        "package stress relaxes between sessions: scale and misalignment move with log(time), "
        "partly by session 1, fully by session 2",
    ),
    "thermal_hysteresis": _fam(
        {"thermal"},
        {"bias"},
        {"direction of approach"},
        False,
        0.08,
        "deg/s",
        "bias depends on the side the die temperature approached from (play operator, half-width "
        "1.5-6 degC, on the die temperature)",
    ),
    "mode_crossing": _fam(
        {"temperature"},
        {"bias", "scale"},
        {"between points"},
        False,
        0.15,
        "deg/s",
        "a narrow bump of bias and scale at a temperature between session 0's points (a parasitic "
        "mode crossing the sense mode), seen by the later sessions' points",
    ),
    "telegraph": _fam(
        {"time"},
        {"bias"},
        {"slow noise"},
        False,
        0.1,
        "deg/s (step)",
        "burst (random telegraph) bias noise: one or two traps switching with dwell times of "
        "minutes to an hour, a new realisation every session",
    ),
}


# ------------------------------------------------------------------------------------ helpers
def _lu(rng, a, b):
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def _sgn(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


def _rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotvec(v):
    """Rotation matrix of rotation vector v (rad)."""
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * kx + (1.0 - math.cos(th)) * (kx @ kx)


def _rotvecs(axis, th):
    """Rotation matrices about one fixed axis by angles th (rad), shape (n, 3, 3)."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3)[None] + s * kx[None] + (1.0 - c) * (kx @ kx)[None]


def _log_of(r):
    """Rotation vector (rad) of rotation matrix r."""
    c = max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))
    th = math.acos(c)
    if th < 1e-12:
        return np.zeros(3)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if th > math.pi - 1e-6:  # near 180 degrees: axis from the symmetric part
        m = (r + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(m)))
        ax = m[:, i] / math.sqrt(max(m[i, i], 1e-12))
        return ax / np.linalg.norm(ax) * th
    return v / (2.0 * math.sin(th)) * th


def _r_mount(m):
    """Sensor -> table rotation of mount word m at azimuth 0: sensor axis m points up."""
    i = "xyz".index(m[1])
    s = 1.0 if m[0] == "+" else -1.0
    r3 = np.zeros(3)
    r3[i] = s
    r1 = np.zeros(3)
    r1[(i + 1) % 3] = 1.0
    r2 = np.cross(r3, r1)
    return np.vstack([r1, r2, r3])


def _merge(ivs):
    ivs = sorted((a, b) for a, b in ivs if b > a)
    out = []
    for a, b in ivs:
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


def _inside(t, ivs):
    ivs = _merge(ivs)
    if not ivs:
        return np.zeros(t.shape, bool)
    a = np.array([x[0] for x in ivs])
    b = np.array([x[1] for x in ivs])
    i = np.searchsorted(a, t, side="right") - 1
    ok = i >= 0
    res = np.zeros(t.shape, bool)
    res[ok] = t[ok] < b[i[ok]]
    return res


def _gm(rng, n, sigma, tau, dt=1.0):
    """Stationary Gauss-Markov process on a grid of step dt."""
    phi = math.exp(-dt / tau)
    x0 = rng.standard_normal() * sigma
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    y, _ = lfilter([1.0], [1.0, -phi], e, zi=[phi * x0])
    return y


# ------------------------------------------------------------------------------------ unit draw
def _set_points0(rng):
    n = int(rng.integers(3, 7))
    lo = 5.0 * round(rng.uniform(-40.0, 0.0) / 5.0)
    hi = 5.0 * round(rng.uniform(40.0, 85.0) / 5.0)
    pts = np.linspace(lo, hi, n)
    pts[1:-1] += rng.uniform(-2.0, 2.0, n - 2)
    return [round(float(p), 1) for p in pts]


def _later_points(rng, p0, mode, frac):
    p0 = np.array(sorted(p0))
    lo, hi = p0[0], p0[-1]
    if mode == "same":
        pts = p0 + rng.uniform(-1.0, 1.0, p0.size)
    elif mode == "mid":
        pts = (p0[:-1] + p0[1:]) / 2.0
    else:
        pts = p0[:-1] + frac * np.diff(p0)
    pts = list(np.clip(pts, lo, hi))
    while len(pts) < 3:
        pts.append(hi if rng.random() < 0.5 else lo)
        pts = sorted(set(round(float(p), 1) for p in pts))
    return [round(float(p), 1) for p in sorted(pts)]


def _temp_order(rng, pts, room):
    n = len(pts)
    asc = list(range(n))  # pts sorted ascending
    styles = ("desc", "room_down_up", "room_up_down", "zigzag", "cold_then_desc", "hot_then_asc", "shuffle")
    style = styles[int(rng.integers(len(styles)))]
    if style == "desc":
        order = asc[::-1]
    elif style in ("room_down_up", "room_up_down"):
        k = int(np.argmin([abs(p - room) for p in pts]))
        down, up = list(range(k, -1, -1)), list(range(k + 1, n))
        order = down + up if style == "room_down_up" else list(range(k, n)) + list(range(k - 1, -1, -1))
    elif style == "zigzag":
        order, lo, hi = [], 0, n - 1
        while lo <= hi:
            order.append(lo)
            if hi != lo:
                order.append(hi)
            lo, hi = lo + 1, hi - 1
    elif style == "cold_then_desc":
        order = [0] + list(range(n - 1, 0, -1))
    elif style == "hot_then_asc":
        order = [n - 1] + list(range(n - 1))
    else:
        order = list(rng.permutation(n))
    if order == asc:
        order = asc[::-1]
        style = "desc"
    return [int(i) for i in order], style


def _rate_order(rng, mags, zero):
    style = ("up", "down", "shuffle", "alternate", "top_first", "sweep")[int(rng.integers(6))]
    pos = sorted(mags)
    signed = [-m for m in pos[::-1]] + ([0.0] if zero else []) + pos
    if style == "up":
        out = signed
    elif style == "down":
        out = signed[::-1]
    elif style == "shuffle":
        out = [signed[i] for i in rng.permutation(len(signed))]
    elif style == "alternate":
        out = ([0.0] if zero else []) + [x for m in pos for x in (m, -m)]
    elif style == "top_first":
        rest = [x for x in signed if abs(x) != pos[-1]]
        out = [pos[-1], -pos[-1]] + [rest[i] for i in rng.permutation(len(rest))]
    else:
        out = ([0.0] if zero else []) + pos + [-m for m in pos[::-1]]
    return [float(x) for x in out], style


def draw_unit(rng, family):
    """Every nuisance and protocol parameter of one unit (all three sessions)."""
    u = {"family": family}
    arw = _lu(rng, 0.003, 0.03) * rng.uniform(0.75, 1.3, 3)
    u["arw"] = arw
    wf_nom = math.sqrt(float(np.mean(arw**2)) / 38.0)
    u["bi_kind"] = "gm" if rng.random() < 0.5 else "flicker"
    u["bi_sigma"] = _lu(rng, 0.1, 2.5) * wf_nom * rng.uniform(0.7, 1.3, 3)
    u["bi_tau"] = _lu(rng, 20.0, 20000.0)
    u["fl_lo"], u["fl_hi"] = _lu(rng, 10.0, 60.0), _lu(rng, 2000.0, 30000.0)
    u["rep_sigma"] = _lu(rng, 1.0, 5.0) * wf_nom
    # K(T), B(T): smooth in the die temperature
    u["B0"] = rng.normal(0.0, 0.5, 3)
    u["B1"] = np.array([_sgn(rng) * _lu(rng, 0.002, 0.04) for _ in range(3)])
    u["B2"] = np.array([_sgn(rng) * _lu(rng, 0.003, 0.2) for _ in range(3)])
    u["B3"] = np.array([_sgn(rng) * _lu(rng, 0.001, 0.05) for _ in range(3)])
    K0 = rng.normal(0.0, 0.004, (3, 3))
    np.fill_diagonal(K0, 1.0 + rng.normal(0.0, 0.01, 3))
    K1 = np.array([[_sgn(rng) * _lu(rng, 0.5e-6, 20e-6) for _ in range(3)] for _ in range(3)])
    K2 = np.array([[_sgn(rng) * _lu(rng, 1e-6, 100e-6) for _ in range(3)] for _ in range(3)])
    for i in range(3):
        K1[i, i] = _sgn(rng) * _lu(rng, 30e-6, 400e-6)
        K2[i, i] = _sgn(rng) * _lu(rng, 50e-6, 1500e-6)
    u["K0"], u["K1"], u["K2"] = K0, K1, K2
    # chamber and thermal path
    u["tau_air"] = _lu(rng, 20.0, 90.0)
    u["Kp"], u["Ti"], u["act_lim"] = rng.uniform(0.5, 3.0), _lu(rng, 60.0, 600.0), rng.uniform(25.0, 60.0)
    u["ramp_rate"] = rng.uniform(1.0, 5.0)  # degC/min
    u["rip_sigma"], u["rip_tau"] = _lu(rng, 0.01, 0.2), _lu(rng, 30.0, 300.0)
    u["tau_door"] = _lu(rng, 15.0, 1000.0)
    u["tau_case"] = _lu(rng, 120.0, 1200.0)
    u["two_stage"] = rng.random() < 0.6
    u["tau_die"] = _lu(rng, 5.0, 120.0)
    u["sh_case"] = rng.uniform(0.3, 5.0)
    u["sh_die"] = rng.uniform(0.2, 2.0) if u["two_stage"] else 0.0
    u["conv"] = 0.0 if rng.random() < 0.3 else rng.uniform(0.1, 0.8)
    u["hand_w"] = rng.uniform(0.0, 0.5)
    slow = u["tau_case"] + (u["tau_die"] if u["two_stage"] else 0.0) + u["tau_air"]
    u["soak"] = float(np.clip(rng.uniform(4.0, 8.0) * slow, 900.0, 6000.0))
    # the unit's temperature sensor
    u["ts_mode"] = ("die", "lag", "lean")[int(rng.choice(3, p=[0.3, 0.35, 0.35]))]
    u["ts_tau"], u["ts_kappa"] = _lu(rng, 3.0, 120.0), rng.uniform(0.1, 0.6)
    u["ts_off"], u["ts_gain"] = rng.normal(0.0, 1.5), 1.0 + rng.normal(0.0, 0.01)
    u["ts_noise"] = _lu(rng, 0.005, 0.15)
    u["ts_q"] = (1 / 256, 1 / 64, 1 / 16, 1 / 8)[int(rng.integers(4))]
    u["ts_upd"] = (0.0, 1.0, 2.0)[int(rng.integers(3))]
    # rig, fixture, operator
    u["n_mounts"] = 3 if rng.random() < 0.55 else 6
    u["accel"] = rng.random() < 0.45
    u["acc_bias"], u["acc_scale"] = rng.normal(0.0, 0.02, 3), rng.normal(0.0, 0.005, 3)
    u["acc_noise"] = _lu(rng, 0.0005, 0.003)
    u["radius"], u["radius_ang"] = rng.uniform(0.0, 0.08), rng.uniform(0.0, 360.0)
    u["lat"], u["heading"] = rng.uniform(25.0, 60.0), rng.uniform(0.0, 360.0)
    u["seat_sigma"] = _lu(rng, 1e-6, 30e-6)
    u["jitter"] = 0.0 if rng.random() < 0.5 else _lu(rng, 1e-6, 1e-4)
    u["acc_peak"] = _lu(rng, 20.0, 200.0)
    u["tremor"] = _lu(rng, 0.3, 5.0)
    u["reseat_p"] = rng.uniform(0.0, 0.25)
    u["power_cycle"] = ("never", "remount", "setpoint")[int(rng.choice(3, p=[0.6, 0.2, 0.2]))]
    # rates
    top = float(rng.choice(TOPS, p=TOP_P))
    below = [m for m in MAGS if m < top]
    n_m = int(rng.integers(2, 5 if u["n_mounts"] == 6 else 7))
    mags = sorted(float(x) for x in rng.choice(below, n_m - 1, replace=False)) + [top]
    u["top"], u["mags"], u["zero"] = top, mags, rng.random() < 0.65
    # output
    u["quant"] = rng.random() < 0.75
    u["range"] = next(r for r in RANGES if r >= 1.31 * top)
    step16 = 2.0 * u["range"] / 65536.0
    u["qstep"] = step16 if float(np.min(arw)) * math.sqrt(10.0) > step16 else 2.0 * u["range"] / 2**20
    u["f32"] = rng.random() < 0.5
    u["rad"] = rng.random() < 0.15
    u["extra"] = rng.random() < 0.5
    # sessions
    u["days"] = [0.0, rng.uniform(2.0, 40.0), rng.uniform(45.0, 200.0)]
    p0 = _set_points0(rng)
    modes = ["same", "mid", "shift"]
    sets = [p0]
    if family == "mode_crossing":
        mode = "mid" if rng.random() < 0.5 else "shift"
        frac = rng.uniform(0.3, 0.7)
        for _ in (1, 2):
            sets.append(_later_points(rng, p0, mode, frac))
    else:
        for _ in (1, 2):
            mode = modes[int(rng.choice(3, p=[0.3, 0.35, 0.35]))]
            sets.append(_later_points(rng, p0, mode, rng.uniform(0.2, 0.8)))
    u["sessions"] = [_draw_session(rng, u, k, sets[k]) for k in range(3)]
    u["power_on0"] = ["late" if rng.random() < 0.3 else "at_insert" for _ in range(3)]
    return u


def _draw_session(rng, u, k, pts):
    s = {"k": k, "room": rng.uniform(19.0, 26.0), "points": sorted(pts)}
    s["order"], s["torder"] = _temp_order(rng, s["points"], s["room"])
    if u["n_mounts"] == 6:
        s["mounts"] = [MOUNTS[i] for i in rng.permutation(6)]
    else:
        s["mounts"] = [("+" if rng.random() < 0.5 else "-") + a for a in "xyz"]
        s["mounts"] = [s["mounts"][i] for i in rng.permutation(3)]
    s["mount_style"] = ("fixed", "serpentine", "random")[int(rng.integers(3))]
    s["rates"], s["rorder"] = _rate_order(rng, u["mags"], u["zero"])
    s["stop"] = rng.random() < 0.5
    n_pts = len(pts)
    s["revisit"] = None
    if rng.random() < 0.35:
        s["revisit"] = (int(rng.integers(n_pts - 1)), 0 if rng.random() < 0.5 else int(rng.integers(1, 3)))
    n_holds = (n_pts + (1 if s["revisit"] else 0)) * u["n_mounts"] * len(s["rates"])
    s["H"] = float(max(12.0, min(rng.uniform(20.0, 60.0), 3.5 * 3600.0 / n_holds)))
    s["soak_log"] = "full" if rng.random() < 0.3 else "tail"
    s["tail"] = 60.0 * rng.uniform(3.0, _lu(rng, 4.0, 15.0))
    s["pauses"] = int(rng.integers(0, 4))
    s["pause_len"] = [60.0 * rng.uniform(1.0, 20.0) for _ in range(4)]
    s["wait_hi"] = _lu(rng, 15.0, 600.0)
    s["tstyle"] = ("zero", "epoch", "ns_utc", "ms_local", "us_naive")[int(rng.integers(5))]
    s["mount_col"] = ("none", "string", "dict")[int(rng.integers(3))]
    s["nan_rows"] = int(rng.integers(1, 6)) if rng.random() < 0.3 else 0
    s["hour"] = rng.uniform(6.0, 10.0)
    s["seed"] = int(rng.integers(2**31))
    return s


# ------------------------------------------------------------------------------------ timeline
class _Timeline:
    """The session as the rig lived it: table segments, holds, door, hands, power, logger."""

    def __init__(self, u, s, rng, shrink):
        self.u, self.s, self.rng, self.shrink = u, s, rng, shrink
        self.t, self.psi, self.rate = 0.0, 0.0, 0.0
        self.segs, self.holds, self.hands, self.places = [], [], [], []
        self.knots = [(0.0, s["room"])]
        self.door, self.lift, self.nolog, self.off, self.pons = [], [], [], [], []
        self.place = -1
        self.H = max(10.0, s["H"] * shrink)

    def new_place(self, mount):
        rng, u = self.rng, self.u
        seat = _rotvec(rng.normal(0.0, u["seat_sigma"], 3))
        R = _rz(rng.uniform(0.0, 360.0)) @ _r_mount(mount) @ seat
        self.places.append({"mount": mount, "R": R})
        return len(self.places) - 1

    def seg(self, d, kind, r1=0.0, hand=-1):
        t0, r0 = self.t, self.rate
        self.segs.append((t0, t0 + d, kind, r0, r1 if kind == RAMP else r0, self.psi, self.place, hand))
        if kind == HOLD:
            self.psi += r0 * d
        elif kind == RAMP:
            self.psi += 0.5 * (r0 + r1) * d
            self.rate = r1
        self.t += d

    def still(self, d):
        if d > 0:
            self.seg(d, STILL)

    def goto(self, r):
        if r != self.rate:
            d = max(0.3, 2.0 * abs(r - self.rate) / self.u["acc_peak"])
            self.seg(d, RAMP, r1=r)
        self.rate = r

    def hold(self, r, pid):
        self.goto(r)
        H = self.H
        self.holds.append((self.t, self.t + H, r, pid, self.place))
        self.seg(H, HOLD)

    def handle(self, mount, pause, power_cycle):
        rng = self.rng
        if pause > 0:
            self.nolog.append((self.t, self.t + pause))
            self.still(pause)
        self.still(rng.uniform(2.0, 10.0))
        t_door = self.t
        self.still(rng.uniform(2.0, 8.0))
        old = self.place
        r_start = _rz(self.psi) @ self.places[old]["R"]
        new = self.new_place(mount)
        r_end = _rz(self.psi) @ self.places[new]["R"]
        rs = [r_start]
        for _ in range(int(rng.integers(1, 3))):
            ax = rng.normal(size=3)
            rs.append(_rotvec(ax / np.linalg.norm(ax) * math.radians(rng.uniform(20.0, 120.0))) @ rs[-1])
        rs.append(r_end)
        moves, peak = [], rng.uniform(120.0, 350.0)
        for k in range(len(rs) - 1):
            v = _log_of(rs[k + 1] @ rs[k].T)
            ang = math.degrees(float(np.linalg.norm(v)))
            d = max(rng.uniform(0.4, 2.0), 2.0 * ang / peak)
            moves.append([0.0, d, v, rs[k]])
        need = sum(m[1] for m in moves) + len(moves) + 2.0
        D = max(rng.uniform(15.0, _lu(rng, 25.0, 90.0)), need)
        gap = (D - sum(m[1] for m in moves)) / (len(moves) + 1)
        tt = self.t
        for m in moves:
            tt += gap * rng.uniform(0.6, 1.4) if m is not moves[0] else gap
            m[0] = tt
            tt += m[1]
        self.hands.append({"t0": self.t, "t1": self.t + D, "moves": moves, "rs": rs, "old": old, "new": new})
        self.lift.append((self.t, self.t + D))
        if power_cycle:
            self.off.append((self.t + 0.2 * D, self.t + 0.8 * D))
            self.pons.append(self.t + 0.8 * D)
        self.place = new
        self.seg(D, HAND, hand=len(self.hands) - 1)
        t_close = self.t + rng.uniform(2.0, rng.uniform(5.0, 25.0))
        self.door.append((t_door, t_close))
        self.still(t_close - self.t)

    def setpoint(self, T):
        prev = self.knots[-1][1]
        d = abs(T - prev) / self.u["ramp_rate"] * 60.0
        self.knots += [(self.t, prev), (self.t + d, T)]
        return d


def _schedule(u, s, shrink):
    rng = np.random.default_rng(s["seed"])
    tl = _Timeline(u, s, rng, shrink)
    pts, order = s["points"], s["order"]
    visits = [(i, None) for i in order]
    if s["revisit"] is not None:
        visits.append((order[s["revisit"][0]], s["revisit"][1]))
    n_remounts = len(visits) * u["n_mounts"]
    pause_at = set(int(x) for x in rng.choice(n_remounts, min(s["pauses"], n_remounts), replace=False))
    remount_no = 0
    base = list(s["mounts"])
    tl.door.append((0.0, rng.uniform(20.0, 60.0)))
    power_cycle = u["power_cycle"]
    late = u["power_on0"][s["k"]] == "late"
    if not late:
        tl.pons.append(0.0)
    for vi, (pid, nm) in enumerate(visits):
        if s["mount_style"] == "fixed":
            mounts = list(base)
        elif s["mount_style"] == "serpentine":
            mounts = list(base) if vi % 2 == 0 else list(base[::-1])
        else:
            mounts = [base[i] for i in rng.permutation(len(base))]
        if nm:
            mounts = mounts[:nm]
        if vi == 0:
            tl.place = tl.new_place(mounts[0])
        cur = tl.places[tl.place]["mount"]
        if vi > 0 and cur in mounts and mounts[0] != cur and s["mount_style"] != "fixed":
            mounts.remove(cur)
            mounts.insert(0, cur)
        if vi > 0 and (mounts[0] != cur or rng.random() < u["reseat_p"]):
            tl.handle(
                mounts[0],
                s["pause_len"][remount_no % 4] * shrink if remount_no in pause_at else 0.0,
                power_cycle == "remount",
            )
            remount_no += 1
        t_pt = tl.t
        d_ramp = tl.setpoint(pts[pid])
        soak = d_ramp + u["soak"]
        if power_cycle == "setpoint" and vi > 0:
            t_on = tl.t + rng.uniform(0.3, 0.7) * soak
            tl.off.append((tl.t, t_on))
            tl.pons.append(t_on)
        if vi == 0 and late:
            t_on = max(1.0, tl.t + soak - 60.0 * _lu(rng, 3.0, 30.0))
            tl.off.append((0.0, t_on))
            tl.pons.append(t_on)
        tl.still(soak)
        if s["soak_log"] == "tail" or shrink < 1.0:
            tl.nolog.append((t_pt, tl.t - s["tail"] * shrink))
        for j, m in enumerate(mounts):
            if j > 0:
                tl.handle(
                    m,
                    s["pause_len"][remount_no % 4] * shrink if remount_no in pause_at else 0.0,
                    power_cycle == "remount",
                )
                remount_no += 1
            tl.still(rng.uniform(5.0, max(6.0, s["wait_hi"] * shrink)))
            for r in s["rates"]:
                tl.hold(r, pid)
                if s["stop"] and r != 0.0:
                    tl.goto(0.0)
                    tl.still(rng.uniform(1.0, 4.0))
            tl.goto(0.0)
            tl.still(rng.uniform(2.0, 10.0))
    tl.still(rng.uniform(5.0, 20.0))
    tl.pons.sort()
    return tl


def _logged_intervals(tl):
    bad = _merge(tl.nolog + tl.off)
    out, a = [], 0.0
    for x, y in bad:
        if x > a:
            out.append((a, x))
        a = max(a, y)
    if tl.t > a:
        out.append((a, tl.t))
    return out


# ------------------------------------------------------------------------------------ evaluation
def _table_eval(tl, t):
    """Table rate (deg/s), angular acceleration (deg/s^2) and angle (deg) at times t."""
    sg = np.array([x[:6] for x in tl.segs])
    t0, t1, kind, r0, r1, psi0 = sg.T
    i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)
    tau = t - t0[i]
    k = kind[i]
    rate = np.where(k == HOLD, r0[i], 0.0)
    alpha = np.zeros_like(t)
    psi = psi0[i] + np.where(k == HOLD, r0[i] * tau, 0.0)
    m = k == RAMP
    if m.any():
        T = (t1 - t0)[i[m]]
        A = 2.0 * (r1 - r0)[i[m]] / T
        ta = tau[m]
        w = 2.0 * math.pi * ta / T
        rate[m] = r0[i[m]] + A * (ta / 2.0 - T * np.sin(w) / (4.0 * math.pi))
        alpha[m] = A * (1.0 - np.cos(w)) / 2.0
        psi[m] = (
            psi0[i[m]] + r0[i[m]] * ta + A * (ta**2 / 4.0 + T**2 * (np.cos(w) - 1.0) / (8.0 * math.pi**2))
        )
    return rate, alpha, psi, i


def _thermal(u, s, tl, tg, rng):
    sp = np.interp(tg, [x[0] for x in tl.knots], [x[1] for x in tl.knots])
    door = _inside(tg, tl.door)
    lift = _inside(tg, tl.lift)
    power = ~_inside(tg, tl.off)
    if tl.pons:
        power &= tg >= tl.pons[0]
    om, _, _, _ = _table_eval(tl, tg)
    rip = _gm(rng, tg.size, u["rip_sigma"], u["rip_tau"])
    a_air = 1.0 - math.exp(-1.0 / u["tau_air"])
    a_door = 1.0 - math.exp(-1.0 / u["tau_door"])
    a_case = 1.0 - math.exp(-1.0 / u["tau_case"])
    a_die = 1.0 - math.exp(-1.0 / u["tau_die"])
    kp, ti, lim = u["Kp"], u["Ti"], u["act_lim"]
    room = s["room"]
    hw, shc, shd, cc, two = u["hand_w"], u["sh_case"], u["sh_die"], u["conv"], u["two_stage"]
    air, integ, case, die = room, 0.0, room, room
    n = tg.size
    A, C, Dd = np.empty(n), np.empty(n), np.empty(n)
    spl, dl, ll, pl, oml, rl = (
        sp.tolist(),
        door.tolist(),
        lift.tolist(),
        power.tolist(),
        np.abs(om).tolist(),
        rip.tolist(),
    )
    for k in range(n):
        e = spl[k] - air
        v = kp * e + integ
        if -lim < v < lim:
            integ += kp * e / ti
        v = min(max(v, -lim), lim)
        air += (spl[k] + v - air) * a_air
        if dl[k]:
            air += (room - air) * a_door
        ta = air + rl[k]
        env = ta + hw * (32.0 - ta) if ll[k] else ta
        p = 1.0 if pl[k] else 0.0
        case += (env + shc * p / (1.0 + cc * oml[k] / 300.0) - case) * a_case
        die = die + (case + shd * p - die) * a_die if two else case
        A[k], C[k], Dd[k] = ta, case, die
    if u["ts_mode"] == "die":
        node = Dd
    elif u["ts_mode"] == "lag":
        b = 1.0 - math.exp(-1.0 / u["ts_tau"])
        node, _ = lfilter([b], [1.0, b - 1.0], Dd, zi=[(1.0 - b) * Dd[0]])
    else:
        node = Dd + u["ts_kappa"] * (C - Dd)
    return {"air": A, "case": C, "die": Dd, "node": node, "sp": sp}


def _hand_eval(tl, h, t):
    """Body rate (deg/s, sensor frame) and gravity direction (sensor frame) while handled."""
    n = t.size
    om = np.zeros((n, 3))
    R = np.repeat(h["rs"][0][None], n, axis=0)
    for j, (mt0, d, v, rk) in enumerate(h["moves"]):
        th_tot = float(np.linalg.norm(v))
        axis = v / th_tot
        after = t >= mt0 + d
        R[after] = h["rs"][j + 1]
        m = (t >= mt0) & ~after
        if m.any():
            tau = (t[m] - mt0) / d
            th = th_tot * (tau - np.sin(2.0 * math.pi * tau) / (2.0 * math.pi))
            thd = th_tot / d * (1.0 - np.cos(2.0 * math.pi * tau))
            R[m] = _rotvecs(axis, th) @ rk
            om[m] = np.outer(thd, rk.T @ axis) * (180.0 / math.pi)
    f = np.einsum("nji,j->ni", R, EZ)
    return om, f, R


def simulate_session(u, k):
    """One session: logs (before effect and output quantisation) and the physics effects read."""
    s = u["sessions"][k]
    shrink = 1.0
    for _ in range(12):
        tl = _schedule(u, s, shrink)
        live = _logged_intervals(tl)
        L = sum(b - a for a, b in live)
        fs = next((f for f in (50.0, 25.0, 20.0, 10.0) if f * L <= MAX_ROWS - 2 * len(live) - 50), None)
        if fs is not None:
            break
        shrink *= 0.85
    else:
        raise RuntimeError("session does not fit the row budget")
    rng = np.random.default_rng(s["seed"] + 7)
    ts = np.concatenate([np.arange(math.ceil(a * fs), math.ceil(b * fs)) / fs for a, b in live])
    tg = np.arange(0.0, math.ceil(tl.t) + 2.0)
    th = _thermal(u, s, tl, tg, rng)
    n = ts.size
    rate, alpha, psi, si = _table_eval(tl, ts)
    kind = np.array([x[2] for x in tl.segs])[si]
    place = np.array([x[6] for x in tl.segs])[si]
    handi = np.array([x[7] for x in tl.segs])[si]
    # body rate and specific force in the sensor frame
    lat = math.radians(u["lat"])
    hd = math.radians(u["heading"])
    e_h = EARTH * math.cos(lat) * np.array([math.cos(hd), math.sin(hd)])
    e_v = EARTH * math.sin(lat)
    c, sn = np.cos(np.radians(psi)), np.sin(np.radians(psi))
    v_t = np.column_stack([c * e_h[0] + sn * e_h[1], -sn * e_h[0] + c * e_h[1], rate + e_v])
    rho = u["radius"] * np.array(
        [math.cos(math.radians(u["radius_ang"])), math.sin(math.radians(u["radius_ang"])), 0]
    )
    w_r, a_r = np.radians(rate), np.radians(alpha)
    f_t = np.zeros((n, 3))
    f_t[:, 2] = 1.0
    f_t[:, :2] += (-(w_r**2)[:, None] * rho[None, :2] + a_r[:, None] * np.array([-rho[1], rho[0]])[None]) / G0
    om = np.zeros((n, 3))
    f = np.zeros((n, 3))
    mount_idx = np.zeros(n, np.int8)
    tab = kind != HAND
    for p in np.unique(place[tab]):
        m = tab & (place == p)
        R = tl.places[p]["R"]
        om[m] = v_t[m] @ R
        f[m] = f_t[m] @ R
        mount_idx[m] = MOUNTS.index(tl.places[p]["mount"])
    lifted = np.zeros(n, bool)
    for hi in np.unique(handi[~tab]):
        m = (~tab) & (handi == hi)
        h = tl.hands[hi]
        o, ff, R = _hand_eval(tl, h, ts[m])
        e_world = np.array([e_h[0], e_h[1], e_v])
        om[m] = o + np.einsum("nji,j->ni", R, e_world)
        f[m] = ff
        lifted[m] = True
        half = ts[m] < 0.5 * (h["t0"] + h["t1"])
        mi = np.where(
            half, MOUNTS.index(tl.places[h["old"]]["mount"]), MOUNTS.index(tl.places[h["new"]]["mount"])
        )
        mount_idx[m] = mi
    if lifted.any():  # hand tremor and hand accelerations
        b = 1.0 - math.exp(-2.0 * math.pi * 5.0 / fs)
        norm = b / math.sqrt(1.0 - (1.0 - b) ** 2)
        tr = lfilter([b], [1.0, b - 1.0], rng.standard_normal((int(lifted.sum()), 3)), axis=0)
        om[lifted] += tr / norm * u["tremor"]
        f[lifted] += rng.standard_normal((int(lifted.sum()), 3)) * 0.05
    # thermal states at the samples
    die = np.interp(ts, tg, th["die"])
    ddie = np.interp(ts, tg, np.gradient(th["die"]) * 60.0)
    pons = np.array(tl.pons if tl.pons else [0.0])
    pi = np.clip(np.searchsorted(pons, ts, side="right") - 1, 0, len(pons) - 1)
    ton = ts - pons[pi]
    # the sensor: K(T), B(T), turn-on bias, bias instability, white noise
    dT = die - 25.0
    q = (dT / 60.0) ** 2
    w = om @ u["K0"].T + dT[:, None] * (om @ u["K1"].T) + q[:, None] * (om @ u["K2"].T)
    w += u["B0"] + dT[:, None] * u["B1"] + q[:, None] * u["B2"] + ((dT / 60.0) ** 3)[:, None] * u["B3"]
    bon = rng.standard_normal((len(pons), 3)) * u["rep_sigma"]
    w += bon[pi]
    bi = np.zeros((tg.size, 3))
    for ax in range(3):
        if u["bi_kind"] == "gm":
            bi[:, ax] = _gm(rng, tg.size, u["bi_sigma"][ax], u["bi_tau"])
        else:
            for tau in np.geomspace(u["fl_lo"], u["fl_hi"], 5):
                bi[:, ax] += _gm(rng, tg.size, u["bi_sigma"][ax] / math.sqrt(5.0), tau)
    for ax in range(3):
        w[:, ax] += np.interp(ts, tg, bi[:, ax])
    w += rng.standard_normal((n, 3)) * (u["arw"] * math.sqrt(fs))
    # reference and temperature columns
    turning = (kind == HOLD) | (kind == RAMP)
    ref = rate.copy()
    if u["jitter"] > 0:
        ref[turning] *= 1.0 + u["jitter"] * rng.standard_normal(int(turning.sum()))
    ref[rate == 0.0] = 0.0
    if u["ts_upd"] > 0:
        tq = np.floor(ts / u["ts_upd"]) * u["ts_upd"]
        upd = np.floor(ts / u["ts_upd"]).astype(np.int64)
        noise = rng.standard_normal(int(upd.max()) + 1)[upd] * u["ts_noise"]
    else:
        tq = ts
        noise = rng.standard_normal(n) * u["ts_noise"]
    temp = u["ts_off"] + u["ts_gain"] * np.interp(tq, tg, th["node"]) + noise
    temp = np.round(temp / u["ts_q"]) * u["ts_q"]
    acc = None
    if u["accel"]:
        acc = f * (1.0 + u["acc_scale"]) + u["acc_bias"] + rng.standard_normal((n, 3)) * u["acc_noise"]
    holds = []
    for t0, t1, r, pid, p in tl.holds:
        mw = tl.places[p]["mount"]
        holds.append((t0, t1, r, pid, "xyz".index(mw[1]), 1.0 if mw[0] == "+" else -1.0))
    return {
        "k": k,
        "ts": ts,
        "fs": fs,
        "H": tl.H,
        "shrink": shrink,
        "gyro": w,
        "ref": ref,
        "temp": temp,
        "acc": acc,
        "mount": mount_idx,
        "lifted": lifted,
        "om": om,
        "f": f,
        "die": die,
        "ddie": ddie,
        "ton": ton,
        "tg": tg,
        "die_g": th["die"],
        "holds": holds,
        "points": s["points"],
        "span": tl.t,
    }


# ------------------------------------------------------------------------------------ effects
def draw_effect(rng, family, u, S):
    e = {}
    if family == "g_bias":
        G = rng.normal(0.0, 1.0, (3, 3))
        G[np.diag_indices(3)] *= 1.5
        e["G"] = G / np.max(np.abs(G))
    elif family in ("g_scale", "rate_cubic", "scale_asym"):
        c = rng.uniform(0.4, 1.0, 3) * np.array([_sgn(rng) for _ in range(3)])
        e["c"] = c / np.max(np.abs(c))
    elif family == "centrifugal_cross":
        C = rng.normal(0.0, 1.0, (3, 3))
        np.fill_diagonal(C, 0.0)
        e["C"] = C / np.max(np.abs(C))
    elif family in ("thermal_rate", "warmup_charge", "thermal_hysteresis", "telegraph", "mode_crossing"):
        v = rng.normal(0.0, 1.0, 3)
        e["u"] = v / np.max(np.abs(v))
        if family == "warmup_charge":
            e["tau"] = 60.0 * _lu(rng, 15.0, 120.0)
        if family == "thermal_hysteresis":
            e["width"] = rng.uniform(1.5, 6.0)
        if family == "telegraph":
            e["traps"] = [(_lu(rng, 2.0, 60.0) * 60.0, _lu(rng, 2.0, 60.0) * 60.0, 1.0)]
            if rng.random() < 0.5:
                e["traps"].append(
                    (_lu(rng, 2.0, 60.0) * 60.0, _lu(rng, 2.0, 60.0) * 60.0, rng.uniform(0.3, 1.0))
                )
            e["seeds"] = [int(x) for x in rng.integers(2**31, size=3)]
        if family == "mode_crossing":
            d = rng.normal(0.0, 1.0, 3)
            e["d"] = d / np.max(np.abs(d)) * rng.uniform(0.3, 1.0)
            die0 = [_point_die(S[0], p) for p in range(len(S[0]["points"]))]
            die2 = [_point_die(S[2], p) for p in range(len(S[2]["points"]))]
            dist = [min(abs(x - y) for y in die0) for x in die2]
            j = int(np.argmax(dist))
            e["Tc"] = die2[j] + rng.normal(0.0, 0.5)
            e["sigma"] = float(np.clip(dist[j] / 3.5, 1.5, rng.uniform(2.0, 4.0)))
    elif family == "fixture_swap":
        v = rng.normal(0.0, 1.0, 3)
        e["ax"] = v / np.linalg.norm(v)
    elif family == "aging":
        D = rng.normal(0.0, 0.5, (3, 3))
        D[np.diag_indices(3)] = rng.uniform(0.5, 1.0, 3) * np.array([_sgn(rng) for _ in range(3)])
        e["D"] = D / np.max(np.abs(D))
        tau = _lu(rng, 5.0, 60.0)
        d1, d2 = u["days"][1], u["days"][2]
        e["frac"] = [0.0, math.log1p(d1 / tau) / math.log1p(d2 / tau), 1.0]
    return e


def _point_die(S, pid):
    vals = [
        float(np.median(S["die"][np.searchsorted(S["ts"], t0) : np.searchsorted(S["ts"], t1)]))
        for t0, t1, _, p, _, _ in S["holds"]
        if p == pid
    ]
    return float(np.median(vals))


def _play(T, width, y0):
    y, out = y0, np.empty(T.size)
    for i, x in enumerate(T.tolist()):
        y = min(max(y, x - width), x + width)
        out[i] = y
    return out


def _telegraph(ts, traps, seed, span):
    rng = np.random.default_rng(seed)
    s = np.zeros(ts.size)
    for t_hi, t_lo, wgt in traps:
        edges, st, t = [], int(rng.random() < t_hi / (t_hi + t_lo)), 0.0
        first = st
        while t < span:
            t += rng.exponential(t_hi if st else t_lo)
            edges.append(t)
            st = 1 - st
        n_sw = np.searchsorted(np.array(edges), ts, side="right")
        state = (first + n_sw) % 2
        s += wgt * state
    return s


def effect_arrays(family, e, S, u):
    """The effect at unit amplitude on one session: (gyro (n,3) | None, ref (n,) | None, acc | None)."""
    k, om, f = S["k"], S["om"], S["f"]
    top = u["top"]
    g = ref = acc = None
    if family == "g_bias":
        g = f @ e["G"].T
    elif family == "g_scale":
        g = e["c"] * f * om
    elif family == "rate_cubic":
        g = e["c"] * om**3 / top**2
    elif family == "scale_asym":
        g = e["c"] * np.abs(om)
    elif family == "centrifugal_cross":
        g = (om**2) @ e["C"].T / top
    elif family == "thermal_rate":
        g = S["ddie"][:, None] * e["u"]
    elif family == "warmup_charge":
        g = np.exp(-S["ton"] / e["tau"])[:, None] * e["u"]
    elif family == "fixture_swap":
        if k > 0:
            g = np.cross(e["ax"], om) @ u["K0"].T
            acc = np.cross(e["ax"], f)
    elif family == "table_clock":
        if k == 0:
            ref = S["ref"].copy()
    elif family == "aging":
        if e["frac"][k] > 0:
            g = e["frac"][k] * (om @ (e["D"] @ u["K0"]).T)
    elif family == "thermal_hysteresis":
        y = _play(S["die_g"], e["width"], u["sessions"][k]["room"])
        g = (np.interp(S["ts"], S["tg"], (S["die_g"] - y) / e["width"]))[:, None] * e["u"]
    elif family == "mode_crossing":
        b = np.exp(-0.5 * ((S["die"] - e["Tc"]) / e["sigma"]) ** 2)
        g = b[:, None] * (e["u"] + e["d"] * om / top)
    elif family == "telegraph":
        g = _telegraph(S["ts"], e["traps"], e["seeds"][k], S["span"])[:, None] * e["u"]
    return g, ref, acc


# ------------------------------------------------------------------------------------ standard calibration
def _means(ts, x, holds):
    a = np.searchsorted(ts, np.array([h[0] for h in holds]) + 1.0)
    b = np.searchsorted(ts, np.array([h[1] for h in holds]) - 1.0)
    cs = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    nn = (b - a).reshape((-1,) + (1,) * (x.ndim - 1))
    return (cs[b] - cs[a]) / nn


def hold_set(S, gyro, ref, gE=None, rE=None):
    hs = S["holds"]
    d = {
        "pid": np.array([h[3] for h in hs]),
        "axis": np.array([h[4] for h in hs]),
        "sign": np.array([h[5] for h in hs]),
        "w": _means(S["ts"], gyro, hs),
        "r": _means(S["ts"], ref, hs),
        "T": _means(S["ts"], S["temp"], hs),
    }
    d["wE"] = _means(S["ts"], gE, hs) if gE is not None else np.zeros_like(d["w"])
    d["rE"] = _means(S["ts"], rE, hs) if rE is not None else np.zeros_like(d["r"])
    return d


def _omega(h, r):
    om = np.zeros((r.size, 3))
    om[np.arange(r.size), h["axis"]] = h["sign"] * r
    return om


def std_error(h0, h2, a=0.0):
    """RMS hold-mean error on session 2 of the standard calibration of session 0 (deg/s)."""
    w0, r0 = h0["w"] + a * h0["wE"], h0["r"] + a * h0["rE"]
    om0 = _omega(h0, r0)
    Ts, P = [], []
    for p in np.unique(h0["pid"]):
        m = h0["pid"] == p
        X = np.column_stack([om0[m], np.ones(int(m.sum()))])
        coef, *_ = np.linalg.lstsq(X, w0[m], rcond=None)
        Ts.append(float(np.mean(h0["T"][m])))
        P.append(coef.ravel())
    o = np.argsort(Ts)
    Ts, P = np.array(Ts)[o], np.array(P)[o]
    w2, r2 = h2["w"] + a * h2["wE"], h2["r"] + a * h2["rE"]
    Pi = np.stack([np.interp(h2["T"], Ts, P[:, j]) for j in range(12)], axis=1).reshape(-1, 4, 3)
    K = np.transpose(Pi[:, :3, :], (0, 2, 1))
    est = np.linalg.solve(K, (w2 - Pi[:, 3, :])[..., None])[..., 0]
    return float(np.sqrt(np.mean((est - _omega(h2, r2)) ** 2)))


def _quant(u, w):
    if not u["quant"]:
        return w
    return np.clip(np.round(w / u["qstep"]) * u["qstep"], -u["range"], u["range"])


def _solve_amplitude(h0, h2, target, cap):
    grid = np.geomspace(cap * 1e-5, cap, 60)
    vals = np.array([std_error(h0, h2, a) for a in grid])
    hit = np.nonzero(vals >= target)[0]
    if hit.size == 0:
        j = int(np.argmax(vals))
        return float(grid[j]), float(vals[j]), False
    j = int(hit[0])
    lo, hi = (grid[j - 1] if j > 0 else 0.0), grid[j]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if std_error(h0, h2, mid) >= target:
            hi = mid
        else:
            lo = mid
    return float(hi), std_error(h0, h2, hi), True


# ------------------------------------------------------------------------------------ plan / build
def plan(units_per_family=3, seed=MASTER_SEED, quick=False):
    """Every unit's spec; uids do not tell the family (seeded shuffle)."""
    k = max(1, int(units_per_family))
    mults = [8.66] if k == 1 else [round(float(x), 2) for x in np.geomspace(1.5, 50.0, k)]
    raw = []
    for fam in FAMILIES:
        for j in range(k):
            raw.append({"family": fam, "multiple": mults[j]})
    for _ in range(N_COMPLETE):
        raw.append({"family": "complete", "multiple": 0.0})
    rng = np.random.default_rng([seed, 12])
    order = rng.permutation(len(raw))
    specs = []
    for n, i in enumerate(order):
        sp = dict(raw[i], uid=f"S12U{n + 1:02d}", seed=int(seed), index=int(i))
        specs.append(sp)
    if quick:  # one complete unit, a carried family, one no sensor term carries, one more
        comp = [x for x in specs if x["family"] == "complete"][:1]
        eff = [x for x in specs if x["family"] != "complete"]
        pick = [
            next(
                x for x in eff if FAMILIES[x["family"]]["carried"] and x["multiple"] == mults[len(mults) // 2]
            ),
            next(x for x in eff if not FAMILIES[x["family"]]["carried"] and x["multiple"] == mults[-1]),
        ]
        pick.append(
            next(
                x for x in eff if x["multiple"] == mults[0] and x["family"] not in {y["family"] for y in pick}
            )
        )
        specs = comp + pick
    return specs


def _attempt(spec, attempt, u_cache):
    fam = spec["family"]
    nuis = 0 if attempt < 2 else attempt - 1
    if nuis not in u_cache:
        rng_u = np.random.default_rng([spec["seed"], spec["index"], 1000 + nuis])
        u = draw_unit(rng_u, fam)
        u_cache.clear()
        u_cache[nuis] = (u, [simulate_session(u, k) for k in range(3)])
    return u_cache[nuis]


def build_unit(spec):
    """Simulate one unit's three sessions and its truth -> {"uid", "truth", "sessions"}."""
    fam = spec["family"]
    complete = fam == "complete"
    F = FAMILIES.get(fam)
    best, cache = None, {}
    for attempt in range(1 if complete else 6):
        u, S = _attempt(spec, attempt, cache)
        qb = [_quant(u, x["gyro"]) for x in S]
        hb0, hb2 = hold_set(S[0], qb[0], S[0]["ref"]), hold_set(S[2], qb[2], S[2]["ref"])
        std0 = std_error(hb0, hb2)
        wf = math.sqrt(float(np.mean(u["arw"] ** 2)) / (S[2]["H"] - 2.0))
        floor = max(wf, std0)
        if complete:
            best = dict(u=u, S=S, e={}, a=0.0, E=[(None, None, None)] * 3, floor=floor, wf=wf, std0=std0)
            break
        rng_e = np.random.default_rng([spec["seed"], spec["index"], 2000 + attempt])
        e = draw_effect(rng_e, fam, u, S)
        E = [effect_arrays(fam, e, S[k], u) for k in range(3)]
        h0 = hold_set(S[0], S[0]["gyro"], S[0]["ref"], E[0][0], E[0][1])
        h2 = hold_set(S[2], S[2]["gyro"], S[2]["ref"], E[2][0], E[2][1])
        target = spec["multiple"] * floor
        a, val, ok = _solve_amplitude(h0, h2, target, F["cap"])
        cand = dict(u=u, S=S, e=e, a=a, E=E, floor=floor, wf=wf, std0=std0, reached=ok, attempt=attempt)
        cand["ratio"] = val / target
        if best is None or cand["ratio"] > best["ratio"]:
            best = cand
        if ok:
            break
    return _assemble(spec, best)


def _assemble(spec, b):
    fam = spec["family"]
    complete = fam == "complete"
    u, S, a, E = b["u"], b["S"], b["a"], b["E"]
    sessions, hs = [], []
    for k in range(3):
        g, r, ac = E[k]
        gyro = _quant(u, S[k]["gyro"] + (a * g if g is not None else 0.0))
        ref = S[k]["ref"] + (a * r if r is not None else 0.0)
        acc = S[k]["acc"]
        if acc is not None and ac is not None:
            acc = acc + a * ac
        hs.append(hold_set(S[k], gyro, ref))
        sessions.append(_table(u, S[k], gyro, ref, acc, spec))
    std_final = std_error(hs[0], hs[2])
    F = FAMILIES.get(fam, {})
    truth = {
        "uid": spec["uid"],
        "family": fam,
        "complete": complete,
        "multiple": spec["multiple"],
        "achieved": std_final / b["floor"],
        "amplitude": a,
        "amplitude_unit": F.get("unit", ""),
        "cap": F.get("cap", 0.0),
        "at_cap": (not complete) and a >= 0.999 * F.get("cap", 0.0),
        "attempt": b.get("attempt", 0),
        "floor": b["floor"],
        "white_floor": b["wf"],
        "std_floor": b["std0"],
        "std_with_effect": std_final,
        "threshold": 1.2 * b["floor"],
        "reads": set(F.get("reads", ())),
        "acts": set(F.get("acts", ())),
        "reasons": set(F.get("reasons", ())),
        "carried": bool(F.get("carried", False)),
        "effect": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in b["e"].items()},
        "protocol": {
            "n_mounts": u["n_mounts"],
            "accel": u["accel"],
            "top": u["top"],
            "points": [S[k]["points"] for k in range(3)],
            "torder": [u["sessions"][k]["torder"] for k in range(3)],
            "fs": [S[k]["fs"] for k in range(3)],
            "H": [S[k]["H"] for k in range(3)],
            "power_cycle": u["power_cycle"],
            "power_on0": u["power_on0"],
        },
    }
    return {"uid": spec["uid"], "truth": truth, "sessions": sessions}


# ------------------------------------------------------------------------------------ writing
def _table(u, S, gyro, ref, acc, spec):
    s = u["sessions"][S["k"]]
    ts = S["ts"]
    n = ts.size
    rng = np.random.default_rng(s["seed"] + 11)
    gyro = gyro.copy()
    if s["nan_rows"]:
        cand = np.nonzero(S["lifted"])[0]
        if cand.size:
            rows = rng.choice(cand, min(s["nan_rows"], cand.size), replace=False)
            gyro[rows, rng.integers(0, 3, rows.size)] = np.nan
    conv = math.pi / 180.0 if u["rad"] else 1.0
    fdt = pa.float32() if u["f32"] else pa.float64()
    epoch = EPOCH0 + 86400.0 * round(u["days"][S["k"]]) + 3600.0 * round(s["hour"], 2)
    style = s["tstyle"]
    if style == "zero":
        tcol = pa.array(ts - ts[0], pa.float64())
    elif style == "epoch":
        tcol = pa.array(epoch + ts, pa.float64())
    else:
        unit, tz = {"ns_utc": ("ns", "UTC"), "ms_local": ("ms", "Europe/Berlin"), "us_naive": ("us", None)}[
            style
        ]
        mul = {"ns": 1e9, "ms": 1e3, "us": 1e6}[unit]
        iv = int(round(epoch)) * int(mul) + np.round(ts * mul).astype(np.int64)
        tcol = pa.array(iv, pa.timestamp(unit, tz=tz))
    cols = {"t": tcol}
    for i, ax in enumerate("xyz"):
        cols[f"gyro_{ax}"] = pa.array(gyro[:, i] * conv, fdt)
    cols["temp"] = pa.array(S["temp"], fdt)
    cols["ref_rate"] = pa.array(ref * conv, fdt)
    if s["mount_col"] != "none":
        words = np.array(MOUNTS, dtype=object)[S["mount"]]
        col = pa.array(words, pa.string())
        cols["mount"] = col.dictionary_encode() if s["mount_col"] == "dict" else col
    if acc is not None:
        for i, ax in enumerate("xyz"):
            cols[f"accel_{ax}"] = pa.array(acc[:, i], fdt)
    if u["extra"]:
        cols["sample"] = pa.array(np.arange(n, dtype=np.int64) + int(rng.integers(0, 10**6)))
    table = pa.table(cols)
    if u["rad"]:
        table = table.replace_schema_metadata(
            {"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})}
        )
    return {"t": ts, "table": table, "day": round(u["days"][S["k"]])}


def write_unit(built, folder):
    """Write the three sessions; returns their paths, sessions 0, 1, 2 in name order."""
    os.makedirs(folder, exist_ok=True)
    paths = []
    for k, ss in enumerate(built["sessions"]):
        p = os.path.join(folder, f"{built['uid']}_s{k}_d{ss['day']:03d}.parquet")
        pq.write_table(ss["table"], p)
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------------ contract validator
_FLOAT = (pa.float32(), pa.float64())


def validate_log(path):
    """Problems of one log against the contract (empty list: it follows it)."""
    probs = []
    try:
        tab = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        return [f"unreadable: {type(exc).__name__}"]
    sch = tab.schema
    names = set(sch.names)
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in names:
            probs.append(f"missing column {c}")
    if probs:
        return probs
    if tab.num_rows < 2:
        probs.append("fewer than two rows")
    if tab.num_rows > MAX_ROWS:
        probs.append(f"{tab.num_rows} rows > {MAX_ROWS}")
    tt = sch.field("t").type
    if pa.types.is_timestamp(tt):
        tv = tab.column("t").cast(pa.int64()).to_numpy().astype(np.float64)
    elif tt == pa.float64():
        tv = tab.column("t").to_numpy()
    else:
        probs.append(f"t has type {tt}")
        tv = None
    if tab.column("t").null_count:
        probs.append("t has nulls")
    elif tv is not None:
        if not np.all(np.isfinite(tv)):
            probs.append("t not finite")
        elif np.any(np.diff(tv) <= 0):
            probs.append("t not strictly increasing")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if sch.field(c).type not in _FLOAT:
            probs.append(f"{c} has type {sch.field(c).type}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in names]
    if acc and len(acc) != 3:
        probs.append("accelerometer columns incomplete")
    for c in acc:
        if sch.field(c).type not in _FLOAT:
            probs.append(f"{c} has type {sch.field(c).type}")
    if "mount" in names:
        mt = sch.field("mount").type
        ok = pa.types.is_string(mt) or pa.types.is_large_string(mt)
        ok = ok or (pa.types.is_dictionary(mt) and pa.types.is_string(mt.value_type))
        if not ok:
            probs.append(f"mount has type {mt}")
        else:
            col = tab.column("mount")
            vals = set(col.cast(pa.string()).unique().to_pylist()) if ok else set()
            bad = vals - set(MOUNTS)
            if bad:
                probs.append(f"mount words outside the contract: {sorted(map(str, bad))}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            units = json.loads(md[b"gyrocal.units"])
            if not isinstance(units, dict) or set(units) - {"gyro", "ref_rate"}:
                probs.append("gyrocal.units has unknown keys")
            elif any(v not in ("rad/s", "deg/s") for v in units.values()):
                probs.append("gyrocal.units has unknown units")
        except ValueError:
            probs.append("gyrocal.units is not JSON")
    g = np.column_stack(
        [tab.column(c).to_numpy(zero_copy_only=False) for c in ("gyro_x", "gyro_y", "gyro_z")]
    )
    bad_rows = int(np.sum(~np.all(np.isfinite(g), axis=1)))
    if bad_rows > 0.01 * max(tab.num_rows, 1):
        probs.append(f"{bad_rows} non-finite rows")
    return probs


# ------------------------------------------------------------------------------------ main
def _one(args):
    spec, root = args
    t0 = time.time()
    built = build_unit(spec)
    paths = write_unit(built, os.path.join(root, spec["uid"]))
    probs = {os.path.basename(p): validate_log(p) for p in paths}
    rows = [int(ss["t"].size) for ss in built["sessions"]]
    return spec["uid"], probs, rows, time.time() - t0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    jobs = int(argv[0]) if argv else 2
    specs = plan()
    root = tempfile.mkdtemp(prefix="sealed12_gen_")
    t0 = time.time()
    try:
        with ProcessPoolExecutor(max_workers=jobs) as ex:
            out = list(ex.map(_one, [(s, root) for s in specs]))
    finally:
        shutil.rmtree(root, ignore_errors=True)
    wall = time.time() - t0
    bad_logs = sum(bool(m) for _, probs, _, _ in out for m in probs.values())
    rows = [r for _, _, rr, _ in out for r in rr]
    n_comp = sum(s["family"] == "complete" for s in specs)
    print(f"units {len(specs)} (effect families {len(FAMILIES)}, complete units {n_comp}); logs {len(rows)}")
    print(f"rows per log {min(rows)}..{max(rows)}; logs with contract problems: {bad_logs}")
    print(f"wall {wall:.0f} s on {jobs} processes; CPU in the workers {sum(x[3] for x in out):.0f} s")
    return 1 if bad_logs else 0


if __name__ == "__main__":
    raise SystemExit(main())
