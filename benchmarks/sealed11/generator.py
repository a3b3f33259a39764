"""Eleventh sealed benchmark: simulator of `turntable` rig logs, its effect families, the standard
calibration that sets the reference floor, and a contract validator.

PRIVATE TO THE BENCHMARK: whoever works on the diagnosis must not read this file (it holds the
effect families, their physics, shapes and magnitudes).  Developers read README.md's "How to
run" and "Scoring" and the runner's aggregate table only.

    python benchmarks/sealed11/generator.py [JOBS] [--seed S] [--units-per-family K] [--quick]
                                            [--keep DIR]

generates every unit's three sessions, validates every log against the contract
(`/work/shared/spec/log-format.md`) and prints counts and the wall time (no per-unit rows).

Each unit is one physical three-axis MEMS gyro written as three sessions (days 0, 2-40 and
45-200), each a new power-on.  The slow states (chamber air under a PI controller, door
openings, the unit's case and die, self-heating, the temperature sensor, bias instability and the
families' own states) run on a 1 s grid; the samples at 10-50 Hz.

Model of the gyro output (deg/s), per sample:

    w = K(T_die) . w_body + B(T_die) + b_on + b_BI(t) + n(t) + a * effect(t)

then quantised and clipped on most units.  `a` is set per unit so that the standard calibration
of session 0 misses on session 2 by a chosen multiple of the reference floor, capped by the
family's physical bound.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.optimize import brentq
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

MASTER_SEED = 20270613
G = 9.80665
EARTH = 15.041067 / 3600.0  # deg/s
D2R = math.pi / 180.0
TABLE2 = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 75.0, 100.0, 150.0, 200.0, 250.0, 300.0)
TOPS = (75.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)
TOP_P = (0.05, 0.13, 0.1, 0.2, 0.1, 0.14, 0.28)
RANGES = (125.0, 250.0, 500.0, 1000.0, 2000.0)
FS_LIST = (50.0, 40.0, 30.0, 25.0, 20.0, 15.0, 10.0)
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
MAX_ROWS = 300_000
N_COMPLETE = 4
N_ATTEMPTS = 5  # effect redrawn, then nuisances and protocol, keeping the strongest
DEVICE_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")

# ---------------------------------------------------------------------------------------------
# The effect families (truth in the judge's words).  `bound` is the physical cap of the
# amplitude `a`, in the unit each family states.
FAMILIES: dict[str, dict] = {
    # odd cubic scale nonlinearity (electrostatic / centrifugal softening); a = relative
    # departure at the top rate, its coefficient drifting with temperature
    "cubic_sf": dict(reads={"rate"}, acts={"scale"}, reasons=set(), carried=True, bound=0.012),
    # scale asymmetry, |w| on each axis (demodulator offset); a = relative
    "asym_sf": dict(reads={"rate"}, acts={"scale"}, reasons=set(), carried=True, bound=0.004),
    # rate-squared coupling into the other axes (centrifugal load on their proof masses);
    # a = bias on the other axis at the top rate, as a fraction of the top rate
    "rate2_cross": dict(reads={"rate"}, acts={"cross-axis"}, reasons=set(), carried=True, bound=0.002),
    # linear and anisoelastic (g x g) acceleration sensitivity; a = deg/s/g
    "g_sens": dict(reads={"accel"}, acts={"bias"}, reasons=set(), carried=True, bound=0.3),
    # power-on transient (reference settling, dielectric charging) of bias and scale,
    # in time since power-on, not temperature; a = deg/s at power-on
    "warmup": dict(reads={"time"}, acts={"bias", "scale"}, reasons=set(), carried=True, bound=1.0),
    # gradient across the package while heat flows into or out of the case (lumped: proportional
    # to the case temperature's rate); a = deg/s per °C/min
    "gradient": dict(reads={"thermal"}, acts={"bias"}, reasons=set(), carried=True, bound=0.3),
    # bias memory of the rate history (charge built up by large sense-loop voltages, per axis);
    # a = deg/s at full charge
    "charging": dict(reads={"rate"}, acts={"bias"}, reasons=set(), carried=True, bound=0.5),
    # thermal hysteresis of the die attach (Duhem loop in the die temperature); a = deg/s
    "hysteresis": dict(
        reads={"thermal"}, acts={"bias"}, reasons={"direction of approach"}, carried=False, bound=0.4
    ),
    # the ASIC's factory compensation table applied as a staircase (zero-order hold in its
    # temperature bins, switching hysteresis): a sawtooth in temperature; a = step in deg/s
    "lut_steps": dict(
        reads={"temperature"}, acts={"bias", "scale"}, reasons={"between points"}, carried=False, bound=0.5
    ),
    # random telegraph (popcorn) bias, long dwell times; a = step in deg/s
    "popcorn": dict(reads=set(), acts=set(), reasons={"slow noise"}, carried=False, bound=0.15),
    # package stress relaxation over days: K and B move with log(age); a = relative
    "aging": dict(reads=set(), acts=set(), reasons={"unit changed"}, carried=False, bound=0.004),
    # debris under the fixture's faces, new every session: the cube sits tilted on some faces;
    # a = rad
    "fixture_debris": dict(
        reads={"mount"}, acts={"cross-axis"}, reasons={"mounting"}, carried=False, bound=0.003
    ),
    # the servo table's speed reference off by a common factor that differs day to day; a = relative
    "table_reference": dict(reads=set(), acts=set(), reasons={"lab"}, carried=False, bound=0.002),
}


# ---------------------------------------------------------------------------------------------
# small helpers
def _lu(rng, lo, hi, size=None):
    return np.exp(rng.uniform(math.log(lo), math.log(hi), size))


def _pick(rng, items, p=None):
    return items[int(rng.choice(len(items), p=p))]


def _gm(rng, n, sigma, tau, dt=1.0):
    """Stationary first-order Gauss–Markov process on a regular grid."""
    phi = math.exp(-dt / tau)
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    x0 = sigma * rng.standard_normal()
    return lfilter([1.0], [1.0, -phi], e, zi=[phi * x0])[0]


def _lag(t, x, tau, y0=None):
    """Exact first-order lag of a zero-order-held input on an irregular (gapped) time base."""
    n = t.size
    y = np.empty(n)
    y[0] = x[0] if y0 is None else y0
    if n == 1:
        return y
    start = 0
    while start < n - 1:
        # blocks short enough that exp() stays finite
        stop = int(np.searchsorted(t, t[start] + 200.0 * tau, side="right"))
        stop = min(max(stop, start + 2), n)
        tt = t[start:stop] - t[start]
        dt = np.diff(tt)
        a = np.exp(-dt / tau)
        grow = np.exp(tt[1:] / tau)
        inc = (1.0 - a) * x[start : stop - 1] * grow
        y[start + 1 : stop] = np.exp(-tt[1:] / tau) * (y[start] + np.cumsum(inc))
        start = stop - 1
    return y


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


MOUNT_BASE = (
    _ry(math.pi / 2),
    _ry(-math.pi / 2),
    _rx(-math.pi / 2),
    _rx(math.pi / 2),
    np.eye(3),
    np.diag([1.0, -1.0, -1.0]),
)
AXIS_VEC = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])


def _random_rotation(rng):
    q = rng.standard_normal(4)
    return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()


def _small_rotation(rng, sigma):
    return Rotation.from_rotvec(rng.standard_normal(3) * sigma).as_matrix()


# ---------------------------------------------------------------------------------------------
# the unit (physics and unit-level protocol)
def draw_unit(rng, family):
    u: dict = {"family": family}
    # rate plan (the rig's standard table for this unit type)
    top = float(_pick(rng, TOPS, TOP_P))
    six = bool(rng.random() < 0.45)
    below = [r for r in TABLE2 if r < top]
    n_mag = int(rng.integers(2, 5 if six else 8))
    mags = sorted(rng.choice(below, size=min(n_mag, len(below)), replace=False).tolist()) + [top]
    u.update(top=top, six=six, mags=mags, zero=bool(rng.random() < 0.65), H=float(rng.uniform(20, 60)))
    u["alpha_pk"] = float(_lu(rng, 20, 200))
    u["jitter"] = float(_lu(rng, 1e-6, 1e-4)) if rng.random() < 0.5 else 0.0
    # K(T), B(T) about 25 °C
    K0 = np.eye(3) + np.diag(rng.normal(0, 0.01, 3))
    off = ~np.eye(3, dtype=bool)
    K0[off] = rng.normal(0, 0.004, 6)
    K1 = np.zeros((3, 3))
    K1[~off] = rng.choice([-1, 1], 3) * _lu(rng, 30e-6, 400e-6, 3)
    K1[off] = rng.choice([-1, 1], 6) * _lu(rng, 0.5e-6, 20e-6, 6)
    K2 = np.zeros((3, 3))
    K2[~off] = rng.choice([-1, 1], 3) * _lu(rng, 50e-6, 1500e-6, 3) / 3600.0
    K2[off] = rng.choice([-1, 1], 6) * _lu(rng, 1e-6, 100e-6, 6) / 3600.0
    u["K"] = (K0, K1, K2)
    u["B"] = (
        rng.normal(0, 0.5, 3),
        rng.choice([-1, 1], 3) * _lu(rng, 0.002, 0.04, 3),
        rng.choice([-1, 1], 3) * _lu(rng, 0.003, 0.2, 3) / 3600.0,
        rng.choice([-1, 1], 3) * _lu(rng, 0.001, 0.05, 3) / 216000.0,
    )
    # noise
    u["arw"] = float(_lu(rng, 0.003, 0.03)) * rng.uniform(0.75, 1.3, 3)
    u["bi_kind"] = "gm" if rng.random() < 0.5 else "flicker"
    u["k_bi"] = float(_lu(rng, 0.1, 2.5))
    u["bi_axis"] = rng.uniform(0.7, 1.3, 3)
    u["bi_tau"] = float(_lu(rng, 20, 20000))
    t_lo, t_hi = float(_lu(rng, 10, 60)), float(_lu(rng, 2000, 30000))
    u["bi_taus"] = np.geomspace(t_lo, t_hi, 5)
    u["k_rep"] = float(_lu(rng, 1, 5))
    # output word: 16 bits over the smallest range above 1.31 x top, or not quantised
    u["range"] = next(r for r in RANGES if r >= 1.31 * top)
    u["quant"] = bool(rng.random() < 0.75)
    # thermal path
    u.update(
        tau_air=float(_lu(rng, 20, 90)),
        kp=float(rng.uniform(0.5, 3)),
        ti=float(_lu(rng, 60, 600)),
        lim=float(rng.uniform(25, 60)),
        ramp=float(rng.uniform(1, 5)),  # °C/min
        rip_sigma=float(_lu(rng, 0.01, 0.2)),
        rip_tau=float(_lu(rng, 30, 300)),
        tau_door=float(_lu(rng, 15, 1000)),
        tau_case=float(_lu(rng, 120, 1200)),
        two_stage=bool(rng.random() < 0.6),
        tau_die=float(_lu(rng, 5, 120)),
        sh_case=float(rng.uniform(0.3, 5)),
        sh_die=float(rng.uniform(0.2, 2)),
        conv=0.0 if rng.random() < 0.3 else float(rng.uniform(0.1, 0.8)),
        hand_w=float(rng.uniform(0, 0.5)),
    )
    u["sensor"] = dict(
        mode=_pick(rng, ("die", "lag", "lead"), (0.3, 0.35, 0.35)),
        tau=float(_lu(rng, 3, 120)),
        kappa=float(rng.uniform(0.1, 0.6)),
        offset=float(rng.normal(0, 1.5)),
        gain=float(1 + rng.normal(0, 0.01)),
        noise=float(_lu(rng, 0.005, 0.15)),
        q=float(_pick(rng, (1 / 256, 1 / 64, 1 / 16, 1 / 8))),
        update=float(_pick(rng, (0.0, 1.0, 2.0))),
    )
    # rig and fixture
    u.update(
        radius=float(rng.uniform(0, 0.08)),
        r_az=float(rng.uniform(0, 2 * math.pi)),
        seat=float(_lu(rng, 1e-6, 30e-6)),
        tremor=float(_lu(rng, 0.3, 5)),
        lat=float(rng.uniform(25, 60)) * D2R,
        north=float(rng.uniform(0, 2 * math.pi)),
    )
    pw = (0.2, 0.35, 0.45) if family == "warmup" else (0.55, 0.2, 0.25)
    u["power_mode"] = _pick(rng, ("never", "remount", "setpoint"), pw)
    u["p_late"] = 0.6 if family == "warmup" else 0.35
    u["accel"] = bool(rng.random() < 0.4 or family == "g_sens")
    u["acc_bias"] = rng.normal(0, 0.01, 3)
    u["acc_S"] = rng.normal(0, 0.003, (3, 3))
    u["acc_noise"] = float(_lu(rng, 0.0005, 0.003))
    u["acc_q"] = float(_pick(rng, (0.0, 1 / 4096, 1 / 16384)))
    # white hold-mean floor needs the final hold length: set after the length check
    _fit_hold_time(u, rng)
    u["wf"] = float(math.sqrt(np.mean(u["arw"] ** 2) / (u["H"] - 2.0)))
    u["device"] = f"MG{int(rng.integers(16**6)):06X}"
    u["batch"] = f"L{int(rng.integers(100, 999))}"
    u["date0"] = _dt.date(2025, 1, 1) + _dt.timedelta(days=int(rng.integers(0, 330)))
    return u


def _fit_hold_time(u, rng):
    """At most about 4 h of holds per session: shorten the holds, then drop magnitudes."""
    n_pts = 7  # a long session: six points and a revisit
    n_m = 6 if u["six"] else 3
    while True:
        n_h = 2 * len(u["mags"]) + (1 if u["zero"] else 0)
        per = n_pts * n_m * n_h
        h_max = 4 * 3600.0 / per - 8.0
        if h_max >= 20.0 or len(u["mags"]) <= 2:
            u["H"] = float(max(20.0, min(u["H"], h_max)))
            return
        drop = int(rng.integers(0, len(u["mags"]) - 1))  # never the top rate
        u["mags"].pop(drop)


# ---------------------------------------------------------------------------------------------
# protocols (per session)
def draw_setpoints0(rng):
    lo = 5.0 * round(rng.uniform(-40, 0) / 5.0)
    hi = 5.0 * round(rng.uniform(40, 85) / 5.0)
    n = int(rng.integers(3, 8))
    pts = np.linspace(lo, hi, n)
    pts[1:-1] += rng.uniform(-2, 2, n - 2)
    return np.round(pts * 2) / 2


def later_setpoints(rng, sp0):
    lo, hi = sp0.min(), sp0.max()
    kind = _pick(rng, ("same", "mid", "shift"), (0.3, 0.35, 0.35))
    if kind == "same":
        pts = np.clip(sp0 + rng.uniform(-1, 1, sp0.size), lo, hi)
    elif kind == "mid":
        s = np.sort(sp0)
        pts = 0.5 * (s[1:] + s[:-1])
        if pts.size < 3:
            pts = np.concatenate([[lo], pts, [hi]])
    else:
        step = (hi - lo) / (sp0.size - 1)
        pts = np.sort(sp0) + rng.uniform(0.2, 0.8) * step
        pts = pts[pts <= hi]
        while pts.size < 3:
            pts = np.concatenate([[lo + rng.uniform(0, 0.3) * step], pts])
    return np.round(np.sort(pts) * 2) / 2, kind


def order_setpoints(rng, pts, room):
    s = list(np.sort(pts))
    kind = _pick(rng, ("desc", "room_down", "room_up", "zigzag", "cold_desc", "hot_asc", "shuffle"))
    if kind == "desc":
        o = s[::-1]
    elif kind in ("room_down", "room_up"):
        i = int(np.argmin(np.abs(np.array(s) - room)))
        below, above = s[:i][::-1], s[i + 1 :]
        o = [s[i]] + (below + above if kind == "room_down" else above + below)
    elif kind == "zigzag":
        o, a, b = [], 0, len(s) - 1
        while a <= b:
            o.append(s[a])
            if a != b:
                o.append(s[b])
            a, b = a + 1, b - 1
    elif kind == "cold_desc":
        o = [s[0]] + s[1:][::-1]
    elif kind == "hot_asc":
        o = [s[-1]] + s[:-1]
    else:
        o = list(rng.permutation(s))
    if all(o[i] < o[i + 1] for i in range(len(o) - 1)):
        o = o[::-1]
    return [float(x) for x in o], kind


def rate_order(rng, mags, zero):
    kind = _pick(rng, ("asc", "desc", "shuffle", "zigzag", "topfirst", "sweep"))
    m = list(mags)
    signed = [-x for x in m[::-1]] + m
    if kind == "asc":
        o = signed
    elif kind == "desc":
        o = signed[::-1]
    elif kind == "shuffle":
        o = [float(x) for x in rng.permutation(signed)]
    elif kind == "zigzag":
        o = [v for x in m for v in (x, -x)]
    elif kind == "topfirst":
        rest = [v for x in m[:-1] for v in (x, -x)]
        o = [m[-1], -m[-1]] + [float(x) for x in rng.permutation(rest)]
    else:
        o = m + [-x for x in m]
    if zero:
        o = [0.0] + o if rng.random() < 0.6 else o + [0.0]
    return o, kind


def draw_protocol(rng, u, s, sp0):
    P: dict = {"s": s}
    P["day"] = 0 if s == 0 else int(rng.integers(2, 41) if s == 1 else rng.integers(45, 201))
    P["room"] = float(rng.uniform(19, 26))
    if s == 0:
        pts, sp_kind = sp0, "base"
    else:
        pts, sp_kind = later_setpoints(rng, sp0)
    order, t_kind = order_setpoints(rng, pts, P["room"])
    P["sp_kind"], P["t_order"] = sp_kind, t_kind
    # mounts
    mset = list(range(6)) if u["six"] else [2 * a + int(rng.integers(0, 2)) for a in range(3)]
    base = [int(x) for x in rng.permutation(mset)]
    m_kind = _pick(rng, ("fixed", "serpentine", "random"))
    per_point = []
    for k in range(len(order)):
        if m_kind == "fixed":
            per_point.append(list(base))
        elif m_kind == "serpentine":
            per_point.append(list(base) if k % 2 == 0 else list(base[::-1]))
        else:
            per_point.append([int(x) for x in rng.permutation(base)])
    if rng.random() < 0.35 and len(order) >= 2:  # revisit an earlier point at the end
        j = int(rng.integers(0, len(order) - 1))
        order.append(order[j])
        nm = len(base) if rng.random() < 0.5 else int(rng.integers(1, 3))
        per_point.append([int(x) for x in rng.permutation(base)[:nm]])
        P["revisit"] = True
    else:
        P["revisit"] = False
    P["sp"], P["mounts"], P["m_order"] = order, per_point, m_kind
    P["rates"], P["r_order"] = rate_order(rng, u["mags"], u["zero"])
    P["stop"] = bool(rng.random() < 0.4)
    P["soak_m"] = float(rng.uniform(4, 8))
    P["soak_log"] = "tail" if rng.random() < 0.6 else "full"
    P["tail"] = float(rng.uniform(3, _lu(rng, 4, 15))) * 60.0
    n_remounts = sum(len(m) for m in per_point)
    n_pause = int(rng.integers(0, 4))
    P["pauses"] = {
        int(i): float(rng.uniform(1, 20)) * 60.0
        for i in rng.choice(max(n_remounts, 1), size=min(n_pause, n_remounts), replace=False)
    }
    P["late"] = bool(rng.random() < u["p_late"])
    P["late_lead"] = float(_lu(rng, 3, 30)) * 60.0
    P["fs_cap"] = float(_pick(rng, FS_LIST[:5]))
    P["t0_table"] = float(rng.uniform(0, 360))
    # file format
    P["tkind"] = _pick(rng, ("float0", "epoch", "ts_ns_utc", "ts_ms_local", "ts_us_naive"))
    P["f32"] = bool(rng.random() < 0.4)
    P["rad"] = bool(rng.random() < 0.15)
    P["mountcol"] = _pick(rng, ("none", "string", "dictionary"), (0.3, 0.35, 0.35))
    P["nan_rows"] = int(rng.integers(1, 6)) if rng.random() < 0.15 else 0
    P["extra"] = _pick(rng, ("frame", "status"))
    P["hour"] = float(rng.uniform(7, 10.5))
    return P


# ---------------------------------------------------------------------------------------------
# the session's schedule: chamber set points, doors, handling, power, table motion, holds
def build_schedule(rng, u, P):
    room = P["room"]
    tau_slow = max(u["tau_case"], u["tau_air"], u["tau_die"] if u["two_stage"] else 0.0)
    seg = []  # table motion: (t0, t1, rate_a, rate_b)
    holds = []  # (t0, t1, rate, mount, group, placement, point)
    handl = []
    doors = [(0.0, float(rng.uniform(30, 90)))]
    knots = [(0.0, room)]
    unlog = []
    soaks = []
    power = []  # [t_on, t_off]
    places = []  # dict(t, mount, C)
    labels = []  # (t, mount)

    def new_place(mount, t_at):
        C = _small_rotation(rng, u["seat"]) @ MOUNT_BASE[mount] @ _rz(rng.uniform(0, 2 * math.pi))
        places.append(dict(t=t_at, mount=mount, C=C))

    first_mount = P["mounts"][0][0]
    new_place(first_mount, -1.0)
    labels.append((-1.0, first_mount))
    cur_mount = first_mount
    cur_sp = room
    t = 0.0
    remount_i = 0
    pmode = u["power_mode"]
    on_since = None
    late = P["late"]

    for k, sp in enumerate(P["sp"]):
        t_r = t
        ramp = abs(sp - cur_sp) / u["ramp"] * 60.0
        knots += [(t_r, cur_sp), (t_r + ramp, sp)]
        soak = float(np.clip(P["soak_m"] * tau_slow, 900.0, 6000.0))
        soak_end = t_r + ramp + soak
        # power
        if on_since is None or (pmode == "setpoint" and k > 0):
            if on_since is not None:
                power.append([on_since, t_r])
            if late:
                t_on = max(t_r + 60.0, soak_end - P["late_lead"])
            else:
                t_on = t_r if k == 0 else t_r + float(rng.uniform(10, 120))
            on_since = t_on
        soaks.append((t_r, soak_end))
        t = soak_end
        for j, mount in enumerate(P["mounts"][k]):
            if mount != cur_mount or (j == 0 and k > 0 and rng.random() < 0.25):
                # remount (or the operator re-seats the same face at a new point)
                still = float(rng.uniform(2, 10))
                if remount_i in P["pauses"]:
                    unlog.append((t, t + P["pauses"][remount_i]))
                    still += P["pauses"][remount_i]
                remount_i += 1
                t_do = t + still
                t_lift = t_do + float(rng.uniform(2, 8))
                n_mid = int(rng.integers(1, 3))
                moves = []
                tm = t_lift
                for _ in range(n_mid + 1):
                    d = float(rng.uniform(0.4, 2.0))
                    moves.append((tm, d))
                    tm += d + float(rng.uniform(0.5, 4.0))
                t_place = moves[-1][0] + moves[-1][1]
                t_dc = t_place + float(rng.uniform(2, rng.uniform(5, 25)))
                doors.append((t_do, t_dc))
                labels.append((t_do, mount))
                new_place(mount, t_place)
                mids = [_random_rotation(rng) for _ in range(n_mid)]
                handl.append(
                    dict(
                        t_do=t_do, t_lift=t_lift, t_place=t_place, moves=moves, mids=mids, pl=len(places) - 1
                    )
                )
                if pmode == "remount":
                    dur = t_place - t_lift
                    power.append([on_since, t_lift + 0.2 * dur])
                    on_since = t_lift + 0.8 * dur
                t = t_dc + float(rng.uniform(5, rng.uniform(15, 600)))
                cur_mount = mount
            else:
                t += float(rng.uniform(5, 30))
            # the holds of this mount
            cur = 0.0
            for r in P["rates"]:
                if r != cur:
                    d = 2.0 * abs(r - cur) / u["alpha_pk"]
                    seg.append((t, t + d, cur, r))
                    t += d
                seg.append((t, t + u["H"], r, r))
                holds.append((t, t + u["H"], r, mount, round(sp * 2) / 2, len(places) - 1, k))
                t += u["H"]
                cur = r
                if P["stop"] and r != 0.0:
                    d = 2.0 * abs(cur) / u["alpha_pk"]
                    seg.append((t, t + d, cur, 0.0))
                    t += d + float(rng.uniform(2, 6))
                    cur = 0.0
            if cur != 0.0:
                d = 2.0 * abs(cur) / u["alpha_pk"]
                seg.append((t, t + d, cur, 0.0))
                t += d
            t += float(rng.uniform(1, 5))
        cur_sp = sp
        t += float(rng.uniform(5, 30))
    t_end = t + float(rng.uniform(10, 60))
    power.append([on_since, t_end])
    return dict(
        seg=seg,
        holds=holds,
        handl=handl,
        doors=doors,
        knots=knots,
        unlog=unlog,
        soaks=soaks,
        power=power,
        places=places,
        labels=labels,
        t_end=t_end,
    )


def _table_eval(sch, t, theta0):
    """Table rate (deg/s), angle (deg) and angular acceleration (deg/s²) at times t."""
    seg = np.array(sch["seg"]) if sch["seg"] else np.zeros((0, 4))
    t0, t1, ra, rb = seg.T
    dur = t1 - t0
    inc = 0.5 * (ra + rb) * dur
    th_start = theta0 + np.concatenate([[0.0], np.cumsum(inc)[:-1]])
    th_end = th_start + inc
    idx = np.searchsorted(t0, t, side="right") - 1
    rate = np.zeros(t.size)
    acc = np.zeros(t.size)
    th = np.full(t.size, theta0)
    ok = idx >= 0
    i = idx[ok]
    tau = t[ok] - t0[i]
    inside = tau < dur[i]
    d = dur[i]
    dr = rb[i] - ra[i]
    x = np.where(d > 0, tau / np.where(d > 0, d, 1.0), 0.0)
    two_pi = 2 * math.pi
    r_in = ra[i] + dr * (x - np.sin(two_pi * x) / two_pi)
    th_in = th_start[i] + ra[i] * tau + dr * d * (x * x / 2 + (np.cos(two_pi * x) - 1) / (4 * math.pi**2))
    a_in = np.where(d > 0, dr / np.where(d > 0, d, 1.0), 0.0) * (1 - np.cos(two_pi * x))
    rate[ok] = np.where(inside, r_in, 0.0)
    th[ok] = np.where(inside, th_in, th_end[i])
    acc[ok] = np.where(inside, a_in, 0.0)
    return rate, th, acc


def _mask(tg, intervals):
    m = np.zeros(tg.size, dtype=bool)
    for a, b in intervals:
        i0, i1 = np.searchsorted(tg, [a, b])
        m[i0:i1] = True
    return m


def _thermal(rng, u, P, sch, tg, absw):
    """Chamber air (PI with anti-windup, ripple, door), case, die, sensor node, on a 1 s grid."""
    kt, kv = zip(*sch["knots"], strict=True)
    sp = np.interp(tg, kt, kv)
    door = _mask(tg, sch["doors"])
    hand = _mask(tg, [(h["t_lift"], h["t_place"]) for h in sch["handl"]])
    on = _mask(tg, sch["power"])
    rip = _gm(rng, tg.size, u["rip_sigma"], u["rip_tau"])
    room = P["room"]
    ea = math.exp(-1.0 / u["tau_air"])
    kd = 1.0 / u["tau_air"] + 1.0 / u["tau_door"]
    ed = math.exp(-kd)
    ec = math.exp(-1.0 / u["tau_case"])
    edie = math.exp(-1.0 / u["tau_die"])
    es = math.exp(-1.0 / u["sensor"]["tau"])
    kp, ti, lim = u["kp"], u["ti"], u["lim"]
    shc, shd, conv, hw = u["sh_case"], u["sh_die"], u["conv"], u["hand_w"]
    two = u["two_stage"]
    n = tg.size
    air = np.empty(n)
    case = np.empty(n)
    die = np.empty(n)
    sen = np.empty(n)
    ta, tc, td, ts, integ = room, room, room, room, 0.0
    spl, doorl, handl, onl = sp.tolist(), door.tolist(), hand.tolist(), on.tolist()
    absl, ripl = absw.tolist(), rip.tolist()
    for i in range(n):
        s = spl[i]
        e = s - ta
        uu = s + kp * e + integ
        uc = min(max(uu, s - lim), s + lim)
        if uc == uu:
            integ += kp * e / ti
        if doorl[i]:
            eq = (uc / u["tau_air"] + room / u["tau_door"]) / kd
            ta = eq + (ta - eq) * ed
        else:
            ta = uc + (ta - uc) * ea
        a = ta + ripl[i]
        env = a + hw * (32.0 - a) if handl[i] else a
        heat = shc / (1.0 + conv * absl[i] / 300.0) if onl[i] else 0.0
        tgt = env + heat
        tc = tgt + (tc - tgt) * ec
        if two:
            tgd = tc + (shd if onl[i] else 0.0)
            td = tgd + (td - tgd) * edie
        else:
            td = tc
        ts = td + (ts - td) * es
        air[i], case[i], die[i], sen[i] = a, tc, td, ts
    return dict(air=air, case=case, die=die, sens_lag=sen, on=on, sp=sp)


def _logged_intervals(sch, P):
    """On and logging: the power intervals minus the pauses (and the soaks' heads when only
    their tails are logged)."""
    unlog = list(sch["unlog"])
    if P["soak_log"] == "tail":
        unlog += [(a, max(a, b - P["tail"])) for a, b in sch["soaks"]]
    out = []
    for a, b in sch["power"]:
        pieces = [(a, b)]
        for ua, ub in unlog:
            nxt = []
            for pa_, pb_ in pieces:
                if ub <= pa_ or ua >= pb_:
                    nxt.append((pa_, pb_))
                else:
                    if ua > pa_:
                        nxt.append((pa_, ua))
                    if ub < pb_:
                        nxt.append((ub, pb_))
            pieces = nxt
        out += [p for p in pieces if p[1] - p[0] > 1.0]
    return sorted(out)


def _sample_times(intervals, fs):
    ks = [np.arange(math.ceil(a * fs), math.ceil(b * fs), dtype=np.int64) for a, b in intervals]
    k = np.unique(np.concatenate(ks))
    return k / fs, k


def simulate_session(rng, u, P):
    """Everything true about one session, at the samples and on the 1 s grid (no effect)."""
    sch = build_schedule(rng, u, P)
    tg = np.arange(0.0, sch["t_end"] + 2.0)
    theta0 = P["t0_table"]
    rate_g, _, _ = _table_eval(sch, tg, theta0)
    th = _thermal(rng, u, P, sch, tg, np.abs(rate_g))
    # sample rate: the largest (up to this session's cap) keeping the log within MAX_ROWS
    iv = _logged_intervals(sch, P)
    if sum(b - a for a, b in iv) * 10.0 > MAX_ROWS and P["soak_log"] == "full":
        P["soak_log"] = "tail"  # too long for the logger at 10 Hz: log only the soak tails
        iv = _logged_intervals(sch, P)
    dur = sum(b - a for a, b in iv)
    fs = next((f for f in FS_LIST if f <= P["fs_cap"] and dur * f <= MAX_ROWS), 10.0)
    P["fs"] = fs
    t, kidx = _sample_times(iv, fs)
    n = t.size
    # table
    rate, theta, alpha = _table_eval(sch, t, theta0)
    ref = rate.copy()
    if u["jitter"] > 0:
        moving = rate != 0
        ref[moving] = rate[moving] * (1 + u["jitter"] * rng.standard_normal(int(moving.sum())))
    # placements per sample (placement k from its t_place)
    pt = np.array([p["t"] for p in sch["places"]])
    pidx = np.searchsorted(pt, t, side="right") - 1
    Cs = np.stack([p["C"] for p in sch["places"]])
    pmount = np.array([p["mount"] for p in sch["places"]])[pidx]
    Cp = Cs[pidx]
    ez = Cp[:, :, 2]
    # Earth rate in the lab, then the table frame
    lat, nb = u["lat"], u["north"]
    om_lab = EARTH * np.array([math.cos(lat) * math.cos(nb), math.cos(lat) * math.sin(nb), math.sin(lat)])
    thr = theta * D2R
    c, s = np.cos(thr), np.sin(thr)
    om_t = np.stack([c * om_lab[0] + s * om_lab[1], -s * om_lab[0] + c * om_lab[1], np.full(n, om_lab[2])], 1)
    om_t[:, 2] += rate
    wb = np.einsum("nij,nj->ni", Cp, om_t)
    # specific force (g): gravity up, centripetal and tangential at the fixture's radius
    pr = u["radius"] * np.array([math.cos(u["r_az"]), math.sin(u["r_az"]), 0.0])
    w_rad, a_rad = rate * D2R, alpha * D2R
    f_t = np.zeros((n, 3))
    f_t[:, 0] = (-(w_rad**2) * pr[0] - a_rad * pr[1]) / G
    f_t[:, 1] = (-(w_rad**2) * pr[1] + a_rad * pr[0]) / G
    f_t[:, 2] = 1.0
    fb = np.einsum("nij,nj->ni", Cp, f_t)
    on_table = np.ones(n, dtype=bool)
    # the person re-mounting the unit: constant-axis moves through random orientations
    for h in sch["handl"]:
        i0, i1 = np.searchsorted(t, [h["t_lift"], h["t_place"]])
        if i1 <= i0:
            continue
        on_table[i0:i1] = False
        th_h = float(np.interp(h["t_lift"], t, theta)) * D2R
        Rz_t = _rz(th_h).T
        rots = (
            [sch["places"][h["pl"] - 1]["C"] @ Rz_t] + list(h["mids"]) + [sch["places"][h["pl"]]["C"] @ Rz_t]
        )
        tt = t[i0:i1]
        w_h = np.zeros((tt.size, 3))
        R_h = np.repeat(rots[0][None], tt.size, 0)
        for mi, (ts_, d) in enumerate(h["moves"]):
            Ra, Rb = rots[mi], rots[mi + 1]
            rv = Rotation.from_matrix(Rb @ Ra.T).as_rotvec()
            phi = float(np.linalg.norm(rv))
            ax = -rv / phi if phi > 0 else np.array([0.0, 0.0, 1.0])
            sel = (tt >= ts_) & (tt < ts_ + d)
            x = (tt[sel] - ts_) / d
            ph = phi * (x - np.sin(2 * math.pi * x) / (2 * math.pi))
            dph = phi / d * (1 - np.cos(2 * math.pi * x))
            R_h[sel] = Rotation.from_rotvec(-ph[:, None] * ax).as_matrix() @ Ra
            w_h[sel] = dph[:, None] * ax / D2R
            R_h[tt >= ts_ + d] = Rb
        trem = lfilter(
            [1 - math.exp(-1 / (0.12 * fs))],
            [1, -math.exp(-1 / (0.12 * fs))],
            rng.standard_normal((tt.size, 3)),
            axis=0,
        )
        trem *= u["tremor"] / max(float(np.std(trem)), 1e-9)
        wb[i0:i1] = w_h + trem + np.einsum("nij,j->ni", R_h, om_lab)
        fb[i0:i1] = R_h[:, :, 2] + 0.03 * rng.standard_normal((tt.size, 3))
    # temperatures at the samples
    Tdie = np.interp(t, tg, th["die"])
    Tcase = np.interp(t, tg, th["case"])
    sen = u["sensor"]
    if sen["mode"] == "die":
        node_g = th["die"]
    elif sen["mode"] == "lag":
        node_g = th["sens_lag"]
    else:
        node_g = th["die"] + sen["kappa"] * (th["case"] - th["die"])
    if sen["update"] > 0:
        slot = np.floor(t / sen["update"]).astype(np.int64)
        ts_slot = slot * sen["update"]
        noise = rng.standard_normal(int(slot.max()) + 2)[slot] * sen["noise"]
        node = np.interp(ts_slot, tg, node_g)
    else:
        node = np.interp(t, tg, node_g)
        noise = rng.standard_normal(n) * sen["noise"]
    Tlog = np.round((sen["offset"] + sen["gain"] * node + noise) / sen["q"]) * sen["q"]
    # power-ons and time since power-on
    pons = np.array([p[0] for p in sch["power"]])
    pon_idx = np.searchsorted(pons, t, side="right") - 1
    ton = t - pons[pon_idx]
    # bias instability on the 1 s grid
    sig_bi = u["k_bi"] * u["wf"]
    bi_g = np.zeros((tg.size, 3))
    for ax in range(3):
        sg = sig_bi * u["bi_axis"][ax]
        if u["bi_kind"] == "gm":
            bi_g[:, ax] = _gm(rng, tg.size, sg, u["bi_tau"])
        else:
            for tau in u["bi_taus"]:
                bi_g[:, ax] += _gm(rng, tg.size, sg / math.sqrt(len(u["bi_taus"])), tau)
    bi = np.stack([np.interp(t, tg, bi_g[:, a]) for a in range(3)], 1)
    b_on = rng.normal(0, u["k_rep"] * u["wf"], (pons.size, 3))[pon_idx]
    # the output without any effect (analog)
    dT = Tdie - 25.0
    K0, K1, K2 = u["K"]
    Kn = K0[None] + K1[None] * dT[:, None, None] + K2[None] * (dT**2)[:, None, None]
    B0, B1, B2, B3 = u["B"]
    Bn = B0[None] + B1[None] * dT[:, None] + B2[None] * (dT**2)[:, None] + B3[None] * (dT**3)[:, None]
    white = rng.standard_normal((n, 3)) * (u["arw"] * math.sqrt(fs))[None]
    base = np.einsum("nij,nj->ni", Kn, wb) + Bn + b_on + bi + white
    # accelerometer
    acc = None
    if u["accel"]:
        acc = (
            fb @ (np.eye(3) + u["acc_S"]).T
            + u["acc_bias"][None]
            + u["acc_noise"] * rng.standard_normal((n, 3))
        )
    # mount labels
    lt = np.array([x[0] for x in sch["labels"]])
    lm = np.array([x[1] for x in sch["labels"]])
    mlab = lm[np.searchsorted(lt, t, side="right") - 1]
    hand_rows = np.flatnonzero(~on_table)
    return dict(
        P=P,
        sch=sch,
        t=t,
        k=kidx,
        fs=fs,
        ref=ref,
        rate=rate,
        wb=wb,
        fb=fb,
        ez=ez,
        pidx=pidx,
        pmount=pmount,
        on_table=on_table,
        Tdie=Tdie,
        Tcase=Tcase,
        Tlog=Tlog,
        ton=ton,
        base=base,
        acc=acc,
        mlab=mlab,
        hand_rows=hand_rows,
        tg=tg,
        die_g=th["die"],
        case_g=th["case"],
    )


# ---------------------------------------------------------------------------------------------
# the effect families: shape at a = 1 (deg/s per sample); some also move the accelerometer
def draw_effect(rng, fam, u, sessions):
    p: dict = {}
    sgn = rng.choice([-1.0, 1.0], 3)
    mag = rng.uniform(0.4, 1.0, 3)
    mag[int(rng.integers(0, 3))] = 1.0
    p["u"] = sgn * mag
    if fam == "cubic_sf":
        p["beta"] = rng.uniform(-0.008, 0.008, 3)
    elif fam == "rate2_cross":
        U = rng.normal(0, 1, (3, 3))
        np.fill_diagonal(U, 0.0)
        p["U"] = U / np.abs(U).max()
    elif fam == "g_sens":
        Gm = rng.normal(0, 1, (3, 3))
        A = rng.normal(0, 1, (3, 3, 3))
        A = 0.5 * (A + A.transpose(0, 2, 1))
        p["G"] = Gm / np.abs(Gm).max()
        p["A"] = float(rng.uniform(0.05, 0.4)) * A / np.abs(A).max()
    elif fam == "warmup":
        p["tau1"] = float(_lu(rng, 3, 20)) * 60.0
        p["tau2"] = float(_lu(rng, 20, 90)) * 60.0
        p["rho"] = float(rng.uniform(0.3, 0.9))
        p["kappa"] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.3, 1.5, 3)
    elif fam == "charging":
        p["tau"] = float(_lu(rng, 1, 15)) * 60.0
    elif fam == "hysteresis":
        p["width"] = float(_lu(rng, 3, 15))
        p["s0"] = rng.uniform(-1, 1, 3).tolist()
    elif fam == "lut_steps":
        p["step"] = float(_pick(rng, (5.0, 8.0, 10.0, 12.5, 16.0)))
        p["phase"] = float(rng.uniform(0, p["step"]))
        p["sw"] = float(rng.uniform(0.1, 0.4))
        p["v"] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.3, 1.5, 3)
        p["eb"] = rng.uniform(-0.25, 0.25, (64, 3))
        p["es"] = rng.uniform(-0.25, 0.25, (64, 3))
    elif fam == "popcorn":
        n_src = int(rng.integers(1, 3))
        src = []
        for _ in range(n_src):
            w = rng.uniform(0, 0.3, 3) * rng.choice([-1.0, 1.0], 3)
            w[int(rng.integers(0, 3))] = float(rng.choice([-1.0, 1.0]))
            src.append(dict(w=w, d0=float(_lu(rng, 5, 90)) * 60.0, d1=float(_lu(rng, 5, 90)) * 60.0))
        p["src"] = src
        p["seeds"] = [int(x) for x in rng.integers(0, 2**31, 3)]
    elif fam == "aging":
        dK = np.zeros((3, 3))
        dK[np.diag_indices(3)] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.4, 1.0, 3)
        off = ~np.eye(3, dtype=bool)
        dK[off] = rng.normal(0, 0.3, 6)
        p["dK"] = dK / np.abs(np.diag(dK)).max()
        v = rng.normal(0, 1, 3)
        p["dB"] = u["top"] * float(rng.uniform(0.02, 0.15)) * v / np.linalg.norm(v)
        p["age0"] = float(rng.uniform(1, 15))
        p["tau_a"] = float(_lu(rng, 2, 30))
    elif fam == "fixture_debris":
        tilts = []
        for S in sessions:
            used = sorted({int(m) for m in np.unique(S["pmount"])})
            while True:
                dirty = {f: rng.random() < 0.4 for f in range(6)}
                if any(dirty[f] for f in used):
                    break
            d = np.zeros((6, 3))
            for f in range(6):
                if dirty[f]:
                    ax = f // 2
                    perp = [a for a in range(3) if a != ax]
                    ang = rng.uniform(0, 2 * math.pi)
                    d[f, perp[0]] = math.cos(ang)
                    d[f, perp[1]] = math.sin(ang)
                    d[f] *= rng.uniform(0.3, 1.0)
            tilts.append(d)
        p["tilts"] = tilts
    elif fam == "table_reference":
        while True:
            z = rng.uniform(-1, 1, len(sessions))
            if abs(z[-1] - z[0]) >= 0.6:
                break
        p["z"] = z.tolist()
    return p


def _duhem(T, width, s0):
    """Rate-independent hysteresis state in [-1, 1] driven by temperature T (1 s grid)."""
    dT = np.diff(T, prepend=T[0])
    tgt = np.sign(dT)
    a = np.exp(-np.abs(dT) / width)
    out = np.empty(T.size)
    s = s0
    al, tl = a.tolist(), tgt.tolist()
    for i in range(T.size):
        if tl[i] != 0.0:
            s = tl[i] + (s - tl[i]) * al[i]
        out[i] = s
    return out


def _lut_bins(T, step, phase, sw):
    """The ASIC's temperature bin with switching hysteresis (1 s grid)."""
    b = math.floor((T[0] - phase) / step)
    out = np.empty(T.size, dtype=np.int64)
    for i, x in enumerate(T.tolist()):
        lo = phase + b * step
        if x < lo - sw or x >= lo + step + sw:
            b = math.floor((x - phase) / step)
        out[i] = b
    return out


