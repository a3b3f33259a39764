"""Independent generator of synthetic hand-rotation (Ferraris) sessions as contract Parquet logs.

Written from the log contract (spec/log-format.md), gyrocal's extension of it (docs/log-format.md:
the `ferraris` protocol and the `section` column), rigid-body kinematics and the statistics of a
real recording (shared/real/imucal-ferraris) -- never from gyrocal's code, so that it can test it.

Physics, in one place:

* World frame: x north, y west, z up.  A pose R maps body vectors to world vectors.
* Every motion segment's attitude is closed-form, a product of exponentials about world-fixed
  axes with analytic angle functions:  R(t) = Exp(phi_1(t) a_1) ... Exp(phi_n(t) a_n) R_base.
  Its body rate is the exact analytic derivative, w_body = R^T sum_i phi_i'(t) (E_1..E_{i-1}) a_i,
  so nothing is integrated numerically while generating; check.py integrates w_body with the
  exponential map and gets the closed-form end attitude back (this is what proves the two agree).
* Gyro:  w_meas = K w_true + b(t) + G f_true + noise   (deg/s; w_true includes Earth rate).
* Accel: f_meas = Ka f_true + ba + noise  (g), f_true = R^T (p'' + g z)/g + (dw x r + w x (w x r))/g,
  i.e. +1 g along the axis that points up at rest, plus the lever-arm terms of a sensor r off
  the pivot, plus the lift of the unit during handling moves.
* The hand: speed profiles are sin^6 bells (smooth to the 5th derivative at both ends, so the
  rectangle sum of the sampled rate equals the integral far below the noise), with tremor,
  wobble about horizontal axes that dies out at both ends, the turn axis vertical but the unit
  tilted 0.5-2 deg from it, and a guide error on the total angle.

Use:  python tests/protocols/ferraris_gen/generate.py --out DIR --seed S [--kinds clean steps ...]
or    from generate import session;  truth = session("clean", 0, "clean.parquet")
"""
from __future__ import annotations

import argparse
import json
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

G0 = 9.80665                                   # m/s^2 per g
EARTH_RATE = np.degrees(7.2921159e-5)          # deg/s
EX, EY, EZ = np.eye(3)
AXES = "xyz"
FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
TURNS = ("x_rot", "y_rot", "z_rot")


# --------------------------------------------------------------------------- shape functions
def bump(s, p=6):
    """sin^6(pi s) on [0,1], 0 outside, with its first two derivatives (per unit s).

    A bump returns to rest with zero rate and acceleration: used for wobble, tremor, lifts and
    the detour of a handling move, so every segment joins its neighbours smoothly (C^5); the
    angle-tremor's rate is then C^4 at the joins, which keeps rectangle sums of the sampled rate
    equal to the integral (see check.py)."""
    s = np.asarray(s, float)
    inside = (s > 0) & (s < 1)
    x = np.pi * np.clip(s, 0, 1)
    sn, cs = np.sin(x), np.cos(x)
    B = sn**p
    dB = p * np.pi * sn ** (p - 1) * cs
    ddB = p * np.pi**2 * ((p - 1) * sn ** (p - 2) * cs**2 - sn**p)
    return B * inside, dB * inside, ddB * inside


PEAK_OVER_MEAN = 16 / 5     # of the sin^6 bell


def ramp(s):
    """Smooth 0->1 step whose speed is the bell (16/5) sin^6(pi s): a hand's turn or move
    (bell-shaped, zero rate and 5 derivatives at both ends; peak speed 3.2 x mean speed)."""
    s = np.asarray(s, float)
    sc = np.clip(s, 0, 1)
    w = 2 * np.pi * sc
    P = sc - 3 * np.sin(w) / (4 * np.pi) + 3 * np.sin(2 * w) / (20 * np.pi) - np.sin(3 * w) / (60 * np.pi)
    B, dB, _ = bump(s)
    return P, PEAK_OVER_MEAN * B, PEAK_OVER_MEAN * dB


def rotz(a_rad):
    return Rotation.from_rotvec(a_rad * EZ).as_matrix()


