"""Fourth sealed benchmark: a simulator of ``turntable`` rig logs (SEALED: not to be read by
whoever tunes the diagnosis).

Each unit is one physical three-axis MEMS gyro written as three sessions of the same sensor:
a fresh power-on, fresh noise, its own temperature order, mount order and rate order per
session.  A session is a chamber programme: power-on at lab ambient, then for every set point
a chamber ramp and a soak, then for each mount a series of constant-rate holds; between mounts
a person opens the chamber door and re-mounts the unit (real motion while the reference rate
is zero).  The physics of the sensor, the chamber, the table and the fixture is simulated on a
uniform sample grid and written as Parquet following ``/work/shared/spec/log-format.md``.

Every unit carries the nuisances of real turntable work: white rate noise, a little bias
instability, turn-on bias repeatability between sessions, a smooth temperature dependence of
bias, scale and misalignment, chamber ramps with overshoot and control wobble, thermal lag of
the unit behind the chamber air, self-heating, windage cooling at high table rates, door
openings at remounts, handling motion, micro-radian re-seating of the fixture, table
acceleration phases between holds, temperature-sensor offset, noise and quantisation, and on
some protocol variants an accelerometer with its own errors, logger pauses, a revisited set
point, a few NaN glitches, radian units or timestamp-typed time.

An effect is written as ``base + a * effect`` where ``effect`` is the family's signal at unit
amplitude and ``a`` is solved so that the RMS hold-mean error on session 2 of the standard
calibration of session 0 (12 parameters per set point, linear interpolation in the logged
temperature) equals a target multiple of the unit's reference floor.

Public entry points (used by ``run.py``): ``FAMILIES``, ``VARIANTS``, ``plan``,
``build_unit``, ``write_unit``.
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
from scipy.spatial.transform import Rotation

MASTER_SEED = 20260301
G0 = 9.80665
D2R = math.pi / 180.0
TRIM = 1.0                       # s trimmed at each end of a hold (reference floor, scoring)

# ----------------------------------------------------------------------------- truth tables
# reads / acts: what a right sensor-term story names; reasons: the right no_sensor_term word.
# For effects no sensor term can carry, empty reads/acts mean that no fix is a right story.
FAMILIES = {
    "scale_nonlinearity": dict(reads=("rate",), acts=("scale",), reasons=(), carried=True,
                               variants=("A", "B", "C", "D")),
    "g_sensitivity": dict(reads=("accel", "mount"), acts=("bias",), reasons=(), carried=True,
                          variants=("B", "D")),
    "thermal_gradient": dict(reads=("thermal",), acts=("bias",), reasons=(), carried=True,
                             variants=("A", "B", "C", "D")),
    "power_on_warmup": dict(reads=("time",), acts=("bias",), reasons=(), carried=True,
                            variants=("A", "B", "C", "D")),
    "clamp_relaxation": dict(reads=("time", "mount"), acts=("bias",), reasons=(), carried=True,
                             variants=("A", "B", "C", "D")),
    "rate_memory": dict(reads=("rate", "time"), acts=("bias",), reasons=(), carried=True,
                        variants=("A", "B", "C", "D")),
    "fixture_faces": dict(reads=("mount", "accel"), acts=("cross-axis",), reasons=(),
                          carried=True, variants=("B", "D")),
    "reference_rig": dict(reads=(), acts=(), reasons=("lab",), carried=False,
                          variants=("A", "B", "C", "D")),
    "reseating": dict(reads=(), acts=(), reasons=("mounting",), carried=False,
                      variants=("A", "C")),
    "unit_shift": dict(reads=(), acts=(), reasons=("unit changed",), carried=False,
                       variants=("A", "B", "C", "D")),
    "bias_wander": dict(reads=(), acts=(), reasons=("slow noise",), carried=False,
                        variants=("A", "B", "C", "D")),
    "midpoint_feature": dict(reads=("temperature",), acts=("bias", "scale"),
                             reasons=("between points",), carried=False, variants=("D",)),
    "thermal_hysteresis": dict(reads=("thermal",), acts=("bias",),
                               reasons=("direction of approach",), carried=False,
                               variants=("A", "B", "C")),
}

# ----------------------------------------------------------------------------- protocol variants
VARIANTS = {
    # three faces, no accelerometer, mount labels as strings, float seconds, float32, deg/s
    "A": dict(faces="plus3", accel=False, mount_col="string", t_type="float",
              dtype="float32", units="deg", fs=(5.0,), npts=(4, 6), nmag=(4, 5),
              hold=(24, 34), verify=False, revisit=False, gaps=False, nan=False,
              extra=False, quant_T=1.0 / 16, quant_gyro=True),
    # six faces, accelerometer, dictionary mount labels, timestamp time, float64
    "B": dict(faces="six", accel=True, mount_col="dictionary", t_type="timestamp",
              dtype="float64", units="deg", fs=(5.0,), npts=(4, 5), nmag=(3, 4),
              hold=(20, 28), verify=False, revisit=False, gaps=False, nan=False,
              extra=False, quant_T=1.0 / 256, quant_gyro=False),
    # three faces with mixed signs, no mount column, rad/s, logger pauses, revisits, glitches
    "C": dict(faces="mixed3", accel=False, mount_col=None, t_type="float",
              dtype="float32", units="rad", fs=(5.0, 10.0), npts=(4, 5), nmag=(4, 5),
              hold=(24, 34), verify=False, revisit=True, gaps=True, nan=True,
              extra=True, quant_T=1.0 / 16, quant_gyro=False),
    # four faces, accelerometer, later sessions at the temperatures between the first's points
    "D": dict(faces="four", accel=True, mount_col="string", t_type="float",
              dtype="float64", units="deg", fs=(5.0,), npts=(4, 5), nmag=(4, 5),
              hold=(24, 32), verify=True, revisit=False, gaps=False, nan=False,
              extra=False, quant_T=1.0 / 256, quant_gyro=False),
}

FACES_ALL = ("+x", "-x", "+y", "-y", "+z", "-z")
SMALL = (0.1, 0.2, 0.5, 1.0, 2.0)
MID = (5.0, 10.0, 20.0, 30.0, 50.0, 80.0)
LARGE = (100.0, 150.0, 200.0, 250.0, 300.0, 400.0)


# ============================================================================= helpers
def _lag(x, tau, dt, y0):
    """First-order lag (exact discretisation for a sample-held input)."""
    k = 1.0 - math.exp(-dt / tau)
    y, _ = lfilter([k], [1.0, -(1.0 - k)], x, zi=[(1.0 - k) * y0])
    return y


def _ar1(rng, n, tau, sigma, dt):
    """Gauss-Markov process with stationary standard deviation sigma."""
    phi = math.exp(-dt / tau)
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    y, _ = lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.standard_normal() * sigma])
    return y


def _face_vec(face):
    e = np.zeros(3)
    e["xyz".index(face[1])] = 1.0 if face[0] == "+" else -1.0
    return e


def _face_matrix(face, yaw):
    """M maps sensor-frame vectors to the table frame; its third row is the rig axis."""
    ax = "xyz".index(face[1])
    e = np.eye(3)
    r3 = _face_vec(face)
    a, b = e[(ax + 1) % 3], e[(ax + 2) % 3]
    r1 = math.cos(yaw) * a + math.sin(yaw) * b
    r2 = np.cross(r3, r1)
    return np.vstack([r1, r2, r3])


def _perp(v, u):
    return v - np.dot(v, u) * u


def _interp_err(x, y, xs):
    """|f - piecewise linear interpolant| of samples y(x) on the knots xs."""
    yk = np.interp(xs, x, y)
    return np.abs(y - np.interp(x, xs, yk))


# ============================================================================= plan
def plan(units_per_family=2, seed=MASTER_SEED, quick=False):
    """The seeded list of unit specs (family, variant, target ratio, seed)."""
    rng = np.random.default_rng(seed)
    specs = []
    lo, hi = math.log(1.6), math.log(50.0)
    for fam in sorted(FAMILIES):
        allowed = list(FAMILIES[fam]["variants"])
        order = [allowed[i] for i in rng.permutation(len(allowed))]
        for k in range(units_per_family):
            a = lo + (hi - lo) * k / units_per_family
            b = lo + (hi - lo) * (k + 1) / units_per_family
            specs.append(dict(family=fam, variant=order[k % len(order)],
                              target=float(math.exp(rng.uniform(a, b)))))
    for v in sorted(VARIANTS):
        specs.append(dict(family=None, variant=v, target=None))
    seeds = np.random.SeedSequence(seed).generate_state(len(specs), dtype=np.uint32)
    for s, sd in zip(specs, seeds):
        s["seed"] = int(sd)
    perm = rng.permutation(len(specs))
    specs = [specs[i] for i in perm]
    for i, s in enumerate(specs):
        s["uid"] = f"u{i:02d}"
    if quick:
        comp = [s for s in specs if s["family"] is None][:1]
        carried = [s for s in specs if s["family"] and FAMILIES[s["family"]]["carried"]][:2]
        other = [s for s in specs if s["family"] and not FAMILIES[s["family"]]["carried"]][:1]
        keep = {s["uid"] for s in comp + carried + other}
        specs = [s for s in specs if s["uid"] in keep]
    return specs


# ============================================================================= unit draw
def _draw_unit(rng, variant):
    V = VARIANTS[variant]
    u = {"variant": variant}
    u["fs"] = fs = float(rng.choice(V["fs"]))
    u["dt"] = 1.0 / fs
    npts = int(rng.integers(V["npts"][0], V["npts"][1] + 1))
    lo = float(rng.choice([-40, -35, -30, -25, -20, -15, -10]))
    hi = float(rng.choice([45, 50, 55, 60, 65, 70, 75, 80, 85]))
    if rng.random() < 0.5:
        grid = np.round(np.linspace(lo, hi, npts))
    else:
        for _ in range(2000):
            inner = np.sort(rng.uniform(lo, hi, npts - 2))
            grid = np.round(np.concatenate([[lo], inner, [hi]]))
            if np.min(np.diff(grid)) >= 12.0:
                break
        else:
            grid = np.round(np.linspace(lo, hi, npts))
    u["grid"] = grid.astype(float)
    u["mid_grid"] = np.round(0.5 * (grid[1:] + grid[:-1]) * 2.0) / 2.0

    f = V["faces"]
    if f == "plus3":
        faces = ["+x", "+y", "+z"]
    elif f == "six":
        faces = list(FACES_ALL)
    elif f == "mixed3":
        faces = [("+" if rng.random() < 0.5 else "-") + a for a in "xyz"]
        if all(x[0] == "+" for x in faces):
            k = int(rng.integers(3))
            faces[k] = "-" + faces[k][1]
    else:  # four
        ax = "xyz"[int(rng.integers(3))]
        faces = ["+x", "+y", "+z", "-" + ax]
    u["faces"] = faces

    nm = int(rng.integers(V["nmag"][0], V["nmag"][1] + 1))
    mags = {float(rng.choice(SMALL)), float(rng.choice(LARGE))}
    while len(mags) < nm:
        mags.add(float(rng.choice(MID + LARGE if rng.random() < 0.4 else MID)))
    u["mags"] = sorted(mags)
    u["wmax"] = max(mags)
    u["H"] = float(rng.integers(V["hold"][0], V["hold"][1] + 1))

    # ---- gyro intrinsic
    base_n = rng.uniform(0.004, 0.011)
    u["arw"] = base_n * rng.uniform(0.85, 1.15, 3)                 # deg/s/sqrt(Hz)
    u["floor_a"] = float(math.sqrt(np.mean(u["arw"] ** 2) / (u["H"] - 2 * TRIM)))
    fa = u["floor_a"]
    u["b0"] = rng.uniform(-1.5, 1.5, 3)
    u["b1"] = rng.uniform(-0.02, 0.02, 3)
    u["s0"] = rng.uniform(-0.012, 0.012, 3)
    u["s1"] = rng.uniform(-1.2e-4, 1.2e-4, 3)
    mis = rng.uniform(-0.015, 0.015, (3, 3))
    np.fill_diagonal(mis, 0.0)
    u["mis"] = mis
    u["self_heat"] = rng.uniform(1.0, 3.0)
    # curvature of bias and scale with temperature, limited so that linear interpolation
    # between the set points leaves well under the white floor
    Tg = u["grid"] + u["self_heat"]
    Tf = np.linspace(Tg[0], Tg[-1], 400)
    b2 = rng.uniform(-1, 1, 3) * 2e-5
    b3 = rng.uniform(-1, 1, 3) * 2e-7
    s2 = rng.uniform(-1, 1, 3) * 3e-8
    s3 = rng.uniform(-1, 1, 3) * 3e-10
    for i in range(3):
        d = Tf - 25.0
        eb = _interp_err(Tf, b2[i] * d ** 2 + b3[i] * d ** 3, Tg).max()
        if eb > 0.15 * fa:
            b2[i] *= 0.15 * fa / eb
            b3[i] *= 0.15 * fa / eb
        es = _interp_err(Tf, s2[i] * d ** 2 + s3[i] * d ** 3, Tg).max() * u["wmax"]
        if es > 0.15 * fa:
            s2[i] *= 0.15 * fa / es
            s3[i] *= 0.15 * fa / es
    u["b2"], u["b3"], u["s2"], u["s3"] = b2, b3, s2, s3
    u["turn_on"] = 0.7 * fa
    u["gm"] = [(rng.uniform(200, 500), 0.25 * fa), (rng.uniform(1500, 4000), 0.3 * fa)]
    u["lsb"] = 1.0 / 65.5 if (V["quant_gyro"] and u["wmax"] <= 450) else None

    # ---- chamber, thermal, fixture, table, people
    u["T_amb"] = rng.uniform(20.0, 25.0)
    u["r_ch"] = rng.uniform(2.0, 5.0) / 60.0                         # degC/s
    u["tau_u"] = rng.uniform(120.0, 220.0)
    u["tau_2"] = rng.uniform(20.0, 45.0)
    u["soak_k"] = rng.uniform(6.5, 8.0)
    u["T_off"] = rng.uniform(-0.6, 0.6)
    u["T_noise"] = rng.uniform(0.03, 0.05) if V["quant_T"] > 0.01 else rng.uniform(0.01, 0.03)
    u["quant_T"] = V["quant_T"]
    u["windage"] = rng.uniform(0.01, 0.04)
    u["wob"] = (rng.uniform(0.03, 0.10), rng.uniform(180, 600), rng.uniform(0, 2 * math.pi))
    u["door"] = (rng.uniform(0.008, 0.025), rng.uniform(15, 40), rng.uniform(60, 150))
    u["overshoot"] = (rng.uniform(0.5, 1.0), rng.uniform(60, 180))
    u["radius"] = rng.uniform(0.02, 0.10)
    ang = rng.uniform(0, 2 * math.pi)
    u["p"] = u["radius"] * np.array([math.cos(ang), math.sin(ang), 0.0])
    u["yaw"] = {fc: rng.uniform(0, 2 * math.pi) for fc in FACES_ALL}
    u["M"] = {fc: _face_matrix(fc, u["yaw"][fc]) for fc in FACES_ALL}
    u["reseat"] = rng.uniform(0.5e-6, 1.5e-6)
    u["alpha"] = rng.uniform(20.0, 100.0)
    u["wait"] = (240.0, 420.0)
    u["handle"] = (15.0, 40.0)
    if V["accel"]:
        Sa = rng.uniform(-0.003, 0.003, (3, 3))
        u["acc_S"] = np.eye(3) + Sa
        u["acc_b"] = rng.uniform(-0.015, 0.015, 3)
        u["acc_b1"] = rng.uniform(-3e-4, 3e-4, 3)
        u["acc_n"] = rng.uniform(100e-6, 250e-6)
    return u


# ============================================================================= session plans
def _temp_order(rng, grid, style, T_amb):
    g = list(grid)
    if style == "descending":
        o = sorted(g, reverse=True)
    elif style == "zigzag":
        s = sorted(g)
        o, hi_first = [], rng.random() < 0.5
        while s:
            o.append(s.pop(-1) if hi_first else s.pop(0))
            hi_first = not hi_first
    elif style == "ambient_out":
        s = sorted(g)
        k = int(np.argmin([abs(x - T_amb) for x in s]))
        if rng.random() < 0.5:
            o = s[k:] + s[:k][::-1]
        else:
            o = s[:k + 1][::-1] + s[k + 1:]
    elif style == "down_up":
        s = sorted(g)
        k = int(rng.integers(1, len(s)))
        o = s[:k][::-1] + s[k:]
    else:  # random
        o = [g[i] for i in rng.permutation(len(g))]
    if all(o[i] < o[i + 1] for i in range(len(o) - 1)):
        o = o[::-1]
    return o


def _rate_orders(rng, mags, style, nmount):
    def signed_desc():
        return [m for m in sorted(mags, reverse=True)] + [0.0] + [-m for m in sorted(mags)]
    out = []
    for k in range(nmount):
        if style == "shuffle":
            r = [0.0] + list(mags) + [-m for m in mags]
            r = [r[i] for i in rng.permutation(len(r))]
        elif style == "descending":
            r = signed_desc()
        elif style == "ascending":
            r = signed_desc()[::-1]
        elif style == "interleaved":
            ms = sorted(mags, reverse=(k % 2 == 1))
            sg = 1.0 if rng.random() < 0.5 else -1.0
            r = [0.0]
            for m in ms:
                r += [sg * m, -sg * m]
        else:  # magnitude descending, alternating sign, zero last
            ms = sorted(mags, reverse=True)
            sg = 1.0 if rng.random() < 0.5 else -1.0
            r = []
            for m in ms:
                r += [sg * m, -sg * m]
                sg = -sg
            r.append(0.0)
        out.append([float(x) for x in r])
    return out


def _approach(order, T_amb):
    prev, d = T_amb, {}
    for sp in order:
        d.setdefault(sp, np.sign(sp - prev))
        prev = sp
    return d


def _session_plans(rng, u, family):
    V = VARIANTS[u["variant"]]
    tstyles = ["descending", "zigzag", "ambient_out", "down_up", "random"]
    rstyles = ["shuffle", "descending", "ascending", "interleaved", "alternating"]
    for _ in range(200):
        ts = [tstyles[i] for i in rng.permutation(len(tstyles))[:3]]
        plans = []
        for s in range(3):
            grid = u["mid_grid"] if (V["verify"] and s > 0) else u["grid"]
            order = _temp_order(rng, grid, ts[s], u["T_amb"])
            if V["revisit"] and rng.random() < 0.6 and len(order) > 2:
                order = order + [order[int(rng.integers(0, len(order) - 1))]]
            plans.append({"temps": [float(x) for x in order]})
        if family == "thermal_hysteresis":
            a0 = _approach(plans[0]["temps"], u["T_amb"])
            ok = True
            for s in (1, 2):
                a = _approach(plans[s]["temps"], u["T_amb"])
                diff = np.mean([a0[k] != a[k] for k in a0])
                ok &= diff >= 0.4
            if not ok:
                continue
        break
    rs = [rstyles[i] for i in rng.permutation(len(rstyles))[:3]]
    cur = u["faces"][int(rng.integers(len(u["faces"])))]
    for s, p in enumerate(plans):
        p["rate_style"] = rs[s]
        p["stop_between"] = bool(rng.random() < 0.35)
        p["first_face"] = cur if s == 0 else u["faces"][int(rng.integers(len(u["faces"])))]
        mounts, rates = [], []
        face = p["first_face"]
        for _sp in p["temps"]:
            perm = [u["faces"][i] for i in rng.permutation(len(u["faces"]))]
            if rng.random() < 0.5 and face in perm:
                perm.remove(face)
                perm = [face] + perm
            mounts.append(perm)
            rates.append(_rate_orders(rng, u["mags"], rs[s], len(perm)))
            face = perm[-1]
        p["mounts"], p["rates"] = mounts, rates
        p["soak"] = [float(u["soak_k"] * (u["tau_u"] + u["tau_2"]) * rng.uniform(0.95, 1.1))
                     for _ in p["temps"]]
    return plans


# ============================================================================= session simulation
class _TL:
    """Sample-grid timeline of one session."""

    def __init__(self, fs):
        self.fs = fs
        self.n = 0
        self.ref, self.alpha, self.ev, self.label, self.hold = [], [], [], [], []
        self.holds, self.spc, self.doors, self.soaks, self.handl = [], [], [], [], []

    def add(self, n, ref=0.0, alpha=0.0, ev=0, label="", hold=-1):
        if n <= 0:
            return
        self.ref.append(np.broadcast_to(np.asarray(ref, float), (n,)).copy())
        self.alpha.append(np.broadcast_to(np.asarray(alpha, float), (n,)).copy())
        self.ev.append(np.full(n, ev, int))
        self.label.append(np.full(n, FACES_ALL.index(label), np.int8))
        self.hold.append(np.full(n, hold, int))
        self.n += n


def _handling_path(rng, M_old, M_new, n, dt):
    """Body rates (deg/s) and specific force (g) of a person re-mounting the unit."""
    tau = np.linspace(0.0, 1.0, n + 1)
    a, b = rng.uniform(0.1, 0.25), rng.uniform(0.75, 0.9)
    x = np.clip((tau - a) / (b - a), 0.0, 1.0)
    s = 0.5 - 0.5 * np.cos(math.pi * x)
    r_old = Rotation.from_matrix(M_old)
    rv = (r_old.inv() * Rotation.from_matrix(M_new)).as_rotvec()
    w = np.zeros((n + 1, 3))
    for k in range(1, 6):
        amp = rng.standard_normal(3)
        amp *= rng.uniform(3.0, 20.0) * D2R / k / np.linalg.norm(amp)
        w += np.sin(math.pi * k * tau)[:, None] * amp[None, :]
    r = r_old * Rotation.from_rotvec(s[:, None] * rv[None, :]) * Rotation.from_rotvec(w)
    rel = r[:-1].inv() * r[1:]
    omega = rel.as_rotvec() / dt / D2R
    grav = r[1:].inv().apply(np.array([0.0, 0.0, 1.0]))
    hand = np.zeros((n, 3))
    tt = tau[1:]
    for k in range(1, 4):
        hand += np.sin(math.pi * k * tt)[:, None] * rng.normal(0, 0.04 / k, 3)[None, :]
    return omega, grav + hand


def _simulate_session(u, p, rng, s_index):
    fs, dt = u["fs"], u["dt"]
    tl = _TL(fs)
    events = []                           # mounting events: face, nuisance tilt, clamp index

    def new_event(face, i_clamp):
        uu = _face_vec(face)
        th = _perp(rng.standard_normal(3), uu) * u["reseat"]
        M = u["M"][face] @ Rotation.from_rotvec(th).as_matrix()
        events.append(dict(face=face, theta=th, M=M, i_clamp=i_clamp))
        return len(events) - 1

    ev = new_event(p["first_face"], -int(rng.uniform(300, 900) * fs))
    face = p["first_face"]
    omega = 0.0

    def ramp_to(w1):
        nonlocal omega
        d = w1 - omega
        if d == 0:
            return
        n = int(math.ceil(abs(d) / u["alpha"] * fs))
        tl.add(n, ref=np.linspace(omega, w1, n + 1)[1:], alpha=np.sign(d) * u["alpha"],
               ev=ev, label=face)
        omega = w1

    def handling(new_face):
        nonlocal ev, face
        n = int(rng.uniform(*u["handle"]) * fs)
        i0 = tl.n
        m1, m2 = rng.uniform(5, 20), rng.uniform(5, 20)
        new = new_event(new_face, i0 + n)
        om, fsp = _handling_path(rng, events[ev]["M"], events[new]["M"], n, dt)
        tl.handl.append((i0, n, om, fsp))
        tl.add(n, ev=-1, label=face)
        tl.doors.append((max(0, i0 - int(m1 * fs)), i0 + n + int(m2 * fs)))
        ev, face = new, new_face

    tl.add(int(rng.uniform(60, 120) * fs), ev=ev, label=face)
    prev_sp = u["T_amb"]
    for pi, sp in enumerate(p["temps"]):
        mounts = p["mounts"][pi]
        if mounts[0] != face:
            handling(mounts[0])
            tl.add(int(rng.uniform(8, 20) * fs), ev=ev, label=face)
        n_soak = int((abs(sp - prev_sp) / u["r_ch"] + p["soak"][pi]) * fs)
        tl.spc.append((tl.n, sp))
        tl.soaks.append((tl.n, tl.n + n_soak))
        tl.add(n_soak, ev=ev, label=face)
        prev_sp = sp
        for mi, fc in enumerate(mounts):
            if mi > 0:
                handling(fc)
                tl.add(int(rng.uniform(*u["wait"]) * fs), ev=ev, label=face)
            for w in p["rates"][pi][mi]:
                if p["stop_between"] and omega != 0.0 and w != 0.0:
                    ramp_to(0.0)
                    tl.add(int(rng.uniform(3, 6) * fs), ev=ev, label=face)
                ramp_to(w)
                n = int(u["H"] * fs)
                tl.holds.append(dict(i0=tl.n, i1=tl.n + n, sp=sp, visit=pi, face=face, w=w,
                                     ev=ev))
                tl.add(n, ref=w, ev=ev, label=face, hold=len(tl.holds) - 1)
            ramp_to(0.0)
            tl.add(int(rng.uniform(3, 8) * fs), ev=ev, label=face)
    tl.add(int(rng.uniform(30, 60) * fs), ev=ev, label=face)

    # ---- assemble sample arrays
    n = tl.n
    t = np.arange(n) * dt
    ref = np.concatenate(tl.ref)
    alpha = np.concatenate(tl.alpha)
    evi = np.concatenate(tl.ev)
    label = np.concatenate(tl.label)
    holdi = np.concatenate(tl.hold)
    Om = ref * D2R
    al = alpha * D2R
    px, py = u["p"][0], u["p"][1]
    f_tab = np.stack([(-Om ** 2 * px - al * py) / G0, (-Om ** 2 * py + al * px) / G0,
                      np.ones(n)], axis=1)
    omega_s = np.zeros((n, 3))
    f_s = np.zeros((n, 3))
    u_true = np.zeros((n, 3))
    for k, e in enumerate(events):
        m = evi == k
        if not m.any():
            continue
        ut = e["M"][2]
        omega_s[m] = ref[m, None] * ut[None, :]
        f_s[m] = f_tab[m] @ e["M"]
        u_true[m] = ut
    for i0, nn, om, fsp in tl.handl:
        omega_s[i0:i0 + nn] = om
        f_s[i0:i0 + nn] = fsp

    # ---- chamber air, unit temperature
    Ta = np.full(n, u["T_amb"])
    cur = u["T_amb"]
    ovk, ovt = u["overshoot"]
    for k, (i, sp) in enumerate(tl.spc):
        j = tl.spc[k + 1][0] if k + 1 < len(tl.spc) else n
        tt = t[i:j] - t[i]
        d = sp - cur
        tr = abs(d) / u["r_ch"]
        after = np.clip(tt - tr, 0.0, None)
        o = min(1.0, 0.02 * abs(d)) * ovk * np.sign(d)
        Ta[i:j] = cur + np.sign(d) * np.minimum(u["r_ch"] * tt, abs(d)) \
            + o * (after / ovt) * np.exp(1.0 - after / ovt) * (tt > tr)
        cur = sp
    Ta[:tl.spc[0][0]] = u["T_amb"]
    A, P, ph = u["wob"]
    Ta += A * np.sin(2 * math.pi * t / P + ph) + 0.3 * A * np.sin(2 * math.pi * t / (0.37 * P))
    fdoor, t_open, t_rec = u["door"]
    for io, ic in tl.doors:
        ic = min(ic, n)
        base = Ta[io]
        tt = t[io:ic] - t[io]
        dd = (u["T_amb"] - base) * fdoor * (1.0 - np.exp(-tt / t_open))
        Ta[io:ic] += dd
        end = min(n, ic + int(10 * t_rec * fs))
        if ic < n:
            Ta[ic:end] += dd[-1] * np.exp(-(t[ic:end] - t[ic]) / t_rec)
    x = Ta - u["windage"] * (np.abs(ref) / 400.0) ** 1.5
    Td = _lag(_lag(x, u["tau_u"], dt, u["T_amb"]), u["tau_2"], dt, u["T_amb"]) \
        + u["self_heat"] * (1.0 - np.exp(-t / 150.0))
    Tlog = Td + u["T_off"] + rng.normal(0, u["T_noise"], n)
    Tlog = np.round(Tlog / u["quant_T"]) * u["quant_T"]

    # ---- gyro (base)
    dT = Td - 25.0
    sc = 1.0 + u["s0"] + u["s1"] * dT[:, None] + u["s2"] * dT[:, None] ** 2 \
        + u["s3"] * dT[:, None] ** 3
    B = u["b0"] + u["b1"] * dT[:, None] + u["b2"] * dT[:, None] ** 2 + u["b3"] * dT[:, None] ** 3
    g = omega_s * sc + omega_s @ u["mis"].T + B
    g += rng.normal(0, u["turn_on"], 3)[None, :]
    for tau, sig in u["gm"]:
        g += np.stack([_ar1(rng, n, tau, sig, dt) for _ in range(3)], axis=1)
    g += rng.standard_normal((n, 3)) * (u["arw"] * math.sqrt(fs))[None, :]

    acc = None
    if "acc_S" in u:
        acc = f_s @ u["acc_S"].T + u["acc_b"] + u["acc_b1"] * dT[:, None] \
            + rng.standard_normal((n, 3)) * u["acc_n"] * math.sqrt(fs)

    return dict(n=n, t=t, ref=ref, alpha=alpha, ev=evi, label=label, hold=holdi,
                holds=tl.holds, events=events, doors=tl.doors, soaks=tl.soaks, spc=tl.spc,
                omega_s=omega_s, f_s=f_s, u_true=u_true, Ta=Ta, Td=Td, Tlog=Tlog, sc=sc,
                gyro=g, acc=acc, s_index=s_index)


# ============================================================================= effects
def _draw_family(rng, fam, u):
    fp = {}
    if fam == "scale_nonlinearity":
        fp["c"] = rng.standard_normal(3)
        fp["kind"] = "cubic" if rng.random() < 0.5 else "asym"
    elif fam == "g_sensitivity":
        fp["G"] = rng.standard_normal((3, 3))
    elif fam == "thermal_gradient":
        fp["c"] = rng.standard_normal(3)
        fp["tau"] = rng.uniform(20.0, 60.0)
    elif fam == "power_on_warmup":
        fp["v"] = rng.standard_normal(3)
        fp["tau"] = rng.uniform(2400.0, 6000.0)
    elif fam == "clamp_relaxation":
        fp["v"] = {fc: rng.standard_normal(3) for fc in FACES_ALL}
        fp["tau"] = rng.uniform(120.0, 420.0)
    elif fam == "rate_memory":
        fp["k"] = rng.standard_normal(3)
        fp["tau"] = rng.uniform(8.0, 0.8 * u["H"])
    elif fam == "fixture_faces":
        fp["theta"] = {fc: _perp(rng.standard_normal(3), _face_vec(fc)) for fc in FACES_ALL}
    elif fam == "reference_rig":
        e0 = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0)
        eps = [e0]
        while len(eps) < 3:
            e = rng.uniform(-1.0, 1.0)
            if abs(e - e0) >= 0.5:
                eps.append(e)
        fp["eps"] = eps
    elif fam == "unit_shift":
        dK = np.zeros((3, 3))
        ax = int(rng.integers(3))
        dK[ax, ax] = rng.choice([-1.0, 1.0])
        i, j = [int(x) for x in rng.choice(3, 2, replace=False)]
        dK[i, j] = rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 1.0)
        fp["dK"] = dK
    elif fam == "midpoint_feature":
        fp["kind"] = "bias" if rng.random() < 0.5 else "scale"
        fp["v"] = rng.standard_normal(3)
        k = int(rng.integers(len(u["mid_grid"])))
        tc = float(u["mid_grid"][k])
        h = float(u["grid"][k + 1] - u["grid"][k])
        fp["Tc"] = tc + u["self_heat"]
        fp["sig"] = rng.uniform(0.11, 0.16) * h
    elif fam == "thermal_hysteresis":
        fp["v"] = rng.standard_normal(3)
        step = float(np.min(np.diff(u["grid"])))
        fp["w"] = rng.uniform(1.5, max(1.6, min(4.0, step / 3.0)))
    return fp


def _play(T, w, y0):
    """Backlash (play) operator on temperature, output in [-1, 1]."""
    s = y0
    out = np.empty_like(T)
    for i, x in enumerate(T.tolist()):
        if x - s > w:
            s = x - w
        elif x - s < -w:
            s = x + w
        out[i] = (x - s) / w
    return out


def _effect(fam, fp, u, S, rng):
    """The family's signal at unit amplitude: (gyro N x 3 deg/s, accel N x 3 g or None)."""
    n, dt, si = S["n"], u["dt"], S["s_index"]
    om, Td, t = S["omega_s"], S["Td"], S["t"]
    Kmat_apply = (lambda v: v * S["sc"] + v @ u["mis"].T)
    eg = np.zeros((n, 3))
    ea = None
    clamped = S["ev"] >= 0
    if fam == "scale_nonlinearity":
        x = om / u["wmax"]
        if fp["kind"] == "cubic":
            eg = fp["c"] * u["wmax"] * x ** 3
        else:
            eg = fp["c"] * u["wmax"] * (np.abs(x) + 0.3 * x ** 3)
    elif fam == "g_sensitivity":
        eg = S["f_s"] @ fp["G"].T
    elif fam == "thermal_gradient":
        dTdt = np.gradient(Td, dt)
        eg = _lag(dTdt, fp["tau"], dt, 0.0)[:, None] * fp["c"][None, :]
    elif fam == "power_on_warmup":
        eg = np.exp(-t / fp["tau"])[:, None] * fp["v"][None, :]
    elif fam == "clamp_relaxation":
        for e_i, e in enumerate(S["events"]):
            m = S["ev"] == e_i
            if not m.any():
                continue
            tc = e["i_clamp"] * dt
            eg[m] = np.exp(-(t[m] - tc) / fp["tau"])[:, None] * fp["v"][e["face"]][None, :]
    elif fam == "rate_memory":
        lp = np.stack([_lag(om[:, i], fp["tau"], dt, 0.0) for i in range(3)], axis=1)
        eg = (lp - om) * fp["k"][None, :]
    elif fam == "fixture_faces":
        rot = np.zeros((n, 3))
        fs_rot = np.zeros((n, 3))
        for e_i, e in enumerate(S["events"]):
            m = S["ev"] == e_i
            if not m.any():
                continue
            th = fp["theta"][e["face"]]
            rot[m] = np.cross(S["omega_s"][m], th)          # small rotation of the rig axis
            fs_rot[m] = np.cross(S["f_s"][m], th)
        eg = Kmat_apply(rot)
        if S["acc"] is not None:
            ea = fs_rot @ u["acc_S"].T
    elif fam == "reference_rig":
        eps = fp["eps"][si]
        d = (S["ref"] * eps)[:, None] * S["u_true"] * clamped[:, None]
        eg = Kmat_apply(d)
    elif fam == "reseating":
        rot = np.zeros((n, 3))
        for e_i, e in enumerate(S["events"]):
            m = S["ev"] == e_i
            if not m.any():
                continue
            th = _perp(rng.standard_normal(3), _face_vec(e["face"]))
            rot[m] = np.cross(S["omega_s"][m], th)
        eg = Kmat_apply(rot)
    elif fam == "unit_shift":
        if si > 0:
            eg = om @ fp["dK"].T
    elif fam == "bias_wander":
        rw = np.cumsum(rng.standard_normal((n, 3)), axis=0) * math.sqrt(dt) * 0.01
        rw -= rw.mean(axis=0)
        gm = np.stack([_ar1(rng, n, 900.0, 0.3, dt) for _ in range(3)], axis=1)
        eg = rw + gm
    elif fam == "midpoint_feature":
        bump = np.exp(-0.5 * ((Td - fp["Tc"]) / fp["sig"]) ** 2)
        if fp["kind"] == "bias":
            eg = bump[:, None] * fp["v"][None, :]
        else:
            eg = bump[:, None] * fp["v"][None, :] * om / u["wmax"]
    elif fam == "thermal_hysteresis":
        y = _play(Td, fp["w"], u["T_amb"])
        eg = y[:, None] * fp["v"][None, :]
    return eg, ea