def _telegraph(rng, tg, d0, d1):
    """Two-level (0/1) random telegraph on the grid with mean dwell times d0, d1."""
    x = np.zeros(tg.size)
    t = 0.0
    state = int(rng.random() < d1 / (d0 + d1))
    t_end = tg[-1]
    while t < t_end:
        dwell = rng.exponential(d1 if state else d0)
        if state:
            i0, i1 = np.searchsorted(tg, [t, t + dwell])
            x[i0:i1] = 1.0
        t += dwell
        state = 1 - state
    return x


def effect_shape(fam, p, u, S, s_idx):
    """(delta gyro N x 3 at a = 1, delta accel N x 3 at a = 1 or None)."""
    top = u["top"]
    wb = S["wb"]
    if fam == "cubic_sf":
        x = wb / top
        return p["u"][None] * top * x**3 * (1 + p["beta"][None] * (S["Tdie"][:, None] - 25.0)), None
    if fam == "asym_sf":
        return p["u"][None] * np.abs(wb), None
    if fam == "rate2_cross":
        return (wb**2) @ p["U"].T / top, None
    if fam == "g_sens":
        f = S["fb"]
        return f @ p["G"].T + np.einsum("ijk,nj,nk->ni", p["A"], f, f), None
    if fam == "warmup":
        e1 = np.exp(-S["ton"] / p["tau1"])
        e2 = np.exp(-S["ton"] / p["tau2"])
        bias = p["u"][None] * (p["rho"] * e1 + (1 - p["rho"]) * e2)[:, None]
        return bias + (p["kappa"][None] / top) * wb * e1[:, None], None
    if fam == "gradient":
        rate_g = np.gradient(S["case_g"]) * 60.0  # °C/min on the 1 s grid
        return p["u"][None] * np.interp(S["t"], S["tg"], rate_g)[:, None], None
    if fam == "charging":
        x = np.minimum(np.abs(wb) / top, 2.0)
        q = np.stack([_lag(S["t"], x[:, a], p["tau"], 0.0) for a in range(3)], 1)
        return p["u"][None] * q, None
    if fam == "hysteresis":
        sg = _duhem(S["die_g"], p["width"], p["s0"][s_idx])
        return p["u"][None] * np.interp(S["t"], S["tg"], sg)[:, None], None
    if fam == "lut_steps":
        b_g = _lut_bins(S["die_g"], p["step"], p["phase"], p["sw"])
        saw_g = (S["die_g"] - p["phase"]) / p["step"] - (b_g + 0.5)
        i = np.clip(np.searchsorted(S["tg"], S["t"]), 0, S["tg"].size - 1)
        b, saw = b_g[i], np.interp(S["t"], S["tg"], saw_g)
        row = np.mod(b, 64)
        bias = p["u"][None] * (saw[:, None] + p["eb"][row])
        scale = (p["v"][None] / top) * (saw[:, None] + p["es"][row]) * wb
        return bias + scale, None
    if fam == "popcorn":
        rng = np.random.default_rng(p["seeds"][s_idx])
        out = np.zeros((S["t"].size, 3))
        for src in p["src"]:
            x = _telegraph(rng, S["tg"], src["d0"], src["d1"])
            out += np.interp(S["t"], S["tg"], x)[:, None] * src["w"][None]
        return out, None
    if fam == "aging":
        age = p["age0"] + S["P"]["day"]
        g = math.log1p(age / p["tau_a"]) / math.log1p(200.0 / p["tau_a"])
        return g * (wb @ p["dK"].T + p["dB"][None]), None
    if fam == "fixture_debris":
        d = p["tilts"][s_idx][S["pmount"]]
        d[~S["on_table"]] = 0.0
        K0 = u["K"][0]
        return (d * S["rate"][:, None]) @ K0.T, d
    if fam == "table_reference":
        K0 = u["K"][0]
        return p["z"][s_idx] * (S["ez"] * S["rate"][:, None]) @ K0.T, None
    raise KeyError(fam)


