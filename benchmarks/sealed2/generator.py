"""Sealed benchmark 2: a simulator of turntable rig logs for one three-axis MEMS gyro unit.

SEALED. This file holds the effect families, their physics, their magnitudes and the truth the
runner scores against. It was written without reading the software it scores; the only
contact is the interface of ``benchmarks/judge.py::judge_unit``. Keep it away from the people
who tune that software.

Physical picture of one unit (every unit, with or without an effect)
--------------------------------------------------------------------
* output  w = K(T) . w_s + B(T) + b_on + b_gm(t) + n(t)  (+ the family's effect)
  - K(T): scale (diagonal, quadratic in T) and misalignment / non-orthogonality
    (off-diagonal, linear in T); B(T): bias, quadratic in T.  T is the die temperature.
  - b_on: turn-on bias, a new draw at every power-on (session), 0.5-1.0 x the hold-mean floor
    (a few deg/h: a good tactical-grade MEMS repeatability).
  - b_gm: bias instability, first-order Gauss-Markov, 0.3-0.6 x the floor, tau 150-400 s.
  - n: white rate noise, ARW 0.0020-0.0040 deg/s/sqrt(Hz) (0.12-0.24 deg/sqrt(h)).
* temperature: chamber air follows set points (ramped, ripple, a small pull towards ambient
  while the door is open to re-mount), the die follows the air through a first-order lag of
  6-10 min plus self-heating; the temp column is the die sensor (offset, noise, 1/64 degC
  steps).  Soaks are long enough that only a small thermal settling is left in the holds.
* turntable: a chamber on a single-axis rate table, axis up. The unit sits in a cube jig
  (dowel-pinned, so its seating in the jig repeats) at radius r from the table axis; three
  mounts (one per sensor axis, signs drawn) or six. Holds at constant rate in both directions
  (Table 2 magnitudes), ramps at constant angular acceleration, the reference is the table's
  encoder rate. Between mounts a person opens the chamber and re-mounts the cube: real motion
  while ref_rate is 0.
* accelerometer (most units): specific force = 1 g along the table axis plus the centripetal
  term w^2 r towards the table axis, bias and noise.
* protocols: five set points 20 degC apart, visited in descending, shuffled, zigzag or
  revisited orders (never ascending); rates in descending, alternating, shuffled or zigzag
  orders (never ascending; 0 never first or last); each session of a unit uses another order.
  Only the last minutes of each soak are logged (logger paused before); t is the unit's
  uptime in seconds.

How the nuisances are to be judged (physics): every one of them is present in every unit and
is no effect. White noise and bias instability are what the floor is made of. The turn-on bias
is a small session-to-session constant at the unit's repeatability level, present on every
MEMS gyro: a complete unit must be judged ``quiet`` (a fix, or ``unit changed``, is a false
alarm). Thermal settling and the door-open dips are followed by the die's own temperature
sensor, so the standard model ``K(T), B(T)`` evaluated at each hold's temperature explains them.

Effect families (each a separate physics, none in the standard per-temperature model)
------------------------------------------------------------------------------------
aniso        anisoelastic (g-squared) sensitivity: bias proportional to products of specific
             force components; on the table the product of gravity (along the mount axis) and
             the centripetal force of the off-axis jig makes it even in rate and mount-dependent.
             A term reading the accelerometer carries it.          reads accel, acts on bias
dTdt_scale   thermoelastic transient: scale factor proportional to the die's rate of
             temperature change (short soaks 15-25 min, zigzag steps; the unit's bias is
             compensated on chip, so its residual tempco is small).   reads thermal, scale
approach_tilt  die-attach hysteresis: misalignment depends on whether the set point was reached
             heating or cooling (play operator, 4 degC wide).  s0 approaches (almost) all points
             from one side, s1/s2 from mixed sides.  reads thermal, cross-axis; or no_sensor_term
             "direction of approach" (s0 alone cannot calibrate the other branch).
isolator     the sensor block sits on elastomer isolators: the centripetal force of the off-axis
             jig tilts it outwards by C*a_c, a cross-axis error ~ w^3. reads rate/accel, cross-axis
charging     dielectric charging: each axis's scale drifts with time since power-on,
             A(1-exp(-t/tau)), tau 1.5-3 h; t is the uptime.       reads time, scale
shock        the unit was dropped after s0: one axis's sense direction and scale shifted
             (non-rigid, so not a re-seating); s1 and s2 share the new state.
             no_sensor_term "unit changed"
ref_clock    the rig's encoder timebase was off by a common ppm error, in s0 only or in s1 and
             s2: every axis's scale moves by the same ratio, no cross-axis. no_sensor_term "lab"
burr         six-mount units: a burr on one cube face tilts the cube whenever it rests on that
             face, the same in every session.  no_sensor_term "mounting" (not a property of the
             sensor), or a fix that reads the mount and acts on cross-axis.
popcorn      random telegraph (burst) noise on one or two axes' bias, dwell minutes, a new
             realisation each session. no_sensor_term "slow noise"
range_switch firmware auto-ranging: above ~260-290 deg/s an axis switches to its high range,
             whose scale (and a little bias) differ.              reads rate, acts on scale/bias

Magnitude: each effect unit is scaled so that the extra RMS hold-mean error it causes on
session 2 after the standard calibration of session 0 (deterministic part: the same run with
and without the effect) is rho x the true hold-mean floor, rho log-uniform in [1.5, 8.7] for
the first unit of a family and [8.7, 50] for the second (more units alternate the strata).

Truth and threshold (see README for the general terms): floor = sqrt(mean_axes ARW^2 / T),
T the hold length less 1 s at each end; complete = RMS hold-mean error on s2 of the standard
calibration of s0 (12 parameters per set point, linear interpolation in temperature, applied
at each hold's temperature), effect removed, same noise; threshold = 1.2 x max(floor, complete).
"""
from __future__ import annotations