# ============================================================================= standard calibration
def _hold_means(S, gy, valid=None):
    hs = S["holds"]
    fs = int(round(1.0 / (S["t"][1] - S["t"][0])))
    tr = int(round(TRIM * fs))
    G = np.empty((len(hs), 3))
    T = np.empty(len(hs))
    W = np.empty((len(hs), 3))
    key = np.empty(len(hs))
    for k, h in enumerate(hs):
        sl = slice(h["i0"] + tr, h["i1"] - tr)
        if valid is not None:
            v = valid[sl]
            G[k] = gy[sl][v].mean(axis=0)
            T[k] = S["Tlog"][sl][v].mean()
        else:
            G[k] = gy[sl].mean(axis=0)
            T[k] = S["Tlog"][sl].mean()
        W[k] = h["w"] * _face_vec(h["face"])
        key[k] = h["sp"]
    return G, T, W, key


def _calibrate(G, T, W, key):
    grid = []
    for sp in np.unique(key):
        m = key == sp
        X = np.hstack([W[m], np.ones((m.sum(), 1))])
        coef, *_ = np.linalg.lstsq(X, G[m], rcond=None)
        grid.append((T[m].mean(), coef[:3].T, coef[3]))
    grid.sort(key=lambda x: x[0])
    Tg = np.array([x[0] for x in grid])
    Kg = np.array([x[1] for x in grid])
    Bg = np.array([x[2] for x in grid])
    return Tg, Kg, Bg