# ---------------------------------------------------------------------------------------------
# output word, hold means, the standard calibration and the reference floor
def quantise(u, x):
    if not u["quant"]:
        return x
    R = u["range"]
    lsb = 2 * R / 65536.0
    if float(np.min(u["arw"])) * math.sqrt(10.0) < 0.6 * lsb:
        lsb = 2 * R / 2**20  # 16 bits would not be dithered
    return np.clip(np.round(x / lsb) * lsb, -R, R - lsb)


def hold_table(S):
    """Hold boundaries (from the schedule), 1 s trimmed at each end -> sample slices and meta."""
    h = np.array([x[:5] for x in S["sch"]["holds"]], dtype=float)
    i0 = np.searchsorted(S["t"], h[:, 0] + 1.0)
    i1 = np.searchsorted(S["t"], h[:, 1] - 1.0)
    ok = i1 > i0 + 2
    e = AXIS_VEC[h[ok, 3].astype(int)] * h[ok, 2][:, None]
    return dict(i0=i0[ok], i1=i1[ok], x=e, group=h[ok, 4])


def hold_means(ht, y):
    cs = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0)])
    return (cs[ht["i1"]] - cs[ht["i0"]]) / (ht["i1"] - ht["i0"]).reshape((-1,) + (1,) * (y.ndim - 1))


