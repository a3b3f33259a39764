"""Sealed benchmark 3: a generator of turntable rig logs with known truth.

SEALED.  This file holds the effect families, their physics, their parameters and the
protocol conventions of the third sealed set.  Whoever develops or tunes the diagnosis
must not read it; they read only README.md's usage/scoring section and run.py's aggregate
table.

Written by a helper from: the rig-log contract (``/work/shared/spec/log-format.md``), the
papers in ``/work/shared/seeds/`` (multi-temperature turntable calibration with the
12-parameter K(T), B(T) model; temperature drift) and general knowledge of MEMS gyroscopes,
rate tables, thermal chambers and fixtures.  It never read the software it scores; its
only contact is ``benchmarks/judge.py::judge_unit`` as a black box (see run.py).

Every unit is one physical three-axis MEMS gyro with:

- K(T) = I + diag(scale(T)) + misalignment(T), gently curved in temperature, and B(T);
- white rate noise (ARW), a Gauss-Markov bias instability, a turn-on bias drawn anew at
  every power-on (a few deg/h, of the order of the hold-mean noise floor), a die
  temperature that follows the chamber air through a first-order lag plus self-heating
  (so the first holds after a soak still settle a little), a temperature sensor with offset,
  noise and quantisation, an accelerometer where the variant has one, and a fixture that is
  repeatable to a few micro-radians at every remount;
- handling between mounts: real motion while ``ref_rate`` is 0, and the chamber door opened,
  so the die temperature dips towards room and recovers during the next holds.

How the nuisances are to be judged (the truth below): they are all present in every unit,
complete or not, at realistic small levels; a correct diagnosis of a complete unit is
``quiet``.  In particular a change of turn-on bias between sessions at the repeatability
level drawn here (a few deg/h, about one or two hold-mean floors) is normal behaviour of a
MEMS gyro, not a "unit changed": it is part of what a complete model leaves on the unseen
session and enters the reference floor of every unit.

Each unit is written as three sessions (s0 diagnosed, s1 the other session, s2 unseen)
with new noise, a new power-on, and their own temperature order, approach convention,
mount order and rate order.

Effect families (10), each a dict in ``FAMILIES`` with the truth used for scoring:

carried by a sensor term (present identically in every session):

1. ``offcentre_gsens``  the fixture puts the unit 6-15 cm off the table axis (so the
   accelerometer sees omega^2 r besides gravity) and the gyro has a g-sensitivity matrix:
   a bias proportional to specific force.  Confusable with an even rate nonlinearity
   (omega^2) and with a per-mount bias.  Right: reads accel, acts on bias.
2. ``thermal_transient_scale``  stress from temperature gradients across the package during
   transients (settling, door openings) shifts the mode split and so the scale factor in
   proportion to dT/dt.  Right: reads thermal, acts on scale.
3. ``centrifugal_cross``  centrifugal load on the proof mass for rotation about one axis
   leaks into the other channels as a bias proportional to that rate squared (even in
   sign).  Confusable with 1 (rate^2 pattern, but the accelerometer shows no matching
   omega^2 r).  Right: reads rate, acts on cross-axis (or bias).
4. ``gdep_scale``  acceleration along the input axis changes the suspension stiffness and so
   the scale factor: on the six-mount protocol +i and -i disagree in scale.  Confusable with
   a fixture/mount effect.  Right: reads accel, acts on scale.

not carried by any sensor term:

5. ``ref_timebase``  the logging PC's time base (or its encoder-count setting) differs
   between sessions, so ``ref_rate`` is scaled by the same factor for every axis in some
   sessions.  Confusable with a scale change of the unit.  Right reason: lab.
6. ``fixture_burr``  a burr or chip under the fixture base tilts the whole cube by a
   different small angle in some sessions; the accelerometer sees the tilt.  Confusable
   with a misalignment change of the unit.  Right reason: mounting.
7. ``stress_relax``  the die-attach stress relaxes after the first thermal cycles (after
   s0): the bias temperature coefficient changes between s0 and s1/s2.  Right reason:
   unit changed.
8. ``mode_crossing``  a parasitic mode crosses the drive frequency in a narrow temperature
   window lying between two of s0's set points; s1 and s2 verify at intermediate
   temperatures.  Right reason: between points (or a fix reading temperature acting on
   the right quantity, if it does fix s2).
9. ``popcorn``  burst (random telegraph) noise of the bias on one or two channels, dwell
   times of minutes, new in every session.  Right reason: slow noise.
10. ``warpage_hysteresis``  package warpage with hysteresis (a play operator of a few deg C)
    tilts the sense axes differently when a set point is approached from above or below;
    s0 approaches every point from one side, s2 from the other.  Right reason: direction of
    approach (or a fix reading thermal acting on cross-axis, if it fixes s2).

Magnitude: each effect unit's amplitude is scaled so that the extra hold-mean RMS error it
causes on s2, after the standard per-set-point calibration of s0 (12 parameters per set
point, linear interpolation in temperature), is k times the unit's reference floor, with k
log-stratified over [1.5, 50].  The reference floor is max(a, b): (a) the true white-noise
floor of a hold mean, sqrt(mean ARW^2 / (H - 2 s)), (b) the RMS hold-mean error that the
standard calibration leaves on s2 for the same unit with the same noise and no effect.

Protocol variants (every family appears on every variant its physics allows):

- ``A``: three mounts with random signs, accelerometer, ``mount`` column, float ``t``;
- ``B``: six mounts, accelerometer, no ``mount`` column, ``t`` as a timestamp;
- ``C``: three mounts with random signs, no accelerometer, ``mount`` column, rates in rad/s
  (the contract's ``gyrocal.units`` metadata).

Temperature orders: descending, shuffled, zigzag, cold-first zigzag, shuffled with a
revisited point; approach conventions: direct, overshoot from above, overshoot from below.
Rate orders: alternating up, alternating down, sweep through zero, negative first, shuffled,
optionally reversed on every other mount.  Sessions may pause the logger during a soak.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.signal import lfilter

FS = 10.0                 # Hz
DT = 1.0 / FS
G0 = 9.80665
ROOM = 23.0
K_MIN, K_MAX = 1.5, 50.0
D2R = math.pi / 180.0

LABELS = ("+x", "-x", "+y", "-y", "+z", "-z")

VARIANTS = {
    "A": dict(six=False, accel=True, mount_col=True, t_kind="float", rad=False),
    "B": dict(six=True, accel=True, mount_col=False, t_kind="timestamp", rad=False),
    "C": dict(six=False, accel=False, mount_col=True, t_kind="float", rad=True),
}

# truth per family: carried (a sensor term can carry it), reads/acts (a fix's right story),
# reasons (right no_sensor_term reasons), variants it can be written on.
FAMILIES = {
    "offcentre_gsens": dict(carried=True, reads={"accel"}, acts={"bias"}, reasons=set(),
                            variants="AB"),
    "thermal_transient_scale": dict(carried=True, reads={"thermal"}, acts={"scale"},
                                    reasons=set(), variants="ABC"),
    "centrifugal_cross": dict(carried=True, reads={"rate"}, acts={"cross-axis", "bias"},
                              reasons=set(), variants="ABC"),
    "gdep_scale": dict(carried=True, reads={"accel"}, acts={"scale"}, reasons=set(),
                       variants="B"),
    "ref_timebase": dict(carried=False, reads=set(), acts=set(), reasons={"lab"},
                         variants="ABC"),
    "fixture_burr": dict(carried=False, reads=set(), acts=set(), reasons={"mounting"},
                         variants="AB"),
    "stress_relax": dict(carried=False, reads=set(), acts=set(), reasons={"unit changed"},
                         variants="ABC"),
    "mode_crossing": dict(carried=False, reads={"temperature"}, acts=None,  # per unit
                          reasons={"between points"}, variants="ABC"),
    "popcorn": dict(carried=False, reads=set(), acts=set(), reasons={"slow noise"},
                    variants="ABC"),
    "warpage_hysteresis": dict(carried=False, reads={"thermal"}, acts={"cross-axis"},
                               reasons={"direction of approach"}, variants="ABC"),
}

GRIDS = ([-40.0, -10.0, 20.0, 50.0], [-40.0, -20.0, 0.0, 20.0, 40.0],
         [-30.0, 0.0, 30.0, 50.0], [-40.0, -15.0, 10.0, 35.0])


# ============================================================================ geometry
def mount_rotation(label):
    """R (sensor <- table): table z (the rig axis, up) maps to the label's sensor axis."""
    k = "xyz".index(label[1])
    s = 1.0 if label[0] == "+" else -1.0
    ez = np.zeros(3)
    ez[k] = s
    ex = np.zeros(3)
    ex[(k + 1) % 3] = 1.0
    ey = np.cross(ez, ex)
    return np.column_stack([ex, ey, ez])


