"""Sealed rig-log generator for the gyro-calibration diagnosis benchmark.

Written from the rig-log contract (/work/shared/spec/log-format.md), the three physics
papers in /work/shared/seeds/ and general MEMS-gyro physics, by a helper that read
neither the calibration software nor its issue tracker.  numpy + pyarrow only.

A *unit* is one physical three-axis MEMS gyro: its own scale/misalignment matrix and bias,
both smooth (at most quadratic) functions of die temperature, white rate noise (ARW), a small
bias instability (Gauss-Markov), a per-power-on bias (turn-on repeatability, well below the
hold-mean noise floor), a die temperature sensor with offset, noise and quantisation, an
accelerometer, and a thermal path (chamber air -> case -> die, with electronics
self-heating after power-on).  A *session* is one turntable calibration run of that unit
(protocol ``turntable`` of the contract): chamber set points in a non-ascending visit order,
at each a soak, then for every mount a series of constant-rate holds in both directions,
with a person re-mounting the unit (real motion while ``ref_rate`` is 0) between mounts.
The same unit is written as sessions 0, 1 and 2: new noise, a new power-on, another visit
order.

Everything the judged software must not see -- the effect families below, their parameters
and magnitudes -- lives in this file only.  The README names only their number and the
magnitude band.

Effect families (each is added on top of the standard per-temperature model
``w = K(T) w_true + B(T)``, which cannot represent it).  ``carried`` says whether a term of
the sensor could compensate it in the field; ``reads`` are the coarse input kinds a right
fix may read; ``reasons`` the no-sensor-term reasons that are right (any other reason of the
judge's vocabulary, listed in run.py, is a wrong story for that family).

  F01 scale asymmetry        carried; output_i += a_i |w_i|  (different scale for forward
                             and reverse rotation, a classic MEMS sense-loop asymmetry)
                             reads {rate}
  F02 odd scale nonlinearity carried; output_i += c_i w_i (w_i / 300)^2  (cubic compression
                             of the sense channel near full scale)          reads {rate}
  F03 cross-axis rate^2      carried; output_j += sum_{i!=j} q_ji w_i^2 / 300  (centrifugal
                             loading of the proof masses couples a rate on one axis into a
                             rectified output on another)                    reads {rate}
  F04 g-sensitivity          carried; output += G f, f the specific force in g (gravity
                             along the rig axis, plus centripetal/tangential acceleration
                             from the unit's radius on the table)      reads {accel, mount}
  F05 thermal creep          carried; output_i += c_i (T_die - T_slow), T_slow a first-order
                             lag of die temperature with tau 600-1200 s: stress in the die
                             attach relaxes slowly after every temperature step, so the bias
                             keeps settling long after the die temperature has (temperature
                             variation as a driver, MTEA paper)                reads {thermal}
  F06 thermal hysteresis     carried; output_i += h_i p(t), p a play (backlash) operator on
                             die temperature of half-width 2 degC: +1 after heating, -1 after
                             cooling (package stress relaxation with friction)  reads {thermal}
                             reason {direction of approach} (a right story; being carried,
                             only a fix makes it a success)
  F07 electronic warm-up     carried; output_i += A_i exp(-t_on / tau), t_on the time since
                             power-on, tau 500-900 s (drive-loop / charge settling, not
                             thermal)                                          reads {time}
  F08 fixture repeatability  NOT carried; every mounting of the unit sits with a new small
                             tilt (fixture seating / burr), so the rig axis is a little off the
                             nominal sensor axis, differently each time; seen by the
                             accelerometer too                              reason {mounting}
  F09 rig rate offset        NOT carried; the table's true rate differs from the logged
                             reference by a constant that changes from session to session
                             (rate-loop zero re-set at each rig start-up)        reason {lab}
  F10 excess slow noise      NOT carried; a unit whose bias wanders far more than nominal
                             (sum of Gauss-Markov processes, 60-2000 s)    reason {slow noise}
  F11 unit changed           NOT carried; between session 0 and session 1 the unit's bias and
                             scale/misalignment step (shock / stress relief), and stay stepped
                             in session 2                               reason {unit changed}
  C   complete               no effect (false-alarm control)

Magnitudes: every effect unit is scaled so that the extra RMS error it causes on session 2's
hold means, after the standard calibration of session 0 (computed noise-free from this
file's own truth), is ``rho`` times the true hold-mean noise floor, with ``rho`` drawn
log-stratified in [1.5, 50].
"""
from __future__ import annotations

import hashlib
import json
import math
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

G0 = 9.80665
AMBIENT = 23.0
RAMP_RATE = 10.0 / 60.0   # chamber ramp, degC/s
TABLE_ACCEL = 150.0       # deg/s^2
TRIM = 1.0                # s trimmed at both ends of a hold for hold means (truth side)
RHO_BAND = (1.5, 50.0)
T_REF = 25.0

