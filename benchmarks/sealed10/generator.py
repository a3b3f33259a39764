"""Tenth sealed benchmark: turntable rig-log simulator, standard calibration, contract validator.

SEALED: not to be read by whoever works on the diagnosis.  Written from the rig-log contract,
the three seed papers and general knowledge of MEMS gyroscopes, rate tables, thermal chambers,
fixtures and loggers, without reading the software it scores.

A unit is one physical three-axis MEMS gyro; it is written as three `turntable` sessions (days
0, 2-40 and 45-200), each with a new power-on, new noise and its own order of chamber set
points, mounts and table rates.  The sensor output is

    w = K(T_die) . w_body + B(T_die) + b_on + b_BI(t) + n(t) + a * effect(...)

with w_body the true body rate (table rate along the placed axis, the Earth's rate, the
operator's hand), quantised and clipped by the output stage.  ``a`` is solved per unit so that
the standard calibration of session 0 misses on session 2 by a chosen multiple of the
reference floor (capped by a physical bound per family).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.optimize import brentq
from scipy.signal import butter, lfilter
from scipy.spatial.transform import Rotation

MASTER_SEED = 20261203
MAX_ROWS = 300_000
FS_CHOICES = (10.0, 15.0, 20.0, 30.0, 40.0, 50.0)
TOPS = (80.0, 120.0, 180.0, 240.0, 320.0, 400.0)
TOP_P = (0.1, 0.15, 0.2, 0.2, 0.15, 0.2)
TABLE2 = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 80.0, 100.0, 150.0, 200.0, 250.0, 300.0)
RANGES = (125.0, 250.0, 500.0, 1000.0, 2000.0)
MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")
EARTH = 15.041 / 3600.0  # deg/s
HAND_T = 32.0
EZ = np.array([0.0, 0.0, 1.0])

# ------------------------------------------------------------------------------------------
# Effect families.  reads/acts: what a right fix reads and acts on; for families no sensor
# term can carry, reads/acts are what a fix may read where the truth allows one (else empty).
# cap: physical bound of the amplitude a (units in the comment).
FAMILIES = {
    # total specific force (gravity, centripetal, tangential, hand) on the bias, deg/s per g
    "g_linear": dict(reads=("accel", "mount"), acts=("bias",), reasons=(), carried=True, cap=0.2),
    # anisoelastic g x g products on the bias, deg/s per g^2
    "g_squared": dict(reads=("accel", "mount"), acts=("bias",), reasons=(), carried=True, cap=0.06),
    # odd scale-factor compression towards full scale, fraction of rate at full scale
    "scale_cubic": dict(reads=("rate",), acts=("scale",), reasons=(), carried=True, cap=0.01),
    # square of the rate about one axis seen on the other axes, fraction of full scale
    "rate_sq_cross": dict(reads=("rate",), acts=("cross-axis",), reasons=(), carried=True, cap=0.003),
    # bias settling after each power-on (charging, drive-loop settling), deg/s at power-on
    "warmup_settle": dict(reads=("time",), acts=("bias",), reasons=(), carried=True, cap=0.4),
    # bias from the die temperature's rate (thermal gradients), deg/s per degC/min
    "thermal_rate": dict(reads=("thermal",), acts=("bias",), reasons=(), carried=True, cap=0.15),
    # scale factor changed by the specific force along the sense axis, fraction per g
    "g_scale": dict(reads=("accel", "mount"), acts=("scale",), reasons=(), carried=True, cap=0.004),
    # package-stress hysteresis: bias depends on the side the temperature came from, deg/s
    "thermal_hyst": dict(
        reads=("thermal",), acts=("bias",), reasons=("direction of approach",), carried=False, cap=0.2
    ),
    # shock in transit between sessions 0 and 1: misalignment / scale / bias moved, mrad
    "shock_shift": dict(reads=(), acts=None, reasons=("unit changed",), carried=False, cap=4.0),
    # session 0's table ran its rate off by a common fraction (controller / encoder setting)
    "table_scale": dict(reads=(), acts=None, reasons=("lab",), carried=False, cap=0.004),
    # debris / worn fixture face: each placement tilted by its own angle, rad (1 sigma)
    "fixture_tilt": dict(reads=(), acts=None, reasons=("mounting",), carried=False, cap=0.0175),
    # random telegraph (burst) noise of the bias, deg/s peak to peak
    "burst_noise": dict(reads=(), acts=None, reasons=("slow noise",), carried=False, cap=0.15),
    # narrow bias feature (mode crossing) between the calibration points, deg/s
    "mode_crossing": dict(
        reads=("temperature",), acts=("bias",), reasons=("between points",), carried=False, cap=0.8
    ),
}
N_COMPLETE = 4
TARGET_LO, TARGET_HI = 1.5, 50.0
MAX_DRAWS = 3  # effect draws per unit draw
MAX_UNIT_DRAWS = 4


def _lu(rng, lo, hi, size=None):
    return np.exp(rng.uniform(np.log(lo), np.log(hi), size))


def _sgn(rng, size=None):
    return rng.choice((-1.0, 1.0), size)


# ------------------------------------------------------------------------------------------ plan
def plan(units_per_family=3, seed=MASTER_SEED, quick=False):
    """The list of unit specs (uid, family or None, target multiple, seed)."""
    rng = np.random.default_rng(seed)
    k = max(1, int(units_per_family))
    targets = np.geomspace(TARGET_LO, TARGET_HI, k) if k > 1 else np.array([8.7])
    raw = [(fam, float(m)) for fam in FAMILIES for m in targets]
    raw += [(None, 0.0)] * N_COMPLETE
    order = rng.permutation(len(raw))
    specs = []
    for i, j in enumerate(order):
        fam, m = raw[j]
        specs.append(dict(uid=f"V{i + 1:02d}", family=fam, target=m, seed=[int(seed), i]))
    if quick:
        picks = []
        comp = [s for s in specs if s["family"] is None]
        carr = [s for s in specs if s["family"] and FAMILIES[s["family"]]["carried"]]
        nonc = [s for s in specs if s["family"] and not FAMILIES[s["family"]]["carried"]]
        picks = [comp[0], carr[0], nonc[0], carr[1] if len(carr) > 1 else nonc[1]]
        specs = sorted(picks, key=lambda s: s["uid"])
    return specs


# ------------------------------------------------------------------------------------------ unit
def draw_unit(rng):
    """Physical and protocol parameters of one unit (nuisances)."""
    p = {}
    p["arw"] = _lu(rng, 0.004, 0.025) * rng.uniform(0.8, 1.25, 3)  # deg/s/sqrt(Hz)
    p["bi_kind"] = "gm" if rng.random() < 0.5 else "flicker"
    p["k_bi"] = _lu(rng, 0.15, 2.0) * rng.uniform(0.75, 1.25, 3)
    if p["bi_kind"] == "gm":
        p["bi_tau"] = [float(_lu(rng, 30, 15000))]
    else:
        p["bi_tau"] = list(np.geomspace(_lu(rng, 15, 60), _lu(rng, 2000, 25000), 4))
    p["k_rep"] = float(_lu(rng, 1.0, 4.0))
    # K(T) = K0 + K1 dT + K2 dT^2, B(T) cubic, dT = T - 25
    k0 = np.eye(3) + np.diag(rng.normal(0, 0.008, 3))
    off = rng.normal(0, 0.003, (3, 3))
    np.fill_diagonal(off, 0.0)
    p["K0"] = k0 + off
    k1 = np.diag(_sgn(rng, 3) * _lu(rng, 20e-6, 300e-6, 3))
    k1 += (1 - np.eye(3)) * _sgn(rng, (3, 3)) * _lu(rng, 0.5e-6, 15e-6, (3, 3))
    k2 = np.diag(_sgn(rng, 3) * _lu(rng, 30e-6, 1200e-6, 3)) / 3600.0
    k2 += (1 - np.eye(3)) * _sgn(rng, (3, 3)) * _lu(rng, 1e-6, 80e-6, (3, 3)) / 3600.0
    p["K1"], p["K2"] = k1, k2
    p["B"] = np.stack(
        [
            rng.normal(0, 0.4, 3),
            _sgn(rng, 3) * _lu(rng, 0.002, 0.03, 3),
            _sgn(rng, 3) * _lu(rng, 0.005, 0.15, 3) / 3600.0,
            _sgn(rng, 3) * _lu(rng, 0.002, 0.04, 3) / 216000.0,
        ]
    )
    # thermal path
    p["tau_air"] = float(_lu(rng, 25, 100))
    p["kp"] = float(rng.uniform(0.6, 2.5))
    p["ti"] = float(_lu(rng, 80, 500))
    p["u_lim"] = float(rng.uniform(20, 50))
    p["ramp"] = float(rng.uniform(1.0, 4.0)) / 60.0  # degC/s
    p["ripple"] = (float(_lu(rng, 0.01, 0.15)), float(_lu(rng, 40, 400)))
    p["room"] = float(rng.uniform(18, 27))
    p["tau_door"] = float(_lu(rng, 40, 1200))
    p["tau_case"] = float(_lu(rng, 150, 1500))
    p["tau_die"] = float(_lu(rng, 8, 150)) if rng.random() < 0.55 else 0.0
    p["sh_case"] = float(rng.uniform(0.4, 4.5))
    p["sh_die"] = float(rng.uniform(0.2, 1.8)) if p["tau_die"] > 0 else 0.0
    p["conv"] = 0.0 if rng.random() < 0.35 else float(rng.uniform(0.1, 0.7))
    p["hand_w"] = float(rng.uniform(0.0, 0.45))
    mode = rng.choice(["die", "lag", "lead"], p=[0.3, 0.35, 0.35])
    p["tsens"] = dict(
        mode=str(mode),
        tau=float(_lu(rng, 4, 100)),
        kappa=float(rng.uniform(0.1, 0.5)),
        offset=float(rng.normal(0, 1.2)),
        gain=float(rng.normal(0, 0.008)),
        noise=float(_lu(rng, 0.005, 0.12)),
        q=float(rng.choice([1 / 128, 1 / 32, 1 / 16, 0.1])),
        upd=float(rng.choice([0.0, 0.5, 1.0])),
    )
    # rig, operator, fixture
    p["n_mounts"] = 3 if rng.random() < 0.55 else 6
    p["power_cycle"] = str(rng.choice(["never", "remount", "setpoint"], p=[0.6, 0.2, 0.2]))
    p["power_first"] = "insert" if rng.random() < 0.7 else "late"
    p["reseat"] = float(_lu(rng, 1e-6, 25e-6))
    p["alpha_pk"] = float(_lu(rng, 15, 150))
    p["jitter"] = 0.0 if rng.random() < 0.5 else float(_lu(rng, 1e-6, 8e-5))
    p["radius"] = float(rng.uniform(0.0, 0.09))  # m, fixture off the table centre
    p["lat"] = float(np.radians(rng.uniform(25, 60)))
    p["north"] = float(rng.uniform(0, 2 * np.pi))
    p["tremor"] = float(_lu(rng, 0.3, 4.0))
    # rates
    top = float(rng.choice(TOPS, p=TOP_P))
    p["top"] = top
    below = [m for m in TABLE2 if m < top]
    nmag = int(rng.integers(2, 7))
    p["mags"] = sorted([top] + list(rng.choice(below, size=min(nmag, len(below)), replace=False)))
    p["zero_hold"] = bool(rng.random() < 0.6)
    p["H"] = float(rng.uniform(25, 70))
    p["stop_between"] = bool(rng.random() < 0.3)
    fs_min = 1.25 * top
    p["fs_range"] = float(min(r for r in RANGES if r >= fs_min))
    p["quantise"] = bool(rng.random() < 0.7)
    # accelerometer
    p["accel"] = bool(rng.random() < 0.45)
    p["acc_K"] = np.eye(3) + rng.normal(0, 0.004, (3, 3))
    p["acc_b"] = rng.normal(0, 0.01, 3)
    p["acc_n"] = float(_lu(rng, 0.001, 0.008))
    # file format
    p["time_fmt"] = str(rng.choice(["f0", "epoch", "ts_ns_utc", "ts_ms_berlin", "ts_us"]))
    p["f32"] = bool(rng.random() < 0.5)
    p["mount_col"] = str(rng.choice(["none", "string", "dict"], p=[0.35, 0.35, 0.3]))
    p["rad"] = bool(rng.random() < 0.2)
    p["extra"] = str(rng.choice(["frame", "supply_v", "rig_id"]))
    p["soak_log"] = "full" if rng.random() < 0.2 else "tail"
    p["tail"] = float(rng.uniform(3.0, _lu(rng, 5.0, 14.0))) * 60.0
    p["soak_mult"] = float(rng.uniform(3.5, 7.0))
    return p


def _mount_rotation(label, rng, reseat):
    """Sensor -> table rotation placing sensor axis `label` along the table axis (+z)."""
    s = 1.0 if label[0] == "+" else -1.0
    i = "xyz".index(label[1])
    v = np.zeros(3)
    v[i] = s
    # rotation taking v to EZ
    c = np.cross(v, EZ)
    if np.linalg.norm(c) < 1e-9:
        base = Rotation.identity() if v @ EZ > 0 else Rotation.from_rotvec([np.pi, 0, 0])
    else:
        ang = np.arccos(np.clip(v @ EZ, -1, 1))
        base = Rotation.from_rotvec(c / np.linalg.norm(c) * ang)
    az = Rotation.from_rotvec(EZ * rng.uniform(0, 2 * np.pi))
    seat = Rotation.from_rotvec(rng.normal(0, reseat, 3))
    return seat * az * base


def _mount_vec(label):
    v = np.zeros(3)
    v["xyz".index(label[1])] = 1.0 if label[0] == "+" else -1.0
    return v


# ------------------------------------------------------------------------------------------ schedule
def _set_points(p, rng, s, s0pts, force_mid):
    if s == 0:
        n = int(rng.integers(3, 8))
        lo = 5.0 * round(rng.uniform(-40, -5) / 5.0)
        hi = 5.0 * round(rng.uniform(40, 80) / 5.0)
        pts = np.linspace(lo, hi, n)
        pts[1:-1] += rng.uniform(-2, 2, n - 2)
        return [float(x) for x in pts]
    lo, hi = min(s0pts), max(s0pts)
    srt = sorted(s0pts)
    mode = "mid" if force_mid else str(rng.choice(["same", "mid", "shift"], p=[0.3, 0.35, 0.35]))
    if mode == "same":
        pts = [min(hi, max(lo, x + rng.uniform(-1, 1))) for x in srt]
    elif mode == "mid":
        pts = [0.5 * (a + b) for a, b in zip(srt[:-1], srt[1:], strict=False)]
        if len(pts) < 3 or rng.random() < 0.4:
            pts.append(lo if rng.random() < 0.5 else hi)
    else:
        f = rng.uniform(0.2, 0.8)
        pts = [a + f * (b - a) for a, b in zip(srt[:-1], srt[1:], strict=False)]
        if len(pts) < 3:
            pts.append(hi)
    return sorted(float(x) for x in pts)


def _temp_order(pts, rng, room):
    pts = sorted(pts)
    n = len(pts)
    kind = str(rng.choice(["desc", "middle_out", "cold_then_desc", "hot_then_asc", "shuffle"]))
    if kind == "desc":
        o = pts[::-1]
    elif kind == "middle_out":
        i0 = int(np.argmin([abs(x - room) for x in pts]))
        o, lo, hi, up = [pts[i0]], i0 - 1, i0 + 1, rng.random() < 0.5
        while lo >= 0 or hi < n:
            if (up and hi < n) or lo < 0:
                o.append(pts[hi])
                hi += 1
            else:
                o.append(pts[lo])
                lo -= 1
            up = not up
    elif kind == "cold_then_desc":
        o = [pts[0]] + pts[1:][::-1]
    elif kind == "hot_then_asc":
        o = [pts[-1]] + pts[:-1]
    else:
        o = list(pts)
        while o == pts:
            o = [pts[i] for i in rng.permutation(n)]
    if o == pts:
        o = pts[::-1]
    return o


def _rate_seq(p, rng, kind):
    mags = list(p["mags"])
    if kind == "asc":
        seq = [s * m for m in mags for s in (1, -1)]
    elif kind == "desc":
        seq = [s * m for m in mags[::-1] for s in (-1, 1)]
    elif kind == "shuffle":
        seq = [s * m for m in mags for s in (1, -1)]
        seq = [seq[i] for i in rng.permutation(len(seq))]
    elif kind == "alt":
        seq = []
        for i, m in enumerate(mags):
            seq += [m, -m] if i % 2 == 0 else [-m, m]
    elif kind == "high_first":
        seq = [mags[-1], -mags[-1]] + [s * m for m in mags[:-1] for s in (1, -1)]
    else:  # one sign, then the other
        seq = list(mags[::-1]) + [-m for m in mags]
    if p["zero_hold"]:
        seq.insert(int(rng.integers(0, len(seq) + 1)), 0.0)
    return [float(x) for x in seq]


def _ramp_time(w1, w2, alpha):
    return np.pi * abs(w2 - w1) / (2.0 * alpha) if w2 != w1 else 0.0


class _Timeline:
    """Segments of one session, with the chamber program, door, hand and power intervals."""

    def __init__(self, p, rng):
        self.p, self.rng = p, rng
        self.t = 0.0
        self.segs = []
        self.sp_prog = []  # (t0, T0, t1, T1)
        self.doors, self.hands, self.power, self.unlog = [], [], [], []
        self.places = []
        self.holds = []
        self.theta = float(rng.uniform(0, 2 * np.pi))
        self.on_since = None

    def place(self, label):
        R = _mount_rotation(label, self.rng, self.p["reseat"])
        self.places.append(dict(label=label, R=R, tilt=self.rng.normal(0, 1.0, 2)))
        return len(self.places) - 1

    def idle(self, dur, pl, logged=True):
        if dur <= 0:
            return
        self.segs.append(dict(kind="idle", t0=self.t, t1=self.t + dur, pl=pl, th0=self.theta))
        if not logged:
            self.unlog.append((self.t, self.t + dur))
        self.t += dur

    def ramp(self, w1, w2, pl):
        d = _ramp_time(w1, w2, self.p["alpha_pk"])
        if d <= 0:
            return
        self.segs.append(dict(kind="ramp", t0=self.t, t1=self.t + d, pl=pl, w1=w1, w2=w2, th0=self.theta))
        self.theta += 0.5 * (w1 + w2) * d * np.pi / 180.0
        self.t += d

    def hold(self, w, dur, pl, pid, hid):
        self.segs.append(dict(kind="hold", t0=self.t, t1=self.t + dur, pl=pl, w=w, th0=self.theta))
        self.holds.append(dict(t0=self.t, t1=self.t + dur, pl=pl, rate=w, pid=pid, hid=hid))
        self.theta += w * dur * np.pi / 180.0
        self.t += dur

    def power_on(self):
        if self.on_since is None:
            self.on_since = self.t

    def power_off(self):
        if self.on_since is not None:
            self.power.append((self.on_since, self.t))
            self.on_since = None

    def handle(self, pl_from, label_to, cycle):
        """A person re-mounts the unit; ref_rate stays 0."""
        rng = self.rng
        self.idle(rng.uniform(2, 8), pl_from)
        t_open = self.t
        self.idle(rng.uniform(2, 6), pl_from)
        pl_to = self.place(label_to)
        dur = float(rng.uniform(12.0, max(12.5, _lu(rng, 20, 70))))
        t0 = self.t
        R0 = self.places[pl_from]["R"]
        R2 = self.places[pl_to]["R"]
        Rz = Rotation.from_rotvec(EZ * self.theta)
        Rw0, Rw2 = Rz * R0, Rz * R2
        Rmid = Rw0 * Rotation.from_rotvec(
            Rotation.random(random_state=int(rng.integers(2**31))).as_rotvec() * 0.5
        )
        moves = []
        tm = t0 + rng.uniform(1.0, 4.0)
        Rcur = Rw0
        targets = [Rmid, Rw2]
        for Rt in targets:
            md = float(rng.uniform(0.6, 2.5))
            rv = (Rcur.inv() * Rt).as_rotvec()
            moves.append((tm, tm + md, Rcur, rv))
            Rcur = Rt
            tm += md + rng.uniform(0.3, 2.0)
        dur = max(dur, tm - t0 + rng.uniform(1.0, 3.0))
        self.segs.append(
            dict(kind="handle", t0=t0, t1=t0 + dur, pl=pl_to, moves=moves, Rw0=Rw0, Rw2=Rw2, th0=self.theta)
        )
        self.hands.append((t0, t0 + dur))
        if cycle:  # unit off for the middle of the handling
            self.t = t0 + 0.2 * dur
            self.power_off()
            self.t = t0 + 0.8 * dur
            self.power_on()
        self.t = t0 + dur
        self.idle(rng.uniform(3, 20), pl_to)
        self.doors.append((t_open, self.t))
        return pl_to


def build_schedule(p, rng, s, s0pts, force_mid, late_first):
    tl = _Timeline(p, rng)
    pts = _set_points(p, rng, s, s0pts, force_mid)
    order = _temp_order(pts, rng, p["room"])
    three = [("+" if rng.random() < 0.5 else "-") + a for a in "xyz"] if p["n_mounts"] == 3 else None
    base_m = three or list(MOUNTS)
    base_m = [base_m[i] for i in rng.permutation(len(base_m))]
    morder = str(rng.choice(["fixed", "serpentine", "random"]))
    rkind = str(rng.choice(["asc", "desc", "shuffle", "alt", "high_first", "one_sign"]))
    visits = [(sp, list(base_m)) for sp in order]
    if rng.random() < 0.3:  # revisit an earlier point at the end
        sp = order[int(rng.integers(0, len(order) - 1))]
        k = len(base_m) if rng.random() < 0.5 else int(rng.integers(1, 3))
        visits.append((sp, [base_m[i] for i in rng.permutation(len(base_m))[:k]]))
    for i, (_sp, ms) in enumerate(visits):
        if morder == "serpentine" and i % 2 == 1:
            ms.reverse()
        elif morder == "random":
            visits[i] = (_sp, [ms[j] for j in rng.permutation(len(ms))])
    pid_of = {sp: i for i, sp in enumerate(order)}
    tau_slow = (
        p["tau_air"]
        + p["tau_case"]
        + p["tau_die"]
        + (p["tsens"]["tau"] if p["tsens"]["mode"] == "lag" else 0)
    )
    n_pause = int(rng.integers(0, 4))
    n_remounts = sum(len(ms) for _, ms in visits)
    pause_at = set(rng.choice(n_remounts, size=min(n_pause, n_remounts), replace=False).tolist())
    # insertion: door open, the unit placed at the first mount
    pl = tl.place(visits[0][1][0])
    tl.doors.append((0.0, float(rng.uniform(20, 60))))
    tl.hands.append((0.0, float(rng.uniform(8, 20))))
    late = late_first
    if not late:
        tl.t = float(rng.uniform(3, 25))
        tl.power_on()
        tl.t = 0.0
    sp_prev = p["room"]
    remount_i = 0
    hid = 0
    for vi, (sp, ms) in enumerate(visits):
        cyc_sp = p["power_cycle"] == "setpoint" and vi > 0
        if cyc_sp:
            tl.power_off()
        t_ramp = abs(sp - sp_prev) / p["ramp"]
        tl.sp_prog.append((tl.t, sp_prev, tl.t + t_ramp, sp))
        soak = t_ramp + float(np.clip(p["soak_mult"] * tau_slow, 1200, 5400))
        if late and vi == 0:
            lead = float(_lu(rng, 300, 2400))
            on_at = max(tl.t + 10.0, tl.t + soak - lead)
        elif cyc_sp:
            on_at = (
                tl.t
                + t_ramp
                + (float(rng.uniform(30, 300)) if rng.random() < 0.6 else soak - _lu(rng, 300, 2000))
            )
            on_at = min(max(on_at, tl.t + 10.0), tl.t + soak - 120.0)
        else:
            on_at = None
        t_end = tl.t + soak
        log_from = tl.t if p["soak_log"] == "full" else t_end - p["tail"]
        if on_at is not None:
            tl.idle(on_at - tl.t, pl, logged=False)
            tl.power_on()
        if log_from > tl.t:
            tl.idle(log_from - tl.t, pl, logged=False)
        tl.idle(t_end - tl.t, pl)
        for mi, lab in enumerate(ms):
            if lab != tl.places[pl]["label"] or (vi > 0 and mi == 0 and rng.random() < 0.15):
                if remount_i in pause_at:
                    tl.idle(float(rng.uniform(60, 900)), pl, logged=False)
                remount_i += 1
                pl = tl.handle(pl, lab, p["power_cycle"] == "remount")
                tl.idle(float(rng.uniform(5, _lu(rng, 20, 400))), pl)
            else:
                tl.idle(float(rng.uniform(5, 30)), pl)
            w = 0.0
            for r in _rate_seq(p, rng, rkind):
                tl.ramp(w, r, pl)
                w = r
                tl.hold(r, p["H"], pl, pid_of[sp], hid)
                hid += 1
                if p["stop_between"] and r != 0.0:
                    tl.ramp(w, 0.0, pl)
                    w = 0.0
                    tl.idle(float(rng.uniform(2, 5)), pl)
            tl.ramp(w, 0.0, pl)
            tl.idle(float(rng.uniform(2, 10)), pl)
        sp_prev = sp
    tl.idle(float(rng.uniform(5, 30)), pl)
    tl.power_off()
    tl.sp_order = order
    tl.visits = visits
    return tl


def _logged_intervals(tl):
    """Power-on intervals minus the logger's pauses."""
    out = []
    un = sorted(tl.unlog)
    for a, b in tl.power:
        cur = a
        for u0, u1 in un:
            if u1 <= cur or u0 >= b:
                continue
            if u0 > cur:
                out.append((cur, u0))
            cur = max(cur, u1)
        if cur < b:
            out.append((cur, b))
    return [(a, b) for a, b in out if b - a > 0.5]