def std_cal(ht, wbar, Tbar):
    """K, B (12 parameters) per set point by least squares on the hold means, at the mean
    logged temperature of the point's holds."""
    temps, Ks, Bs = [], [], []
    for g in np.unique(ht["group"]):
        m = ht["group"] == g
        X = np.concatenate([ht["x"][m], np.ones((int(m.sum()), 1))], 1)
        P, *_ = np.linalg.lstsq(X, wbar[m], rcond=None)
        Ks.append(P[:3].T)
        Bs.append(P[3])
        temps.append(float(np.mean(Tbar[m])))
    o = np.argsort(temps)
    return np.array(temps)[o], np.array(Ks)[o], np.array(Bs)[o]


def std_error(cal, ht, wbar, Tbar):
    temps, Ks, Bs = cal
    n = wbar.shape[0]
    Kh = np.empty((n, 3, 3))
    Bh = np.empty((n, 3))
    for i in range(3):
        Bh[:, i] = np.interp(Tbar, temps, Bs[:, i])
        for j in range(3):
            Kh[:, i, j] = np.interp(Tbar, temps, Ks[:, i, j])
    comp = np.linalg.solve(Kh, (wbar - Bh)[:, :, None])[:, :, 0]
    return float(np.sqrt(np.mean((comp - ht["x"]) ** 2)))