# --------------------------------------------------------------------------------------
# protocol variants (all are the contract's `turntable` protocol)
# --------------------------------------------------------------------------------------
VARIANTS = {
    # descending / shuffled orders, interleaved-sign rates in descending magnitude,
    # accelerometer and a string mount column logged, float seconds, a few NaN rows
    "A": dict(fs=12.5, setpoints=(50.0, 30.0, 10.0, -10.0),
              orders=((50.0, 30.0, 10.0, -10.0), (10.0, 50.0, -10.0, 30.0),
                      (10.0, -10.0, 30.0, 50.0)),
              mounts=("+x", "+y", "+z"),
              rates=(400.0, -400.0, 200.0, -200.0, 50.0, -50.0, 10.0, -10.0, 0.0),
              rate_shuffle=False, hold=12.0, soak=420.0, log_ramps=True, accel=True,
              mount_col="string", time="float", units="deg/s", dtype="float64",
              nan_rows=6, t0=12.0, extra="seq"),
    # six mounts (both directions of every axis), a revisited point (other direction of
    # travel) in session 0, rates shuffled per mount, logger paused during chamber ramps
    # (gaps), gyro and reference in rad/s (metadata), dictionary mount column
    "B": dict(fs=20.0, setpoints=(-20.0, 15.0, 50.0),
              orders=((15.0, 50.0, -20.0, 15.0), (50.0, 15.0, -20.0),
                      (-20.0, 50.0, 15.0)),
              mounts=("+x", "-y", "+z", "-x", "+y", "-z"),
              rates=(300.0, -300.0, 60.0, -60.0, 5.0, -5.0, 0.0),
              rate_shuffle=True, hold=10.0, soak=420.0, log_ramps=False, accel=True,
              mount_col="dictionary", time="float", units="rad/s", dtype="float64",
              nan_rows=0, t0=8123.4, extra="frame"),
    # three points, negative mounts, no mount column (derived from data), no accelerometer,
    # Arrow timestamps, float32 gyro, 10 Hz with longer holds, mixed rate order
    "C": dict(fs=10.0, setpoints=(-20.0, 15.0, 45.0),
              orders=((15.0, 45.0, -20.0), (-20.0, 45.0, 15.0), (45.0, -20.0, 15.0)),
              mounts=("-x", "+y", "-z"),
              rates=(-250.0, 150.0, 0.0, -150.0, 250.0, -30.0, 30.0, -5.0, 5.0),
              rate_shuffle=False, hold=18.0, soak=420.0, log_ramps=True, accel=False,
              mount_col=None, time="timestamp", units="deg/s", dtype="float32",
              nan_rows=0, t0=0.0, extra=None),
}

FAMILIES = {
    "F01": dict(carried=True, reads={"rate"}, reasons=set(), variants=("A", "C", "B")),
    "F02": dict(carried=True, reads={"rate"}, reasons=set(), variants=("C", "B", "A")),
    "F03": dict(carried=True, reads={"rate"}, reasons=set(), variants=("B", "A", "C")),
    "F04": dict(carried=True, reads={"accel", "mount"}, reasons=set(), variants=("A", "B")),
    "F05": dict(carried=True, reads={"thermal"}, reasons=set(), variants=("C", "A", "B")),
    "F06": dict(carried=True, reads={"thermal"}, reasons={"direction of approach"},
                variants=("B", "C", "A")),
    "F07": dict(carried=True, reads={"time"}, reasons=set(), variants=("A", "C", "B")),
    "F08": dict(carried=False, reads=set(), reasons={"mounting"}, variants=("B", "A", "C")),
    "F09": dict(carried=False, reads=set(), reasons={"lab"}, variants=("A", "B", "C")),
    "F10": dict(carried=False, reads=set(), reasons={"slow noise"}, variants=("C", "A", "B")),
    "F11": dict(carried=False, reads=set(), reasons={"unit changed"}, variants=("B", "C", "A")),
}
COMPLETE = "C"
COMPLETE_VARIANTS = ("A", "B", "C")

_E = np.eye(3)
_MOUNT_AXES = {  # columns: images of rig x, rig y, rig z (=u) in the sensor frame
    "+x": (_E[1], _E[2], _E[0]), "-x": (_E[1], -_E[2], -_E[0]),
    "+y": (_E[2], _E[0], _E[1]), "-y": (_E[2], -_E[0], -_E[1]),
    "+z": (_E[0], _E[1], _E[2]), "-z": (_E[0], -_E[1], -_E[2]),
}


def mount_R(m):
    a, b, u = _MOUNT_AXES[m]
    return np.column_stack([a, b, u])


def seed_for(*parts):
    h = hashlib.sha256(repr(parts).encode()).digest()
    return int.from_bytes(h[:8], "little")


# --------------------------------------------------------------------------------------
# small numerics
# --------------------------------------------------------------------------------------
def ar1_scan(x, phi):
    """y_k = phi*y_{k-1} + x_k (y_{-1}=0) along axis 0, constant phi, log-depth scan."""
    y = np.array(x, dtype=float, copy=True)
    n = y.shape[0]
    s, p = 1, float(phi)
    while s < n:
        y[s:] = y[s:] + p * y[:-s]
        s *= 2
        p = p * p
        if p < 1e-300:
            break
    return y