# ------------------------------------------------------------------------------------------ thermal
def _gm(rng, n, sigma, tau, dt=1.0):
    phi = np.exp(-dt / tau)
    e = rng.normal(0, sigma * np.sqrt(1 - phi**2), n)
    x0 = rng.normal(0, sigma)
    y = lfilter([1.0], [1.0, -phi], e)
    return y + x0 * phi ** np.arange(1, n + 1)


def _in_intervals(tg, ivs):
    m = np.zeros(tg.size, bool)
    for a, b in ivs:
        m[(tg >= a) & (tg < b)] = True
    return m


def thermal(p, tl, rng):
    n = int(np.ceil(tl.t)) + 3
    tg = np.arange(n, dtype=float)
    sp = np.full(n, p["room"])
    for t0, T0, t1, T1 in tl.sp_prog:
        m = tg >= t0
        if t1 > t0:
            sp[m] = np.where(tg[m] < t1, T0 + (T1 - T0) * (tg[m] - t0) / (t1 - t0), T1)
        else:
            sp[m] = T1
    door = _in_intervals(tg, tl.doors)
    hand = _in_intervals(tg, tl.hands)
    power = _in_intervals(tg, tl.power)
    absw = np.zeros(n)
    for sg in tl.segs:
        if sg["kind"] == "hold":
            absw[(tg >= sg["t0"]) & (tg < sg["t1"])] = abs(sg["w"])
        elif sg["kind"] == "ramp":
            absw[(tg >= sg["t0"]) & (tg < sg["t1"])] = 0.5 * (abs(sg["w1"]) + abs(sg["w2"]))
    room, kp, ti, lim = p["room"], p["kp"], p["ti"], p["u_lim"]
    ta_, td_ = p["tau_air"], p["tau_door"]
    ec = np.exp(-1.0 / p["tau_case"])
    ed = np.exp(-1.0 / p["tau_die"]) if p["tau_die"] > 0 else 0.0
    air = np.empty(n)
    case = np.empty(n)
    die = np.empty(n)
    Ta = Tc = Td = room
    integ = 0.0
    sh_c, sh_d, conv, hw = p["sh_case"], p["sh_die"], p["conv"], p["hand_w"]
    for i in range(n):
        e = sp[i] - Ta
        u = kp * e + integ
        if abs(u) < lim:
            integ += kp * e / ti
        u = min(max(u, -lim), lim)
        target = sp[i] + u
        lam = 1.0 / ta_ + (1.0 / td_ if door[i] else 0.0)
        teq = (target / ta_ + (room / td_ if door[i] else 0.0)) / lam
        Ta = teq + (Ta - teq) * np.exp(-lam)
        env = Ta * (1 - hw) + HAND_T * hw if hand[i] else Ta
        if power[i]:
            env += sh_c / (1.0 + conv * absw[i] / 300.0)
        Tc = env + (Tc - env) * ec
        if p["tau_die"] > 0:
            tgt = Tc + (sh_d if power[i] else 0.0)
            Td = tgt + (Td - tgt) * ed
        else:
            Td = Tc
        air[i], case[i], die[i] = Ta, Tc, Td
    rip = _gm(rng, n, p["ripple"][0], p["ripple"][1])
    # the ripple reaches the case/die through their lags
    rc = lfilter([1 - ec], [1, -ec], rip)
    rd = lfilter([1 - ed], [1, -ed], rc) if p["tau_die"] > 0 else rc
    air += rip
    case += rc
    die += rd
    ts = p["tsens"]
    if ts["mode"] == "die":
        node = die.copy()
    elif ts["mode"] == "lag":
        es = np.exp(-1.0 / ts["tau"])
        node = lfilter([1 - es], [1, -es], die - die[0]) + die[0]
    else:
        node = die + ts["kappa"] * (case - die)
    return dict(tg=tg, air=air, case=case, die=die, node=node, sp=sp)