import json
import math
import os
import sys

import numpy as np

FS = 50.0            # Hz, logged sample rate
G0 = 9.80665
AMBIENT = 23.0
TRIM = 1.0           # s trimmed at each end of a hold for hold means
D2R = math.pi / 180.0

# ------------------------------------------------------------------------- truth table
# reads / acts: the right story for a fix; reasons: right no_sensor_term reasons;
# reason_ok: a right reason counts as a success (no sensor term can carry it from s0).
FAMILIES = {
    "aniso":         dict(reads={"accel"}, acts={"bias"}, reasons=set(), reason_ok=False),
    "dTdt_scale":    dict(reads={"thermal"}, acts={"scale"}, reasons=set(), reason_ok=False),
    "approach_tilt": dict(reads={"thermal"}, acts={"cross-axis"},
                          reasons={"direction of approach"}, reason_ok=True),
    "isolator":      dict(reads={"rate", "accel"}, acts={"cross-axis"}, reasons=set(),
                          reason_ok=False),
    "charging":      dict(reads={"time"}, acts={"scale"}, reasons=set(), reason_ok=False),
    "shock":         dict(reads=set(), acts=set(), reasons={"unit changed"}, reason_ok=True),
    "ref_clock":     dict(reads=set(), acts=set(), reasons={"lab"}, reason_ok=True),
    "burr":          dict(reads={"mount"}, acts={"cross-axis"}, reasons={"mounting"},
                          reason_ok=True),
    "popcorn":       dict(reads=set(), acts=set(), reasons={"slow noise"}, reason_ok=True),
    "range_switch":  dict(reads={"rate"}, acts={"scale", "bias"}, reasons=set(),
                          reason_ok=False),
}
FAMILY_ORDER = list(FAMILIES)
RHO_LO, RHO_MID, RHO_HI = 1.5, math.sqrt(1.5 * 50.0), 50.0

T_ORDERS = ("descending", "shuffled", "zigzag", "revisit")
R_ORDERS = ("descending", "alternating", "shuffled", "zigzag")
AXIS_NAMES = "xyz"


# ------------------------------------------------------------------------- small helpers
def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _mount_label(axis, sign):
    return ("+" if sign > 0 else "-") + AXIS_NAMES[axis]


def _seed_for(master, *keys):
    return np.random.SeedSequence([int(master) & 0xFFFFFFFF] + [int(k) for k in keys])


# ------------------------------------------------------------------------- the unit
def make_sensor(rng, hold_s):
    arw = rng.uniform(0.0020, 0.0040) * rng.uniform(0.85, 1.15, 3)
    floor = float(np.sqrt(np.mean(arw ** 2) / (hold_s - 2 * TRIM)))
    off = np.ones((3, 3)) - np.eye(3)
    return dict(
        arw=arw, floor=floor,
        K0=np.eye(3) + np.diag(rng.normal(0, 0.004, 3)) + off * rng.normal(0, 0.003, (3, 3)),
        K1=np.diag(rng.normal(0, 80e-6, 3)) + off * rng.normal(0, 4e-6, (3, 3)),
        K2=np.diag(rng.normal(0, 0.6e-6, 3)),
        B0=rng.normal(0, 0.3, 3), B1=rng.normal(0, 0.008, 3), B2=rng.normal(0, 6e-5, 3),
        R0=np.eye(3) + _skew(rng.normal(0, 2e-3, 3)),
        tau_th=rng.uniform(6, 10) * 60.0, self_heat=rng.uniform(2.0, 4.0),
        ts_off=rng.normal(0, 0.5),
        bi_sigma=floor * rng.uniform(0.3, 0.6), bi_tau=rng.uniform(150, 400),
        on_sigma=floor * rng.uniform(0.5, 1.0),
        acc_bias=rng.normal(0, 0.004, 3), acc_noise=0.002,
    )