# ---------------------------------------------------------------------------------------------
# one unit
def _simulate_base(seed, fam, draw):
    rng = np.random.default_rng([seed, draw, 1])
    u = draw_unit(rng, fam)
    sp0 = draw_setpoints0(rng)
    sessions = []
    for s in range(3):
        P = draw_protocol(rng, u, s, sp0)
        sessions.append(simulate_session(rng, u, P))
    for S in sessions:
        S["ht"] = hold_table(S)
        S["hm_base"] = hold_means(S["ht"], quantise(u, S["base"]))
        S["hm_T"] = hold_means(S["ht"], S["Tlog"])
    cal = std_cal(sessions[0]["ht"], sessions[0]["hm_base"], sessions[0]["hm_T"])
    std = std_error(cal, sessions[2]["ht"], sessions[2]["hm_base"], sessions[2]["hm_T"])
    floor = max(u["wf"], std)
    return dict(u=u, sessions=sessions, std=std, floor=floor)


def _err_with(base, shapes_hm, a):
    S0, S2 = base["sessions"][0], base["sessions"][2]
    cal = std_cal(S0["ht"], S0["hm_base"] + a * shapes_hm[0], S0["hm_T"])
    return std_error(cal, S2["ht"], S2["hm_base"] + a * shapes_hm[2], S2["hm_T"])