def first_order(u, y0, tau, dt):
    phi = math.exp(-dt / tau)
    x = (1.0 - phi) * np.asarray(u, float)
    x = x.copy()
    x[0] += phi * y0
    return ar1_scan(x, phi)


def gauss_markov(rng, n, dt, sigma, tau, ncol=3):
    phi = math.exp(-dt / tau)
    e = rng.normal(0.0, sigma * math.sqrt(1 - phi * phi), (n, ncol))
    e[0] = rng.normal(0.0, sigma, ncol)
    return ar1_scan(e, phi)


def rot_log(D):
    c = np.clip((np.trace(D) - 1.0) / 2.0, -1.0, 1.0)
    phi = math.acos(c)
    if phi < 1e-9:
        return 0.0, np.array([0.0, 0.0, 1.0])
    if math.pi - phi < 1e-6:
        B = (D + np.eye(3)) / 2.0
        k = int(np.argmax(np.diag(B)))
        ax = B[:, k] / math.sqrt(max(B[k, k], 1e-12))
        return phi, ax / np.linalg.norm(ax)
    ax = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / (2 * math.sin(phi))
    return phi, ax / np.linalg.norm(ax)


def rotate(v, k, theta):
    """Rotate vector v (3,) about unit axis k (3,) by angles theta (n,) -> (n,3)."""
    ct, st = np.cos(theta)[:, None], np.sin(theta)[:, None]
    return v[None] * ct + np.cross(k, v)[None] * st + (k * (k @ v))[None] * (1 - ct)


# --------------------------------------------------------------------------------------
# unit
# --------------------------------------------------------------------------------------
def make_unit(spec):
    """spec: dict(uid, seed, family, variant, rho)."""
    rng = np.random.default_rng(seed_for("unit", spec["seed"]))
    V = VARIANTS[spec["variant"]]
    u = dict(spec)
    K0 = np.eye(3) + np.diag(rng.normal(0, 0.005, 3))
    off = rng.normal(0, 0.004, (3, 3))
    np.fill_diagonal(off, 0.0)
    u["K0"] = K0 + off
    K1 = rng.normal(0, 3e-6, (3, 3))
    np.fill_diagonal(K1, rng.normal(0, 100e-6, 3))
    u["K1"] = K1
    u["K2"] = np.diag(rng.normal(0, 1.5e-8, 3))
    u["B0"] = rng.normal(0, 0.3, 3)
    u["B1"] = rng.normal(0, 0.004, 3)
    u["B2"] = rng.normal(0, 1.5e-5, 3)
    u["arw"] = rng.uniform(0.006, 0.011, 3)          # deg/s/sqrt(Hz)
    u["t_used"] = V["hold"] - 2 * TRIM
    sig_hm = u["arw"] / math.sqrt(u["t_used"])        # per-axis hold-mean sigma (white)
    u["floor"] = float(np.sqrt(np.mean(sig_hm ** 2)))  # RMS over axes
    u["gm_sigma"] = 0.3 * u["floor"]
    u["gm_tau"] = rng.uniform(150.0, 400.0)
    u["turnon_sigma"] = 0.25 * u["floor"]
    u["tau_case"] = rng.uniform(8.0, 12.0)
    u["tau_th"] = rng.uniform(35.0, 50.0)
    u["self_heat"] = rng.uniform(1.5, 3.0)
    u["temp_off"] = rng.normal(0, 0.4)
    u["acc_bias"] = rng.normal(0, 0.008, 3)
    u["acc_scale"] = 1 + rng.normal(0, 0.003, 3)
    u["radius"] = rng.uniform(0.02, 0.05)
    u["shape"] = family_shape(spec["family"], np.random.default_rng(seed_for("shape", spec["seed"])))
    return u


def family_shape(fam, rng):
    s = {}
    if fam == "F01":
        s["a"] = rng.normal(0, 1, 3) * 1e-3
    elif fam == "F02":
        s["c"] = rng.normal(0, 1, 3) * 1e-3
    elif fam == "F03":
        q = rng.normal(0, 1, (3, 3)) * 1e-3
        np.fill_diagonal(q, 0.0)
        s["q"] = q
    elif fam == "F04":
        G = rng.normal(0, 1, (3, 3)) * 0.02
        G += np.diag(rng.normal(0, 1, 3) * 0.03)
        s["G"] = G
    elif fam == "F05":
        s["c"] = rng.normal(0, 1, 3) * 0.005
        s["tau"] = rng.uniform(600.0, 1200.0)
    elif fam == "F06":
        s["h"] = rng.normal(0, 1, 3) * 0.01
        s["w"] = 2.0
    elif fam == "F07":
        s["A"] = rng.normal(0, 1, 3) * 0.01
        s["tau"] = rng.uniform(500.0, 900.0)
    elif fam == "F08":
        s["tilt"] = 2e-5
    elif fam == "F09":
        z0 = rng.choice([-1, 1]) * rng.uniform(0.6, 1.4)
        z1 = -np.sign(z0) * rng.uniform(0.3, 1.2)
        z2 = -np.sign(z0) * rng.uniform(0.6, 1.4)
        s["delta"] = 0.005 * np.array([z0, z1, z2])
    elif fam == "F10":
        s["sigma"] = 0.005
        s["taus"] = (60.0, 400.0, 2000.0)
    elif fam == "F11":
        s["db"] = rng.normal(0, 1, 3) * 0.005
        dK = rng.normal(0, 1e-5, (3, 3))
        np.fill_diagonal(dK, rng.normal(0, 3e-5, 3))
        s["dK"] = dK
    return s