def make_protocol(rng, family, six=False):
    lo = float(rng.choice([-40.0, -30.0, -20.0]))
    grid = lo + 20.0 * np.arange(5)
    extra = list(rng.choice([0.1, 1.0, 50.0, 150.0, 200.0, 250.0], 2, replace=False))
    mags = sorted({400.0, 300.0, 100.0, 10.0, *[float(x) for x in extra]})
    if six:
        mounts = [(a, s) for a in range(3) for s in (1, -1)]
    else:
        mounts = [(a, int(rng.choice([1, -1]))) for a in range(3)]
    return dict(
        grid=grid, mags=mags, mounts=mounts, hold_s=float(rng.uniform(16, 22)),
        alpha=float(rng.uniform(100, 300)), radius=float(rng.uniform(0.08, 0.20)),
        phi=rng.uniform(0, 2 * np.pi, len(mounts)),
        soak_min=(15.0, 25.0) if family == "dTdt_scale" else (35.0, 55.0),
        tail_s=240.0, chamber_rate=float(rng.uniform(1.5, 3.0)),  # degC/min
        door_frac=float(rng.uniform(0.02, 0.05)),
    )


def temp_order(rng, kind, n=5):
    idx = list(range(n))
    if kind == "descending":
        return idx[::-1]
    if kind == "zigzag":
        pats = [[0, 4, 1, 3, 2], [4, 0, 3, 1, 2], [2, 4, 0, 3, 1], [2, 0, 4, 1, 3], [1, 4, 0, 3, 2]]
        return list(pats[rng.integers(len(pats))])
    if kind == "revisit":
        p = list(rng.permutation(n))
        while p == idx:
            p = list(rng.permutation(n))
        return p + [p[int(rng.integers(0, n - 2))]]
    p = list(rng.permutation(n))
    while p == idx:
        p = list(rng.permutation(n))
    return p


def rate_order(rng, kind, mags):
    vals = [m for m in mags] + [-m for m in mags]
    if kind == "descending":
        seq = sorted(vals, reverse=True)
    elif kind == "alternating":
        seq = []
        for m in sorted(mags, reverse=True):
            seq += [m, -m] if rng.random() < 0.5 else [-m, m]
    elif kind == "zigzag":
        srt = sorted(vals, key=abs)
        seq = []
        while srt:
            seq.append(srt.pop(0))
            if srt:
                seq.append(srt.pop(-1))
    else:
        seq = list(rng.permutation(vals))
    mid = len(seq) // 2 + int(rng.integers(-2, 3))
    seq.insert(max(1, min(len(seq) - 1, mid)), 0.0)
    return [float(v) for v in seq]


def _rates_of(sess, rng):
    """The rate sequence of one mount: fixed for the session, or drawn anew when shuffled."""
    if sess["rkind"] == "shuffled":
        return rate_order(rng, "shuffled", sess["mags"])
    return list(sess["rseq"])