def tilt_vector(R, d):
    """Sensor-frame change of the rig axis for a small tilt d = (dx, dy) of the cube."""
    return R @ np.array([-d[1], d[0], 0.0])


# ============================================================================ plan
def _kgrid(n, rng):
    lo, hi = math.log(K_MIN), math.log(K_MAX)
    return [math.exp(lo + (j + rng.uniform(0.05, 0.95)) / n * (hi - lo)) for j in range(n)]


def plan(units_per_family=2, seed=20250917, quick=False, complete_per_variant=2):
    """The list of unit specs (uid, family or None, variant, seed, k), in a seeded order."""
    rng = np.random.default_rng(seed)
    specs = []
    for fi, (fam, F) in enumerate(FAMILIES.items()):
        ks = _kgrid(units_per_family, rng)
        for j in range(units_per_family):
            var = F["variants"][(j + fi) % len(F["variants"])]
            specs.append(dict(family=fam, variant=var, k=ks[j],
                              seed=int(rng.integers(1, 2**31 - 1))))
    for var in "ABC":
        for j in range(complete_per_variant):
            specs.append(dict(family=None, variant=var, k=0.0, shifted=(j % 2 == 1),
                              seed=int(rng.integers(1, 2**31 - 1))))
    if quick:                        # one effect unit per variant (three families), one complete
        pick, fams = [], set()
        for var in "ABC":
            for s in specs:
                if s["family"] and s["family"] not in fams and s["variant"] == var:
                    pick.append(s)
                    fams.add(s["family"])
                    break
        pick += [s for s in specs if s["family"] is None][:1]
        specs = pick
    order = rng.permutation(len(specs))
    specs = [specs[i] for i in order]
    for i, s in enumerate(specs):
        s["uid"] = f"u{i:03d}"
    return specs