def _apply(cal, G, T, W):
    Tg, Kg, Bg = cal
    j = np.clip(np.searchsorted(Tg, T) - 1, 0, len(Tg) - 2)
    wgt = (T - Tg[j]) / (Tg[j + 1] - Tg[j])
    K = Kg[j] + wgt[:, None, None] * (Kg[j + 1] - Kg[j])
    B = Bg[j] + wgt[:, None] * (Bg[j + 1] - Bg[j])
    w_hat = np.linalg.solve(K, (G - B)[:, :, None])[:, :, 0]
    return w_hat - W


def _next_rms(h0, h2):
    cal = _calibrate(*h0)
    e = _apply(cal, h2[0], h2[1], h2[2])
    return float(np.sqrt(np.mean(e ** 2)))


# ============================================================================= unit
def build_unit(spec):
    """Simulate one unit's three sessions and its truth (no files written)."""
    ss = np.random.SeedSequence(spec["seed"])
    r_unit, r_plan, r_fam, *r_sess = [np.random.default_rng(x) for x in ss.spawn(9)]
    fam = spec["family"]
    u = _draw_unit(r_unit, spec["variant"])
    V = VARIANTS[spec["variant"]]
    fp = _draw_family(r_fam, fam, u) if fam else None
    if fam == "thermal_gradient":
        # this chamber regulates loosely and the holds start in the settling tail; this die
        # has a small static temperature coefficient
        u["soak_k"] = r_fam.uniform(4.0, 5.5)
        u["wob"] = (r_fam.uniform(0.3, 0.7), r_fam.uniform(600, 1500), r_fam.uniform(0, 6.28))
        u["b1"] = u["b1"] * 0.15
        u["s1"] = u["s1"] * 0.15
    plans = _session_plans(r_plan, u, fam)
    sessions = []
    for s in range(3):
        S = _simulate_session(u, plans[s], r_sess[s], s)
        if fam:
            S["eff_g"], S["eff_a"] = _effect(fam, fp, u, S, r_sess[3 + s])
        sessions.append(S)
    # write-side decorations that also shape the hold means (NaN glitches)
    for S in sessions:
        valid = np.ones(S["n"], bool)
        if V["nan"]:
            k = int(r_plan.integers(3, 9))
            valid[r_plan.integers(0, S["n"], k)] = False
        keep = np.ones(S["n"], bool)
        if V["gaps"]:
            for a, b in S["soaks"]:
                if r_plan.random() < 0.5:
                    L = b - a
                    i0 = a + int(L * r_plan.uniform(0.1, 0.3))
                    i1 = i0 + int(L * r_plan.uniform(0.15, 0.35))
                    keep[i0:i1] = False
        S["valid"], S["keep"] = valid, keep

    hb = [_hold_means(S, S["gyro"], S["valid"]) for S in sessions]
    floor_b = _next_rms(hb[0], hb[2])
    floor_ref = max(u["floor_a"], floor_b)
    amp = 0.0
    if fam:
        he = [_hold_means(S, S["eff_g"], S["valid"])[0] for S in sessions]
        target = spec["target"] * floor_ref

        def rms(a):
            h0 = (hb[0][0] + a * he[0],) + hb[0][1:]
            h2 = (hb[2][0] + a * he[2],) + hb[2][1:]
            return _next_rms(h0, h2) - target

        hi = 1e-6
        while rms(hi) < 0 and hi < 1e6:
            hi *= 2.0
        amp = brentq(rms, hi / 2.0 if rms(hi / 2.0) < 0 else 0.0, hi, xtol=1e-12, rtol=1e-6)
        for S in sessions:
            S["gyro"] = S["gyro"] + amp * S["eff_g"]
            if S.get("eff_a") is not None and S["acc"] is not None:
                S["acc"] = S["acc"] + amp * S["eff_a"]
    hf = [_hold_means(S, S["gyro"], S["valid"]) for S in sessions]
    before = _next_rms(hf[0], hf[2])

    F = FAMILIES[fam] if fam else None
    reads = set(F["reads"]) if F else set()
    if fam == "fixture_faces" and not V["accel"]:
        reads.discard("accel")
    acts = set(F["acts"]) if F else set()
    if fam == "midpoint_feature":
        acts = {fp["kind"]}
    truth = dict(complete=fam is None, reads=reads, acts=acts,
                 reasons=set(F["reasons"]) if F else set(),
                 carried=bool(F["carried"]) if F else True,
                 threshold=1.2 * floor_ref, floor=floor_ref, floor_white=u["floor_a"],
                 floor_model=floor_b, before=before, amplitude=amp)
    return dict(spec=spec, unit=u, plans=plans, sessions=sessions, truth=truth)