# ------------------------------------------------------------------------- one session
def simulate_session(unit, s_idx, rng):
    """Return the session's sample arrays split into base and unit-amplitude effect parts,
    and its hold table."""
    sen, pro, fam = unit["sensor"], unit["protocol"], unit["family"]
    sess = unit["sessions"][s_idx]
    grid = pro["grid"]
    mounts = pro["mounts"]
    nm = len(mounts)
    hold_s = pro["hold_s"]
    alpha = pro["alpha"]

    # ---------------- schedule: chamber events, logged segments, table knots, holds
    knots = [(0.0, 0.0)]
    segs = []       # (t0, t1, kind, mount_idx, next_mount_idx)
    holds = []      # dict(t0, t1, rate, mount, g)
    chamber = []    # (t_start_ramp, t_reach, T_from, T_set, t_end_visit)
    doors = []      # (t0, t1, T_set)
    t = 120.0
    C_now = AMBIENT
    cur_m = sess["first_mount"]
    for v, gi in enumerate(sess["torder"]):
        Ts = float(grid[gi])
        t_ramp = t
        t_reach = t + abs(Ts - C_now) / pro["chamber_rate"] * 60.0
        soak = sess["soak_s"][v]
        t_soak_end = t_reach + soak
        segs.append((t_soak_end - pro["tail_s"], t_soak_end, "rest", cur_m, cur_m))
        t = t_soak_end
        morder = list(rng.permutation(nm))
        for mi in morder:
            if mi != cur_m:
                dur = float(rng.uniform(30, 60))
                segs.append((t, t + dur, "handle", cur_m, mi))
                doors.append((t, t + dur, Ts))
                t += dur
                cur_m = mi
            t_block = t
            r_prev = 0.0
            t += 5.0
            knots.append((t, 0.0))
            for r in _rates_of(sess, rng):
                t += abs(r - r_prev) / alpha
                knots.append((t, r))
                holds.append(dict(t0=t, t1=t + hold_s, rate=r, mount=mi, g=gi, v=v))
                t += hold_s
                knots.append((t, r))
                r_prev = r
            t += abs(r_prev) / alpha
            knots.append((t, 0.0))
            t += 3.0
            segs.append((t_block, t, "block", mi, mi))
        chamber.append((t_ramp, t_reach, C_now, Ts))
        C_now = Ts
    t_end = t
    knots.append((t_end + 1.0, 0.0))
    knots_t = np.array([k[0] for k in knots])
    knots_r = np.array([k[1] for k in knots])

    # ---------------- thermal on a 1 s grid over the whole session
    tg = np.arange(0.0, t_end + 2.0, 1.0)
    C = np.full_like(tg, AMBIENT)
    starts = [c[0] for c in chamber] + [np.inf]
    for k, (t0c, t_reach, T_from, Ts) in enumerate(chamber):
        m = (tg >= t0c) & (tg < starts[k + 1])
        tt = tg[m]
        ramp = np.clip((tt - t0c) / max(t_reach - t0c, 1e-9), 0, 1)
        C[m] = T_from + (Ts - T_from) * ramp
        ph = rng.uniform(0, 2 * np.pi)
        C[m] += 0.03 * np.sin(2 * np.pi * tt / 300.0 + ph) * (tt >= t_reach)
    for (d0, d1, Ts) in doors:
        pull = (AMBIENT - Ts) * pro["door_frac"]
        on = (tg >= d0) & (tg <= d1)
        C[on] += pull * (1 - np.exp(-(tg[on] - d0) / 30.0))
        aft = tg > d1
        peak = pull * (1 - np.exp(-(d1 - d0) / 30.0))
        C[aft] += peak * np.exp(-(tg[aft] - d1) / 60.0)
    a_th = 1.0 - np.exp(-1.0 / sen["tau_th"])
    sh = sen["self_heat"] * (1 - np.exp(-tg / 300.0))
    Td = np.empty_like(tg)
    Td[0] = AMBIENT
    drive = C + sh
    for k in range(1, len(tg)):
        Td[k] = Td[k - 1] + (drive[k - 1] - Td[k - 1]) * a_th
    dTdt_g = np.gradient(Td) * 60.0     # degC/min

    # bias instability (Gauss-Markov) on the 1 s grid
    phi = np.exp(-1.0 / sen["bi_tau"])
    e = rng.normal(0, sen["bi_sigma"] * np.sqrt(1 - phi ** 2), (len(tg), 3))
    gm = np.empty((len(tg), 3))
    gm[0] = rng.normal(0, sen["bi_sigma"], 3)
    for k in range(1, len(tg)):
        gm[k] = phi * gm[k - 1] + e[k]
    b_on = sess["b_on"]

    # ---------------- samples
    ts, mid, handle = [], [], []
    for (a, b, kind, m0, m1) in segs:
        n = int(np.floor((b - a) * FS))
        ts.append(a + np.arange(n) / FS)
        mid.append(np.full(n, m0 if kind != "handle" else m1))
        handle.append(np.full(n, kind == "handle"))
    t_s = np.concatenate(ts)
    m_s = np.concatenate(mid).astype(int)
    h_s = np.concatenate(handle)
    assert np.all(np.diff(t_s) > 0)
    n = len(t_s)
    w_tab = np.interp(t_s, knots_t, knots_r)          # deg/s
    T_die = np.interp(t_s, tg, Td)
    dTdt = np.interp(t_s, tg, dTdt_g)

    # geometry per mount (sensor frame)
    u_nom = np.array([s * np.eye(3)[a] for (a, s) in mounts])
    u_true = (sen["R0"].T @ u_nom.T).T
    d_out = []
    for k, (a, _sign) in enumerate(mounts):
        b_, c_ = [i for i in range(3) if i != a]
        d_out.append(np.cos(pro["phi"][k]) * np.eye(3)[b_] + np.sin(pro["phi"][k]) * np.eye(3)[c_])
    d_out = (sen["R0"].T @ np.array(d_out).T).T
    u_s = u_true[m_s]
    d_s = d_out[m_s]

    # handling: hand rotations and gravity moving from the previous to the next mount
    w_hand = np.zeros((n, 3))
    f_grav = u_s.copy()
    for (a, b, kind, m0, m1) in segs:
        if kind != "handle":
            continue
        i0, i1 = np.searchsorted(t_s, [a, b])
        tt = t_s[i0:i1]
        for ax in range(3):
            for _ in range(int(rng.integers(2, 5))):
                c0 = rng.uniform(a + 5, b - 5)
                w_hand[i0:i1, ax] += rng.uniform(10, 60) * rng.choice([-1, 1]) * \
                    np.exp(-0.5 * ((tt - c0) / rng.uniform(0.8, 3.0)) ** 2)
        frac = np.clip((tt - a - 5) / max(b - a - 10, 1), 0, 1)[:, None]
        g = (1 - frac) * u_true[m0] + frac * u_true[m1]
        g /= np.linalg.norm(g, axis=1)[:, None]
        f_grav[i0:i1] = g + rng.normal(0, 0.03, (i1 - i0, 3))
    w_rad = (w_tab * D2R) ** 2
    f_true = f_grav - (w_rad * pro["radius"] / G0)[:, None] * d_s     # g, sensor frame
    w_s = u_s * w_tab[:, None] + w_hand                                 # true rate, sensor frame

    dT = T_die - 25.0
    K = sen["K0"][None] + sen["K1"][None] * dT[:, None, None] + \
        sen["K2"][None] * (dT ** 2)[:, None, None]
    B = sen["B0"][None] + sen["B1"][None] * dT[:, None] + sen["B2"][None] * (dT ** 2)[:, None]
    gyro = np.einsum("nij,nj->ni", K, w_s) + B + b_on[None] + \
        np.stack([np.interp(t_s, tg, gm[:, i]) for i in range(3)], 1) + \
        rng.normal(0, 1, (n, 3)) * (sen["arw"] * np.sqrt(FS))[None]
    acc = f_true + sen["acc_bias"][None] + rng.normal(0, sen["acc_noise"], (n, 3))
    temp = T_die + sen["ts_off"] + rng.normal(0, 0.01, n)
    temp = np.round(temp * 64.0) / 64.0

    # ---------------- the family's effect at unit amplitude
    eff = unit["effect"]
    dg = np.zeros((n, 3))       # gyro delta per unit amplitude
    da = np.zeros((n, 3))       # accel delta per unit amplitude
    dref = np.zeros(n)          # relative ref_rate delta per unit amplitude
    if fam == "aniso":
        prods = np.stack([f_true[:, 0] * f_true[:, 1], f_true[:, 0] * f_true[:, 2],
                          f_true[:, 1] * f_true[:, 2]], 1)
        dg = prods @ eff["c"].T
    elif fam == "dTdt_scale":
        dg = eff["kappa"][None] * dTdt[:, None] * w_s
    elif fam == "approach_tilt":
        width = 4.0
        x = np.empty_like(Td)
        x[0] = Td[0] + sess["p0"] * width
        for k in range(1, len(Td)):
            x[k] = min(max(x[k - 1], Td[k] - width), Td[k] + width)
        p = np.interp(t_s, tg, (Td - x) / width)          # +1 heating, -1 cooling
        dg = p[:, None] * (w_s @ eff["E"].T)
    elif fam == "isolator":
        theta = w_rad * pro["radius"] / G0                  # tilt per unit C (rad/g)
        dg = np.einsum("nij,nj->ni", K, -(theta * w_tab)[:, None] * d_s)
    elif fam == "charging":
        dg = eff["A"][None] * (1 - np.exp(-t_s / eff["tau"]))[:, None] * w_s
    elif fam == "shock":
        if s_idx >= 1:
            dg = w_s @ eff["dK"].T
    elif fam == "ref_clock":
        if s_idx in eff["bad"]:
            dref = np.full(n, eff["sign"])
    elif fam == "burr":
        on = (m_s == eff["mount"]) & ~h_s
        tilt = np.cross(eff["axis"], u_true[eff["mount"]])
        dg[on] = np.einsum("nij,nj->ni", K[on], tilt[None] * w_tab[on][:, None])
        da[on] = tilt[None]
    elif fam == "popcorn":
        lv = np.zeros((len(tg), 3))
        for ax in eff["axes"]:
            state, k = int(rng.integers(0, 2)), 0
            while k < len(tg):
                dwell = int(max(5, rng.exponential(eff["dwell"])))
                lv[k:k + dwell, ax] = state
                state = 1 - state
                k += dwell
        idx = np.clip(np.searchsorted(tg, t_s, side="right") - 1, 0, len(tg) - 1)
        dg = lv[idx] * eff["weights"][None]
    elif fam == "range_switch":
        hi = np.abs(w_s) > eff["R_sw"][None]
        dg = hi * (eff["delta"][None] * w_s + eff["beta"][None] * 100.0)

    # ---------------- hold table (sample index ranges of the trimmed windows)
    hw = []
    for h in holds:
        i0, i1 = np.searchsorted(t_s, [h["t0"] + TRIM, h["t1"] - TRIM])
        hw.append((i0, i1))
    hw = np.array(hw)

    labels = np.array([_mount_label(a, s) for (a, s) in mounts])
    return dict(
        t=t_s, gyro=gyro, dg=dg, acc=acc, da=da, temp=temp, ref=w_tab, dref=dref,
        mount_label=labels[m_s], holds=holds, hw=hw, u_nom=u_nom,
    )