# ============================================================================ unit and protocol
def draw_unit(rng, variant):
    V = VARIANTS[variant]
    u = dict(variant=variant)
    u["arw"] = rng.uniform(0.004, 0.007, 3)                 # deg/s/sqrt(Hz)
    u["b0"] = rng.normal(0, 0.3, 3)                         # deg/s
    u["b1"] = rng.normal(0, 0.004, 3)                       # deg/s/C
    u["b2"] = rng.normal(0, 3e-6, 3)                        # deg/s/C^2
    k0 = np.diag(rng.normal(0, 0.01, 3))
    m0 = rng.normal(0, 0.004, (3, 3))
    np.fill_diagonal(m0, 0.0)
    u["K0"] = np.eye(3) + k0 + m0
    k1 = np.diag(rng.normal(0, 1.5e-4, 3))
    m1 = rng.normal(0, 4e-6, (3, 3))
    np.fill_diagonal(m1, 0.0)
    u["K1"] = k1 + m1                                       # per C
    u["K2"] = np.diag(rng.normal(0, 2e-8, 3))               # per C^2
    u["turn_on"] = rng.uniform(0.0006, 0.0012)              # deg/s, 1 sigma per power-on
    u["bi_sigma"] = rng.uniform(0.0003, 0.0006)             # deg/s
    u["bi_tau"] = rng.uniform(200.0, 600.0)                 # s
    u["gsens"] = rng.normal(0, 1e-4, (3, 3))                # deg/s/g, negligible
    u["t_off"] = rng.normal(0, 1.0)
    u["tau_die"] = rng.uniform(90.0, 150.0)
    u["self_heat"] = rng.uniform(1.5, 3.0)
    u["door"] = rng.uniform(0.08, 0.25)
    u["radius"] = rng.uniform(0.0, 0.02)                    # m, fixture off-centre
    u["acc_M"] = np.eye(3) + rng.normal(0, 2e-3, (3, 3))
    u["acc_b"] = rng.normal(0, 0.01, 3)
    u["face"] = {lab: rng.normal(0, 2e-6, 2) for lab in LABELS}
    u["jitter"] = 2e-6
    # protocol constants of this unit's line
    u["H"] = float(rng.choice([30.0, 30.0, 40.0]))
    u["grid"] = list(GRIDS[int(rng.integers(len(GRIDS)))])
    mags = [1.0, 10.0, 50.0, 100.0]
    if rng.random() < 0.5:
        mags = [0.1] + mags
    if rng.random() < 0.35:
        mags.append(150.0)
    mags.append(float(rng.choice([200.0, 250.0])))
    u["mags"] = mags
    u["alpha"] = rng.uniform(60.0, 150.0)                   # deg/s^2
    if V["six"]:
        u["mounts"] = list(LABELS)
    else:
        u["mounts"] = [("+" if rng.random() < 0.6 else "-") + ax for ax in "xyz"]
    return u


def temp_order(rng, grid, style):
    g = sorted(grid)
    if style == "descending":
        return g[::-1]
    if style in ("zigzag", "coldzig"):
        lo, hi, out = 0, len(g) - 1, []
        take_hi = style == "zigzag"
        while lo <= hi:
            if take_hi:
                out.append(g[hi])
                hi -= 1
            else:
                out.append(g[lo])
                lo += 1
            take_hi = not take_hi
        return out
    while True:
        out = [g[i] for i in rng.permutation(len(g))]
        if out != g and out != g[::-1]:
            break
    if style == "revisit":
        mid = g[1 + int(rng.integers(len(g) - 2))]
        if out[-1] == mid:
            out = out[::-1]
        out.append(mid)
    return out


def rate_order(rng, mags, style):
    if style == "alt_up":
        return [0.0] + [s * m for m in mags for s in (1.0, -1.0)]
    if style == "alt_down":
        return [s * m for m in mags[::-1] for s in (-1.0, 1.0)] + [0.0]
    if style == "sweep":
        return [m for m in mags[::-1]] + [0.0] + [-m for m in mags]
    if style == "neg_first":
        return [-m for m in mags] + [0.0] + [m for m in mags[::-1]]
    allr = [0.0] + [s * m for m in mags for s in (1.0, -1.0)]
    return [allr[i] for i in rng.permutation(len(allr))]