# --------------------------------------------------------------------------------------
# session timeline
# --------------------------------------------------------------------------------------
class _TL:
    def __init__(self, fs):
        self.fs = fs
        self.parts = []
        self.n = 0
        self.holds = []

    def add(self, kind, n, prof, alpha, air, inst, mlabel, visit, setpoint,
            hw=None, hf=None, logged=True, hold=None):
        n = int(n)
        d = dict(kind=np.full(n, kind, dtype="U6"), prof=np.broadcast_to(prof, (n,)).astype(float),
                 alpha=np.broadcast_to(alpha, (n,)).astype(float),
                 air=np.broadcast_to(air, (n,)).astype(float),
                 inst=np.full(n, inst, int), mlabel=np.full(n, mlabel, dtype="U2"),
                 visit=np.full(n, visit, int), setpoint=np.full(n, setpoint, float),
                 hw=np.zeros((n, 3)) if hw is None else hw,
                 hf=np.zeros((n, 3)) if hf is None else hf,
                 logged=np.full(n, logged, bool))
        if hold is not None:
            self.holds.append(dict(i0=self.n, i1=self.n + n, **hold))
        self.parts.append(d)
        self.n += n

    def arrays(self):
        return {k: np.concatenate([p[k] for p in self.parts]) for k in self.parts[0]}


def _handling(R_old, R_new, n, fs, rng):
    tt = np.arange(n) / fs
    D = n / fs
    phi_tot, ax = rot_log(R_old @ R_new.T)
    s = (1 - np.cos(np.pi * tt / D)) / 2
    ds = np.pi / (2 * D) * np.sin(np.pi * tt / D)
    w = ax[None] * (phi_tot * ds)[:, None]                 # rad/s, body frame
    for k in range(2, 6):
        w += rng.normal(0, 0.12, 3)[None] * np.sin(2 * np.pi * k * tt / D)[:, None]
    f = rotate(R_old[:, 2], ax, -phi_tot * s)
    f += ar1_scan(rng.normal(0, 0.02, (n, 3)), 0.8)
    return np.degrees(w), f


def build_timeline(V, order, rng):
    fs = V["fs"]
    tl = _TL(fs)
    mounts = V["mounts"]
    cur = 0
    inst = 0
    Tset = AMBIENT
    rate = 0.0
    nsec = lambda d: max(1, int(round(d * fs)))

    def trans(r1, visit, mlabel):
        nonlocal rate
        r0 = rate
        if r1 == r0:
            tl.add("settle", nsec(0.5), r1, 0.0, Tset, inst, mlabel, visit, Tset)
            return
        dur = abs(r1 - r0) / TABLE_ACCEL
        n = nsec(dur)
        prof = r0 + (r1 - r0) * (np.arange(1, n + 1) / n)
        tl.add("trans", n, prof, np.sign(r1 - r0) * TABLE_ACCEL, Tset, inst, mlabel, visit, Tset)
        tl.add("settle", nsec(0.5), r1, 0.0, Tset, inst, mlabel, visit, Tset)
        rate = r1

    tl.add("static", nsec(60.0), 0.0, 0.0, AMBIENT, inst, mounts[cur], -1, AMBIENT)
    for visit, Ts in enumerate(order):
        dur = max(abs(Ts - Tset) / RAMP_RATE, 10.0)
        n = nsec(dur)
        air = Tset + (Ts - Tset) * (np.arange(1, n + 1) / n)
        tl.add("ramp", n, 0.0, 0.0, air, inst, mounts[cur], visit, Ts, logged=V["log_ramps"])
        Tset = Ts
        if V["log_ramps"]:
            tl.add("soak", nsec(V["soak"]), 0.0, 0.0, Tset, inst, mounts[cur], visit, Tset)
        else:   # logger resumed only for the end of the soak
            tl.add("soak", nsec(V["soak"] - 120.0), 0.0, 0.0, Tset, inst, mounts[cur], visit, Tset,
                   logged=False)
            tl.add("soak", nsec(120.0), 0.0, 0.0, Tset, inst, mounts[cur], visit, Tset)
        cycle = [(cur + j) % len(mounts) for j in range(len(mounts))]
        for j, mi in enumerate(cycle):
            if j > 0:
                nh = nsec(rng.uniform(12.0, 18.0))
                hw, hf = _handling(mount_R(mounts[cur]), mount_R(mounts[mi]), nh, fs, rng)
                tl.add("handle", nh, 0.0, 0.0, Tset, -1, mounts[cur], visit, Tset, hw=hw, hf=hf)
                inst += 1
                cur = mi
            rates = list(V["rates"])
            if V["rate_shuffle"]:
                rates = [rates[k] for k in rng.permutation(len(rates))]
            for r in rates:
                trans(r, visit, mounts[cur])
                tl.add("hold", nsec(V["hold"]), r, 0.0, Tset, inst, mounts[cur], visit, Tset,
                       hold=dict(rate=r, mount=mounts[cur], inst=inst, visit=visit, setpoint=Ts))
            trans(0.0, visit, mounts[cur])
            tl.add("static", nsec(2.0), 0.0, 0.0, Tset, inst, mounts[cur], visit, Tset)
    tl.add("static", nsec(20.0), 0.0, 0.0, Tset, inst, mounts[cur], len(order), Tset)
    return tl