# ------------------------------------------------------------------------- hold level
def hold_means(S, a):
    """Hold-level data of a session at effect amplitude a (what a standard calibration sees)."""
    cs = lambda x: np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, 0)])  # noqa: E731
    i0, i1 = S["hw"][:, 0], S["hw"][:, 1]
    cnt = (i1 - i0).astype(float)
    W = (cs(S["gyro"])[i1] - cs(S["gyro"])[i0] + a * (cs(S["dg"])[i1] - cs(S["dg"])[i0])) / cnt[:, None]
    ref_log = S["ref"] * (1.0 + a * S["dref"])
    R = (cs(ref_log)[i1] - cs(ref_log)[i0]) / cnt
    T = (cs(S["temp"])[i1] - cs(S["temp"])[i0]) / cnt
    u = np.array([S["u_nom"][h["mount"]] for h in S["holds"]])
    g = np.array([h["g"] for h in S["holds"]])
    return dict(W=W, ref=R, T=T, u=u, g=g)


def std_calibrate(H):
    pts = []
    for gi in np.unique(H["g"]):
        m = H["g"] == gi
        X = np.c_[H["u"][m] * H["ref"][m][:, None], np.ones(m.sum())]
        coef, *_ = np.linalg.lstsq(X, H["W"][m], rcond=None)
        pts.append((float(H["T"][m].mean()), coef[:3].T, coef[3]))
    pts.sort(key=lambda p: p[0])
    return (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]),
            np.array([p[2] for p in pts]))