def draw_session_protocol(rng, u, shifted=False, tstyle=None, approach="random"):
    grid = list(u["grid"])
    if shifted:
        g = sorted(grid)
        grid = [0.5 * (g[i] + g[i + 1]) for i in range(len(g) - 1)]
    if tstyle is None:
        tstyle = str(rng.choice(["descending", "shuffled", "zigzag", "coldzig", "revisit"]))
    if len(grid) < 4 and tstyle == "revisit":
        tstyle = "shuffled"
    if approach == "random":
        r = rng.random()
        approach = None if r < 0.6 else ("above" if r < 0.8 else "below")
    mounts = list(u["mounts"])
    mounts = [mounts[i] for i in rng.permutation(len(mounts))]
    rstyle = str(rng.choice(["alt_up", "alt_down", "sweep", "neg_first", "shuffled"]))
    return dict(grid=grid, order=temp_order(rng, grid, tstyle), approach=approach,
                mounts=mounts, rates=rate_order(rng, u["mags"], rstyle),
                rate_snake=bool(rng.random() < 0.5), soak=float(rng.uniform(6.5, 8.0) * u["tau_die"]),
                gap=bool(rng.random() < 0.3), overshoot=8.0,
                ch_rate=float(rng.uniform(4.0, 6.0)), t0=float(rng.uniform(50.0, 5000.0)))


# ============================================================================ timeline
class Timeline:
    """Sample-by-sample schedule of one session: table rate, chamber set point, door,
    mount slot, holds."""

    def __init__(self, u, rng):
        self.u, self.rng = u, rng
        self.om, self.cset, self.door, self.slot = [], [], [], []
        self.n = 0
        self.cur_om = 0.0
        self.cur_c = ROOM
        self.cur_slot = 0
        self.slots = []          # dicts: label, visit
        self.holds = []          # dicts: i0, i1, rate, slot, visit, sp
        self.handling = []       # (i0, n, slot_from, slot_to)
        self.gaps = []           # (i0, i1) rows dropped from the log
        self.visit, self.sp = -1, ROOM

    def _add(self, om, cset, door):
        n = len(om)
        self.om.append(np.asarray(om, float))
        self.cset.append(np.asarray(cset, float))
        self.door.append(np.full(n, door, np.int8))
        self.slot.append(np.full(n, self.cur_slot, np.int32))
        self.n += n

    def static(self, dur, c_to=None):
        n = max(1, int(round(dur * FS)))
        c_to = self.cur_c if c_to is None else c_to
        c = np.linspace(self.cur_c, c_to, n + 1)[1:]
        self._add(np.full(n, self.cur_om), c, 0)
        self.cur_c = c_to

    def chamber(self, target, rate_c_per_min):
        dur = abs(target - self.cur_c) / rate_c_per_min * 60.0
        if dur > 0:
            self.static(dur, target)

    def rate_to(self, w1):
        w0 = self.cur_om
        if w1 != w0:
            n = max(1, int(math.ceil(abs(w1 - w0) / self.u["alpha"] * FS)))
            om = np.linspace(w0, w1, n + 1)[1:]
            self._add(om, np.full(n, self.cur_c), 0)
        self.cur_om = w1
        # servo settling: a short damped ripple the encoder also sees
        n = int(2.0 * FS)
        tt = np.arange(1, n + 1) * DT
        rip = 0.004 * abs(w1 - w0) * np.exp(-tt / 0.4) * np.sin(2 * np.pi * 1.3 * tt)
        self._add(w1 + rip, np.full(n, self.cur_c), 0)

    def hold(self, w, H):
        n = int(round(H * FS))
        i0 = self.n
        self._add(np.full(n, w), np.full(n, self.cur_c), 0)
        self.holds.append(dict(i0=i0, i1=i0 + n, rate=w, slot=self.cur_slot,
                               visit=self.visit, sp=self.sp))

    def new_slot(self, label):
        self.slots.append(dict(label=label, visit=self.visit))
        return len(self.slots) - 1

    def handle(self, label, dur):
        n = int(round(dur * FS))
        i0 = self.n
        self._add(np.zeros(n), np.full(n, self.cur_c), 1)
        s_from = self.cur_slot
        self.cur_slot = self.new_slot(label)
        self.handling.append((i0, n, s_from, self.cur_slot))

    def arrays(self):
        return (np.concatenate(self.om), np.concatenate(self.cset),
                np.concatenate(self.door), np.concatenate(self.slot))