def _miss(a, base, shapes_hm, target):
    return _err_with(base, shapes_hm, a) - target


def build_unit(spec):
    seed, fam, mult = int(spec["seed"]), spec["family"], spec["multiple"]
    if fam is None:
        base = _simulate_base(seed, None, 0)
        chosen = dict(base=base, a=0.0, p=None, ratio=base["std"] / base["floor"], capped=False, attempt=0)
    else:
        F = FAMILIES[fam]
        chosen = None
        base = None
        for att in range(N_ATTEMPTS):
            draw = att // 2  # attempts 0, 1; 2, 3; 4 share a nuisance/protocol draw
            if base is None or base["draw"] != draw:
                base = _simulate_base(seed, fam, draw)
                base["draw"] = draw
            rng = np.random.default_rng([seed, att, 2])
            p = draw_effect(rng, fam, base["u"], base["sessions"])
            hm = {}
            for s in (0, 2):
                S = base["sessions"][s]
                d, _ = effect_shape(fam, p, base["u"], S, s)
                hm[s] = hold_means(S["ht"], d)
            target = mult * base["floor"]
            bound = F["bound"]
            e_b = _err_with(base, hm, bound)
            if e_b < target:
                a, ratio, capped = bound, e_b / base["floor"], True
            else:
                a = brentq(_miss, 0.0, bound, args=(base, hm, target), xtol=bound * 1e-6)
                ratio, capped = _err_with(base, hm, a) / base["floor"], False
            cand = dict(base=base, a=float(a), p=p, ratio=float(ratio), capped=capped, attempt=att)
            if chosen is None or cand["ratio"] / mult > chosen["ratio"] / mult:
                chosen = cand
            if not capped:
                break
    return _finish(spec, chosen)