def std_errors(cal, H):
    Ts, Ks, Bs = cal
    n = len(H["T"])
    Kf = Ks.reshape(len(Ts), 9)
    K = np.stack([np.interp(H["T"], Ts, Kf[:, j]) for j in range(9)], 1).reshape(n, 3, 3)
    B = np.stack([np.interp(H["T"], Ts, Bs[:, j]) for j in range(3)], 1)
    w = np.linalg.solve(K, (H["W"] - B)[:, :, None])[:, :, 0]
    return w - H["u"] * H["ref"][:, None]


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def s2_errors(S0, S2, a):
    return std_errors(std_calibrate(hold_means(S0, a)), hold_means(S2, a))


# ------------------------------------------------------------------------- planning
def plan(units_per_family=2, seed=20260514, quick=False, n_complete=None):
    """The list of unit specs (plain dicts). Unit ids do not reveal the family."""
    rng = np.random.default_rng(_seed_for(seed, 1))
    specs = []
    for fam in FAMILY_ORDER:
        for k in range(units_per_family):
            lo, hi = (RHO_LO, RHO_MID) if k % 2 == 0 else (RHO_MID, RHO_HI)
            rho = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            specs.append(dict(family=fam, rho=rho))
    nc = n_complete if n_complete is not None else max(4, units_per_family * 2 + 1)
    for k in range(nc):
        specs.append(dict(family=None, rho=0.0, variant=k))
    if quick:
        eff = [s for s in specs if s["family"]]
        pick = [eff[int(i)] for i in rng.choice(len(eff), 3, replace=False)]
        specs = pick + [s for s in specs if not s["family"]][:1]
    order = rng.permutation(len(specs))
    out = []
    for j, i in enumerate(order):
        s = dict(specs[i])
        s["uid"] = f"unit{j:02d}"
        s["seed"] = int(rng.integers(0, 2 ** 31 - 1))
        s["master"] = int(seed)
        out.append(s)
    return out