def run_protocol(u, sp, rng):
    tl = Timeline(u, rng)
    tl.cur_slot = tl.new_slot(sp["mounts"][0])
    tl.static(150.0)                                   # power-on at room temperature
    cur_label = sp["mounts"][0]
    mounts = list(sp["mounts"])
    for vi, T in enumerate(sp["order"]):
        tl.visit, tl.sp = vi, T
        if sp["approach"] in ("above", "below"):
            pre = T + (sp["overshoot"] if sp["approach"] == "above" else -sp["overshoot"])
            tl.chamber(pre, sp["ch_rate"])
            tl.static(360.0)
        tl.chamber(T, sp["ch_rate"])
        i_soak = tl.n
        tl.static(sp["soak"])
        if sp["gap"] and vi == 1:
            a = i_soak + int(120 * FS)
            tl.gaps.append((a, a + int(90 * FS)))
        vm = mounts if vi % 2 == 0 else mounts[::-1]
        if vm[0] != cur_label:                         # keep the unit where it is
            vm = [cur_label] + [m for m in vm if m != cur_label]
        for mi, lab in enumerate(vm):
            if lab != cur_label:
                tl.rate_to(0.0)
                tl.handle(lab, rng.uniform(28.0, 50.0))
                tl.static(15.0)
                cur_label = lab
            else:
                tl.slots[tl.cur_slot]["visit"] = vi
            rates = sp["rates"] if (not sp["rate_snake"] or mi % 2 == 0) else sp["rates"][::-1]
            for r in rates:
                tl.rate_to(r)
                tl.hold(r, u["H"])
            tl.rate_to(0.0)
            tl.static(3.0)
    tl.static(30.0)
    return tl


# ============================================================================ physics
def first_order(x, tau, y0):
    a = math.exp(-DT / tau)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * y0])
    return y


def play_operator(T, width, s0):
    s = np.empty_like(T)
    cur = s0
    for i, x in enumerate(T):
        if cur < x - width:
            cur = x - width
        elif cur > x + width:
            cur = x + width
        s[i] = cur
    return s


def telegraph(rng, n, m_up, m_dn):
    st = np.empty(n)
    i = 0
    state = 1.0 if rng.random() < m_up / (m_up + m_dn) else -1.0
    while i < n:
        dwell = rng.exponential(m_up if state > 0 else m_dn)
        j = min(n, i + max(1, int(dwell * FS)))
        st[i:j] = state
        state = -state
        i = j
    return 0.5 * st