# --------------------------------------------------------------------------- motion segments
class Static:
    """The unit lies still in pose R (a face, or a rest before/after a turn)."""

    def __init__(self, R, t0, t1):
        self.R, self.t0, self.t1 = R, t0, t1

    def terms(self, t, wobble=True):
        return []

    def lift_acc(self, t):
        return np.zeros((len(t), 3))


class Move:
    """Handling between poses Ra -> Rb: a smooth turn along the short arc, combined with a detour
    about an axis orthogonal to it (beta peaks mid-move, 0 at both ends) and a lift of the unit,
    so the motion is never a rotation about a single axis, as a real hand re-orienting a unit."""

    def __init__(self, Ra, Rb, t0, t1, detour_axis, beta_rad, lift_m):
        rv = Rotation.from_matrix(Rb @ Ra.T).as_rotvec()
        self.alpha = np.linalg.norm(rv)
        self.v = rv / self.alpha if self.alpha > 1e-12 else EX
        u = detour_axis - detour_axis @ self.v * self.v
        self.u = u / np.linalg.norm(u)
        self.R, self.t0, self.t1, self.beta, self.lift = Ra, t0, t1, beta_rad, np.asarray(lift_m)

    def terms(self, t, wobble=True):
        T = self.t1 - self.t0
        s = (t - self.t0) / T
        P, dP, _ = ramp(s)
        B, dB, _ = bump(s)
        return [(self.v, self.alpha * P, self.alpha * dP / T), (self.u, self.beta * B, self.beta * dB / T)]

    def lift_acc(self, t):
        T = self.t1 - self.t0
        _, _, ddB = bump((t - self.t0) / T)
        return ddB[:, None] * self.lift[None, :] / T**2


@dataclass
class SubTurn:
    """One stroke of the hand about the vertical: angle (rad) from ta to tb, with tremor (A, f, psi)
    on the angle and wobble [(A, f, psi), (A, f, psi)] about world x and y (A in rad, f in Hz)."""
    ta: float
    tb: float
    angle: float
    tremor: tuple
    wobble: tuple


class Turn:
    """A hand turn about the world vertical, in one stroke or several with rests between.

    R(t) = Exp(phi1 x) Exp(phi2 y) Exp(theta z) R0: the axis of the turn is the vertical, the
    unit (pose R0) is tilted from it; phi1, phi2 (wobble) vanish outside the strokes, so the end
    pose is exactly Exp(theta_total z) R0."""

    def __init__(self, R0, subs):
        self.R, self.subs = R0, subs
        self.t0, self.t1 = subs[0].ta, subs[-1].tb
        self.breaks = tuple(sorted({x for sb in subs for x in (sb.ta, sb.tb)}))

    def _sum(self, t, pick):
        val, der = np.zeros_like(t), np.zeros_like(t)
        for sb in self.subs:
            T = sb.tb - sb.ta
            v, d = pick(sb, (t - sb.ta) / T, T, t - sb.ta)
            val += v
            der += d
        return val, der

    @staticmethod
    def _osc(A, f, psi, s, T, tau):
        B, dB, _ = bump(s)
        w = 2 * np.pi * f
        return A * B * np.sin(w * tau + psi), A * (dB / T * np.sin(w * tau + psi) + B * w * np.cos(w * tau + psi))

    def theta(self, t):
        def pick(sb, s, T, tau):
            P, dP, _ = ramp(s)
            tv, td = self._osc(*sb.tremor, s, T, tau)
            return sb.angle * P + tv, sb.angle * dP / T + td
        return self._sum(t, pick)

    def terms(self, t, wobble=True):
        th, dth = self.theta(t)
        out = []
        if wobble:
            for k, axis in enumerate((EX, EY)):
                ph, dph = self._sum(t, lambda sb, s, T, tau: self._osc(*sb.wobble[k], s, T, tau))
                out.append((axis, ph, dph))
        return out + [(EZ, th, dth)]

    def lift_acc(self, t):
        return np.zeros((len(t), 3))