def _make_effect(rng, fam, pro):
    if fam == "aniso":
        c = rng.normal(0, 1, (3, 3))
        return dict(c=c / np.abs(c).max())
    if fam == "dTdt_scale":
        return dict(kappa=rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.0, 3))
    if fam == "approach_tilt":
        E = rng.normal(0, 1, (3, 3))
        np.fill_diagonal(E, 0.0)
        return dict(E=E / np.abs(E).max())
    if fam == "isolator":
        return dict()
    if fam == "charging":
        return dict(A=rng.choice([-1, 1], 3) * rng.uniform(0.4, 1.0, 3),
                    tau=float(rng.uniform(1.5, 3.0) * 3600))
    if fam == "shock":
        j = int(rng.integers(3))
        others = [i for i in range(3) if i != j]
        dK = np.zeros((3, 3))
        ang = rng.uniform(0, 2 * np.pi)
        dK[j, others[0]] = np.cos(ang)
        dK[j, others[1]] = np.sin(ang)
        dK[j, j] = rng.choice([-1, 1]) * rng.uniform(0.2, 0.5)
        return dict(dK=dK)
    if fam == "ref_clock":
        return dict(sign=float(rng.choice([-1, 1])),
                    bad=(0,) if rng.random() < 0.5 else (1, 2))
    if fam == "burr":
        m = int(rng.integers(len(pro["mounts"])))
        a, s = pro["mounts"][m]
        perp = [i for i in range(3) if i != a]
        ang = rng.uniform(0, 2 * np.pi)
        ax = np.cos(ang) * np.eye(3)[perp[0]] + np.sin(ang) * np.eye(3)[perp[1]]
        return dict(mount=m, axis=ax)
    if fam == "popcorn":
        k = int(rng.integers(1, 3))
        axes = list(rng.choice(3, k, replace=False))
        w = np.zeros(3)
        w[axes] = rng.choice([-1, 1], k) * rng.uniform(0.6, 1.0, k)
        return dict(axes=axes, weights=w, dwell=float(rng.uniform(120, 600)))
    if fam == "range_switch":
        return dict(R_sw=np.full(3, rng.uniform(260, 290)),
                    delta=rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.0, 3),
                    beta=rng.normal(0, 0.3, 3))
    return dict()


def make_unit(spec):
    rng = np.random.default_rng(_seed_for(spec["seed"], 7))
    fam = spec["family"]
    six = fam == "burr" or rng.random() < 0.15 or spec.get("variant") == 0
    pro = make_protocol(rng, fam, six=six)
    sen = make_sensor(rng, pro["hold_s"])
    if fam == "dTdt_scale":      # a unit with on-chip bias compensation: small residual tempco
        sen["B1"] = sen["B1"] * 0.2
        sen["B2"] = sen["B2"] * 0.2
    kinds = list(rng.permutation(T_ORDERS))[:3]
    rkinds = list(rng.permutation(R_ORDERS))[:3]
    if fam == "approach_tilt":
        kinds = ["descending", "zigzag", str(rng.choice(["shuffled", "revisit"]))]
    if fam == "dTdt_scale":
        kinds = ["zigzag", str(rng.choice(["shuffled", "revisit"])), "zigzag"]
    sessions = []
    for s in range(3):
        to = temp_order(rng, kinds[s])
        if s > 0:
            while to == sessions[0]["torder"]:
                to = temp_order(rng, kinds[s])
        rk = rkinds[s]
        sessions.append(dict(
            torder=to, tkind=str(kinds[s]), rkind=str(rk), mags=list(pro["mags"]),
            rseq=rate_order(rng, rk, pro["mags"]),
            soak_s=[float(rng.uniform(*pro["soak_min"]) * 60.0) for _ in to],
            first_mount=int(rng.integers(len(pro["mounts"]))),
            b_on=rng.normal(0, sen["on_sigma"], 3),
            p0=float(rng.choice([-1.0, 1.0])),
            seed=int(rng.integers(0, 2 ** 31 - 1)),
        ))
    effect = _make_effect(rng, fam, pro) if fam else {}
    unit = dict(spec=spec, family=fam, sensor=sen, protocol=pro, sessions=sessions,
                effect=effect,
                has_accel=(fam in ("aniso", "isolator")) or rng.random() < 0.75,
                has_mount=rng.random() < 0.5, rad=rng.random() < 0.1)
    # complete units cover the protocol variants: six mounts, no accelerometer, rad/s, mount column
    v = spec.get("variant")
    if v == 1:
        unit["has_accel"] = False
    elif v == 2:
        unit["rad"] = True
    elif v == 3:
        unit["has_mount"] = True
    return unit