def simulate(u, sp, rng, fam, fp, sidx):
    """One session: every per-sample quantity, the clean gyro output, the unit-amplitude
    effect, and the hold-level table."""
    tl = run_protocol(u, sp, rng)
    om, cset, door, slot = tl.arrays()
    n = len(om)
    t = np.arange(n) * DT
    # ---- temperatures
    dtarget = door * u["door"] * (ROOM - cset)
    d = first_order(dtarget, 25.0, 0.0)
    die = first_order(cset + d, u["tau_die"], ROOM) + u["self_heat"] * (1 - np.exp(-t / 120.0))
    dTdt = np.gradient(die, DT) * 60.0                    # C/min
    tsens = die + u["t_off"] + rng.normal(0, 0.03, n)
    tsens = np.round(tsens * 32.0) / 32.0
    # ---- orientation per slot
    nslot = len(tl.slots)
    U = np.zeros((nslot, 3))
    RADIAL = np.zeros((nslot, 3))
    for k, s in enumerate(tl.slots):
        R = mount_rotation(s["label"])
        dj = u["face"][s["label"]] + rng.normal(0, u["jitter"], 2)
        v = R[:, 2] + tilt_vector(R, dj)
        U[k] = v / np.linalg.norm(v)
        RADIAL[k] = R[:, 0]
        s["R"] = R
    us = U[slot]                                          # rig axis in sensor frame
    wtrue = us * om[:, None]                              # deg/s
    cent = (om * D2R) ** 2 * u["radius"] / G0             # g
    fs = us - RADIAL[slot] * cent[:, None]                # specific force, g
    hmask = np.zeros(n, bool)
    for (i0, m, sf, st) in tl.handling:
        hmask[i0:i0 + m] = True
        tt = np.arange(m) * DT
        rates = np.zeros((m, 3))
        for ax in range(3):
            for _ in range(3):
                c = rng.uniform(0.15, 0.85) * m * DT
                w = rng.uniform(1.5, 4.0)
                rates[:, ax] += rng.uniform(-70, 70) * np.exp(-0.5 * ((tt - c) / w) ** 2)
        wtrue[i0:i0 + m] = rates
        sm = np.clip((tt / (m * DT) - 0.2) / 0.6, 0, 1)
        sm = sm * sm * (3 - 2 * sm)
        g = (1 - sm)[:, None] * U[sf] + sm[:, None] * U[st]
        g /= np.linalg.norm(g, axis=1)[:, None]
        jig = np.cumsum(rng.normal(0, 0.004, (m, 3)), axis=0)
        jig -= jig.mean(axis=0)
        fs[i0:i0 + m] = g + jig
    # ---- gyro (clean)
    dT = die - 25.0
    Kt = u["K0"][None] + u["K1"][None] * dT[:, None, None] + u["K2"][None] * (dT ** 2)[:, None, None]
    Kw = np.einsum("nij,nj->ni", Kt, wtrue)
    B = u["b0"] + u["b1"] * dT[:, None] + u["b2"] * (dT ** 2)[:, None]
    to = rng.normal(0, u["turn_on"], 3)
    phi = math.exp(-DT / u["bi_tau"])
    gm = np.column_stack([lfilter([u["bi_sigma"] * math.sqrt(1 - phi * phi)], [1, -phi],
                                  rng.normal(0, 1, n)) for _ in range(3)])
    white = rng.normal(0, 1, (n, 3)) * (u["arw"] * math.sqrt(FS))
    gs = fs @ u["gsens"].T
    w_clean = Kw + B + to + gm + white + gs
    # ---- accelerometer (clean)
    acc = fs @ u["acc_M"].T + u["acc_b"] + 2e-5 * dT[:, None] + rng.normal(0, 0.002, (n, 3))
    # ---- effect at unit amplitude
    e = np.zeros((n, 3))
    acc_e = np.zeros((n, 3))
    ref_eps = 0.0
    if fam == "offcentre_gsens":
        e = fs @ fp["G"].T
    elif fam == "thermal_transient_scale":
        e = fp["c"][None] * dTdt[:, None] * Kw
    elif fam == "centrifugal_cross":
        e = ((wtrue / 100.0) ** 2) @ fp["C"].T
        e[hmask] = 0.0
    elif fam == "gdep_scale":
        e = fp["c"][None] * fs * wtrue / 100.0
        e[hmask] = 0.0
    elif fam == "ref_timebase":
        ref_eps = fp["eps"][sidx]
    elif fam == "fixture_burr":
        dv = fp["tilt"][sidx]
        if dv is not None:
            DU = np.array([tilt_vector(s["R"], dv) for s in tl.slots])[slot]
            DU[hmask] = 0.0
            e = np.einsum("nij,nj->ni", Kt, DU * om[:, None])
            acc_e = DU @ u["acc_M"].T
    elif fam == "stress_relax":
        if sidx > 0:
            e = fp["d"][None] * ((die - fp["Tc"]) / 50.0)[:, None]
    elif fam == "mode_crossing":
        bump = np.exp(-0.5 * ((die - fp["Tk"]) / fp["w"]) ** 2)
        if fp["acts"] == "bias":
            e = fp["a"][None] * bump[:, None]
        else:
            e = fp["a"][None] * bump[:, None] * Kw / 100.0
    elif fam == "popcorn":
        for ax in fp["axes"]:
            e[:, ax] = telegraph(rng, n, *fp["dwell"][ax])
    elif fam == "warpage_hysteresis":
        s = play_operator(die, fp["w"], ROOM)
        h = (s - die) / fp["w"]
        e = (h[:, None] * wtrue / 100.0) @ fp["M"].T
        e[hmask] = 0.0
    # ---- hold table
    cw = np.cumsum(np.vstack([np.zeros((1, 3)), w_clean]), axis=0)
    ce = np.cumsum(np.vstack([np.zeros((1, 3)), e]), axis=0)
    ct = np.concatenate([[0.0], np.cumsum(tsens)])
    co = np.concatenate([[0.0], np.cumsum(om)])
    edge = int(FS)
    H = []
    for h in tl.holds:
        a, b = h["i0"] + edge, h["i1"] - edge
        m = b - a
        H.append((h["sp"], mount_rotation(tl.slots[h["slot"]]["label"])[:, 2],
                  (co[b] - co[a]) / m, (cw[b] - cw[a]) / m, (ce[b] - ce[a]) / m,
                  (ct[b] - ct[a]) / m))
    holds = dict(sp=np.array([x[0] for x in H]), unom=np.array([x[1] for x in H]),
                 ref=np.array([x[2] for x in H]), w=np.array([x[3] for x in H]),
                 e=np.array([x[4] for x in H]), T=np.array([x[5] for x in H]))
    return dict(tl=tl, t0=sp["t0"], t=t, om=om, slot=slot, tsens=tsens, w_clean=w_clean, e=e, acc=acc,
                acc_e=acc_e, ref_eps=ref_eps, holds=holds, rng=rng)


# ============================================================================ standard calibration
def hat(T, nodes):
    """Linear-interpolation weights of temperatures T on the grid nodes (the end segments
    extended linearly: holds a little beyond the outer set points' mean temperature)."""
    W = np.zeros((len(T), len(nodes)))
    if len(nodes) == 1:
        W[:, 0] = 1.0
        return W
    j = np.clip(np.searchsorted(nodes, T, side="right") - 1, 0, len(nodes) - 2)
    f = (T - nodes[j]) / (nodes[j + 1] - nodes[j])
    W[np.arange(len(T)), j] = 1.0 - f
    W[np.arange(len(T)), j + 1] = f
    return W