def _finish(spec, ch):
    base, fam, a, p = ch["base"], spec["family"], ch["a"], ch["p"]
    u = base["u"]
    out_sessions = []
    hm_final = {}
    for s, S in enumerate(base["sessions"]):
        y = S["base"]
        acc = S["acc"]
        if fam is not None:
            d, da = effect_shape(fam, p, u, S, s)
            y = y + a * d
            if da is not None and acc is not None:
                acc = acc + a * da @ (np.eye(3) + u["acc_S"]).T
        yq = quantise(u, y)
        hm_final[s] = hold_means(S["ht"], yq)
        out_sessions.append(_table_for(u, S, yq, acc, s))
    # the realised miss of the standard calibration on the logged (quantised) output
    S0, S2 = base["sessions"][0], base["sessions"][2]
    cal = std_cal(S0["ht"], hm_final[0], S0["hm_T"])
    realised = std_error(cal, S2["ht"], hm_final[2], S2["hm_T"])
    F = FAMILIES[fam] if fam is not None else None
    floor = base["floor"]
    truth = dict(
        uid=spec["uid"],
        family=fam,
        complete=fam is None,
        multiple=spec["multiple"],
        amplitude=a,
        bound=F["bound"] if F else None,
        capped=ch["capped"],
        attempt=ch["attempt"],
        ratio_target_solve=ch["ratio"],
        ratio_realised=realised / floor,
        floor=floor,
        white_floor=u["wf"],
        standard_floor=base["std"],
        threshold=1.2 * floor,
        reads=set(F["reads"]) if F else set(),
        acts=set(F["acts"]) if F else set(),
        reasons=set(F["reasons"]) if F else set(),
        carried=bool(F["carried"]) if F else False,
        device=u["device"],
        top=u["top"],
        six=u["six"],
        power_mode=u["power_mode"],
        accel=u["accel"],
        sessions=[
            dict(
                day=S["P"]["day"],
                fs=S["fs"],
                rows=int(S["t"].size),
                sp=S["P"]["sp"],
                sp_kind=S["P"]["sp_kind"],
                t_order=S["P"]["t_order"],
                r_order=S["P"]["r_order"],
                tkind=S["P"]["tkind"],
            )
            for S in base["sessions"]
        ],
    )
    return dict(truth=truth, sessions=out_sessions, unit=dict(device=u["device"], batch=u["batch"]))