def kinematics(seg, t, wobble=True):
    """Closed-form attitude R (n,3,3) and exact body rate (n,3, rad/s) of a segment at times t."""
    t = np.asarray(t, float)
    M = np.tile(np.eye(3), (len(t), 1, 1))
    w = np.zeros((len(t), 3))
    for axis, phi, dphi in seg.terms(t, wobble):
        w += dphi[:, None] * (M @ axis)
        M = M @ Rotation.from_rotvec(phi[:, None] * axis[None, :]).as_matrix()
    R = M @ seg.R
    return R, np.einsum("nji,nj->ni", R, w)


def gauss_integral(f, a, b, panels=64, order=10, breaks=(), per_s=25):
    """Composite Gauss-Legendre integral of a vector function f(t)->(n,3) over [a,b].

    At least `panels` (and `per_s` per second, so a 10 Hz tremor gets 2.5 panels per period) per
    piece between `breaks` (the joins of strokes and rests, where the rate is only C^4), so
    every panel sees an analytic, well-resolved integrand: error ~1e-12 deg."""
    x, wq = np.polynomial.legendre.leggauss(order)
    pts = np.unique(np.r_[a, [c for c in breaks if a < c < b], b])
    edges = np.unique(np.concatenate([np.linspace(p, q, max(panels, int(np.ceil((q - p) * per_s))) + 1)
                                      for p, q in zip(pts[:-1], pts[1:])]))
    mid, half = (edges[1:] + edges[:-1]) / 2, (edges[1:] - edges[:-1]) / 2
    tt = (mid[:, None] + half[:, None] * x[None, :]).ravel()
    ww = (half[:, None] * wq[None, :]).ravel()
    return (f(tt) * ww[:, None]).sum(0)


# --------------------------------------------------------------------------- kinds
@dataclass(frozen=True)
class Kind:
    """What a kind of session looks like; every number not fixed here is drawn from the seed."""
    fs: float = 102.4
    temp: bool = False
    accel: bool = True
    section: bool = False
    steps: bool = False                 # each turn in four ~90 deg strokes with rests
    peak: tuple = (120.0, 300.0)        # hand's peak rate per stroke, deg/s
    g_sens: tuple | None = None         # |G_ij| range, deg/s per g; None: no g-sensitivity
    bias_walk: tuple = (0.5e-4, 2e-4)   # deg/s/sqrt(s)
    earth: bool = True
    order: str = "default"              # or "shuffled"
    signs: str = "random"               # "neg" (imucal's clockwise), "random", "mixed"
    lsb: tuple | None = None            # (gyro deg/s, accel g) quantization steps
    odd_angle: float | None = None      # one turn of this nominal angle instead of 360
    missing_face: bool = False
    dtype: str = "float32"
    t_offset: bool = False              # t starts at an arbitrary logger time, not 0
    expect: str = "calibrate"
    acceptable: tuple = ("calibrate",)
    why: str = ""