def calibrate(h, A=0.0, eps=0.0):
    """The standard model: K and B (12 parameters) at every set point, linear interpolation in
    the logged temperature between set points; fitted by least squares on the hold means of
    the whole session (each hold weighted onto its two neighbouring set points)."""
    w = h["w"] + A * h["e"]
    ref = h["ref"] * (1.0 + A * eps)
    X = np.column_stack([h["unom"] * ref[:, None], np.ones(len(ref))])
    nodes = np.array(sorted(h["T"][h["sp"] == sp].mean() for sp in np.unique(h["sp"])))
    W = hat(h["T"], nodes)
    D = (W[:, :, None] * X[:, None, :]).reshape(len(ref), -1)
    coef, *_ = np.linalg.lstsq(D, w, rcond=None)
    coef = coef.reshape(len(nodes), 4, 3)
    Ks = np.transpose(coef[:, :3, :], (0, 2, 1))
    Bs = coef[:, 3, :]
    return nodes, Ks, Bs


def residual(cal, h, A=0.0, eps=0.0):
    nodes, Ks, Bs = cal
    w = h["w"] + A * h["e"]
    ref = h["ref"] * (1.0 + A * eps)
    W = hat(h["T"], nodes)
    K = np.einsum("hn,nij->hij", W, Ks)
    Bv = W @ Bs
    est = np.linalg.solve(K, (w - Bv)[:, :, None])[:, :, 0]
    return est - h["unom"] * ref[:, None]


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


# ============================================================================ families
def draw_family(rng, fam, u, spec):
    """Family parameters (unit amplitude) and protocol constraints."""
    fp = {}
    if fam == "offcentre_gsens":
        u["radius"] = rng.uniform(0.06, 0.15)
        G = rng.normal(0, 1, (3, 3))
        fp["G"] = G / np.linalg.norm(G)
    elif fam == "thermal_transient_scale":
        c = rng.normal(0, 1, 3)
        fp["c"] = c / np.abs(c).max()
    elif fam == "centrifugal_cross":
        C = rng.normal(0, 1, (3, 3))
        np.fill_diagonal(C, 0.0)
        fp["C"] = C / np.abs(C).max()
    elif fam == "gdep_scale":
        c = rng.normal(0, 1, 3)
        fp["c"] = c / np.abs(c).max()
    elif fam == "ref_timebase":
        s = 1e-4 if rng.random() < 0.5 else -1e-4        # unit amplitude: 100 ppm
        fp["eps"] = [s, 0.0, 0.0] if rng.random() < 0.5 else [0.0, s, s]
    elif fam == "fixture_burr":
        def tilt():
            a = rng.uniform(0, 2 * np.pi)
            return np.array([math.cos(a), math.sin(a)]) * rng.uniform(0.7, 1.3)
        if rng.random() < 0.5:
            fp["tilt"] = [tilt(), None, None]
        else:
            fp["tilt"] = [None, tilt(), tilt()]
    elif fam == "stress_relax":
        d = rng.normal(0, 1, 3)
        fp["d"] = d / np.abs(d).max()
        fp["Tc"] = rng.uniform(15.0, 30.0)
    elif fam == "mode_crossing":
        g = sorted(u["grid"])
        i = int(rng.integers(len(g) - 1))
        mid = 0.5 * (g[i] + g[i + 1])
        fp["Tk"] = mid + rng.uniform(-3.0, 3.0)
        fp["w"] = rng.uniform(2.5, 4.0)
        fp["acts"] = "bias" if rng.random() < 0.5 else "scale"
        a = rng.normal(0, 1, 3)
        fp["a"] = a / np.abs(a).max()
    elif fam == "popcorn":
        k = 1 if rng.random() < 0.6 else 2
        fp["axes"] = [int(x) for x in rng.choice(3, size=k, replace=False)]
        fp["dwell"] = {ax: (rng.uniform(300, 1800), rng.uniform(300, 1800)) for ax in range(3)}
    elif fam == "warpage_hysteresis":
        fp["w"] = rng.uniform(2.0, 3.0)
        M = rng.normal(0, 1, (3, 3))
        np.fill_diagonal(M, 0.0)
        fp["M"] = M / np.abs(M).max()
    return fp


def session_protocols(rng, u, fam, shifted_flag):
    if fam == "warpage_hysteresis":
        side = "above" if rng.random() < 0.5 else "below"
        other = "below" if side == "above" else "above"
        return [draw_session_protocol(rng, u, approach=side),
                draw_session_protocol(rng, u, tstyle="shuffled", approach=None),
                draw_session_protocol(rng, u, approach=other)]
    shifted = fam == "mode_crossing" or shifted_flag
    return [draw_session_protocol(rng, u),
            draw_session_protocol(rng, u, shifted=shifted),
            draw_session_protocol(rng, u, shifted=shifted)]