# ------------------------------------------------------------------------------------------ samples
def _smooth_step(x):
    return 0.5 * (1 - np.cos(np.pi * np.clip(x, 0, 1)))


def kinematics(p, tl, t):
    """Per-sample table rate, ref, body rate, specific force (g), placement index, handling flag."""
    n = t.size
    starts = np.array([sg["t0"] for sg in tl.segs])
    seg_i = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(tl.segs) - 1)
    w_tab = np.zeros(n)
    alpha = np.zeros(n)
    theta = np.zeros(n)
    pl = np.zeros(n, int)
    handling = np.zeros(n, bool)
    w_body = np.zeros((n, 3))
    f_body = np.zeros((n, 3))
    Ew = EARTH * np.array(
        [np.cos(p["lat"]) * np.cos(p["north"]), np.cos(p["lat"]) * np.sin(p["north"]), np.sin(p["lat"])]
    )
    d_off = np.array([np.cos(p["north"] * 1.7), np.sin(p["north"] * 1.7), 0.0])  # fixture offset direction
    r_g = p["radius"] / 9.80665
    for k in np.unique(seg_i):
        sg = tl.segs[k]
        idx = np.arange(np.searchsorted(seg_i, k, "left"), np.searchsorted(seg_i, k, "right"))
        tau = t[idx] - sg["t0"]
        pl[idx] = sg["pl"]
        if sg["kind"] == "handle":
            handling[idx] = True
            wb = np.zeros((idx.size, 3))
            # orientation: piecewise geodesic moves
            rots = Rotation.concatenate([sg["Rw0"]] * idx.size)
            for m0, m1, Rc, rv in sg["moves"]:
                x = (t[idx] - m0) / (m1 - m0)
                s = _smooth_step(x)
                ds = np.where(
                    (x > 0) & (x < 1), 0.5 * np.pi * np.sin(np.pi * np.clip(x, 0, 1)) / (m1 - m0), 0.0
                )
                sel = x > 0
                if sel.any():
                    rr = Rc * Rotation.from_rotvec(s[sel, None] * rv[None, :])
                    rl = rots.as_quat()
                    rl[sel] = rr.as_quat()
                    rots = Rotation.from_quat(rl)
                wb += np.degrees(ds[:, None] * rv[None, :])
            inv = rots.inv()
            f_body[idx] = inv.apply(EZ)
            w_body[idx] = wb + inv.apply(Ew)
            theta[idx] = sg["th0"]
            continue
        R = tl.places[sg["pl"]]["R"]
        u = R.inv().apply(EZ)
        if sg["kind"] == "idle":
            w = np.zeros(idx.size)
            a = np.zeros(idx.size)
            th = np.full(idx.size, sg["th0"])
        elif sg["kind"] == "hold":
            w = np.full(idx.size, sg["w"])
            a = np.zeros(idx.size)
            th = sg["th0"] + np.radians(sg["w"]) * tau
        else:
            w1, w2 = sg["w1"], sg["w2"]
            D = sg["t1"] - sg["t0"]
            x = tau / D
            w = w1 + (w2 - w1) * _smooth_step(x)
            a = (w2 - w1) * 0.5 * np.pi / D * np.sin(np.pi * x)
            th = sg["th0"] + np.radians(
                w1 * tau + (w2 - w1) * (tau / 2 - D / (2 * np.pi) * np.sin(np.pi * x))
            )
        w_tab[idx], alpha[idx], theta[idx] = w, a, th
        # Earth's rate in the table frame rotates backwards with the table
        c, s_ = np.cos(th), np.sin(th)
        e_tab = np.stack([c * Ew[0] + s_ * Ew[1], -s_ * Ew[0] + c * Ew[1], np.full(idx.size, Ew[2])], 1)
        w_body[idx] = w[:, None] * u[None, :] + R.inv().apply(e_tab)
        wr = np.radians(w)
        ar = np.radians(a)
        f_tab = (
            EZ[None, :]
            - (wr**2)[:, None] * r_g * d_off[None, :]
            + ar[:, None] * r_g * np.cross(EZ, d_off)[None, :]
        )
        f_body[idx] = R.inv().apply(f_tab)
    return dict(w_tab=w_tab, alpha=alpha, theta=theta, pl=pl, handling=handling, w_body=w_body, f_body=f_body)