KINDS = {
    "clean": Kind(fs=200.0, signs="neg", bias_walk=(0.0, 0.0), earth=False, dtype="float64",
                  why="textbook session: six faces then three clockwise one-go turns, accel, no temp, "
                      "no g-sensitivity, no bias drift, no Earth rate"),
    "annotated": Kind(section=True,
                      why="complete session with the `section` column (docs/log-format.md); phases come "
                          "from it"),
    "steps": Kind(steps=True, peak=(250.0, 450.0), lsb=(2000 / 32768, 16 / 32768),
                  why="each turn in four ~90 deg strokes with rests, quantized like the real 16-bit unit"),
    "temperature": Kind(fs=128.0, temp=True,
                        why="complete session with a `temp` column (~25 C, slow self-heating drift)"),
    "gsens": Kind(fs=200.0, g_sens=(0.05, 0.2),
                  why="large g-sensitivity: opposite faces' gyro means differ by 2 G[:,j]; a correct "
                      "tool estimates G from the faces and removes G f before integrating the turns"),
    "fast": Kind(fs=100.0, peak=(380.0, 450.0),
                 why="fast hand turns (peak ~400 deg/s) at 100 Hz"),
    "shuffled": Kind(fs=150.0, order="shuffled", signs="mixed", t_offset=True,
                     why="faces and turns in non-default orders, turns of both signs, t not starting at 0"),
    "sections_only": Kind(accel=False, section=True,
                          why="no accel but a `section` column: allowed by docs/log-format.md"),
    "missing_face": Kind(fs=100.0, missing_face=True, expect="refuse", acceptable=("refuse", "warn"),
                         why="one static face (an axis-down face) is never visited: the six-face "
                             "protocol is incomplete; a message should name the missing face"),
    "half_turn": Kind(fs=200.0, odd_angle=180.0, expect="refuse", acceptable=("refuse",),
                      why="one turn is only ~180 deg: its integrated rate is half the 360 deg "
                          "reference, calibrating would give a scale of ~0.5 on that axis"),
    "no_accel": Kind(accel=False, expect="refuse", acceptable=("refuse",),
                     why="no accel columns and no `section` column: the static faces cannot be "
                         "found (docs/log-format.md requires one of them)"),
    "two_turns": Kind(fs=128.0, odd_angle=720.0, expect="refuse", acceptable=("refuse", "warn"),
                      why="one axis turned ~720 deg in one go; using 360 would give a scale of ~2; "
                          "refuse, or at least warn if the tool recognises two whole turns"),
}


# --------------------------------------------------------------------------- session
def face_pose(face, yaw, tilt_vec):
    """Pose with body axis +/-e_j up, turned by yaw about the vertical, tilted by tilt_vec (rad,
    horizontal world rotation vector): the unit is never perfectly flat."""
    j, up = AXES.index(face[0]), face[2] == "p"
    A = np.zeros((3, 3))
    A[:, j] = EZ if up else -EZ
    A[:, (j + 1) % 3] = EX if up else EY
    A[:, (j + 2) % 3] = EY if up else EX
    return Rotation.from_rotvec(tilt_vec).as_matrix() @ rotz(yaw) @ A


@dataclass
class Session:
    """Everything generated for one log: the segments, the sensor, the samples and the truth."""
    kind: str
    seed: int
    cfg: Kind
    segs: list
    t: np.ndarray
    columns: dict
    truth: dict
    w_true: np.ndarray = field(repr=False, default=None)   # deg/s, incl. Earth rate
    f_true: np.ndarray = field(repr=False, default=None)   # g
    earth_world: np.ndarray = field(repr=False, default=None)