# --------------------------------------------------------------------------------------
# session simulation
# --------------------------------------------------------------------------------------
def _K_of(u, dT):
    return u["K0"][None] + u["K1"][None] * dT[:, None, None] + u["K2"][None] * (dT ** 2)[:, None, None]


def simulate_session(u, s):
    V = VARIANTS[u["variant"]]
    fs = V["fs"]
    dt = 1.0 / fs
    rng_tl = np.random.default_rng(seed_for("timeline", u["seed"], s))
    rng_n = np.random.default_rng(seed_for("noise", u["seed"], s))
    rng_e = np.random.default_rng(seed_for("effect", u["seed"], s))
    tl = build_timeline(V, V["orders"][s], rng_tl)
    a = tl.arrays()
    n = tl.n
    t_on = 3.0 + np.arange(n) * dt      # the log starts 3 s after power-on

    # thermal path
    case = first_order(a["air"], AMBIENT, u["tau_case"], dt)
    q = u["self_heat"] * (1 - np.exp(-t_on / 120.0))
    die = first_order(case + q, AMBIENT, u["tau_th"], dt)
    dT = die - T_REF

    # kinematics in the sensor frame (nominal mounts)
    mounted = a["kind"] != "handle"
    R_by = {m: mount_R(m) for m in _MOUNT_AXES}
    U = np.zeros((n, 3))
    Rx = np.zeros((n, 3))
    Ry = np.zeros((n, 3))
    for m, R in R_by.items():
        sel = mounted & (a["mlabel"] == m)
        U[sel] = R[:, 2]
        Rx[sel] = R[:, 0]
        Ry[sel] = R[:, 1]
    angle = np.cumsum(np.radians(a["prof"])) * dt
    table = a["prof"] * (1 + 1e-5 * np.sin(2 * angle))           # true table rate
    w = U * table[:, None] + a["hw"]
    om = np.radians(table)
    f = U + (-(om ** 2) * u["radius"] / G0)[:, None] * Rx \
        + (np.radians(a["alpha"]) * u["radius"] / G0)[:, None] * Ry
    f[~mounted] = a["hf"][~mounted]

    K = _K_of(u, dT)
    B = u["B0"][None] + u["B1"][None] * dT[:, None] + u["B2"][None] * (dT ** 2)[:, None]
    turnon = rng_n.normal(0, u["turnon_sigma"], 3)
    clean = np.einsum("nij,nj->ni", K, w) + B
    noise = rng_n.normal(0, 1, (n, 3)) * (u["arw"] * math.sqrt(fs))[None]
    noise += gauss_markov(rng_n, n, dt, u["gm_sigma"], u["gm_tau"])
    noise += turnon[None]
    temp = die + u["temp_off"] + rng_n.normal(0, 0.015, n)
    temp = np.round(temp * 128.0) / 128.0
    ref = a["prof"] + rng_n.normal(0, 1, n) * 5e-5 * np.maximum(np.abs(a["prof"]), 1.0)
    acc_noise = rng_n.normal(0, 0.002, (n, 3))

    ctx = dict(w=w, f=f, die=die, case=case, t_on=t_on, inst=a["inst"], U=U, table=table,
               mounted=mounted, K=K, s=s, dt=dt, n=n)
    eff, eff_acc = family_effect(u, ctx, rng_e)

    return dict(unit=u, s=s, V=V, a=a, n=n, t_on=t_on, clean=clean, noise=noise, eff=eff,
                eff_acc=eff_acc, temp=temp, ref=ref, f=f, acc_noise=acc_noise,
                holds=tl.holds, die=die, case=case)