def _tremor(rng, n, fs, amp):
    hi = min(10.0, 0.45 * fs)
    lo = min(3.0, 0.5 * hi)
    b, a = butter(2, [lo / (fs / 2), hi / (fs / 2)], "band")
    x = lfilter(b, a, rng.normal(0, 1, (n, 3)), axis=0)
    sd = x.std() if n > 10 else 1.0
    return amp * x / max(sd, 1e-12)


def simulate_session(p, tl, fs, rng):
    """Sample-level true quantities of one session (no output stage, no effect)."""
    ivs = _logged_intervals(tl)
    t = np.concatenate([np.arange(np.ceil(a * fs), np.ceil(b * fs)) / fs for a, b in ivs])
    th = thermal(p, tl, rng)
    kin = kinematics(p, tl, t)
    n = t.size
    hmask = kin["handling"]
    if hmask.any():
        kin["w_body"][hmask] += _tremor(rng, int(hmask.sum()), fs, p["tremor"])
        kin["f_body"][hmask] += _tremor(rng, int(hmask.sum()), fs, 0.08)
    die = np.interp(t, th["tg"], th["die"])
    ddie = np.interp(t, th["tg"], np.gradient(th["die"]) * 60.0)  # degC/min
    # logged temperature: node, gain, offset, noise, update, quantisation
    ts = p["tsens"]
    node = np.interp(t, th["tg"], th["node"])
    if ts["upd"] > 0:
        tu = np.floor(t / ts["upd"]) * ts["upd"]
        _, first = np.unique(tu, return_index=True)
        grp = np.searchsorted(tu[first], tu)
        vals = np.interp(tu[first], th["tg"], th["node"]) + rng.normal(0, ts["noise"], first.size)
        tlog = vals[grp]
    else:
        tlog = node + rng.normal(0, ts["noise"], n)
    tlog = 25.0 + (tlog - 25.0) * (1 + ts["gain"]) + ts["offset"]
    tlog = np.round(tlog / ts["q"]) * ts["q"]
    # power-ons
    ons = np.array([a for a, _ in tl.power])
    on_i = np.clip(np.searchsorted(ons, t, side="right") - 1, 0, len(ons) - 1)
    t_on = t - ons[on_i]
    # bias instability on the 1 s grid
    wf = white_floor(p)
    bi = np.zeros((n, 3))
    for ax in range(3):
        sig = p["k_bi"][ax] * wf / np.sqrt(len(p["bi_tau"]))
        for tau in p["bi_tau"]:
            bi[:, ax] += np.interp(t, th["tg"], _gm(rng, th["tg"].size, sig, tau))
    b_on = rng.normal(0, p["k_rep"] * wf, (len(ons), 3))[on_i]
    noise = rng.normal(0, 1, (n, 3)) * (p["arw"] * np.sqrt(fs))[None, :]
    # ref rate: encoder jitter while turning
    ref = kin["w_tab"] * (1 + p["jitter"] * rng.normal(0, 1, n))
    return dict(
        t=t,
        fs=fs,
        die=die,
        ddie=ddie,
        tlog=tlog,
        t_on=t_on,
        on_i=on_i,
        bi=bi,
        b_on=b_on,
        noise=noise,
        ref=ref,
        th=th,
        tl=tl,
        **kin,
    )