def _rng(seed, kind):
    """Per-kind stream, stable across Python runs (crc32, not hash())."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(kind.encode())]))


def _horiz(rng, mag_rad):
    a = rng.uniform(0, 2 * np.pi)
    return mag_rad * np.array([np.cos(a), np.sin(a), 0.0])


def build(kind: str, seed: int) -> Session:
    """Generate one session in memory (see session() to write it)."""
    cfg = KINDS[kind]
    rng = _rng(seed, kind)
    U = rng.uniform

    # --- sensor
    K = np.diag(1 + U(-0.03, 0.03, 3)) + (1 - np.eye(3)) * U(-0.015, 0.015, (3, 3))
    b0 = U(-1.0, 1.0, 3)
    G = None
    if cfg.g_sens:
        G = U(*cfg.g_sens, (3, 3)) * rng.choice([-1.0, 1.0], (3, 3))
    sigma = U(0.035, 0.07, 3)
    walk = U(*cfg.bias_walk)
    Ka = np.diag(1 + U(-0.02, 0.02, 3)) + (1 - np.eye(3)) * U(-0.01, 0.01, (3, 3))
    ba = U(-0.06, 0.06, 3)
    sigma_a = U(0.0012, 0.002, 3)
    r_lever = rng.normal(0, 1, 3)
    r_lever *= U(0.02, 0.05) / np.linalg.norm(r_lever)          # m, sensor off the turn axis
    lat = U(30, 60)
    earth_world = EARTH_RATE * np.array([np.cos(np.radians(lat)), 0, np.sin(np.radians(lat))]) if cfg.earth else np.zeros(3)

    # --- the person's plan
    faces = list(FACES)
    turns = list(TURNS)
    missing = None
    if cfg.missing_face:
        missing = str(rng.choice(["x_a", "y_a", "z_a"]))
        faces.remove(missing)
    if cfg.order == "shuffled":
        while faces == list(FACES):
            faces = list(rng.permutation(faces))
        while turns == list(TURNS):
            turns = list(rng.permutation(turns))
    if cfg.signs == "neg":
        signs = {tr: -1 for tr in TURNS}
    else:
        while True:
            signs = {tr: int(rng.choice([-1, 1])) for tr in TURNS}
            if cfg.signs != "mixed" or len(set(signs.values())) == 2:
                break
    nominal = {tr: 360.0 for tr in TURNS}
    if cfg.odd_angle:
        nominal[str(rng.choice(TURNS))] = cfg.odd_angle
    guide_sigma = U(0.3, 1.0)
    guide_err = {tr: float(rng.normal(0, guide_sigma)) for tr in TURNS}

    # --- timeline
    t_start = float(np.round(U(100, 5000), 3)) if cfg.t_offset else 0.0
    t = t_start
    segs = []
    pose = face_pose(faces[0], U(0, 2 * np.pi), _horiz(rng, np.radians(U(0, 3))))
    lead = U(1, 3)
    segs.append(Static(pose, t, t + lead))
    t += lead
    face_iv, turn_iv = {}, {}

    def osc(amp_deg, f_lo, f_hi):
        """(amplitude rad, frequency Hz, phase) of a tremor or wobble oscillation."""
        return np.radians(U(*amp_deg)), U(f_lo, f_hi), U(0, 2 * np.pi)

    def move_to(target):
        nonlocal t, pose
        dur = U(1.0, 2.0)                     # the real session's moves: 0.8-1.8 s
        lift = np.r_[rng.normal(0, 0.03, 2), U(0.03, 0.15)]
        segs.append(Move(pose, target, t, t + dur, rng.normal(0, 1, 3), np.radians(U(15, 45)), lift))
        t += dur
        pose = target

    for face in faces:
        move_to(face_pose(face, U(0, 2 * np.pi), _horiz(rng, np.radians(U(0, 1.5)))))
        dur = U(4.0, 9.0)
        segs.append(Static(pose, t, t + dur))
        face_iv[face] = {"t": [t, t + dur]}
        t += dur

    for tr in turns:
        tilt = np.radians(U(0.5, 2.0))
        R0 = face_pose(tr[0] + "_p", U(0, 2 * np.pi), _horiz(rng, tilt))
        move_to(R0)
        rest = U(1.0, 3.0)
        segs.append(Static(R0, t, t + rest))
        t += rest
        total = signs[tr] * (nominal[tr] + guide_err[tr])
        if cfg.steps:
            jit = rng.normal(0, 6.0, 4)
            strokes = total / 4 + signs[tr] * (jit - jit.mean())
        else:
            strokes = np.array([total])
        subs = []
        for k, ang in enumerate(strokes):
            if k:
                t += U(0.2, 0.8)                       # rest between strokes
            dur = abs(ang) * PEAK_OVER_MEAN / U(*cfg.peak)
            subs.append(SubTurn(t, t + dur, np.radians(ang), osc((0.05, 0.3), 4, 10),
                                (osc((0.1, 0.5), 1, 4), osc((0.1, 0.5), 1, 4))))
            t += dur
        turn = Turn(R0, subs)
        segs.append(turn)
        turn_iv[tr] = {"t_motion": [turn.t0, turn.t1], "angle_deg": float(total), "nominal_deg": nominal[tr],
                       "sign": signs[tr], "guide_error_deg": guide_err[tr],
                       "tilt_deg": float(np.degrees(tilt)), "n_strokes": len(subs),
                       "strokes_deg": [float(np.degrees(s.angle)) for s in subs]}
        pose = rotz(np.radians(total)) @ R0
        rest = U(1.0, 3.0)
        segs.append(Static(pose, t, t + rest))
        t += rest
    tail = U(1, 3)
    segs.append(Static(pose, t, t + tail))
    t_end = t + tail

    # --- sampling: evaluate each sample in the segment that holds it
    fs = cfg.fs
    n = int(np.floor((t_end - t_start) * fs)) + 1
    ts = t_start + np.arange(n) / fs
    starts = np.array([s.t0 for s in segs])
    which = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(segs) - 1)
    R = np.empty((n, 3, 3))
    w = np.empty((n, 3))
    f = np.empty((n, 3))
    d = 1e-4
    for i, seg in enumerate(segs):
        m = which == i
        if not m.any():
            continue
        tt = ts[m]
        Ri, wi = kinematics(seg, tt)
        dw = (kinematics(seg, tt + d)[1] - kinematics(seg, tt - d)[1]) / (2 * d)
        lever = np.cross(dw, r_lever) + np.cross(wi, np.cross(wi, r_lever))
        acc_world = seg.lift_acc(tt) + G0 * EZ
        R[m], w[m] = Ri, wi
        f[m] = (np.einsum("nji,nj->ni", Ri, acc_world) + lever) / G0
    w_true = np.degrees(w) + np.einsum("nji,j->ni", R, earth_world)

    bias = b0 + np.cumsum(rng.normal(0, 1, (n, 3)), axis=0) * walk / np.sqrt(fs)
    g_clean = w_true @ K.T + bias + (f @ G.T if G is not None else 0)
    gyro = g_clean + rng.normal(0, 1, (n, 3)) * sigma
    acc = f @ Ka.T + ba + rng.normal(0, 1, (n, 3)) * sigma_a
    if cfg.lsb:
        gyro = np.round(gyro / cfg.lsb[0]) * cfg.lsb[0]
        acc = np.round(acc / cfg.lsb[1]) * cfg.lsb[1]

    cols = {"t": ts}
    for k, a in enumerate(AXES):
        cols[f"gyro_{a}"] = gyro[:, k].astype(cfg.dtype)
    if cfg.accel:
        for k, a in enumerate(AXES):
            cols[f"accel_{a}"] = acc[:, k].astype(cfg.dtype)
    temp_model = None
    if cfg.temp:
        T0, dT, tau = U(23, 27), U(0.3, 1.5), U(60, 300)
        temp = T0 + dT * (1 - np.exp(-(ts - t_start) / tau)) + rng.normal(0, 0.03, n)
        cols["temp"] = (np.round(temp * 16) / 16).astype(cfg.dtype)
        temp_model = {"T0": T0, "dT": dT, "tau_s": tau, "noise_c": 0.03, "lsb_c": 1 / 16,
                      "effect": "none: K, b and G do not depend on temperature here"}

    # --- intervals in samples, annotation
    def samples(a, b):
        return [int(np.searchsorted(ts, a, "left")), int(np.searchsorted(ts, b, "right"))]

    labels = np.full(n, None, dtype=object)
    for face, iv in face_iv.items():
        iv["samples"] = samples(*iv["t"])
        if cfg.section:
            lab = [iv["t"][0] + U(0.3, 1.0), iv["t"][1] - U(0.3, 1.0)]
            iv["labelled_t"] = lab
            iv["labelled_samples"] = samples(*lab)
            labels[slice(*iv["labelled_samples"])] = face
    for tr, iv in turn_iv.items():
        iv["samples"] = samples(*iv["t_motion"])
        if cfg.section:
            lab = [iv["t_motion"][0] - U(0.1, 0.4), iv["t_motion"][1] + U(0.1, 0.4)]
            iv["labelled_t"] = lab
            iv["labelled_samples"] = samples(*lab)
            labels[slice(*iv["labelled_samples"])] = tr
    if cfg.section:
        cols["section"] = labels

    # --- truth derived from the physics
    turn_seg = {tr: s for tr, s in zip(turns, [s for s in segs if isinstance(s, Turn)])}
    for tr, iv in turn_iv.items():
        seg = turn_seg[tr]

        def rate(tt, seg=seg):
            Ri, wi = kinematics(seg, tt)
            return np.degrees(wi) + np.einsum("nji,j->ni", Ri, earth_world)

        def earth_part(tt, seg=seg):
            return np.einsum("nji,j->ni", kinematics(seg, tt)[0], earth_world)

        iv["theta_body_deg"] = gauss_integral(rate, seg.t0, seg.t1, breaks=seg.breaks).tolist()
        iv["theta_earth_deg"] = gauss_integral(earth_part, seg.t0, seg.t1, breaks=seg.breaks).tolist()
        n_axis = seg.R.T @ EZ
        iv["axis_body"] = n_axis.tolist()
        iv["axis_tilt_from_sensor_axis_deg"] = float(np.degrees(np.arccos(abs(n_axis[AXES.index(tr[0])]))))
        sl = slice(*iv["samples"])
        iv["peak_rate_dps"] = float(np.abs(w_true[sl]).max())
        iv["Gf_integral_dps_s"] = ((f[sl] @ G.T).sum(0) / fs).tolist() if G is not None else [0.0] * 3

    # what the six faces' noise-free gyro means give (a correct tool's bias) and its uncertainty
    sig_eff = np.sqrt(sigma**2 + (cfg.lsb[0] ** 2 / 12 if cfg.lsb else 0))
    face_means = {fc: g_clean[slice(*iv["samples"])].mean(0) for fc, iv in face_iv.items()}
    b_expected = np.mean(list(face_means.values()), axis=0)
    b_mean = np.mean([bias[slice(*iv["samples"])].mean(0) for iv in face_iv.values()], axis=0)
    nf = np.array([np.diff(iv["samples"])[0] for iv in face_iv.values()])
    b_sigma = sig_eff / len(nf) * np.sqrt((1 / nf).sum())

    Kn = np.zeros((3, 3))
    Kg = np.zeros((3, 3))
    Ks = np.zeros((3, 3))
    Ka_allow = np.zeros((3, 3))
    for tr, iv in turn_iv.items():
        j = AXES.index(tr[0])
        ref = iv["sign"] * 360.0
        Kn[:, j] = K @ np.array(iv["theta_body_deg"]) / ref
        Kg[:, j] = Kn[:, j] + np.array(iv["Gf_integral_dps_s"]) / ref
        N = np.diff(iv["samples"])[0]
        Ks[:, j] = np.sqrt(N * sig_eff**2 / fs**2 + (b_sigma * N / fs) ** 2) / 360.0
        # rate errors no noise model covers: Earth rate during the turn vs in the bias, bias walk,
        # and a tool's G*f with an accel calibrated from tilted faces (<~5 % of G per g)
        slow = (2 * EARTH_RATE if cfg.earth else 0) + (bias.max(0) - bias.min(0)) \
            + (0.05 * np.abs(G).max() if G is not None else 0)
        Ka_allow[:, j] = slow * (N / fs + 0.4) / 360.0

    truth = {
        "kind": kind, "seed": int(seed), "protocol": "ferraris", "file": f"{kind}.parquet",
        "expect": cfg.expect, "acceptable": list(cfg.acceptable), "why": cfg.why,
        "columns": list(cols), "sample_rate_hz": fs, "n_samples": n,
        "t_start": ts[0], "t_end": ts[-1], "dtype": cfg.dtype,
        "K": K.tolist(), "b": b_mean.tolist(), "b_t0": b0.tolist(),
        "b_expected": b_expected.tolist(),
        "b_sigma": b_sigma.tolist(),
        "bias_walk_dps_per_sqrt_s": walk,
        "bias_range": (bias.max(0) - bias.min(0)).tolist(),
        "G": G.tolist() if G is not None else None,
        "noise_sigma_dps": sigma.tolist(), "gyro_lsb_dps": cfg.lsb[0] if cfg.lsb else None,
        "K_nominal": Kn.tolist(), "K_if_G_ignored": Kg.tolist() if G is not None else None,
        "K_sigma": Ks.tolist(),
        "suggested_tolerance": {
            "K_vs_K_nominal": (8 * Ks + Ka_allow).tolist(),
            "K_vs_K": (np.abs(Kn - K) + 8 * Ks + Ka_allow).tolist(),
            "b_vs_b_expected": (8 * b_sigma + (bias.max(0) - bias.min(0))).tolist(),
            "why": "8 noise sigmas (a tool may use fewer still samples than the full intervals) plus "
                   "the slow errors no noise model covers (Earth rate, bias walk, G with a face-"
                   "calibrated accel); K_nominal, not K, is what the 360-deg reference allows; K_vs_K "
                   "is for a tool that also corrects the axis tilt (e.g. from gravity during the turn)",
        },
        "accel": {"present": cfg.accel, "Ka": Ka.tolist(), "ba_g": ba.tolist(), "noise_sigma_g": sigma_a.tolist(),
                  "lsb_g": cfg.lsb[1] if cfg.lsb else None, "lever_arm_m": r_lever.tolist()},
        "earth_rate_world_dps": earth_world.tolist(), "latitude_deg": lat if cfg.earth else None,
        "temperature": temp_model,
        "guide_error_sigma_deg": guide_sigma,
        "ordering": faces + turns, "missing_face": missing,
        "faces": face_iv, "turns": turn_iv,
        "notes": {
            "b": "mean true bias over the face intervals (b(t) = b_t0 + random walk)",
            "b_expected": "noise-free mean of the six face means: b + K*Earth rate + G*f residuals",
            "K_nominal": "K with column j = K theta_body_j / (sign_j * 360): the unavoidable result of a "
                         "perfect tool assuming exactly 360 deg about the sensor axis (guide error, tilt)",
            "K_sigma": "noise-propagated 1-sigma of each K element (turn samples + bias estimate)",
            "K_if_G_ignored": "K_nominal plus the G f integral over each turn / (sign*360): what a tool "
                              "that does not model G gets (gsens only)",
            "turns.theta_body_deg": "integral of the true inertial body rate over t_motion (incl. Earth)",
            "turns.angle_deg": "signed hand angle about the vertical: sign*(nominal + guide error)",
        },
    }
    return Session(kind, seed, cfg, segs, ts, cols, plain(truth), w_true, f, earth_world)


def plain(x):
    """JSON-plain copy: numpy scalars/arrays to Python floats/ints/lists."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_parquet(sess: Session, out_path) -> None:
    """Contract log: t float64, gyro/accel/temp floats, optional dictionary `section` column.
    No pandas metadata, no timestamps: same seed, same bytes."""
    arrays, names = [], []
    for name, v in sess.columns.items():
        a = pa.array(list(v), type=pa.string()).dictionary_encode() if name == "section" else pa.array(v)
        arrays.append(a)
        names.append(name)
    meta = {b"ferraris_gen": json.dumps({"kind": sess.kind, "seed": sess.seed}).encode()}
    table = pa.Table.from_arrays(arrays, names=names).replace_schema_metadata(meta)
    pq.write_table(table, str(out_path), compression="zstd")


def session(kind: str, seed: int, out_path) -> dict:
    """Write one synthetic Ferraris log of this kind to out_path; return its truth (JSON-plain)."""
    sess = build(kind, seed)
    write_parquet(sess, out_path)
    return sess.truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    truths = {}
    for kind in a.kinds:
        truths[kind] = session(kind, a.seed, a.out / f"{kind}.parquet")
        tr = truths[kind]
        print(f"{kind:14s} {tr['n_samples']:6d} samples {tr['sample_rate_hz']:6.1f} Hz "
              f"{tr['t_end'] - tr['t_start']:6.1f} s  expect={tr['expect']}", file=sys.stderr)
    doc = {"generator": "tests/ferraris_gen/generate.py", "seed": a.seed, "kinds": truths}
    (a.out / "truth.json").write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