# ============================================================================ a unit
def build_unit(spec):
    """Simulate one unit's three sessions; scale its effect; return logs and truth."""
    rng = np.random.default_rng(spec["seed"])
    fam = spec["family"]
    u = draw_unit(rng, spec["variant"])
    fp = draw_family(rng, fam, u, spec) if fam else {}
    shifted_flag = bool(spec.get("shifted", False)) or (fam is not None and rng.random() < 0.25)
    sps = session_protocols(rng, u, fam, shifted_flag)
    seeds = rng.integers(1, 2**31 - 1, 3)
    sims = [simulate(u, sps[s], np.random.default_rng(int(seeds[s])), fam, fp, s) for s in range(3)]
    h0, h2 = sims[0]["holds"], sims[2]["holds"]
    e0, e2 = sims[0]["ref_eps"], sims[2]["ref_eps"]

    floor_a = float(np.sqrt(np.mean(u["arw"] ** 2) / (u["H"] - 2.0)))
    r_clean = residual(calibrate(h0), h2)
    floor_b = rms(r_clean)
    ref = max(floor_a, floor_b)

    def excess(A):
        r = residual(calibrate(h0, A, e0), h2, A, e2)
        return rms(r - r_clean)

    A = 0.0
    E = 0.0
    if fam:
        target = spec["k"] * ref
        A = 1.0
        for _ in range(4):
            E = excess(A)
            if E <= 0:
                raise RuntimeError("effect leaves no trace on the unseen session")
            A *= target / E
        E = excess(A)
    F = FAMILIES.get(fam, {}) if fam else {}
    acts = F.get("acts")
    if fam == "mode_crossing":
        acts = {fp["acts"]}
    truth = dict(complete=fam is None, family=fam, variant=spec["variant"],
                 carried=bool(F.get("carried", False)),
                 reads=set(F.get("reads", set())), acts=set(acts or set()),
                 reasons=set(F.get("reasons", set())),
                 floor=floor_a, complete_left=floor_b, ref=ref, threshold=1.2 * ref,
                 k=spec["k"], excess=E, amplitude=A)
    return dict(u=u, sims=sims, A=A, truth=truth, spec=spec)


def _table(u, sim, A, sidx, spec):
    V = VARIANTS[u["variant"]]
    tl = sim["tl"]
    rng = sim["rng"]
    n = len(sim["om"])
    keep = np.ones(n, bool)
    for a, b in tl.gaps:
        keep[a:b] = False
    gyro = sim["w_clean"] + A * sim["e"]
    ref = sim["om"] * (1.0 + A * sim["ref_eps"]) + rng.normal(0, 1e-4, n)
    acc = sim["acc"] + A * sim["acc_e"]
    t = sim["t"] + 0.0
    scale = D2R if V["rad"] else 1.0
    cols = {}
    t0 = 1_700_000_000.0 + 86400.0 * (30 * sidx + (spec["seed"] % 97)) + 3600.0 * 7
    if V["t_kind"] == "timestamp":
        us = ((t0 + t[keep]) * 1e6).astype(np.int64)
        cols["t"] = pa.array(us, type=pa.timestamp("us"))
    else:
        cols["t"] = pa.array(t[keep] + sim["t0"], pa.float64())
    for i, ax in enumerate("xyz"):
        cols[f"gyro_{ax}"] = pa.array(gyro[keep, i] * scale, pa.float64())
    cols["temp"] = pa.array(sim["tsens"][keep], pa.float32())
    cols["ref_rate"] = pa.array(ref[keep] * scale, pa.float64())
    if V["accel"]:
        for i, ax in enumerate("xyz"):
            cols[f"accel_{ax}"] = pa.array(acc[keep, i], pa.float32())
    if V["mount_col"]:
        labels = np.array([s["label"] for s in tl.slots])
        lab = labels[sim["slot"]]
        # during handling the unit is still labelled with the mount it is leaving
        for (i0, m, sf, _st) in tl.handling:
            lab[i0:i0 + m] = tl.slots[sf]["label"]
        cols["mount"] = pa.array(lab[keep]).dictionary_encode()
    table = pa.table(cols)
    if V["rad"]:
        md = {b"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"}).encode()}
        table = table.replace_schema_metadata(md)
    return table


def write_unit(built, folder):
    os.makedirs(folder, exist_ok=True)
    paths = []
    for s, sim in enumerate(built["sims"]):
        p = os.path.join(folder, f"s{s}.parquet")
        pq.write_table(_table(built["u"], sim, built["A"], s, built["spec"]), p,
                       compression="zstd")
        paths.append(p)
    return paths


# ============================================================================ self-check
def selfcheck(units_per_family=2, seed=20250917):
    """Consistency of the generator only: prints counts, never families or magnitudes."""
    bad = 0
    specs = plan(units_per_family, seed)
    for s in specs:
        b = build_unit(s)
        tr = b["truth"]
        if not tr["complete"] and \
                not (0.9 * tr["k"] * tr["ref"] <= tr["excess"] <= 1.1 * tr["k"] * tr["ref"]):
            bad += 1
    print(f"selfcheck: {len(specs)} units, {bad} off target")
    return bad


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--selfcheck", action="store_true")
    ap.add_argument("--units-per-family", type=int, default=2)
    ap.add_argument("--seed", type=int, default=20250917)
    a = ap.parse_args()
    if a.selfcheck:
        sys.exit(1 if selfcheck(a.units_per_family, a.seed) else 0)