def _table_for(u, S, y, acc, s):
    """One session's log as an Arrow table following the contract."""
    P = S["P"]
    n = S["t"].size
    ft = np.float32 if P["f32"] else np.float64
    date = u["date0"] + _dt.timedelta(days=P["day"])
    epoch0 = _dt.datetime(date.year, date.month, date.day, tzinfo=_dt.UTC).timestamp() + P["hour"] * 3600.0
    epoch0 = round(epoch0)
    gy = y.copy()
    ref = S["ref"].copy()
    temp = S["Tlog"].copy()
    if P["nan_rows"] and S["hand_rows"].size:
        rng = np.random.default_rng([int(epoch0), s, 5])
        rows = rng.choice(S["hand_rows"], size=min(P["nan_rows"], S["hand_rows"].size), replace=False)
        gy[rows, int(rng.integers(0, 3))] = np.nan
        temp[rows[:1]] = np.nan
    if P["rad"]:
        gy = gy * D2R
        ref = ref * D2R
    cols = {}
    kind = P["tkind"]
    if kind == "float0":
        t_col = pa.array(S["t"], pa.float64())
    elif kind == "epoch":
        t_col = pa.array(epoch0 + S["t"], pa.float64())
    else:
        ns = np.int64(epoch0) * 1_000_000_000 + np.round(S["t"] * 1e9).astype(np.int64)
        if kind == "ts_ns_utc":
            t_col = pa.array(ns, pa.timestamp("ns", tz="UTC"))
        elif kind == "ts_ms_local":
            t_col = pa.array(np.round(ns / 1e6).astype(np.int64), pa.timestamp("ms", tz="Europe/Berlin"))
        else:
            t_col = pa.array(np.round(ns / 1e3).astype(np.int64), pa.timestamp("us"))
    cols["t"] = t_col
    for i, a in enumerate("xyz"):
        cols[f"gyro_{a}"] = pa.array(gy[:, i].astype(ft))
    cols["temp"] = pa.array(temp.astype(ft))
    cols["ref_rate"] = pa.array(ref.astype(ft))
    if P["mountcol"] != "none":
        lab = np.array(MOUNTS, dtype=object)[S["mlab"]]
        arr = pa.array(lab.tolist(), pa.string())
        cols["mount"] = arr.dictionary_encode() if P["mountcol"] == "dictionary" else arr
    if u["accel"] and acc is not None:
        a_q = acc if u["acc_q"] == 0 else np.round(acc / u["acc_q"]) * u["acc_q"]
        for i, ax in enumerate("xyz"):
            cols[f"accel_{ax}"] = pa.array(a_q[:, i].astype(ft))
    if P["extra"] == "frame":
        cols["frame"] = pa.array(S["k"].astype(np.uint32))
    else:
        cols["status"] = pa.array(np.where(S["on_table"], 0, 3).astype(np.int8))
    table = pa.table(cols)
    meta = {"rig": "turntable-chamber"}
    if P["rad"]:
        meta["gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})
    table = table.replace_schema_metadata(meta)
    return dict(t=np.asarray(S["t"]), table=table, date=date.isoformat(), rows=n)


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    dev, batch = built["unit"]["device"], built["unit"]["batch"]
    paths, lines = [], ["device\tbatch\tsession\tprotocol\tpath"]
    for s, ss in enumerate(built["sessions"]):
        name = f"{dev}_{ss['date']}_s{s}.parquet"
        path = os.path.join(folder, name)
        pq.write_table(ss["table"], path)
        paths.append(path)
        lines.append(f"{dev}\t{batch}\t{ss['date']}\tturntable\t{name}")
    with open(os.path.join(folder, "devices.tsv"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return paths


# ---------------------------------------------------------------------------------------------
# contract validator
_FLOATS = (pa.float32(), pa.float64())


def validate_log(path):
    """Problems of one rig log against the contract (empty list: it follows it)."""
    probs = []
    try:
        tab = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        return [f"unreadable parquet: {exc}"]
    names = tab.schema.names
    if len(set(names)) != len(names):
        probs.append("duplicate column names")
    for c in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if c not in names:
            probs.append(f"missing required column {c}")
    if probs:
        return probs
    if tab.num_rows == 0:
        return ["no rows"]
    ty = tab.schema.field("t").type
    if ty == pa.float64():
        tv = tab.column("t").to_numpy()
        if not np.all(np.isfinite(tv)):
            probs.append("t not finite")
    elif pa.types.is_timestamp(ty):
        tv = tab.column("t").cast(pa.int64()).to_numpy()
    else:
        probs.append(f"t has type {ty}")
        tv = None
    if tab.column("t").null_count:
        probs.append("t has nulls")
    if tv is not None and tv.size > 1 and not np.all(np.diff(tv) > 0):
        probs.append("t not strictly increasing")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
        if tab.schema.field(c).type not in _FLOATS:
            probs.append(f"{c} has type {tab.schema.field(c).type}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in names]
    if acc and len(acc) != 3:
        probs.append("accelerometer columns incomplete")
    for c in acc:
        if tab.schema.field(c).type not in _FLOATS:
            probs.append(f"{c} has type {tab.schema.field(c).type}")
    if "mount" in names:
        mt = tab.schema.field("mount").type
        col = tab.column("mount")
        if pa.types.is_dictionary(mt):
            if not (pa.types.is_string(mt.value_type) or pa.types.is_large_string(mt.value_type)):
                probs.append("mount dictionary of non-strings")
            col = col.cast(pa.string())
        elif not (pa.types.is_string(mt) or pa.types.is_large_string(mt)):
            probs.append(f"mount has type {mt}")
        vals = set(col.drop_null().unique().to_pylist())
        if not vals <= set(MOUNTS):
            probs.append(f"mount words outside the contract: {sorted(vals - set(MOUNTS))[:3]}")
    meta = tab.schema.metadata or {}
    if b"gyrocal.units" in meta:
        try:
            um = json.loads(meta[b"gyrocal.units"])
            if not isinstance(um, dict) or not set(um) <= {"gyro", "ref_rate"}:
                probs.append("gyrocal.units: unknown keys")
            elif not set(um.values()) <= {"deg/s", "rad/s"}:
                probs.append("gyrocal.units: unknown units")
        except ValueError:
            probs.append("gyrocal.units is not JSON")
    ref = tab.column("ref_rate").to_numpy(zero_copy_only=False)
    if not np.any(np.nan_to_num(ref) != 0):
        probs.append("ref_rate never turns")
    return probs


def validate_manifest(folder):
    probs = []
    path = os.path.join(folder, "devices.tsv")
    with open(path) as fh:
        rows = [ln.rstrip("\n").split("\t") for ln in fh if ln.strip()]
    if rows[0] != ["device", "batch", "session", "protocol", "path"]:
        return ["manifest header"]
    for r in rows[1:]:
        if len(r) != 5 or not DEVICE_RE.match(r[0]) or r[3] != "turntable":
            probs.append(f"manifest row {r}")
            continue
        try:
            _dt.date.fromisoformat(r[2])
        except ValueError:
            probs.append(f"manifest date {r[2]}")
        if not os.path.exists(os.path.join(folder, r[4])):
            probs.append(f"manifest path {r[4]}")
    return probs


# ---------------------------------------------------------------------------------------------
# the set
def plan(units_per_family=3, seed=MASTER_SEED, quick=False):
    rng = np.random.default_rng([seed, 11])
    k = max(1, int(units_per_family))
    mults = [8.66] if k == 1 else [float(x) for x in np.geomspace(1.5, 50.0, k)]
    raw = [dict(family=f, multiple=m) for f in FAMILIES for m in mults]
    raw += [dict(family=None, multiple=None) for _ in range(N_COMPLETE)]
    order = rng.permutation(len(raw))
    seeds = rng.integers(0, 2**62, len(raw))
    specs = []
    for n, i in enumerate(order):
        specs.append(dict(raw[int(i)], uid=f"u{n + 1:02d}", seed=int(seeds[n])))
    if quick:
        pick, seen = [], set()
        comp = next(s for s in specs if s["family"] is None)
        for s in specs:
            if s["family"] is not None and s["family"] not in seen and len(pick) < 3:
                pick.append(s)
                seen.add(s["family"])
        specs = sorted(pick + [comp], key=lambda s: s["uid"])
    return specs


def _gen_one(args):
    spec, root = args
    t0 = time.process_time()
    built = build_unit(spec)
    folder = os.path.join(root, spec["uid"])
    paths = write_unit(built, folder)
    probs = [m for p in paths for m in validate_log(p)] + validate_manifest(folder)
    tr = built["truth"]
    return dict(
        uid=spec["uid"],
        rows=[int(ss["t"].size) for ss in built["sessions"]],
        problems=probs,
        capped=tr["capped"],
        complete=tr["complete"],
        cpu=time.process_time() - t0,
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description="generate and validate the eleventh sealed set")
    ap.add_argument("jobs", nargs="?", type=int, default=2)
    ap.add_argument("--seed", type=int, default=MASTER_SEED)
    ap.add_argument("--units-per-family", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--keep", default=None, help="keep the logs here")
    args = ap.parse_args(argv)
    for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(v, "1")
    specs = plan(args.units_per_family, args.seed, quick=args.quick)
    root = args.keep or tempfile.mkdtemp(prefix="sealed11_gen_")
    t0 = time.time()
    try:
        with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as ex:
            res = list(ex.map(_gen_one, [(s, root) for s in specs]))
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    wall = time.time() - t0
    rows = [r for x in res for r in x["rows"]]
    bad = [x["uid"] for x in res if x["problems"]]
    print(
        f"units {len(res)} ({sum(x['complete'] for x in res)} complete), logs {len(rows)}, "
        f"rows {min(rows)}-{max(rows)}, below their multiple at the bound: "
        f"{sum(x['capped'] for x in res)}"
    )
    print(
        f"contract validation: {len(rows) - 3 * len(bad)}/{len(rows)} logs pass; units with problems: {bad}"
    )
    for x in res:
        for m in x["problems"][:5]:
            print(f"  {x['uid']}: {m}")
    print(f"wall {wall:.0f} s, cpu {sum(x['cpu'] for x in res):.0f} s, jobs {args.jobs}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