# ============================================================================= writing
def _session_table(u, S, rng):
    V = VARIANTS[u["variant"]]
    keep = S["keep"] & np.ones(S["n"], bool)
    n = int(keep.sum())
    dt = u["dt"]
    t = S["t"] + rng.uniform(-0.04, 0.04, S["n"]) * dt
    gy = S["gyro"].copy()
    if u["lsb"]:
        gy = np.round(gy / u["lsb"]) * u["lsb"]
    ref = S["ref"].copy()
    if V["units"] == "rad":
        gy *= D2R
        ref *= D2R
    bad = ~S["valid"]
    gy[bad, rng.integers(0, 3)] = np.nan
    dtype = np.float32 if V["dtype"] == "float32" else np.float64
    cols = {}
    if V["t_type"] == "timestamp":
        t0 = np.datetime64("2025-03-03T08:00:00") + np.timedelta64(int(S["s_index"]) * 9, "D") \
            + np.timedelta64(int(rng.integers(0, 3600)), "s")
        us = t0.astype("datetime64[us]").astype(np.int64) + np.round(t * 1e6).astype(np.int64)
        cols["t"] = pa.array(us[keep].astype("datetime64[us]"), type=pa.timestamp("us"))
    else:
        cols["t"] = pa.array(t[keep], type=pa.float64())
    for i, a in enumerate("xyz"):
        cols[f"gyro_{a}"] = pa.array(gy[keep, i].astype(dtype))
    cols["temp"] = pa.array(S["Tlog"][keep].astype(dtype))
    cols["ref_rate"] = pa.array(ref[keep].astype(dtype))
    if V["mount_col"]:
        labels = np.array(FACES_ALL)[S["label"][keep]]
        if V["mount_col"] == "dictionary":
            cols["mount"] = pa.array(labels.tolist()).dictionary_encode()
        else:
            cols["mount"] = pa.array(labels.tolist(), type=pa.string())
    if S["acc"] is not None:
        for i, a in enumerate("xyz"):
            cols[f"accel_{a}"] = pa.array(S["acc"][keep, i].astype(dtype))
    if V["extra"]:
        cols["seq"] = pa.array(np.nonzero(keep)[0].astype(np.uint32))
    table = pa.table(cols)
    if V["units"] == "rad":
        md = {b"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()}
        table = table.replace_schema_metadata(md)
    assert n == table.num_rows
    return table


def write_unit(built, folder):
    """Write the three sessions as Parquet files; returns their paths in session order."""
    os.makedirs(folder, exist_ok=True)
    rng = np.random.default_rng(built["spec"]["seed"] ^ 0x5EA1)
    paths = []
    for s, S in enumerate(built["sessions"]):
        tab = _session_table(built["unit"], S, rng)
        p = os.path.join(folder, f"session{s}.parquet")
        pq.write_table(tab, p, compression="zstd")
        paths.append(p)
    return paths
