"""An open, independent generator of turntable rig logs for judging a gyro diagnosis.

Written by a helper from the log contract (``shared/spec/log-format.md``) and the three seed
papers only, without reading the diagnosis software, its simulator or its tests. Numpy and
pyarrow only.

Every unit is one simulated MEMS triaxial gyro (with an accelerometer beside it) calibrated
three times (sessions s0, s1, s2) on a single-axis rate table inside a thermal chamber. Each
session: power-on, chamber ramps between temperature points with soaks, and at each point a
series of constant-rate holds on three or six mounts; between mounts a person opens the door
and re-mounts the unit (real motion while ``ref_rate`` is 0, and a small thermal upset).

Nominal physics (every unit, every family):

- ``w = K(T) w_true + B(T) + noise`` with ``K = I + diag(s0 + s1 dT + s2 dT^2) + M + M1 dT``,
  ``B = b0 + b1 dT + b2 dT^2`` (``dT = T - 25 C``), T the package temperature;
- white rate noise (rate noise density 0.004..0.008 deg/s/rtHz), bias instability as three
  Gauss-Markov processes (30 s, 300 s, 3000 s; ~2..3 deg/h in all), a turn-on bias offset per
  session (per axis, 0.7..1.2 times the white hold-mean floor), table rate ripple once per
  revolution (2e-5 of the rate) and encoder jitter;
- thermal: chamber air (tau 25 s, door upsets towards the room), a fixture (tau 120..200 s
  from the air) and the package (coupled to the air, 400 s, and to the fixture, 100 s), plus
  1..1.5 K of self-heating after power-on; the unit's ``temp`` reads the package with an
  offset, 0.03 K noise and 1/128 K steps;
- accelerometer: gravity along the rig axis, the centripetal and tangential specific force of
  a unit sitting 3..8 cm off the table axis, bias, scale and noise.

Families (effects) are listed in ``FAMILIES``; see README.md for physics and truth.

Usage:
    python generator.py --out DIR [--seed S] [--family NAME] [--max-units N]
    python generator.py --selfcheck
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

G0 = 9.80665
T_ROOM = 23.0
T_REF = 25.0

# sensor-frame unit vectors: rig axis (up), radial (fixed in the table, outward) per mount
_E = np.eye(3)
MOUNT_UP = {'+x': _E[0], '-x': -_E[0], '+y': _E[1], '-y': -_E[1], '+z': _E[2], '-z': -_E[2]}
MOUNT_RADIAL = {'+x': _E[1], '-x': _E[2], '+y': _E[2], '-y': _E[0], '+z': _E[0], '-z': _E[1]}

R_A = [0.0, 0.5, 3.0, 20.0, 80.0, 200.0, 350.0]
R_B = [0.0, 2.0, 10.0, 45.0, 120.0, 300.0]
R_C = [0.0, 1.0, 5.0, 25.0, 100.0, 250.0, 420.0]

# Protocol variants. t_orders / r_orders are per session (s0, s1, s2).
VARIANTS = {
    'V1': dict(fs=50, temps=[-30, -10, 10, 30, 50], t_orders=('desc', 'asc', 'desc'),
               mounts=['+z', '+x', '+y'], serpentine=False, rates=R_A,
               r_orders=('alt_asc', 'alt_asc', 'shuffled'), hold=8.0, soak=600.0,
               ramp_kpm=3.0, accel=True, mount_col='string', time='float', rad=False,
               dtype='float64', nan_rows=0, gaps=False),
    'V2': dict(fs=50, temps=[-20, 0, 20, 40, 60], t_orders=('asc', 'zigzag', 'desc'),
               mounts=['+x', '-x', '+y', '-y', '+z', '-z'], serpentine=True, rates=R_B,
               r_orders=('shuffled', 'shuffled', 'shuffled'), hold=6.0, soak=660.0,
               ramp_kpm=4.0, accel=True, mount_col=None, time='timestamp', rad=False,
               dtype='float64', nan_rows=0, gaps=False),
    'V3': dict(fs=100, temps=[60, 35, 10, -15, -40], t_orders=('desc', 'zigzag', 'asc'),
               mounts=['+x', '-y', '+z'], serpentine=False, rates=R_C,
               r_orders=('desc', 'desc', 'asc'), hold=7.0, soak=600.0, ramp_kpm=3.0,
               accel=False, mount_col='dictionary', time='float', rad=True,
               dtype='float64', nan_rows=0, gaps=False),
    'V4': dict(fs=50, temps=[-25, 5, 35, 65], t_orders=('zigzag', 'zigzag2', 'desc'),
               mounts=['+y', '+z', '+x'], serpentine=True, rates=R_A,
               r_orders=('pos_then_neg', 'shuffled', 'pos_then_neg'), hold=10.0, soak=720.0,
               ramp_kpm=2.5, accel=True, mount_col='string', time='float', rad=False,
               dtype='float32', nan_rows=7, gaps=True),
    'V5': dict(fs=100, temps=[-30, 0, 30, 60], t_orders=('asc', 'desc', 'revisit'),
               mounts=['+z', '-z', '+x', '-x', '+y', '-y'], serpentine=False, rates=R_C,
               r_orders=('alt_asc', 'alt_desc', 'alt_asc'), hold=6.0, soak=600.0,
               ramp_kpm=3.0, accel=True, mount_col=None, time='float', rad=False,
               dtype='float64', nan_rows=0, gaps=False),
    'V6': dict(fs=50, temps=[50, 30, 10, -10], t_orders=('revisit', 'asc', 'zigzag'),
               mounts=['+z', '+y', '+x'], serpentine=False, rates=R_B,
               r_orders=('alt_desc', 'alt_asc', 'shuffled'), hold=8.0, soak=660.0,
               ramp_kpm=3.0, accel=True, mount_col='string', time='timestamp', rad=False,
               dtype='float64', nan_rows=3, gaps=False),
}

# Family table: category, allowed variants, protocol overrides, truth in the judge's words.
#   category: 'sensor' (a term of the sensor's inputs carries it), 'no_term' (no sensor term can),
#             'confusable' (a term carries it, but inputs move together in the protocol)
#   fix: a fix is a right answer; reads_right: a fix's reads must hold at least one of these and
#   nothing outside reads_right + reads_ok; acts_on: accepted acts_on values.
#   reasons: right no_sensor_term reasons (empty: no_sensor_term is a wrong answer).
FAMILIES = {
    'cubic_scale': dict(cat='sensor', variants=['V1', 'V3', 'V5', 'V2'], over={},
                        fix=True, reads_right=['rate'], reads_ok=[], acts_on=['scale'],
                        reasons=[], one_log=True),
    'cw_ccw_asymmetry': dict(cat='sensor', variants=['V2', 'V4', 'V6', 'V1'], over={},
                             fix=True, reads_right=['rate'], reads_ok=[], acts_on=['scale'],
                             reasons=[], one_log=True),
    'cross_rate_square': dict(cat='sensor', variants=['V3', 'V5', 'V1', 'V6'], over={},
                              fix=True, reads_right=['rate'], reads_ok=[],
                              acts_on=['cross-axis'], reasons=[], one_log=True),
    'small_rate_compression': dict(cat='sensor', variants=['V1', 'V3', 'V6', 'V4'], over={},
                                   fix=True, reads_right=['rate'], reads_ok=[],
                                   acts_on=['scale'], reasons=[], one_log=True),
    'exposure_charging': dict(cat='confusable', variants=['V1', 'V4', 'V2', 'V5'],
                              over={'r_orders': ('pos_then_neg', 'shuffled', 'alt_desc')},
                              fix=True, reads_right=['rate'], reads_ok=['time'],
                              acts_on=['bias'], reasons=[], one_log=True),
    'fixture_heat_flux': dict(cat='sensor', variants=['V2', 'V1', 'V4', 'V6'],
                              over={'soak_scale': (0.45, 1.0, 0.6)},
                              fix=True, reads_right=['thermal'], reads_ok=['temperature', 'time'],
                              acts_on=['bias'], reasons=[], one_log=True),
    'log_creep': dict(cat='confusable', variants=['V1', 'V3', 'V2', 'V5'],
                      over={'t_orders_by_variant': True},
                      fix=True, reads_right=['time'], reads_ok=['thermal'], acts_on=['bias'],
                      reasons=[], one_log=True),
    'clamp_relaxation': dict(cat='confusable', variants=['V4', 'V1', 'V6', 'V2'], over={},
                             fix=True, reads_right=['time', 'mount'], reads_ok=[],
                             acts_on=['bias'], reasons=[], one_log=True),
    'thermal_play': dict(cat='sensor', variants=['V1', 'V3', 'V2', 'V5'],
                         over={'t_orders_by_variant': True},
                         fix=True, reads_right=['thermal'], reads_ok=['temperature'],
                         acts_on=['bias'], reasons=['direction of approach'], one_log=False),
    'offcenter_g': dict(cat='confusable', variants=['V1', 'V2', 'V4', 'V5'], over={},
                        fix=True, reads_right=['accel'], reads_ok=['rate', 'mount'],
                        acts_on=['bias'], reasons=[], one_log=True),
    'table_tach_scale': dict(cat='no_term', variants=['V3', 'V6', 'V1', 'V2'], over={},
                             fix=False, reads_right=[], reads_ok=[], acts_on=[],
                             reasons=['lab'], one_log=False),
    'fixture_reseat': dict(cat='no_term', variants=['V5', 'V2', 'V3', 'V1'], over={},
                           fix=True, reads_right=['accel', 'mount'], reads_ok=[],
                           acts_on=['cross-axis'], reasons=['mounting'], one_log=True),
    'board_stress_change': dict(cat='no_term', variants=['V2', 'V4', 'V6', 'V3'], over={},
                                fix=False, reads_right=[], reads_ok=[], acts_on=[],
                                reasons=['unit changed'], one_log=False),
    'popcorn_bias': dict(cat='no_term', variants=['V6', 'V1', 'V3', 'V4'], over={},
                         fix=False, reads_right=[], reads_ok=[], acts_on=[],
                         reasons=['slow noise'], one_log=True),
    'mode_crossing': dict(cat='no_term', variants=['V1', 'V2', 'V3', 'V6'],
                          over={'midpoints': True},
                          fix=True, reads_right=['temperature'], reads_ok=[],
                          acts_on=['bias'], reasons=['between points'], one_log=False),
}
COMPLETE = 'complete'


# ----------------------------------------------------------------------------- helpers
def _rng(seed, *key):
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *key]))


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def temp_order(temps, how):
    s = sorted(temps)
    if how == 'asc':
        return s
    if how == 'desc':
        return s[::-1]
    if how in ('zigzag', 'zigzag2'):
        lo, hi, out, take_lo = 0, len(s) - 1, [], how == 'zigzag'
        while lo <= hi:
            if take_lo:
                out.append(s[lo]); lo += 1
            else:
                out.append(s[hi]); hi -= 1
            take_lo = not take_lo
        return out
    if how == 'revisit':
        # descending, then the second-highest point once more, reached from below
        d = s[::-1]
        return d + [d[1]]
    raise ValueError(how)


def rate_order(rates, how, rng):
    pos = [r for r in rates if r > 0]
    if how == 'alt_asc':
        out = [0.0]
        for r in pos:
            out += [r, -r]
        return out
    if how == 'alt_desc':
        out = []
        for r in pos[::-1]:
            out += [r, -r]
        return out + [0.0]
    if how == 'pos_then_neg':
        return [0.0] + pos + [-r for r in pos]
    if how == 'desc':
        return pos[::-1] + [0.0] + [-r for r in pos]
    if how == 'asc':
        return [-r for r in pos[::-1]] + [0.0] + pos
    if how == 'shuffled':
        out = [0.0] + pos + [-r for r in pos]
        return [out[i] for i in rng.permutation(len(out))]
    raise ValueError(how)


# ----------------------------------------------------------------------------- unit spec
def session_protocol(unit, k):
    """The protocol of session k of a unit (a dict)."""
    v = dict(VARIANTS[unit['variant']])
    fam = unit['family']
    over = FAMILIES.get(fam, {}).get('over', {})
    temps = list(v['temps'])
    t_orders = list(v['t_orders'])
    r_orders = list(over.get('r_orders', v['r_orders']))
    if over.get('t_orders_by_variant'):
        # s0 monotone, s1 and s2 travel the other way
        if t_orders[0] not in ('asc', 'desc'):
            t_orders[0] = 'desc'
        other = 'asc' if t_orders[0] == 'desc' else 'desc'
        t_orders = [t_orders[0], other, other]
    order = temp_order(temps, t_orders[k])
    if over.get('midpoints') and k >= 1:
        s = sorted(temps)
        mids = [0.5 * (a + b) for a, b in zip(s[:-1], s[1:])]
        order = temp_order(mids, t_orders[k] if t_orders[k] != 'revisit' else 'asc')
    soak = v['soak'] * (over.get('soak_scale', (1, 1, 1))[k])
    mounts = list(v['mounts'])
    if k == 1:
        mounts = mounts[1:] + mounts[:1]      # another mount order on the other session
    return dict(v, order=order, r_order=r_orders[k], soak=soak, mounts=mounts, k=k)


def make_units(seed=20250611, per_family=3, n_complete=6, families=None):
    """The unit list: per family `per_family` units with log-stratified magnitudes."""
    rng = _rng(seed, 7)
    units = []
    lo, hi = 1.5, 50.0
    fams = list(FAMILIES) if families is None else [f for f in FAMILIES if f in families]
    uid = 0
    for fi, fam in enumerate(FAMILIES):
        strata = rng.permutation(per_family)
        mags = [math.exp(math.log(lo) + (s + rng.uniform(0.1, 0.9)) / per_family
                         * (math.log(hi) - math.log(lo))) for s in strata]
        for j in range(per_family):
            var = FAMILIES[fam]['variants'][j % len(FAMILIES[fam]['variants'])]
            u = dict(name=f'o2_{fam}_{j}', family=fam, variant=var, magnitude=round(mags[j], 3),
                     seed=int(rng.integers(1, 2**31 - 1)))
            uid += 1
            if fam in fams:
                units.append(u)
    vnames = list(VARIANTS)
    for j in range(n_complete):
        u = dict(name=f'o2_complete_{j}', family=COMPLETE, variant=vnames[j % len(vnames)],
                 magnitude=0.0, seed=int(rng.integers(1, 2**31 - 1)))
        if families is None or COMPLETE in families:
            units.append(u)
    return units


def sensor_params(seed):
    r = _rng(seed, 99, 1)
    p = dict(
        s0=r.normal(0, 0.004, 3), s1=r.normal(0, 80e-6, 3), s2=r.normal(0, 0.25e-6, 3),
        M=r.normal(0, 0.004, (3, 3)) * (1 - np.eye(3)),
        M1=r.normal(0, 8e-6, (3, 3)) * (1 - np.eye(3)),
        b0=r.normal(0, 0.5, 3), b1=r.choice([-1, 1], 3) * r.uniform(0.002, 0.006, 3),
        b2=r.normal(0, 1.2e-5, 3),
        nd=r.uniform(0.004, 0.008, 3),               # deg/s/rtHz
        bi=r.uniform(0.0005, 0.0008, 3),             # deg/s, Gauss-Markov sum
        to_factor=r.uniform(0.5, 1.0),
        acc_b=r.normal(0, 0.005, 3), acc_s=r.normal(0, 0.003, 3), acc_n=r.uniform(0.002, 0.004),
        t_off=r.normal(0, 1.5), self_heat=r.uniform(1.0, 1.5),
        tau_fix=r.uniform(120, 200), k_door=r.uniform(0.0005, 0.0010),
        radius=r.uniform(0.03, 0.08),
    )
    return p


def effect_params(seed, fam):
    r = _rng(seed, 99, 2)
    v = _unit(r.normal(0, 1, 3))
    signs = r.choice([-1.0, 1.0], 3)
    w = signs * r.uniform(0.5, 1.0, 3)
    p = dict(v=v, w=w)
    if fam == 'cross_rate_square':
        p['pairs'] = [(0, 1, w[0]), (1, 2, w[1]), (2, 0, w[2])]
    if fam == 'exposure_charging':
        p['tau'] = r.uniform(20, 45)
    if fam == 'log_creep':
        p['tau0'] = r.uniform(200, 600)
    if fam == 'clamp_relaxation':
        p['tau'] = r.uniform(60, 120)
    if fam == 'thermal_play':
        p['width'] = r.uniform(5, 8)
    if fam == 'offcenter_g':
        G = r.normal(0, 1.0, (3, 3))
        G += np.diag(r.choice([-1, 1], 3) * 1.5)
        p['G'] = G
        r0 = r.uniform(0.06, 0.10)
        p['radii'] = [r0, r0 * r.uniform(1.5, 1.8), r0 * r.uniform(0.45, 0.6)]
    if fam == 'table_tach_scale':
        p['sign'] = float(r.choice([-1, 1]))
    if fam == 'popcorn_bias':
        p['dwell'] = r.uniform(150, 500)
        p['axes'] = w * (r.uniform(0, 1, 3) > 0.3)
        if not np.any(p['axes']):
            p['axes'][0] = 1.0
    if fam == 'board_stress_change':
        p['ds'] = r.normal(0, 1, 3)
        p['dm'] = r.normal(0, 0.5, (3, 3)) * (1 - np.eye(3))
        p['db'] = r.normal(0, 1, 3)
        p['db1'] = r.normal(0, 1, 3)
    if fam == 'mode_crossing':
        p['width'] = r.uniform(2.0, 3.5)
    return p


# ----------------------------------------------------------------------------- timeline
def build_timeline(proto, seed):
    """Segments of one session as per-sample arrays."""
    k = proto['k']
    rng = _rng(seed, k, 0)
    fs = proto['fs']
    alpha = 100.0                                  # table acceleration, deg/s^2
    segs = []
    cur_T = T_ROOM
    mounts0 = proto['mounts']
    cur_mount = mounts0[0]
    hold_id = 0
    ev = 0

    def add(kind, dur, **kw):
        n = max(1, int(round(dur * fs)))
        segs.append(dict(kind=kind, n=n, **kw))

    add('idle', rng.uniform(90, 150), T0=cur_T, T1=cur_T, r0=0, r1=0, ev=ev, point=-1)
    for pi, T in enumerate(proto['order']):
        dur = abs(T - cur_T) / (proto['ramp_kpm'] / 60.0)
        if dur > 0:
            add('tramp', dur, T0=cur_T, T1=T, r0=0, r1=0, ev=ev, point=-1)
        cur_T = T
        add('soak', proto['soak'] * rng.uniform(0.95, 1.1), T0=T, T1=T, r0=0, r1=0, ev=ev,
            point=-1)
        mounts = list(mounts0)
        if proto['serpentine'] and pi % 2 == 1:
            mounts = mounts[::-1]
        for m in mounts:
            if m != cur_mount:
                ev += 1
                add('handle', rng.uniform(30, 50), T0=T, T1=T, r0=0, r1=0, ev=ev, point=-1,
                    m_from=cur_mount, m_to=m)
                add('settle', rng.uniform(70, 100), T0=T, T1=T, r0=0, r1=0, ev=ev, point=-1)
                cur_mount = m
            r_prev = 0.0
            for r in rate_order(proto['rates'], proto['r_order'], rng):
                if r != r_prev:
                    add('rramp', abs(r - r_prev) / alpha + 0.2, T0=T, T1=T, r0=r_prev, r1=r,
                        ev=ev, point=-1)
                add('hold', proto['hold'], T0=T, T1=T, r0=r, r1=r, ev=ev, point=pi,
                    hold=hold_id, mount=m, Tnom=T)
                hold_id += 1
                r_prev = r
            if r_prev != 0:
                add('rramp', abs(r_prev) / alpha + 0.2, T0=T, T1=T, r0=r_prev, r1=0, ev=ev,
                    point=-1)
            add('rest', 3.0, T0=T, T1=T, r0=0, r1=0, ev=ev, point=-1)
    add('idle', 30.0, T0=cur_T, T1=cur_T, r0=0, r1=0, ev=ev, point=-1)

    N = sum(s['n'] for s in segs)
    t = np.arange(N) / fs
    Tset = np.empty(N)
    rate = np.empty(N)
    evs = np.empty(N, int)
    kind = np.empty(N, 'U6')
    door = np.zeros(N, bool)
    hold_of = np.full(N, -1)
    holds = []
    events = [dict(mount=mounts0[0], start=0)]
    handles = []
    i = 0
    for s in segs:
        n = s['n']
        sl = slice(i, i + n)
        f = np.linspace(0, 1, n, endpoint=False) if n > 1 else np.zeros(1)
        Tset[sl] = s['T0'] + (s['T1'] - s['T0']) * f
        if s['kind'] == 'rramp':
            f2 = np.clip((np.arange(n) / fs) / max(abs(s['r1'] - s['r0']) / alpha, 1e-9), 0, 1)
            rate[sl] = s['r0'] + (s['r1'] - s['r0']) * f2
        else:
            rate[sl] = s['r0']
        evs[sl] = s['ev']
        kind[sl] = s['kind']
        if s['kind'] == 'handle':
            door[sl] = True
            events.append(dict(mount=s['m_to'], start=i))
            handles.append(dict(start=i, n=n, m_from=s['m_from'], m_to=s['m_to']))
        if s['kind'] == 'settle':
            events[-1]['clamped'] = i
        if s['kind'] == 'hold':
            hold_of[sl] = s['hold']
            holds.append(dict(id=s['hold'], start=i, stop=i + n, point=s['point'],
                              Tnom=s['Tnom'], mount=s['mount'], ref=s['r0'], ev=s['ev']))
        i += n
    events[0]['clamped'] = 0
    return dict(t=t, Tset=Tset, rate=rate, ev=evs, kind=kind, door=door, hold_of=hold_of,
                holds=holds, events=events, handles=handles, fs=fs, N=N)


def simulate_thermal(tl, sp, proto, seed, dt=0.5):
    """Chamber air, fixture and package temperatures at the sample times."""
    t = tl['t']
    tg = np.arange(0, t[-1] + dt, dt)
    Tset = np.interp(tg, t, tl['Tset'])
    door = np.interp(tg, t, tl['door'].astype(float)) > 0.5
    tau_air, tau_pa, tau_pf = 25.0, 400.0, 100.0
    air = np.empty_like(tg); fix = np.empty_like(tg); pkg = np.empty_like(tg)
    a = f = p = T_ROOM
    kd = sp['k_door']
    tfix = sp['tau_fix']
    for j in range(len(tg)):
        a += dt * ((Tset[j] - a) / tau_air + (kd * (T_ROOM - a) if door[j] else 0.0))
        f += dt * (a - f) / tfix
        p += dt * ((a - p) / tau_pa + (f - p) / tau_pf)
        air[j] = a; fix[j] = f; pkg[j] = p
    sh = sp['self_heat'] * (1 - np.exp(-tg / 150.0))
    pkg = pkg + sh
    fix_ = fix + 0.0
    return (np.interp(t, tg, air), np.interp(t, tg, fix_), np.interp(t, tg, pkg))


def gauss_markov(rng, n_s, taus, sig, dt=1.0):
    """Sum of first-order Gauss-Markov processes sampled every dt (3 axes)."""
    n = int(n_s / dt) + 2
    out = np.zeros((n, 3))
    for tau, s in zip(taus, sig):
        phi = math.exp(-dt / tau)
        e = rng.normal(0, 1, (n, 3)) * (s * math.sqrt(1 - phi * phi))
        x = rng.normal(0, 1, 3) * s
        col = np.empty((n, 3))
        for j in range(n):
            x = phi * x + e[j]
            col[j] = x
        out += col
    return np.arange(n) * dt, out


def first_order(u, t, tau, dt=1.0):
    """First-order lag of u(t) (1-D), evaluated on a coarse grid and interpolated back."""
    tg = np.arange(0, t[-1] + dt, dt)
    ug = np.interp(tg, t, u)
    phi = math.exp(-dt / tau)
    y = np.empty_like(ug)
    x = 0.0
    for j in range(len(ug)):
        x = phi * x + (1 - phi) * ug[j]
        y[j] = x
    return np.interp(t, tg, y)


def play_operator(T, width, t, dt=1.0):
    """Backlash (play) operator on the temperature: the stress-memory state."""
    tg = np.arange(0, t[-1] + dt, dt)
    Tg = np.interp(tg, t, T)
    h = width / 2
    p = Tg[0] - h   # the unit has been warming up from power-on
    y = np.empty_like(Tg)
    for j in range(len(Tg)):
        p = min(max(p, Tg[j] - h), Tg[j] + h)
        y[j] = (Tg[j] - p) / h
    return np.interp(t, tg, y)


def telegraph(rng, t_end, dwell, dt=1.0):
    n = int(t_end / dt) + 2
    st = np.empty(n)
    s = rng.choice([-1.0, 1.0])
    p = 1 - math.exp(-dt / dwell)
    flips = rng.uniform(0, 1, n) < p
    for j in range(n):
        if flips[j]:
            s = -s
        st[j] = s
    return np.arange(n) * dt, st


# ----------------------------------------------------------------------------- session
def simulate_session(unit, k, amp=None, noise=True, effect=True):
    """Simulate session k of a unit. Returns a dict of physical arrays plus the hold table."""
    fam = unit['family']
    seed = unit['seed']
    amp = unit.get('amp', 0.0) if amp is None else amp
    if not effect or fam == COMPLETE:
        amp = 0.0
    proto = session_protocol(unit, k)
    sp = sensor_params(seed)
    ep = effect_params(seed, fam)
    tl = build_timeline(proto, seed)
    N, fs, t = tl['N'], tl['fs'], tl['t']
    air, fix, pkg = simulate_thermal(tl, sp, proto, seed)

    # ----- geometry per mount event (rig axis and radial direction in the sensor frame)
    nev = len(tl['events'])
    U = np.zeros((nev, 3)); Rd = np.zeros((nev, 3)); Tg = np.zeros((nev, 3))
    r_tilt = _rng(seed, k, 11)
    for e, evd in enumerate(tl['events']):
        u = MOUNT_UP[evd['mount']].copy(); rr = MOUNT_RADIAL[evd['mount']].copy()
        tg_ = np.cross(u, rr)
        if fam == 'fixture_reseat':
            th = r_tilt.normal(0, 1.0e-3, 2) * amp
            u = _unit(u + th[0] * rr + th[1] * tg_)
            rr = _unit(rr - th[0] * u)
            tg_ = np.cross(u, rr)
        U[e], Rd[e], Tg[e] = u, rr, tg_
    ev = tl['ev']
    radius = sp['radius']
    if fam == 'offcenter_g':
        radius = ep['radii'][k]

    # ----- table: actual rate (ripple, jitter) and the logged reference
    r_tab = _rng(seed, k, 7)
    rate_cmd = tl['rate']
    angle = np.cumsum(rate_cmd) / fs
    rate_act = rate_cmd.copy()
    if noise:
        ph = r_tab.uniform(0, 2 * np.pi)
        rate_act = rate_act + 2e-5 * rate_cmd * np.sin(np.deg2rad(angle) + ph)
        moving = np.abs(rate_cmd) > 0
        rate_act[moving] += r_tab.normal(0, 0.001, int(moving.sum()))
    ref_logged = rate_cmd.copy()
    if fam == 'table_tach_scale' and k == 0:
        ref_logged = rate_cmd * (1 + ep['sign'] * 1e-3 * amp)

    omega = rate_act[:, None] * U[ev]
    alpha = np.gradient(rate_act) * fs                       # deg/s^2
    w_rad = np.deg2rad(rate_act)
    f_spec = (U[ev] * 1.0 - Rd[ev] * (w_rad ** 2 * radius / G0)[:, None]
              + Tg[ev] * (np.deg2rad(alpha) * radius / G0)[:, None])
    # handling: real motion at ref 0, orientation moves from one mount to the next
    r_h = _rng(seed, k, 9)
    for h in tl['handles']:
        i0, n = h['start'], h['n']
        tt = np.arange(n) / fs
        mot = np.zeros((n, 3))
        for _ in range(r_h.integers(3, 7)):
            c = r_h.uniform(2, max(3, n / fs - 2)); wdt = r_h.uniform(0.7, 2.5)
            mot += np.exp(-0.5 * ((tt - c) / wdt) ** 2)[:, None] * r_h.normal(0, 40, 3)
        omega[i0:i0 + n] = mot
        s = np.clip((tt - 0.3 * n / fs) / (0.4 * n / fs), 0, 1)[:, None]
        g = (1 - s) * MOUNT_UP[h['m_from']] + s * MOUNT_UP[h['m_to']]
        g /= np.maximum(np.linalg.norm(g, axis=1), 1e-3)[:, None]
        f_spec[i0:i0 + n] = g + r_h.normal(0, 0.08, (n, 3))

    # ----- sensor
    T = pkg
    dT = T - T_REF
    s = sp['s0'][None] + sp['s1'][None] * dT[:, None] + sp['s2'][None] * dT[:, None] ** 2
    K = np.eye(3)[None] + sp['M'][None] + sp['M1'][None] * dT[:, None, None]
    K[:, [0, 1, 2], [0, 1, 2]] += s
    B = sp['b0'][None] + sp['b1'][None] * dT[:, None] + sp['b2'][None] * dT[:, None] ** 2
    if fam == 'board_stress_change' and k >= 1:
        K[:, [0, 1, 2], [0, 1, 2]] += amp * 4e-4 * ep['ds'][None] * (1 + dT[:, None] / 40)
        K += amp * 3e-4 * ep['dm'][None]
        B = B + amp * 1.5e-3 * (ep['db'][None] + ep['db1'][None] * dT[:, None] / 30)
    w = np.einsum('nij,nj->ni', K, omega) + B

    # ----- effects
    dw = np.zeros((N, 3))
    v = ep['v']
    if amp != 0.0:
        if fam == 'cubic_scale':
            dw += amp * 1e-3 * ep['w'][None] * omega * (omega / 300.0) ** 2
        elif fam == 'cw_ccw_asymmetry':
            dw += amp * 1e-4 * ep['w'][None] * omega * np.tanh(omega / 8.0)
        elif fam == 'cross_rate_square':
            for i, j, c in ep['pairs']:
                dw[:, j] += amp * 1e-4 * c * omega[:, i] * np.abs(omega[:, i]) / 300.0
        elif fam == 'small_rate_compression':
            dw += -amp * 0.02 * np.abs(ep['w'])[None] * omega * np.exp(-0.5 * (omega / 2.0) ** 2)
        elif fam == 'exposure_charging':
            x = first_order(np.linalg.norm(omega, axis=1) / 300.0, t, ep['tau'])
            dw += amp * 2e-3 * x[:, None] * v[None]
        elif fam == 'fixture_heat_flux':
            dw += amp * 2e-3 * (fix - (pkg - sp['self_heat'] * (1 - np.exp(-t / 150.0))))[:, None] * v[None]
        elif fam == 'log_creep':
            dw += amp * 1e-3 * np.log1p(t / ep['tau0'])[:, None] * v[None]
        elif fam == 'clamp_relaxation':
            since = np.zeros(N)
            clamped = [e.get('clamped', e['start']) for e in tl['events']]
            st = np.asarray(clamped)[ev]
            since = np.maximum(t - st / fs, 0)
            dw += amp * 2e-3 * np.exp(-since / ep['tau'])[:, None] * v[None]
        elif fam == 'thermal_play':
            y = play_operator(T, ep['width'], t)
            dw += amp * 1e-3 * y[:, None] * v[None]
        elif fam == 'offcenter_g':
            dw += amp * 1e-3 * f_spec @ ep['G'].T
        elif fam == 'popcorn_bias':
            tg_, st = telegraph(_rng(seed, k, 12), t[-1], ep['dwell'])
            stf = st[np.minimum((t / 1.0).astype(int), len(st) - 1)]
            dw += amp * 1e-3 * stf[:, None] * ep['axes'][None]
        elif fam == 'mode_crossing':
            Tstar = ep.get('Tstar')
            if Tstar is None:
                s_ = sorted(VARIANTS[unit['variant']]['temps'])
                mids = [0.5 * (a + b) for a, b in zip(s_[:-1], s_[1:])]
                Tstar = mids[_rng(seed, 99, 3).integers(len(mids))] + _rng(seed, 99, 4).uniform(-1, 1)
            dw += amp * 5e-3 * np.exp(-0.5 * ((T - Tstar) / ep['width']) ** 2)[:, None] * v[None]
    w = w + dw

    # ----- stochastic nuisances
    if noise:
        hold_floor = sp['nd'] / math.sqrt(proto['hold'])
        to = _rng(seed, k, 4).normal(0, 1, 3) * sp['to_factor'] * hold_floor
        white = _rng(seed, k, 2).normal(0, 1, (N, 3)) * (sp['nd'] * math.sqrt(fs / 2))[None]
        tg_, gm = gauss_markov(_rng(seed, k, 3), t[-1], (30.0, 300.0, 3000.0),
                               [sp['bi'] * 0.6, sp['bi'] * 0.6, sp['bi'] * 0.5])
        bi = np.stack([np.interp(t, tg_, gm[:, i]) for i in range(3)], 1)
        nz = white + bi
        w = w + to[None] + nz
    else:
        nz = np.zeros((N, 3))
    # accelerometer
    acc = f_spec * (1 + sp['acc_s'])[None] + sp['acc_b'][None]
    if noise:
        acc = acc + _rng(seed, k, 5).normal(0, sp['acc_n'], (N, 3))
    # temperature reading
    temp = T + sp['t_off']
    if noise:
        temp = temp + _rng(seed, k, 6).normal(0, 0.03, N)
    temp = np.round(temp * 128) / 128

    return dict(t=t, w=w, ref=ref_logged, rate_act=rate_act, omega=omega, temp=temp, T=T,
                air=air, fix=fix, acc=acc, f=f_spec, nz=nz, dw=dw, ev=ev, U=U,
                holds=tl['holds'], events=tl['events'], kind=tl['kind'], proto=proto, fs=fs,
                mount_label=np.array([e['mount'] for e in tl['events']])[ev])


# ----------------------------------------------------------------------------- standard cal
def hold_means(sim, skip=0.3):
    fs = sim['fs']
    sk = int(skip * fs)
    rows = []
    for h in sim['holds']:
        a, b = h['start'] + sk, h['stop']
        rows.append(dict(point=h['Tnom'], mount=h['mount'], ref=float(sim['ref'][a:b].mean()),
                         w=sim['w'][a:b].mean(0), temp=sim['temp'][a:b].mean(),
                         nz=sim['nz'][a:b].mean(0), t=sim['t'][a:b].mean()))
    return rows


def std_calibrate(hm):
    """Per temperature point 12-parameter least squares: w = K (ref u) + B."""
    pts = {}
    for r in hm:
        pts.setdefault(r['point'], []).append(r)
    cal = []
    for P, rows in pts.items():
        X = np.array([np.r_[r['ref'] * MOUNT_UP[r['mount']], 1.0] for r in rows])
        Y = np.array([r['w'] for r in rows])
        coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
        cal.append((float(np.mean([r['temp'] for r in rows])), coef[:3].T, coef[3]))
    cal.sort(key=lambda c: c[0])
    return cal


def std_errors(cal, hm):
    Ts = np.array([c[0] for c in cal])
    Ks = np.array([c[1] for c in cal]); Bs = np.array([c[2] for c in cal])
    errs = []
    for r in hm:
        T = min(max(r['temp'], Ts[0]), Ts[-1])
        if len(Ts) == 1:
            K, B = Ks[0], Bs[0]
        else:
            j = int(np.clip(np.searchsorted(Ts, T) - 1, 0, len(Ts) - 2))
            f = (T - Ts[j]) / (Ts[j + 1] - Ts[j])
            K = Ks[j] * (1 - f) + Ks[j + 1] * f
            B = Bs[j] * (1 - f) + Bs[j + 1] * f
        est = np.linalg.solve(K, r['w'] - B)
        errs.append(est - r['ref'] * MOUNT_UP[r['mount']])
    return np.array(errs)


def rms(x):
    x = np.asarray(x)
    return float(np.sqrt(np.mean(x ** 2)))


def noise_floor(sim):
    """True hold-mean noise floor: RMS of the hold means of the noise processes."""
    return rms([r['nz'] for r in hold_means(sim)])


# ----------------------------------------------------------------------------- calibrate amp
def unit_reference(unit):
    """Reference floor (max of the true hold-mean noise floor and what a complete model
    leaves on s2 after calibrating s0) and the effect amplitude for the target magnitude."""
    c0 = simulate_session(unit, 0, effect=False)
    c2 = simulate_session(unit, 2, effect=False)
    hm0, hm2 = hold_means(c0), hold_means(c2)
    nf = noise_floor(c2)
    complete_left = rms(std_errors(std_calibrate(hm0), hm2))
    floor = max(nf, complete_left)
    out = dict(noise_floor=nf, complete_left=complete_left, floor_ref=floor, amp=0.0,
               extra=0.0)
    if unit['family'] == COMPLETE:
        return out
    q0 = hold_means(simulate_session(unit, 0, noise=False, effect=False))
    q2 = hold_means(simulate_session(unit, 2, noise=False, effect=False))
    e_clean = std_errors(std_calibrate(q0), q2)

    def extra(a):
        p0 = hold_means(simulate_session(unit, 0, amp=a, noise=False))
        p2 = hold_means(simulate_session(unit, 2, amp=a, noise=False))
        return rms(std_errors(std_calibrate(p0), p2) - e_clean)

    a0 = 1.0
    x0 = extra(a0)
    if x0 <= 0:
        raise RuntimeError(f'{unit["name"]}: effect invisible on s2')
    target = unit['magnitude'] * floor
    a = a0 * target / x0
    x = extra(a)
    if abs(x / target - 1) > 0.05:          # mildly nonlinear: one secant step
        a = a * target / x
        x = extra(a)
    out.update(amp=float(a), extra=float(x))
    return out


# ----------------------------------------------------------------------------- writing
def write_session(sim, path, unit, k):
    proto = sim['proto']
    N = len(sim['t'])
    keep = np.ones(N, bool)
    r = _rng(unit['seed'], k, 20)
    if proto['gaps']:
        # the logger was paused for a minute in the middle of some soaks
        soak_idx = np.flatnonzero(sim['kind'] == 'soak')
        if len(soak_idx):
            for c in r.choice(soak_idx, 2, replace=False):
                seg = np.arange(c, min(c + int(60 * sim['fs']), N))
                keep[seg[sim['kind'][seg] == 'soak']] = False
    t = sim['t'][keep]
    t0 = r.uniform(0, 5000)
    cols = {}
    if proto['time'] == 'timestamp':
        base = np.datetime64('2025-03-03T07:00:00', 'us') + np.timedelta64(int(k * 86400e6 * 3), 'us')
        cols['t'] = pa.array(base + ((t + t0) * 1e6).astype('int64').astype('timedelta64[us]'),
                             pa.timestamp('us'))
    else:
        cols['t'] = pa.array(t + t0, pa.float64())
    gyro = sim['w'][keep]
    ref = sim['ref'][keep]
    if proto['rad']:
        gyro = np.deg2rad(gyro); ref = np.deg2rad(ref)
    dt_ = pa.float32() if proto['dtype'] == 'float32' else pa.float64()
    gyro = gyro.copy()
    if proto['nan_rows']:
        idx = r.choice(len(t), proto['nan_rows'], replace=False)
        gyro[idx, r.integers(0, 3)] = np.nan
    for i, a in enumerate('xyz'):
        cols[f'gyro_{a}'] = pa.array(gyro[:, i], dt_)
    cols['temp'] = pa.array(sim['temp'][keep], pa.float32())
    cols['ref_rate'] = pa.array(ref, pa.float64())
    if proto['mount_col'] == 'string':
        cols['mount'] = pa.array(sim['mount_label'][keep].tolist(), pa.string())
    elif proto['mount_col'] == 'dictionary':
        cols['mount'] = pa.array(sim['mount_label'][keep].tolist(), pa.string()).dictionary_encode()
    if proto['accel']:
        for i, a in enumerate('xyz'):
            cols[f'accel_{a}'] = pa.array(sim['acc'][keep][:, i], pa.float32())
    table = pa.table(cols)
    meta = {b'open2.generator': b'benchmarks/open2'}
    if proto['rad']:
        meta[b'gyrocal.units'] = json.dumps({'gyro': 'rad/s', 'ref_rate': 'rad/s'}).encode()
    table = table.replace_schema_metadata(meta)
    pq.write_table(table, path)
    sim['keep'] = keep
    return path


def truth_of(unit, ref):
    fam = unit['family']
    if fam == COMPLETE:
        return dict(family=fam, category='complete', magnitude=0.0, expected='quiet',
                    fix_ok=False, reads_right=[], reads_ok=[], acts_on=[], reasons=[],
                    one_log_visible=True, variant=unit['variant'], **ref)
    F = FAMILIES[fam]
    one_log = F['one_log']
    if fam == 'fixture_reseat' and not VARIANTS[unit['variant']]['accel']:
        fix_ok = False
    else:
        fix_ok = F['fix']
    expected = 'fix' if F['cat'] in ('sensor', 'confusable') else 'no_sensor_term'
    return dict(family=fam, category=F['cat'], magnitude=unit['magnitude'], expected=expected,
                fix_ok=fix_ok, reads_right=F['reads_right'], reads_ok=F['reads_ok'],
                acts_on=F['acts_on'], reasons=F['reasons'], one_log_visible=one_log,
                variant=unit['variant'], **ref)


def generate_unit(unit, out_dir):
    """Write s0, s1, s2 of a unit into out_dir; return (paths, truth)."""
    os.makedirs(out_dir, exist_ok=True)
    ref = unit_reference(unit)
    u = dict(unit, amp=ref['amp'])
    paths = []
    sims = []
    for k in range(3):
        sim = simulate_session(u, k)
        p = os.path.join(out_dir, f'{unit["name"]}_s{k}.parquet')
        write_session(sim, p, unit, k)
        paths.append(p)
        sims.append(sim)
    my_before = rms(std_errors(std_calibrate(hold_means(sims[0])), hold_means(sims[2])))
    truth = truth_of(unit, ref)
    truth['my_before'] = my_before
    truth['amp'] = ref['amp']
    truth['sessions'] = [dict(order=s['proto']['order'], mounts=s['proto']['mounts'],
                              r_order=s['proto']['r_order'], fs=s['fs'], rows=len(s['t']))
                         for s in sims]
    with open(os.path.join(out_dir, f'{unit["name"]}_truth.json'), 'w') as fh:
        json.dump(truth, fh, indent=1, default=float)
    return paths, truth, sims


# ----------------------------------------------------------------------------- selfcheck
def _read(path):
    tb = pq.read_table(path)
    d = {c: tb.column(c).to_numpy(zero_copy_only=False) for c in tb.column_names
         if c != 'mount'}
    meta = tb.schema.metadata or {}
    if b'gyrocal.units' in meta:
        for c in ('gyro_x', 'gyro_y', 'gyro_z', 'ref_rate'):
            d[c] = np.rad2deg(d[c])
    if 'mount' in tb.column_names:
        d['mount'] = np.asarray(tb.column('mount').to_pylist())
    return d


def _written_holds(d, sim, skip=0.3):
    """Hold means from the written columns, over the simulation's hold windows (ref != 0).
    Returns (ref, gyro mean, written a, written b, sim a, sim b) per hold."""
    widx = np.cumsum(sim['keep']) - 1
    g = np.stack([d['gyro_x'], d['gyro_y'], d['gyro_z']], 1).astype(float)
    sk = int(skip * sim['fs'])
    out = []
    for h in sim['holds']:
        if h['ref'] == 0:
            continue
        sa, sb = h['start'] + sk, h['stop']
        wa, wb = widx[sa], widx[sb - 1] + 1
        seg = g[wa:wb]
        ok = np.all(np.isfinite(seg), 1)
        out.append((float(d['ref_rate'][wa:wb].mean()), seg[ok].mean(0), wa, wb, sa, sb))
    return out


def selfcheck(seed=424242, families=None, verbose=True):
    """Generate one unit per family and check the physics is in the written logs."""
    tmp = tempfile.mkdtemp(prefix='open2-selfcheck-')
    fams = list(FAMILIES) + [COMPLETE] if families is None else families
    units = {u['family']: u for u in make_units(seed, per_family=1, n_complete=1)}
    fails = []
    for fam in fams:
        unit = dict(units[fam], magnitude=20.0) if fam != COMPLETE else units[fam]
        paths, truth, sims = generate_unit(unit, tmp)
        d = [_read(p) for p in paths]
        clean = [simulate_session(dict(unit, amp=truth['amp']), k, effect=False)
                 for k in range(3)]
        msgs = []

        def check(cond, msg):
            if not cond:
                msgs.append(msg)

        # ---- the contract, on every log
        for k, dk in enumerate(d):
            t = dk['t'].astype('datetime64[us]').astype('int64') / 1e6 if dk['t'].dtype.kind == 'M' else dk['t']
            check(np.all(np.diff(t) > 0), f's{k}: t not strictly increasing')
            for c in ('gyro_x', 'gyro_y', 'gyro_z', 'temp', 'ref_rate'):
                check(c in dk, f's{k}: missing {c}')
            if 'mount' in dk:
                check(set(np.unique(dk['mount'])) <= set(MOUNT_UP), f's{k}: bad mount labels')
            if 'accel_x' in dk:
                a = np.stack([dk['accel_x'], dk['accel_y'], dk['accel_z']], 1)
                still = (dk['ref_rate'] == 0)
                nrm = np.linalg.norm(a[still], axis=1)
                check(abs(np.median(nrm) - 1) < 0.02, f's{k}: accel at rest not 1 g')
            # temperature lags the chamber: just after a ramp the package is off the set point
            sim = sims[k]
            soak = np.flatnonzero(sim['kind'] == 'soak')
            first = soak[0]
            check(abs(sim['T'][first] - sim['air'][first]) > 0.5,
                  f's{k}: package temperature does not lag the chamber')
            # the written gyro matches the physics (float32 and rad/s aside)
            wr = np.stack([dk['gyro_x'], dk['gyro_y'], dk['gyro_z']], 1).astype(float)
            check(np.isfinite(wr).sum() >= wr.size - 30, f's{k}: too many NaN')
        # ---- the effect: written hold means minus a clean twin with the same noise
        hw = [_written_holds(dk, sims[k]) for k, dk in enumerate(d)]
        diff = [np.array([h[1] - clean[k]['w'][h[4]:h[5]][np.all(np.isfinite(
            np.stack([d[k]['gyro_x'], d[k]['gyro_y'], d[k]['gyro_z']], 1)[h[2]:h[3]]), 1)].mean(0)
            for h in hw[k]]) for k in range(3)]
        refs = [np.array([h[0] for h in hw[k]]) for k in range(3)]
        check_family(fam, unit, truth, sims, clean, d, diff, refs, check)
        # the magnitude: extra RMS on s2 after the standard calibration of s0
        if fam != COMPLETE:
            check(abs(truth['extra'] / (truth['magnitude'] * truth['floor_ref']) - 1) < 0.1,
                  f'extra {truth["extra"]:.4g} off target')
            check(truth['my_before'] > 1.2 * truth['floor_ref'],
                  f'before {truth["my_before"]:.4g} not above 1.2 floor {truth["floor_ref"]:.4g}')
        else:
            check(truth['my_before'] <= 1.3 * truth['floor_ref'], 'complete unit not at floor')
        status = 'ok' if not msgs else 'FAIL: ' + '; '.join(msgs)
        if verbose:
            print(f'{fam:24s} floor {truth["floor_ref"]:.4f} (noise {truth["noise_floor"]:.4f}) '
                  f'amp {truth["amp"]:.3g} my_before/floor {truth["my_before"] / truth["floor_ref"]:.2f}  {status}',
                  flush=True)
        if msgs:
            fails.append((fam, msgs))
    return fails


def check_family(fam, unit, truth, sims, clean, d, diff, refs, check):
    ep = effect_params(unit['seed'], fam)
    amp = truth['amp']

    def axis_rate(k):
        sh = [h for h in sims[k]['holds'] if h['ref'] != 0]
        return np.array([h['ref'] * MOUNT_UP[h['mount']] for h in sh])

    def corr(a, b):
        a = np.ravel(a); b = np.ravel(b)
        return float(np.corrcoef(a, b)[0, 1])

    if fam == COMPLETE:
        for k in range(3):
            check(np.max(np.abs(diff[k])) < 1e-4, f's{k}: complete unit differs from clean twin')
        return
    if fam == 'cubic_scale':
        wv = axis_rate(0)
        pred = amp * 1e-3 * ep['w'][None] * wv * (wv / 300) ** 2
        check(corr(diff[0], pred) > 0.99, 'cubic signature missing')
        check(abs(np.sum(diff[0] * pred) / np.sum(pred * pred) - 1) < 0.05, 'cubic size off')
    elif fam == 'cw_ccw_asymmetry':
        wv = axis_rate(0)
        pred = amp * 1e-4 * ep['w'][None] * wv * np.tanh(wv / 8)
        check(corr(diff[0], pred) > 0.99, 'asymmetry signature missing')
        # even in the rate: the same hold forward and reverse carries the same excess
        sh = [h for h in sims[0]['holds'] if h['ref'] != 0]
        key = {(h['Tnom'], h['ev'], h['ref']): i for i, h in enumerate(sh)}
        pairs = [(i, key[(h['Tnom'], h['ev'], -h['ref'])]) for i, h in enumerate(sh)
                 if h['ref'] > 0 and (h['Tnom'], h['ev'], -h['ref']) in key]
        check(len(pairs) > 5 and max(np.max(np.abs(diff[0][i] - diff[0][j])) for i, j in pairs)
              < 0.02 * np.max(np.abs(diff[0])), 'asymmetry not even in the rate')
    elif fam == 'cross_rate_square':
        wv = axis_rate(0)
        pred = np.zeros_like(wv)
        for i, j, c in ep['pairs']:
            pred[:, j] += amp * 1e-4 * c * wv[:, i] * np.abs(wv[:, i]) / 300
        check(corr(diff[0], pred) > 0.99, 'cross-axis signature missing')
        sens = np.abs(wv) > 0
        check(np.max(np.abs(diff[0][sens])) < 1e-6 + 1e-4 * np.max(np.abs(diff[0])),
              'cross effect leaks onto the sensing axis')
    elif fam == 'small_rate_compression':
        small = np.abs(refs[0]) <= 3
        check(np.all(np.abs(diff[0][~small]).max() < 1e-3 * np.abs(diff[0][small]).max() + 1e-9),
              'compression not confined to small rates')
        wv = axis_rate(0)
        check(np.all(diff[0][small] * wv[small] <= 1e-12), 'compression does not shrink')
    elif fam == 'exposure_charging':
        x = first_order(np.linalg.norm(sims[0]['omega'], axis=1) / 300.0, sims[0]['t'], ep['tau'])
        sh = [h for h in sims[0]['holds'] if h['ref'] != 0]
        pred = np.array([x[h['start'] + 15:h['stop']].mean() for h in sh])[:, None] * ep['v'][None] * amp * 2e-3
        check(corr(diff[0], pred) > 0.99, 'charging does not follow the rate history')
    elif fam == 'fixture_heat_flux':
        k = 0
        sim = sims[k]
        dd = sim['dw']
        check(np.std(dd[sim['kind'] == 'settle']) > 0, 'no heat flux bias after door openings')
        g = sim['fix'] - (sim['T'] - truth_self_heat(unit, sim))
        check(corr(dd[::50], g[::50, None] * ep['v'][None]) > 0.999, 'bias does not follow flux')
    elif fam == 'log_creep':
        for k in (0, 2):
            sh = [h for h in sims[k]['holds'] if h['ref'] != 0]
            tt = np.array([sims[k]['t'][h['start']:h['stop']].mean() for h in sh])
            pred = amp * 1e-3 * np.log1p(tt / ep['tau0'])[:, None] * ep['v'][None]
            check(corr(diff[k], pred) > 0.99, f's{k}: creep does not follow log time')
    elif fam == 'clamp_relaxation':
        sim = sims[0]
        dd = sim['dw'] @ ep['v']
        sh = [h for h in sim['holds'] if h['ref'] != 0]
        check(np.corrcoef(diff[0] @ ep['v'], [dd[h['start']:h['stop']].mean() for h in sh])[0, 1]
              > 0.99, 'written excess does not follow the time since clamping')
        check(all(dd[e['clamped']] > 1.5 * dd[e['start'] - 1] for e in sim['events'][1:]),
              'no relaxation restart at remount')
    elif fam == 'thermal_play':
        # the same temperature point approached from the other side has a shifted bias on s2
        p0 = np.array([h['Tnom'] for h in sims[0]['holds'] if h['ref'] != 0])
        p2 = np.array([h['Tnom'] for h in sims[2]['holds'] if h['ref'] != 0])
        m0 = np.mean(diff[0] @ ep['v']); m2 = np.mean(diff[2] @ ep['v'])
        check(np.sign(m0) != np.sign(m2) and abs(m0 - m2) > 0.8e-3 * amp,
              'no direction-of-approach offset between sessions')
    elif fam == 'offcenter_g':
        for k in (0, 2):
            dk = d[k]
            a = np.stack([dk['accel_x'], dk['accel_y'], dk['accel_z']], 1)
            am = np.array([a[h[2]:h[3]].mean(0) for h in _written_holds(dk, sims[k])])
            X = np.c_[am, np.ones(len(am))]
            coef, *_ = np.linalg.lstsq(X, diff[k], rcond=None)
            res = diff[k] - X @ coef
            check(rms(res) < 0.05 * rms(diff[k]), f's{k}: gyro excess not linear in written accel')
            check(np.allclose(coef[:3].T, amp * 1e-3 * ep['G'], rtol=0.1, atol=0.05 * amp * 1e-3),
                  f's{k}: g-sensitivity off')
        # the radius differs: centripetal accel at the top rate differs between s0 and s2
        cen = [np.max(np.abs(sims[k]['f'] - sims[k]['U'][sims[k]['ev']]).sum(1)[
            sims[k]['kind'] == 'hold']) for k in (0, 2)]
        check(cen[0] > 1.4 * cen[1], 'radius does not change between sessions')
    elif fam == 'table_tach_scale':
        r0 = d[0]['ref_rate']; act = sims[0]['rate_act']
        m = np.abs(act) > 50
        ratio = np.median(r0[:len(act)][m] / act[m]) if len(r0) == len(act) else None
        check(ratio is not None and abs(ratio - 1 - ep['sign'] * 1e-3 * amp) < 5e-5,
              'logged reference not scaled on s0')
        check(np.allclose(d[2]['ref_rate'], sims[2]['rate_act'], atol=0.01), 's2 reference off')
    elif fam == 'fixture_reseat':
        U = sims[0]['U']
        nom = np.array([MOUNT_UP[e['mount']] for e in sims[0]['events']])
        tilt = np.linalg.norm(U - nom, axis=1)
        check(np.std(tilt) > 0 and np.median(tilt) > 0.3e-3 * amp, 'no reseat tilt')
        wv = axis_rate(0)
        off = (np.abs(wv) == 0)
        check(np.max(np.abs(diff[0][off])) > 0, 'tilt not in the cross axes')
    elif fam == 'board_stress_change':
        check(np.max(np.abs(diff[0])) < 1e-9, 's0 changed already')
        check(rms(diff[1]) > 0 and rms(diff[2]) > 0, 'no change on s1/s2')
    elif fam == 'popcorn_bias':
        dd = sims[0]['dw'] @ (ep['axes'] / np.linalg.norm(ep['axes']))
        lv = np.unique(np.round(dd, 12))
        check(len(lv) == 2, 'popcorn noise not two-level')
    elif fam == 'mode_crossing':
        check(np.max(np.abs(diff[0])) < 0.05 * np.max(np.abs(diff[2])), 's0 sees the bump')
        pts2 = sorted({h['Tnom'] for h in sims[2]['holds']})
        pts0 = sorted({h['Tnom'] for h in sims[0]['holds']})
        check(not set(pts2) & set(pts0), 's2 at the same points as s0')


def truth_self_heat(unit, sim):
    sp = sensor_params(unit['seed'])
    return sp['self_heat'] * (1 - np.exp(-sim['t'] / 150.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out')
    ap.add_argument('--seed', type=int, default=20250611)
    ap.add_argument('--family')
    ap.add_argument('--max-units', type=int)
    ap.add_argument('--selfcheck', action='store_true')
    a = ap.parse_args(argv)
    if a.selfcheck:
        fails = selfcheck(families=[a.family] if a.family else None)
        print('selfcheck:', 'ok' if not fails else f'{len(fails)} families failed')
        return 1 if fails else 0
    if not a.out:
        ap.error('--out or --selfcheck')
    units = make_units(a.seed, families=[a.family] if a.family else None)
    if a.max_units:
        units = units[:a.max_units]
    for u in units:
        paths, truth, _ = generate_unit(u, a.out)
        print(u['name'], truth['variant'], f'mag {u["magnitude"]}', 'floor',
              f'{truth["floor_ref"]:.4g}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