def white_floor(p):
    return float(np.sqrt(np.mean(p["arw"] ** 2) / (p["H"] - 2.0)))


def K_of(p, T):
    d = T - 25.0
    return p["K0"][None] + p["K1"][None] * d[:, None, None] + p["K2"][None] * (d**2)[:, None, None]


def B_of(p, T):
    d = (T - 25.0)[:, None]
    b = p["B"]
    return b[0][None] + b[1][None] * d + b[2][None] * d**2 + b[3][None] * d**3


def base_output(p, sim):
    K = K_of(p, sim["die"])
    return (
        np.einsum("nij,nj->ni", K, sim["w_body"])
        + B_of(p, sim["die"])
        + sim["b_on"]
        + sim["bi"]
        + sim["noise"]
    )


# ------------------------------------------------------------------------------------------ effects
def draw_effect(fam, p, rng):
    e = dict(fam=fam)
    v = rng.normal(0, 1, 3)
    e["v"] = v / np.linalg.norm(v)
    if fam == "g_linear":
        e["G"] = rng.normal(0, 1, (3, 3)) / np.sqrt(3)
    elif fam == "g_squared":
        Q = rng.normal(0, 1, (3, 3, 3))
        e["Q"] = 0.5 * (Q + Q.transpose(0, 2, 1)) / 3.0
    elif fam in ("scale_cubic", "g_scale"):
        e["s"] = _sgn(rng, 3) * rng.uniform(0.4, 1.0, 3)
    elif fam == "rate_sq_cross":
        C = _sgn(rng, (3, 3)) * rng.uniform(0.3, 1.0, (3, 3))
        np.fill_diagonal(C, 0.0)
        e["C"] = C
    elif fam == "warmup_settle":
        e["tau"] = float(_lu(rng, 1800, 10000))
    elif fam == "thermal_hyst":
        e["half"] = float(_lu(rng, 1.5, 6.0))
    elif fam == "shock_shift":
        e["rot"] = rng.normal(0, 1e-3, 3)
        e["scl"] = rng.normal(0, 0.8e-3, 3)
        e["bias"] = rng.normal(0, 0.01, 3)
        e["drift"] = float(rng.uniform(0.0, 0.3))  # further creep per 100 days
    elif fam == "burst_noise":
        w = np.abs(rng.normal(0, 0.25, 3))
        w[int(rng.integers(0, 3))] = 1.0
        e["v"] = w * _sgn(rng, 3)
        e["dwell"] = (float(_lu(rng, 120, 3000)), float(_lu(rng, 120, 3000)))
    elif fam == "mode_crossing":
        e["w_frac"] = float(rng.uniform(0.06, 0.12))
        e["pos"] = float(rng.uniform(0.35, 0.65))
    return e