def family_effect(u, c, rng):
    fam = u["family"]
    sh = u["shape"]
    n = c["n"]
    w = c["w"]
    eff = np.zeros((n, 3))
    eff_acc = None
    if fam == "F01":
        eff = sh["a"][None] * np.abs(w)
    elif fam == "F02":
        eff = sh["c"][None] * w * (w / 300.0) ** 2
    elif fam == "F03":
        eff = (w ** 2 / 300.0) @ sh["q"].T
    elif fam == "F04":
        eff = c["f"] @ sh["G"].T
    elif fam == "F05":
        slow = first_order(c["die"], c["die"][0], sh["tau"], c["dt"])
        eff = sh["c"][None] * (c["die"] - slow)[:, None]
    elif fam == "F06":
        wd = sh["w"]
        T = c["die"]
        x = T[0] + rng.uniform(-wd, wd)
        p = np.empty(n)
        for i in range(n):
            Ti = T[i]
            if x < Ti - wd:
                x = Ti - wd
            elif x > Ti + wd:
                x = Ti + wd
            p[i] = (Ti - x) / wd
        eff = sh["h"][None] * p[:, None]
    elif fam == "F07":
        eff = sh["A"][None] * np.exp(-c["t_on"] / sh["tau"])[:, None]
    elif fam == "F08":
        inst = c["inst"]
        ninst = inst.max() + 1
        th = rng.normal(0, sh["tilt"], (ninst, 3))
        d = np.zeros((n, 3))
        da = np.zeros((n, 3))
        m = c["mounted"]
        TH = th[inst[m]]
        d[m] = np.cross(TH, c["U"][m]) * c["table"][m][:, None]
        da[m] = np.cross(TH, c["f"][m])
        eff = np.einsum("nij,nj->ni", c["K"], d)
        eff_acc = da
    elif fam == "F09":
        delta = sh["delta"][c["s"]]
        d = c["U"] * delta * c["mounted"][:, None]
        eff = np.einsum("nij,nj->ni", c["K"], d)
    elif fam == "F10":
        sig = sh["sigma"] / math.sqrt(len(sh["taus"]))
        for tau in sh["taus"]:
            eff += gauss_markov(rng, n, c["dt"], sig, tau)
    elif fam == "F11":
        if c["s"] >= 1:
            eff = w @ sh["dK"].T + sh["db"][None]
    return eff, eff_acc


# --------------------------------------------------------------------------------------
# truth-side standard calibration (the 12-parameter per-temperature model)
# --------------------------------------------------------------------------------------
def hold_table(sim):
    fs = sim["V"]["fs"]
    k = int(round(TRIM * fs))
    rows = []
    for h in sim["holds"]:
        i0, i1 = h["i0"] + k, h["i1"] - k
        rows.append((i0, i1))
    def hm(x):
        return np.array([x[i0:i1].mean(axis=0) for i0, i1 in rows])
    U = np.array([mount_R(h["mount"])[:, 2] for h in sim["holds"]])
    return dict(clean=hm(sim["clean"]), noise=hm(sim["noise"]), eff=hm(sim["eff"]),
                temp=hm(sim["temp"]), ref=np.array([h["rate"] for h in sim["holds"]]),
                U=U, group=np.array([h["setpoint"] for h in sim["holds"]]))


def calibrate(hm, H):
    Ts, Ks, Bs = [], [], []
    for g in np.unique(H["group"]):
        sel = H["group"] == g
        X = np.column_stack([H["ref"][sel, None] * H["U"][sel], np.ones(sel.sum())])
        P, *_ = np.linalg.lstsq(X, hm[sel], rcond=None)
        Ts.append(H["temp"][sel].mean())
        Ks.append(P[:3].T)
        Bs.append(P[3])
    o = np.argsort(Ts)
    return np.array(Ts)[o], np.array(Ks)[o], np.array(Bs)[o]


def evaluate(cal, hm, H):
    Ts, Ks, Bs = cal
    err = np.zeros_like(hm)
    for i in range(len(hm)):
        T = H["temp"][i]
        K = np.array([[np.interp(T, Ts, Ks[:, a, b]) for b in range(3)] for a in range(3)])
        B = np.array([np.interp(T, Ts, Bs[:, a]) for a in range(3)])
        err[i] = np.linalg.solve(K, hm[i] - B) - H["ref"][i] * H["U"][i]
    return err


def transfer_error(H0, H2, x0, x2):
    return evaluate(calibrate(x0, H0), x2, H2)


def rms(x):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