def build_unit(spec):
    """Simulate the unit's three sessions, scale the effect to its target and compute truth."""
    unit = make_unit(spec)
    S = [simulate_session(unit, s, np.random.default_rng(unit["sessions"][s]["seed"]))
         for s in range(3)]
    floor = unit["sensor"]["floor"]
    e0 = s2_errors(S[0], S[2], 0.0)
    complete = _rms(e0)
    amp, excess = 0.0, 0.0
    if unit["family"]:
        target = spec["rho"] * floor
        a = 1e-4
        for _ in range(3):
            resp = _rms(s2_errors(S[0], S[2], a) - e0) / a
            if not np.isfinite(resp) or resp <= 0:
                raise RuntimeError("effect has no response on the unseen session")
            a = target / resp
        amp = a
        excess = _rms(s2_errors(S[0], S[2], amp) - e0)
    ref = max(floor, complete)
    F = FAMILIES.get(unit["family"], dict(reads=set(), acts=set(), reasons=set(), reason_ok=False))
    truth = dict(
        family=unit["family"] or "complete", complete=unit["family"] is None,
        floor=floor, complete_rms=complete, reference=ref, threshold=1.2 * ref,
        rho=spec["rho"], amplitude=amp, excess=excess,
        with_effect_rms=_rms(s2_errors(S[0], S[2], amp)) if unit["family"] else complete,
        reads=set(F["reads"]), acts=set(F["acts"]), reasons=set(F["reasons"]),
        reason_ok=bool(F["reason_ok"]), six=len(unit["protocol"]["mounts"]) == 6,
    )
    return dict(unit=unit, sessions=S, amp=amp, truth=truth)


# ------------------------------------------------------------------------- writing
def write_unit(built, folder):
    import pyarrow as pa
    import pyarrow.parquet as pq
    os.makedirs(folder, exist_ok=True)
    unit, a = built["unit"], built["amp"]
    paths = []
    for s, S in enumerate(built["sessions"]):
        gyro = S["gyro"] + a * S["dg"]
        ref = S["ref"] * (1.0 + a * S["dref"])
        scale = D2R if unit["rad"] else 1.0
        cols = {"t": pa.array(S["t"], pa.float64())}
        for i, ax in enumerate(AXIS_NAMES):
            cols[f"gyro_{ax}"] = pa.array((gyro[:, i] * scale).astype(np.float32))
        cols["temp"] = pa.array(S["temp"].astype(np.float32))
        cols["ref_rate"] = pa.array((ref * scale).astype(np.float32))
        if unit["has_accel"]:
            acc = S["acc"] + a * S["da"]
            for i, ax in enumerate(AXIS_NAMES):
                cols[f"accel_{ax}"] = pa.array(acc[:, i].astype(np.float32))
        if unit["has_mount"]:
            cols["mount"] = pa.array(S["mount_label"]).dictionary_encode()
        table = pa.table(cols)
        if unit["rad"]:
            table = table.replace_schema_metadata(
                {"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})})
        p = os.path.join(folder, f"s{s}.parquet")
        pq.write_table(table, p)
        paths.append(p)
    return paths


def selfcheck(units_per_family=2, seed=20260514):
    """Aggregate sanity only (no family names): every effect unit's excess on its target."""
    specs = plan(units_per_family, seed)
    bad = 0
    for sp in specs:
        tr = build_unit(sp)["truth"]
        if not tr["complete"] and abs(tr["excess"] / (tr["rho"] * tr["floor"]) - 1) > 0.05:
            bad += 1
    print(f"{len(specs)} units built; {bad} effect units off their target magnitude")
    return bad


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--selfcheck", action="store_true")
    ap.add_argument("--units-per-family", type=int, default=2)
    ap.add_argument("--seed", type=int, default=20260514)
    args = ap.parse_args()
    if args.selfcheck:
        sys.exit(1 if selfcheck(args.units_per_family, args.seed) else 0)