def _hyst(Tg, half):
    """Play (backlash) operator of half-width `half` on the die temperature; returns -1..1."""
    out = np.empty(Tg.size)
    pl = Tg[0]
    for i, x in enumerate(Tg):
        if x - pl > half:
            pl = x - half
        elif pl - x > half:
            pl = x + half
        out[i] = (x - pl) / half
    return out


def _telegraph(rng, tg, dwell):
    n = tg.size
    s = np.empty(n)
    state = 1.0 if rng.random() < 0.5 else -1.0
    i = 0
    while i < n:
        d = int(max(1, rng.exponential(dwell[0] if state > 0 else dwell[1])))
        s[i : i + d] = state
        state = -state
        i += d
    return 0.5 * s


def effect_shape(e, p, sim, s, day, unit_info):
    """Output change (deg/s) at unit amplitude for session s; linear in the amplitude."""
    fam = e["fam"]
    n = sim["t"].size
    wb, fb = sim["w_body"], sim["f_body"]
    FS = p["fs_range"]
    if fam == "g_linear":
        return fb @ e["G"].T
    if fam == "g_squared":
        return np.einsum("ijk,nj,nk->ni", e["Q"], fb, fb)
    if fam == "scale_cubic":
        return -e["s"][None, :] * wb * (wb / FS) ** 2
    if fam == "rate_sq_cross":
        return (wb**2 / FS) @ e["C"].T
    if fam == "warmup_settle":
        return np.exp(-sim["t_on"] / e["tau"])[:, None] * e["v"][None, :]
    if fam == "thermal_rate":
        return sim["ddie"][:, None] * e["v"][None, :]
    if fam == "g_scale":
        return e["s"][None, :] * fb * wb
    if fam == "thermal_hyst":
        th = sim["th"]
        h = _hyst(th["die"], e["half"])
        return np.interp(sim["t"], th["tg"], h)[:, None] * e["v"][None, :]
    if fam == "shock_shift":
        if s == 0:
            return np.zeros((n, 3))
        f = 1.0 + e["drift"] * (day - unit_info["day1"]) / 100.0
        dK = np.array(
            [[0, -e["rot"][2], e["rot"][1]], [e["rot"][2], 0, -e["rot"][0]], [-e["rot"][1], e["rot"][0], 0]]
        ) + np.diag(e["scl"])
        return f * (wb @ dK.T + e["bias"][None, :])
    if fam == "table_scale":
        if s != 0:
            return np.zeros((n, 3))
        K = K_of(p, sim["die"])
        u = np.zeros((n, 3))
        m = ~sim["handling"]
        for k in np.unique(sim["pl"][m]):
            sel = m & (sim["pl"] == k)
            u[sel] = sim["tl"].places[k]["R"].inv().apply(EZ)
        return np.einsum("nij,nj->ni", K, sim["w_tab"][:, None] * u)
    if fam == "fixture_tilt":
        out = np.zeros((n, 3))
        m = ~sim["handling"]
        K = K_of(p, sim["die"])
        for k in np.unique(sim["pl"][m]):
            sel = m & (sim["pl"] == k)
            R = sim["tl"].places[k]["R"]
            th = np.array([*sim["tl"].places[k]["tilt"], 0.0])
            # rotating the placement by a small angle th (table frame): w_b -> w_b - R^T(th x w_tab)
            w_tab_vec = R.apply(wb[sel])
            out[sel] = -R.inv().apply(np.cross(th[None, :], w_tab_vec))
        return np.einsum("nij,nj->ni", K, out)
    if fam == "burst_noise":
        tg = sim["th"]["tg"]
        rng = np.random.default_rng(unit_info["burst_seed"] + s)
        return np.interp(sim["t"], tg, _telegraph(rng, tg, e["dwell"]))[:, None] * e["v"][None, :]
    if fam == "mode_crossing":
        pts = sorted(unit_info["s0pts"])
        gaps = np.diff(pts)
        j = int(np.argmax(gaps))
        T0 = pts[j] + e["pos"] * gaps[j]
        w = e["w_frac"] * gaps[j]
        # the feature sits in the true die temperature
        return np.exp(-0.5 * ((sim["die"] - T0) / w) ** 2)[:, None] * e["v"][None, :]
    raise ValueError(fam)


def tilt_accel(sim, a):
    """Specific force under the fixture tilt of amplitude a."""
    fb = sim["f_body"].copy()
    m = ~sim["handling"]
    for k in np.unique(sim["pl"][m]):
        sel = m & (sim["pl"] == k)
        R = sim["tl"].places[k]["R"]
        th = a * np.array([*sim["tl"].places[k]["tilt"], 0.0])
        fb[sel] -= R.inv().apply(np.cross(th[None, :], R.apply(fb[sel])))
    return fb


# ------------------------------------------------------------------------------------------ calibration
def hold_means(sim, out):
    t = sim["t"]
    rows = []
    for h in sim["tl"].holds:
        i0, i1 = np.searchsorted(t, [h["t0"] + 1.0, h["t1"] - 1.0])
        if i1 - i0 < 5:
            continue
        seg = out[i0:i1]
        ok = np.all(np.isfinite(seg), axis=1)
        rows.append(
            (
                seg[ok].mean(0),
                float(np.nanmean(sim["tlog"][i0:i1])),
                h["rate"],
                _mount_vec(sim["tl"].places[h["pl"]]["label"]),
                h["pid"],
            )
        )
    return dict(
        w=np.array([r[0] for r in rows]),
        T=np.array([r[1] for r in rows]),
        r=np.array([r[2] for r in rows]),
        e=np.array([r[3] for r in rows]),
        pid=np.array([r[4] for r in rows]),
    )