# --------------------------------------------------------------------------------------
# unit build: three sessions, magnitude scaling, truth
# --------------------------------------------------------------------------------------
def build_unit(spec):
    u = make_unit(spec)
    sims = [simulate_session(u, s) for s in range(3)]
    H = [hold_table(x) for x in sims]
    base = transfer_error(H[0], H[2], H[0]["clean"], H[2]["clean"])
    scale = 0.0
    landed = 0.0
    if spec["family"] != COMPLETE:
        e1 = transfer_error(H[0], H[2], H[0]["clean"] + H[0]["eff"], H[2]["clean"] + H[2]["eff"]) - base
        scale = spec["rho"] * u["floor"] / max(rms(e1), 1e-15)
        eS = transfer_error(H[0], H[2], H[0]["clean"] + scale * H[0]["eff"],
                            H[2]["clean"] + scale * H[2]["eff"]) - base
        landed = rms(eS) / u["floor"]
    oracle = rms(transfer_error(H[0], H[2], H[0]["clean"] + H[0]["noise"],
                                H[2]["clean"] + H[2]["noise"]))
    fam = FAMILIES.get(spec["family"])
    truth = dict(uid=spec["uid"], family=spec["family"], variant=spec["variant"],
                 complete=spec["family"] == COMPLETE,
                 carried=bool(fam and fam["carried"]),
                 reads=set(fam["reads"]) if fam else set(),
                 reasons=set(fam["reasons"]) if fam else set(),
                 floor=u["floor"], oracle=oracle, base=rms(base),
                 threshold=1.2 * max(u["floor"], oracle),
                 rho=spec.get("rho", 0.0), landed=landed, scale=scale)
    return dict(unit=u, sims=sims, scale=scale, truth=truth)


def write_session(sim, scale, path):
    V = sim["V"]
    u = sim["unit"]
    a = sim["a"]
    logged = a["logged"]
    idx = np.nonzero(logged)[0]
    rng = np.random.default_rng(seed_for("write", u["seed"], sim["s"]))
    fs = V["fs"]
    t = V["t0"] + idx / fs + rng.uniform(-0.15, 0.15, idx.size) / fs
    gyro = (sim["clean"] + sim["noise"] + scale * sim["eff"])[idx]
    ref = sim["ref"][idx]
    if V["units"] == "rad/s":
        gyro = np.radians(gyro)
        ref = np.radians(ref)
    dtype = np.float32 if V["dtype"] == "float32" else np.float64
    cols = {}
    if V["time"] == "timestamp":
        epoch_us = 1_717_000_000_000_000 + int(sim["s"]) * 86_400_000_000 * 7
        cols["t"] = pa.array(epoch_us + np.round(t * 1e6).astype(np.int64),
                             type=pa.timestamp("us", tz="UTC"))
    else:
        cols["t"] = pa.array(t, type=pa.float64())
    gyro = gyro.astype(dtype)
    if V["nan_rows"]:
        bad = rng.choice(idx.size, V["nan_rows"], replace=False)
        gyro[bad, rng.integers(0, 3, bad.size)] = np.nan
    for k, ax in enumerate("xyz"):
        cols[f"gyro_{ax}"] = pa.array(gyro[:, k])
    cols["temp"] = pa.array(sim["temp"][idx].astype(dtype))
    cols["ref_rate"] = pa.array(ref.astype(dtype))
    if V["mount_col"] == "string":
        cols["mount"] = pa.array(a["mlabel"][idx].tolist(), type=pa.string())
    elif V["mount_col"] == "dictionary":
        cols["mount"] = pa.array(a["mlabel"][idx].tolist(), type=pa.string()).dictionary_encode()
    if V["accel"]:
        f = sim["f"] + (0 if sim["eff_acc"] is None else scale * sim["eff_acc"])
        acc = u["acc_scale"][None] * f + u["acc_bias"][None] + sim["acc_noise"]
        for k, ax in enumerate("xyz"):
            cols[f"accel_{ax}"] = pa.array(acc[idx, k].astype(dtype))
    if V["extra"] == "seq":
        cols["seq"] = pa.array(idx.astype(np.uint32))
    elif V["extra"] == "frame":
        cols["frame"] = pa.array(idx.astype(np.int64))
    table = pa.table(cols)
    if V["units"] == "rad/s":
        md = dict(table.schema.metadata or {})
        md[b"gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()
        table = table.replace_schema_metadata(md)
    pq.write_table(table, path)
    return path


def write_unit(built, outdir):
    os.makedirs(outdir, exist_ok=True)
    paths = []
    for sim in built["sims"]:
        p = os.path.join(outdir, f"s{sim['s']}.parquet")
        write_session(sim, built["scale"], p)
        paths.append(p)
    return paths


# --------------------------------------------------------------------------------------
# unit plan (shared with run.py)
# --------------------------------------------------------------------------------------
def plan(units_per_family=2, seed=20250611, quick=False):
    rng = np.random.default_rng(seed_for("plan", seed))
    specs = []
    lo, hi = math.log(RHO_BAND[0]), math.log(RHO_BAND[1])
    for fam, F in FAMILIES.items():
        k = units_per_family
        strata = rng.permutation(k)
        for j in range(k):
            rho = math.exp(lo + (strata[j] + rng.uniform(0.05, 0.95)) * (hi - lo) / k)
            specs.append(dict(family=fam, variant=F["variants"][j % len(F["variants"])],
                              rho=float(rho), seed=seed_for("u", seed, fam, j)))
    ncomp = max(3, 2 * units_per_family)
    for j in range(ncomp):
        specs.append(dict(family=COMPLETE, variant=COMPLETE_VARIANTS[j % 3], rho=0.0,
                          seed=seed_for("u", seed, COMPLETE, j)))
    if quick:
        pick = [s for s in specs if s["family"] in ("F01", "F06", "F08")][::units_per_family]
        pick += [s for s in specs if s["family"] == COMPLETE][:1]
        specs = pick
    order = rng.permutation(len(specs))     # opaque ids: family not recoverable from the id
    out = []
    for i, k in enumerate(order):
        sp = dict(specs[k])
        sp["uid"] = f"u{i:02d}"
        out.append(sp)
    out.sort(key=lambda s: s["uid"])
    return out


# --------------------------------------------------------------------------------------
# self-check: contract compliance and magnitude band, aggregate output only
# --------------------------------------------------------------------------------------
REQUIRED = ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate")


def check_log(path):
    problems = []
    pf = pq.ParquetFile(path)
    tab = pf.read()
    names = tab.schema.names
    for c in REQUIRED:
        if c not in names:
            problems.append(f"missing {c}")
    if problems:
        return problems
    tt = tab.schema.field("t").type
    if not (pa.types.is_float64(tt) or pa.types.is_timestamp(tt)):
        problems.append("t type")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate") + tuple(
            x for x in ("accel_x", "accel_y", "accel_z") if x in names):
        ty = tab.schema.field(c).type
        if not (pa.types.is_float32(ty) or pa.types.is_float64(ty)):
            problems.append(f"{c} type")
    tv = tab.column("t")
    if pa.types.is_timestamp(tt):
        tv = tv.cast(pa.int64()).to_numpy() / 1e6
    else:
        tv = tv.to_numpy()
    if not np.all(np.diff(tv) > 0):
        problems.append("t not strictly increasing")
    if "mount" in names:
        mt = tab.schema.field("mount").type
        if not (pa.types.is_string(mt) or pa.types.is_dictionary(mt)):
            problems.append("mount type")
        vals = set(tab.column("mount").cast(pa.string()).to_pylist()) if not pa.types.is_dictionary(mt) \
            else set(tab.column("mount").combine_chunks().dictionary.to_pylist())
        if not vals <= set(_MOUNT_AXES):
            problems.append("mount values")
    md = pf.schema_arrow.metadata or {}
    if b"gyrocal.units" in md:
        u = json.loads(md[b"gyrocal.units"])
        if set(u) - {"gyro", "ref_rate"} or set(u.values()) - {"rad/s", "deg/s"}:
            problems.append("units metadata")
    ref = tab.column("ref_rate").to_numpy()
    if np.nanmax(np.abs(ref)) <= 0:
        problems.append("no rotation")
    return problems