def standard_cal(h):
    """K, B (12 parameters) per set point by least squares on hold means, at the mean logged T."""
    Ts, Ks, Bs = [], [], []
    for pid in np.unique(h["pid"]):
        m = h["pid"] == pid
        A = np.column_stack([h["r"][m, None] * h["e"][m], np.ones(m.sum())])
        sol, *_ = np.linalg.lstsq(A, h["w"][m], rcond=None)
        Ts.append(h["T"][m].mean())
        Ks.append(sol[:3].T)
        Bs.append(sol[3])
    o = np.argsort(Ts)
    return np.array(Ts)[o], np.array(Ks)[o], np.array(Bs)[o]


def standard_error(cal, h):
    Ts, Ks, Bs = cal
    n = h["T"].size
    K = np.empty((n, 3, 3))
    B = np.empty((n, 3))
    for i in range(3):
        B[:, i] = np.interp(h["T"], Ts, Bs[:, i])
        for j in range(3):
            K[:, i, j] = np.interp(h["T"], Ts, Ks[:, i, j])
    est = np.linalg.solve(K, (h["w"] - B)[:, :, None])[:, :, 0]
    err = est - h["r"][:, None] * h["e"]
    return float(np.sqrt(np.mean(err**2)))


def _combine(h, hs, a):
    return dict(h, w=h["w"] + a * hs["w"])


# ------------------------------------------------------------------------------------------ output stage
def output_stage(p, out, fs):
    out = out.copy()
    FS = p["fs_range"]
    if p["quantise"]:
        lsb = 2 * FS / 65536.0
        if np.min(p["arw"]) * np.sqrt(fs) < 0.5 * lsb:
            lsb = 2 * FS / 2**20
        out = np.round(out / lsb) * lsb
    return np.clip(out, -FS, FS)


# ------------------------------------------------------------------------------------------ build
def _attempt(spec, attempt):
    """One draw of the unit (nuisances, protocol, effect); the amplitude solved for the target."""
    seed = list(spec["seed"]) + ([attempt] if attempt else [])
    ss = np.random.SeedSequence(seed)
    r_unit, r_sched, r_sim, r_eff, r_fmt = (np.random.default_rng(x) for x in ss.spawn(5))
    fam = spec["family"]
    p = draw_unit(r_unit)
    days = [0, int(r_unit.integers(2, 41)), int(r_unit.integers(45, 201))]
    late_first = [p["power_first"] == "late"] + [bool(r_unit.random() < 0.3) for _ in range(2)]
    # schedules (fs-independent)
    for _ in range(8):
        tls = []
        s0pts = None
        for s in range(3):
            tl = build_schedule(p, r_sched, s, s0pts, fam == "mode_crossing", late_first[s])
            if s == 0:
                s0pts = list(tl.sp_order)
            tls.append(tl)
        logged = max(sum(b - a for a, b in _logged_intervals(tl)) for tl in tls)
        ok = [f for f in FS_CHOICES if logged * f <= MAX_ROWS]
        if ok:
            break
        # too long: fewer magnitudes, shorter holds and tails
        if len(p["mags"]) > 2:
            p["mags"] = p["mags"][1:]
        p["H"] = max(20.0, 0.8 * p["H"])
        p["tail"] = max(180.0, 0.7 * p["tail"])
        p["soak_log"] = "tail"
    fs = float(r_unit.choice(ok))
    sims = [simulate_session(p, tls[s], fs, np.random.default_rng(r_sim.integers(2**63))) for s in range(3)]
    base_raw = [base_output(p, sm) for sm in sims]
    wf = white_floor(p)
    h0q = hold_means(sims[0], output_stage(p, base_raw[0], fs))
    h2q = hold_means(sims[2], output_stage(p, base_raw[2], fs))
    std_base = standard_error(standard_cal(h0q), h2q)
    floor = max(wf, std_base)
    truth = dict(
        uid=spec["uid"],
        family=fam,
        complete=fam is None,
        target=spec["target"],
        white_floor=wf,
        std_base=std_base,
        floor=floor,
        threshold=1.2 * floor,
        fs=fs,
        days=days,
        unit_draw=attempt,
    )
    a = 0.0
    shapes = [None] * 3
    reached, at_cap = True, 1.0
    if fam is None:
        truth.update(reads=set(), acts=set(), reasons=set(), carried=True)
    else:
        F = FAMILIES[fam]
        truth.update(
            reads=set(F["reads"]), acts=set(F["acts"] or ()), reasons=set(F["reasons"]), carried=F["carried"]
        )
        info = dict(s0pts=tls[0].sp_order, day1=days[1], burst_seed=int(r_eff.integers(2**31)))
        h0r, h2r = hold_means(sims[0], base_raw[0]), hold_means(sims[2], base_raw[2])
        best = None  # (reached, amplitude, shapes, draw, ratio at the cap)
        cap = F["cap"]
        m = spec["target"]
        for draw in range(MAX_DRAWS):
            e = draw_effect(fam, p, r_eff)
            sh = [effect_shape(e, p, sims[s], s, days[s], info) for s in range(3)]
            hs0, hs2 = hold_means(sims[0], sh[0]), hold_means(sims[2], sh[2])

            def ratio(x, hs0=hs0, hs2=hs2):
                return standard_error(standard_cal(_combine(h0r, hs0, x)), _combine(h2r, hs2, x)) / floor

            grid = cap * np.logspace(-5, 0, 41)
            rs = np.array([ratio(x) for x in grid])
            if rs[-1] >= m:
                k = int(np.argmax(rs >= m))
                lo = grid[k - 1] if k > 0 else 0.0
                amp = brentq(lambda x, m=m, ratio=ratio: ratio(x) - m, lo, grid[k], xtol=1e-12 * cap)
                best = (True, amp, sh, draw, float(rs[-1]))
                break
            if best is None or rs[-1] > best[4]:
                best = (False, cap, sh, draw, float(rs[-1]))
        reached, a, shapes, draw, at_cap = best
        truth.update(amplitude=float(a), cap=cap, capped=not reached, draws=draw + 1, ratio_at_cap=at_cap)
    return dict(
        reached=reached,
        at_cap=at_cap,
        p=p,
        sims=sims,
        base_raw=base_raw,
        shapes=shapes,
        a=a,
        truth=truth,
        tls=tls,
        days=days,
        fs=fs,
        r_fmt=r_fmt,
    )


def build_unit(spec):
    """Three sessions of one unit and its truth.  A unit whose effect cannot reach its target
    within the family's bound is drawn again (nuisances, protocol and effect), up to
    MAX_UNIT_DRAWS times, keeping the strongest."""
    best = None
    for attempt in range(MAX_UNIT_DRAWS if spec["family"] else 1):
        res = _attempt(spec, attempt)
        if res["reached"]:
            best = res
            break
        if best is None or res["at_cap"] > best["at_cap"]:
            best = res
        res = None
    r = best
    p, sims, fs, a, fam = r["p"], r["sims"], r["fs"], r["a"], spec["family"]
    truth = r["truth"]
    sessions = []
    finals = []
    for s in range(3):
        out = r["base_raw"][s] + (a * r["shapes"][s] if r["shapes"][s] is not None else 0.0)
        outq = output_stage(p, out, fs)
        finals.append(outq)
        fb = tilt_accel(sims[s], a) if fam == "fixture_tilt" else sims[s]["f_body"]
        rng = np.random.default_rng(r["r_fmt"].integers(2**63))
        sessions.append(_table(p, sims[s], outq, fb, r["days"][s], s, rng))
    hf0, hf2 = hold_means(sims[0], finals[0]), hold_means(sims[2], finals[2])
    truth["std_final"] = standard_error(standard_cal(hf0), hf2)
    truth["ratio"] = truth["std_final"] / truth["floor"]
    truth["protocol"] = dict(
        n_mounts=p["n_mounts"],
        top=p["top"],
        H=p["H"],
        accel=p["accel"],
        time_fmt=p["time_fmt"],
        rad=p["rad"],
        power_cycle=p["power_cycle"],
        points=[len(tl.sp_order) for tl in r["tls"]],
    )
    return dict(truth=truth, sessions=sessions)


def _table(p, sim, out, fb, day, s, rng):
    """The Parquet table of one session, in the unit's file format."""
    t = sim["t"]
    n = t.size
    gyro = out.copy()
    temp = sim["tlog"].copy()
    ref = sim["ref"].copy()
    if p["rad"]:
        gyro = np.radians(gyro)
        ref = np.radians(ref)
    # a few NaN rows during handling
    if rng.random() < 0.2 and sim["handling"].any():
        hi = np.nonzero(sim["handling"])[0]
        bad = rng.choice(hi, size=min(int(rng.integers(1, 7)), hi.size), replace=False)
        gyro[bad, int(rng.integers(0, 3))] = np.nan
    ft = pa.float32() if p["f32"] else pa.float64()
    cols = {}
    epoch0 = 1767225600.0 + 86400.0 * (day + 30) + 3600.0 * 7 + float(rng.uniform(0, 7200))
    tf = p["time_fmt"]
    if tf == "f0":
        cols["t"] = pa.array(t - t[0], pa.float64())
    elif tf == "epoch":
        cols["t"] = pa.array(epoch0 + t, pa.float64())
    else:
        unit = {"ts_ns_utc": "ns", "ts_ms_berlin": "ms", "ts_us": "us"}[tf]
        tz = {"ts_ns_utc": "UTC", "ts_ms_berlin": "Europe/Berlin", "ts_us": None}[tf]
        mul = {"ns": 1e9, "ms": 1e3, "us": 1e6}[unit]
        iv = np.round((epoch0 + t) * mul).astype(np.int64)
        cols["t"] = pa.array(iv, pa.timestamp(unit, tz=tz))
    for i, a in enumerate("xyz"):
        cols[f"gyro_{a}"] = pa.array(gyro[:, i], ft)
    cols["temp"] = pa.array(temp, ft)
    cols["ref_rate"] = pa.array(ref, ft)
    if p["mount_col"] != "none":
        labels = np.array([pl["label"] for pl in sim["tl"].places])[sim["pl"]]
        arr = pa.array(labels.tolist(), pa.string())
        cols["mount"] = arr.dictionary_encode() if p["mount_col"] == "dict" else arr
    if p["accel"]:
        acc = fb @ p["acc_K"].T + p["acc_b"][None, :] + rng.normal(0, p["acc_n"], (n, 3))
        acc = np.clip(acc, -8.0, 8.0)
        for i, a in enumerate("xyz"):
            cols[f"accel_{a}"] = pa.array(acc[:, i], ft)
    if p["extra"] == "frame":
        cols["frame"] = pa.array(np.round(t * sim["fs"]).astype(np.int64), pa.int64())
    elif p["extra"] == "supply_v":
        cols["supply_v"] = pa.array(3.3 + 0.004 * rng.normal(0, 1, n), pa.float32())
    else:
        cols["rig_id"] = pa.array(["TT-2"] * n, pa.string()).dictionary_encode()
    meta = {b"rig.chamber": b"climatic chamber, single-axis rate table", b"rig.session": str(s).encode()}
    if p["rad"]:
        meta[b"gyrocal.units"] = json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()
    tab = pa.table(cols).replace_schema_metadata(meta)
    return dict(t=t, table=tab)


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    paths = []
    for s, ss in enumerate(built["sessions"]):
        path = os.path.join(folder, f"session{s}.parquet")
        pq.write_table(ss["table"], path, compression="zstd")
        paths.append(path)
    return paths


# ------------------------------------------------------------------------------------------ validator
REQUIRED = ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate")


def validate_log(path):
    """Problems of one log against the rig-log contract (empty list when it follows it)."""
    probs = []
    try:
        tab = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        return [f"unreadable: {exc}"]
    sch = tab.schema
    for c in REQUIRED:
        if c not in sch.names:
            probs.append(f"missing column {c}")
    if probs:
        return probs
    tt = sch.field("t").type
    if pa.types.is_timestamp(tt):
        tv = tab.column("t").cast(pa.int64()).to_numpy()
    elif pa.types.is_float64(tt):
        tv = tab.column("t").to_numpy()
    else:
        probs.append(f"t has type {tt}")
        tv = None
    if tv is not None:
        if not np.all(np.isfinite(tv.astype(float))):
            probs.append("t not finite")
        if tv.size < 2 or not np.all(np.diff(tv) > 0):
            probs.append("t not strictly increasing")
    for c in ("gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "accel_x", "accel_y", "accel_z"):
        if c in sch.names:
            ty = sch.field(c).type
            if not (pa.types.is_float32(ty) or pa.types.is_float64(ty)):
                probs.append(f"{c} has type {ty}")
    acc = [c for c in ("accel_x", "accel_y", "accel_z") if c in sch.names]
    if acc and len(acc) != 3:
        probs.append("partial accelerometer columns")
    if "mount" in sch.names:
        ty = sch.field("mount").type
        if pa.types.is_dictionary(ty):
            vals = tab.column("mount").cast(pa.string()).to_pylist()
        elif pa.types.is_string(ty) or pa.types.is_large_string(ty):
            vals = tab.column("mount").to_pylist()
        else:
            vals = None
            probs.append(f"mount has type {ty}")
        if vals is not None and not set(vals) <= set(MOUNTS):
            probs.append(f"mount words {sorted(set(vals) - set(MOUNTS))[:5]}")
    md = sch.metadata or {}
    if b"gyrocal.units" in md:
        try:
            u = json.loads(md[b"gyrocal.units"])
            if not isinstance(u, dict) or not set(u) <= {"gyro", "ref_rate"}:
                probs.append("gyrocal.units keys")
            elif not set(u.values()) <= {"rad/s", "deg/s"}:
                probs.append("gyrocal.units values")
        except ValueError:
            probs.append("gyrocal.units not JSON")
    # physics checks the contract implies: ref 0 while handled, no row all NaN in t
    ref = tab.column("ref_rate").to_numpy(zero_copy_only=False)
    if np.isnan(ref).all():
        probs.append("ref_rate all NaN")
    g = np.column_stack(
        [tab.column(c).to_numpy(zero_copy_only=False) for c in ("gyro_x", "gyro_y", "gyro_z")]
    )
    if np.mean(~np.isfinite(g).all(1)) > 0.01:
        probs.append("more than 1 % of rows not finite")
    return probs


if __name__ == "__main__":  # generate and validate every unit (does not run the tool)
    import sys
    import tempfile
    import time
    from concurrent.futures import ProcessPoolExecutor

    def _one(spec):
        t0 = time.time()
        built = build_unit(spec)
        with tempfile.TemporaryDirectory() as d:
            paths = write_unit(built, d)
            probs = [m for pth in paths for m in validate_log(pth)]
        return spec["uid"], len(probs), [ss["t"].size for ss in built["sessions"]], time.time() - t0

    jobs = int(sys.argv[1]) if len(sys.argv) > 1 else 2
    specs = plan()
    t0 = time.time()
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        res = list(ex.map(_one, specs))
    bad = sum(r[1] > 0 for r in res)
    logs = 3 * len(res)
    rows = [x for r in res for x in r[2]]
    print(f"{len(res)} units, {logs} logs, rows {min(rows)}-{max(rows)}, problems in {bad} unit(s)")
    print(f"wall {time.time() - t0:.0f}s, per unit {np.mean([r[3] for r in res]):.1f}s")