def selfcheck(units_per_family=1, seed=20250611, outdir=None):
    import tempfile
    import shutil
    tmp = outdir or tempfile.mkdtemp(prefix="sealed_selfcheck_")
    specs = plan(units_per_family, seed)
    n_logs = n_bad = 0
    ratios, comp, base_rel, thr_rel, rows = [], [], [], [], []
    for sp in specs:
        b = build_unit(sp)
        paths = write_unit(b, os.path.join(tmp, sp["uid"]))
        for p in paths:
            n_logs += 1
            pr = check_log(p)
            n_bad += bool(pr)
            rows.append(pq.ParquetFile(p).metadata.num_rows)
        tr = b["truth"]
        base_rel.append(tr["base"] / tr["floor"])
        thr_rel.append(tr["threshold"] / tr["floor"])
        if tr["complete"]:
            comp.append(tr["oracle"] / tr["floor"])
        else:
            ratios.append(tr["landed"])
    if outdir is None:
        shutil.rmtree(tmp, ignore_errors=True)
    lo, hi = RHO_BAND
    ok_band = all(lo * 0.97 <= r <= hi * 1.03 for r in ratios)
    print(f"logs written: {n_logs}, contract problems: {n_bad}")
    print(f"rows per log: {min(rows)}..{max(rows)}")
    print(f"effect units: {len(ratios)}; landed excess/floor in [{min(ratios):.2f}, {max(ratios):.2f}]"
          f" (band {lo}-{hi}): {'OK' if ok_band else 'OUT OF BAND'}")
    print(f"noise-free standard-model residual / floor: max {max(base_rel):.3f}")
    print(f"complete units: {len(comp)}; complete-model s2 RMS / floor in "
          f"[{min(comp):.2f}, {max(comp):.2f}]; threshold / floor in [{min(thr_rel):.2f}, {max(thr_rel):.2f}]")
    return n_bad == 0 and ok_band


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description="sealed rig-log generator (self-check)")
    ap.add_argument("--selfcheck", action="store_true")
    ap.add_argument("--units-per-family", type=int, default=1)
    ap.add_argument("--seed", type=int, default=20250611)
    ap.add_argument("--out", default=None, help="keep the self-check logs here")
    args = ap.parse_args()
    ok = selfcheck(args.units_per_family, args.seed, args.out)
    raise SystemExit(0 if ok else 1)
