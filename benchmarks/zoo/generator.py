"""Independent simulator of MEMS-gyroscope calibration-rig logs.

Written only from the log contract (/work/shared/spec/log-format.md), the three physics
papers in /work/shared/seeds and general MEMS-gyro physics, by someone who did not read
gyrocal's own simulator, terms, tests or docs.  numpy + pyarrow only.

API
---
    unit = make_unit(effect="warmup", protocol="turntable3", noise="white", seed=7)
    info = write_session(unit, path, session=0, seed=123, rate_hz=25.0, **overrides)

``effect`` is one name of ``EFFECTS`` (or several joined by "+", e.g. "warmup+g_sensitivity").
The base sensor (K(T), B(T), noise, thermal constants) depends only on ``seed`` and
``noise``, not on the effect, so ``make_unit("none", seed=7)`` and
``make_unit("warmup", seed=7)`` are the same physical unit with and without the effect.

Sensor model (per sample, deg/s, T in degC, T_ref = 25 degC):

    w = K(T_k) w_true + B(T_k) + sum(effects) + noise
    K(T)  = I + diag(s0 + s1 dT + s2 dT^2) + M          (M: off-diagonal misalignment)
    B(T)  = b0 + b1 dT + b2 dT^2,        dT = T_k - 25
    T_k   = true (noise-free) sensor temperature, or the die temperature for "die_lag".

"die_lag_curved" replaces the polynomials by the die's own curves (a cubic bias, a stronger
scale TC) and makes every other temperature effect of the unit follow the die too.

The third set (rate_band_bias ... mount_bias_shift) sizes its amplitudes on the unit's own
20 s hold-mean floor (drawn ARW / sqrt(20 s)); "warmup_selfheat" adds a self-heating rise to
the sensor temperature.  Turntable sessions take ``rate_order`` and ``temp_order`` to visit
the holds / set points in another order ("default" is byte-identical to no override).

The fourth set adds a stronger slow pole, a wide bias bump between the rate levels, a
g-sensitivity that changes with temperature and a bias step between sessions; turntable
sessions also take ``settle_c`` / ``settle_tau_s`` (the package still settling at each new set
point, through the fixture's slower heat path) and ``temp_order="zigzag"`` or an explicit list
of set points.
"""
from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

__all__ = ["UnitSpec", "make_unit", "write_session", "simulate_session", "EFFECTS", "SESSION_RESTART",
           "PROTOCOLS", "NOISES", "RATE_ORDERS", "TEMP_ORDERS"]

G0 = 9.80665            # m/s^2 per g
T_REF = 25.0            # degC, reference of the polynomials
ROOM_T = 22.0           # degC, where the unit was stored before the session
D2R = math.pi / 180.0

EFFECTS: dict[str, str] = {
    "none": "clean unit: only the temperature-dependent linear model K(T) w + B(T) plus noise",
    "g_sensitivity": "bias proportional to specific force (g-sensitivity of the proof mass), e = G f",
    "g_squared": "bias proportional to the square of specific force (anisoelasticity), e = G2 (f*f)",
    "die_lag": "MEMS die temperature lags the logged temperature sensor (first order, 10-20 min); "
               "bias (strong TC) and scale follow the die",
    "warmup": "turn-on transient of the bias, A exp(-t_since_power_on / tau), tau 15-25 min",
    "bias_ramp": "slow linear-in-time bias drift after power-on (charging/aging), e = d t",
    "run_to_run_bias": "turn-on to turn-on bias repeatability: a new constant offset every session",
    "scale_quadratic": "even scale-factor nonlinearity, e = k u^2",
    "scale_asymmetry": "different scale for positive and negative rate, e = k |u|",
    "scale_cubic": "odd cubic scale-factor nonlinearity, e = k u^3",
    "rate_dependent_bias_sat": "output compresses smoothly near full scale (soft clip of order 8)",
    "cross_coupling": "products of rates on different sense axes (centrifugal coupling), "
                      "e_a = sum C_a,bc u_b u_c",
    "temp_rate": "thermal-gradient bias proportional to dT/dt of the package, e = q dT/dt",
    "bias_quadratic_temp": "strong extra bias curvature with temperature, e = c (T - 25)^2",
    "hysteresis": "thermal hysteresis: bias depends on whether temperature rose or fell "
                  "(Duhem state that switches smoothly over a few degC of travel)",
    "vibration_rectification": "rectified motor/bearing vibration of the rig: bias grows with the "
                               "square of the rig speed, depending on orientation",
    # the die's own temperature: every temperature dependence felt through a lag
    "die_lag_curved": "die lags the sensor (first order, 5-20 min) and the whole temperature model "
                      "follows the die: K(Td), B(Td) with a strong DT^2 and DT^3 bias curve and a "
                      "stronger scale TC; other temperature effects of the unit follow the die too",
    # products of two inputs
    "scale_warmup": "scale factor relaxing after power-on, e = u s exp(-t/tau) (own-axis rate x time)",
    "scale_temp_rate": "scale factor proportional to the temperature rate (thermal gradient across the "
                       "sense structure), e = u q dT/dt",
    "misalign_warp_tanh": "package warp tilts the sense axes with temperature, saturating past the "
                          "adhesive's transition: e = Mw w tanh((T - Tg)/W), Mw off-diagonal",
    # non-polynomial shapes of one input
    "bias_bump_temp": "mode crossing near one temperature: Gaussian bias bump "
                      "h exp(-(T-Tb)^2/(2 sig^2))",
    "bias_tanh_temp": "bias transition across a temperature, e = a tanh((T - Tt)/w)",
    "scale_low_rate_tanh": "low-rate scale excess that saturates, e = a tanh(u/W), W 20-80 deg/s",
    "warmup_two_exp": "turn-on transient of two thermal time constants, "
                      "A1 exp(-t/tau1) + A2 exp(-t/tau2)",
    "warmup_power_law": "turn-on transient decaying as a power law, A (1 + t/t0)^-p",
    # steps
    "bias_step_temp": "firmware compensation table switching at a sensor temperature, with hysteresis",
    "bias_step_time": "mode change (re-trim/latch) a fixed time after power-on: a bias step",
    # histories of the rotation
    "motor_heating_bias": "local heating by the rig motor: bias follows a first-order lag of the "
                          "mechanical power (rig rate squared), tau minutes",
    "table_angle_bias": "a lab-fixed horizontal disturbance field seen through the turning table: "
                        "bias periodic in the accumulated table angle",
    # third set: sharp shapes of the rate and cross-axis shapes
    "rate_band_bias": "parasitic mode excited near one rotation rate: Lorentzian bias bump in the "
                      "own-axis rate, h / (1 + ((|w| - r0)/gamma)^2), r0 near 100 or 200 deg/s",
    "scale_range_switch": "auto-ranging: above |u| > u_th the part switches range and its scale "
                          "factor (and offset) step, e = [|u| > u_th] (ds u + db)",
    "cross_axis_quadratic": "anisoinertia / centrifugal loading: the square of the rate about another "
                            "axis appears on each output, e_a = sum_{b!=a} q_ab w_b^2",
    "warmup_selfheat": "turn-on bias transient A exp(-t/tau) on a unit that self-heats after power-on "
                       "(sensor temperature rises dT_self (1 - exp(-t/tau_heat))); no temperature-rate term",
    # third set: effects with a history
    "slow_pole": "part of the output passes a slow pole: e = k (lag(u, tau) - u), tau 2-8 s, "
                 "so the output settles over seconds after every rate change",
    "rotation_heating": "turning heats the sensor package (bearing friction): bias follows a first-order "
                        "lag of |w|, tau 0.5-4 min; the logged temperature sensor does not see it",
    "temp_hysteresis_play": "thermal hysteresis with a remembered direction: e = h s, s = direction of "
                            "the last motion of a play (backlash) operator of width w on the temperature",
    "mount_bias_shift": "each mounting on the fixture strains the package: a new random bias vector "
                        "at every mount stretch, fresh in every session",
    # fourth set: effects a calibration may take for something else
    "slow_pole_strong": "slow_pole with a larger share of the output: e = k (lag(u, tau) - u), tau about "
                        "6 s, k sized so that the settling moves a hold's mean tens of times its floor",
    "rate_band_bias_wide": "bias bump over a band of rates between the protocol's levels: Gaussian (or "
                           "Lorentzian) in the own-axis rate, centre about 150 deg/s, FWHM about 40 deg/s",
    "g_sensitivity_temp": "g-sensitivity whose coefficients change linearly with temperature, "
                          "e = (G0 + G1 (T - 25)) f",
    "session_bias_step": "a constant bias offset present only in the listed sessions (default: session 1): "
                         "a step between power-ons, constant within a session",
}

# effects whose parameters live in the unit but whose state restarts at every power-on
SESSION_RESTART = ("warmup", "bias_ramp", "run_to_run_bias", "scale_warmup", "warmup_two_exp",
                   "warmup_power_law", "bias_step_time", "motor_heating_bias", "table_angle_bias",
                   "warmup_selfheat", "slow_pole", "rotation_heating", "mount_bias_shift",
                   "slow_pole_strong", "session_bias_step")

# session overrides that change the order a turntable visits its rates or set points
RATE_ORDERS = ("default", "reversed", "shuffled", "ascending", "descending")
TEMP_ORDERS = ("default", "ascending", "descending", "updown", "downup", "revisit", "zigzag")

PROTOCOLS = ("turntable3", "turntable6", "sweep", "servo")
NOISES = ("white", "coloured")

_MOUNT_LABELS = ("+x", "-x", "+y", "-y", "+z", "-z")


# --------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------
def _rng(*keys) -> np.random.Generator:
    ent = []
    for k in keys:
        if isinstance(k, str):
            ent.append(zlib.crc32(k.encode()))
        else:
            ent.append(int(k) & 0xFFFFFFFF)
    return np.random.default_rng(np.random.SeedSequence(ent))


def _signs(rng, n):
    return np.where(rng.random(n) < 0.5, -1.0, 1.0)


def _u(rng, lo, hi, n=None):
    return rng.uniform(lo, hi, n)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def _mount_R(label: str) -> np.ndarray:
    """Body->rig rotation for a mount: the sensor axis `label` points up the rig axis (+z rig).

    Columns are the body axes expressed in the rig frame."""
    base = {
        "x": np.array([[0., 1., 0.], [0., 0., 1.], [1., 0., 0.]]),   # bx->rz, by->rx, bz->ry
        "y": np.array([[0., 0., 1.], [1., 0., 0.], [0., 1., 0.]]),   # by->rz, bz->rx, bx->ry
        "z": np.eye(3),
    }[label[1]]
    if label[0] == "-":
        base = np.diag([1.0, -1.0, -1.0]) @ base                     # 180 deg about rig x
    return base


def _rotvec_to_R(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * Kx + (1 - math.cos(th)) * (Kx @ Kx)


def _R_to_rotvec(Q: np.ndarray) -> np.ndarray:
    c = float(np.clip((np.trace(Q) - 1) / 2, -1.0, 1.0))
    th = math.acos(c)
    if th < 1e-12:
        return np.zeros(3)
    if math.pi - th < 1e-6:
        B = (Q + np.eye(3)) / 2
        i = int(np.argmax(np.diag(B)))
        k = B[:, i] / math.sqrt(max(B[i, i], 1e-300))
        return k / np.linalg.norm(k) * th
    k = np.array([Q[2, 1] - Q[1, 2], Q[0, 2] - Q[2, 0], Q[1, 0] - Q[0, 1]]) / (2 * math.sin(th))
    return k * th


def _rotate(rv: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (n,3) by rotation vectors rv (n,3) (Rodrigues, vectorised)."""
    th = np.linalg.norm(rv, axis=1, keepdims=True)
    safe = np.where(th < 1e-15, 1.0, th)
    k = rv / safe
    c, s = np.cos(th), np.sin(th)
    kv = np.sum(k * v, axis=1, keepdims=True)
    out = v * c + np.cross(k, v) * s + k * kv * (1 - c)
    return np.where(th < 1e-15, v, out)


def _right_jacobian_apply(e: np.ndarray, ed: np.ndarray) -> np.ndarray:
    """Body angular velocity contribution J_r(e) e_dot of R = Exp(e) (vectorised)."""
    th = np.linalg.norm(e, axis=1, keepdims=True)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5, (1 - np.cos(ths)) / ths ** 2)
    b = np.where(small, 1.0 / 6.0, (ths - np.sin(ths)) / ths ** 3)
    exed = np.cross(e, ed)
    return ed - a * exed + b * np.cross(e, exed)


# --------------------------------------------------------------------------------------
# thermal: chamber (piecewise linear) -> sensor (1st-order lag) -> die (1st-order lag)
# --------------------------------------------------------------------------------------
def _thermal(knots_t, knots_T, tau_s, tau_d, t):
    """Exact response of a cascade of first-order lags to a piecewise-linear chamber.

    Returns Tc, Ts, dTs/dt, Td (Td is None when tau_d is None).  Both lags start
    equilibrated with the chamber at t = knots_t[0]."""
    kt = np.asarray(knots_t, float)
    kT = np.asarray(knots_T, float)
    tend = max(float(t[-1]), float(kt[-1])) + 1.0
    if kt[-1] < tend:
        kt = np.append(kt, tend)
        kT = np.append(kT, kT[-1])
    Tc = np.interp(t, kt, kT)
    Ts = np.empty_like(t)
    dTs = np.empty_like(t)
    Td = np.empty_like(t) if tau_d is not None else None
    y1 = kT[0]
    y2 = kT[0]
    t1, t2 = tau_s, tau_d
    if tau_d is not None and abs(t1 - t2) < 1e-6 * t1:
        t2 = t1 * (1 + 1e-6)
    idx = np.searchsorted(t, kt, side="left")
    for k in range(len(kt) - 1):
        dt_seg = kt[k + 1] - kt[k]
        if dt_seg <= 0:
            continue
        u0 = kT[k]
        r = (kT[k + 1] - kT[k]) / dt_seg
        c1 = y1 - u0 + r * t1
        i0, i1 = idx[k], idx[k + 1]
        s = t[i0:i1] - kt[k]
        e1 = np.exp(-s / t1)
        Ts[i0:i1] = u0 + r * s - r * t1 + c1 * e1
        dTs[i0:i1] = r - c1 / t1 * e1
        if tau_d is not None:
            A = c1 * t1 / (t1 - t2)
            c2 = y2 - u0 + r * (t1 + t2) - A
            Td[i0:i1] = u0 + r * s - r * (t1 + t2) + A * e1 + c2 * np.exp(-s / t2)
        # state at the end of the interval
        E1 = math.exp(-dt_seg / t1)
        ny1 = u0 + r * dt_seg - r * t1 + c1 * E1
        if tau_d is not None:
            y2 = u0 + r * dt_seg - r * (t1 + t2) + A * E1 + c2 * math.exp(-dt_seg / t2)
        y1 = ny1
    return Tc, Ts, dTs, Td


# --------------------------------------------------------------------------------------
# unit
# --------------------------------------------------------------------------------------
@dataclass
class UnitSpec:
    """One physical unit: its base parameters, noise parameters and effect parameters."""
    effect: str
    protocol: str
    noise: str
    seed: int
    params: dict = field(default_factory=dict)

    @property
    def effects(self) -> list[str]:
        return [e for e in self.effect.split("+") if e and e != "none"]

    def to_dict(self) -> dict:
        return _jsonable({"effect": self.effect, "protocol": self.protocol, "noise": self.noise,
                          "seed": self.seed, "params": self.params})


def _draw_base(seed):
    r = _rng(seed, "base")
    p = {}
    p["T_ref"] = T_REF
    p["s0"] = _signs(r, 3) * _u(r, 0.005, 0.02, 3)               # scale error
    p["s1"] = _signs(r, 3) * _u(r, 50e-6, 300e-6, 3)             # /degC
    p["s2"] = _signs(r, 3) * _u(r, 0.01e-6, 0.05e-6, 3)          # /degC^2
    M = np.zeros((3, 3))
    off = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    vals = _signs(r, 6) * _u(r, 0.002, 0.01, 6)
    for (i, j), v in zip(off, vals):
        M[i, j] = v
    p["M"] = M
    p["b0"] = _signs(r, 3) * _u(r, 0.1, 1.0, 3)                   # deg/s
    p["b1"] = _signs(r, 3) * _u(r, 0.005, 0.02, 3)                # deg/s/degC
    p["b2"] = _signs(r, 3) * _u(r, 0.2e-5, 1.0e-5, 3)             # deg/s/degC^2
    p["tau_sensor_s"] = float(_u(r, 80.0, 120.0))                  # sensor vs chamber
    p["temp_noise_c"] = float(_u(r, 0.01, 0.05))
    p["temp_lsb_c"] = 0.0625 if r.random() < 0.5 else 0.0
    p["accel_bias_g"] = _u(r, -0.01, 0.01, 3)
    p["accel_scale"] = _u(r, -0.003, 0.003, 3)
    p["accel_noise_g"] = float(_u(r, 0.001, 0.003))
    d = r.normal(size=3)
    p["imu_offset_m"] = d / np.linalg.norm(d) * _u(r, 0.005, 0.02)   # from the rig axis
    return p


def _draw_noise(seed, noise):
    r = _rng(seed, "noise")
    arw = float(_u(r, 0.005, 0.02)) * _u(r, 0.8, 1.2, 3)           # deg/s/sqrt(Hz)
    gm_sigma = _u(r, 0.002, 0.01, 3)
    gm_tau = _u(r, 100.0, 1000.0, 3)
    rrw = _u(r, 0.0, 2e-5, 3)                                        # deg/s/sqrt(s)
    p = {"kind": noise, "arw_dps_rthz": arw}
    if noise == "coloured":
        p.update({"gm_sigma_dps": gm_sigma, "gm_tau_s": gm_tau, "rrw_dps_rts": rrw})
    return p


def _draw_effect(seed, name):
    r = _rng(seed, "effect", name)
    if name == "g_sensitivity":
        G = _u(r, -0.03, 0.03, (3, 3))
        G[np.diag_indices(3)] = _signs(r, 3) * _u(r, 0.08, 0.2, 3)
        return {"G_dps_per_g": G}
    if name == "g_squared":
        return {"G2_dps_per_g2": _signs(r, 9).reshape(3, 3) * _u(r, 0.02, 0.08, (3, 3))}
    if name == "die_lag":
        return {"tau_die_s": float(_u(r, 600.0, 1200.0)),
                "b1_die_dps_per_c": _signs(r, 3) * _u(r, 0.02, 0.05, 3)}
    if name == "warmup":
        return {"A_dps": _signs(r, 3) * _u(r, 0.2, 0.4, 3), "tau_s": float(_u(r, 900.0, 1500.0))}
    if name == "bias_ramp":
        return {"d_dps_per_h": _signs(r, 3) * _u(r, 0.03, 0.1, 3)}
    if name == "run_to_run_bias":
        return {"sigma_dps": _u(r, 0.05, 0.2, 3)}
    if name == "scale_quadratic":
        return {"k_per_dps": _signs(r, 3) * _u(r, 0.05, 0.3, 3) / 400.0 ** 2}
    if name == "scale_asymmetry":
        return {"k": _signs(r, 3) * _u(r, 200e-6, 800e-6, 3)}
    if name == "scale_cubic":
        return {"k_per_dps2": _signs(r, 3) * _u(r, 0.05, 0.3, 3) / 400.0 ** 3}
    if name == "rate_dependent_bias_sat":
        n = 8.0
        d = _u(r, 0.1, 0.4, 3)                                     # deficit at 400 deg/s
        x = 400.0
        W = x / ((x / (x - d)) ** n - 1.0) ** (1.0 / n)
        return {"order": n, "W_dps": W, "deficit_at_400_dps": d}
    if name == "cross_coupling":
        return {"C_per_dps": _signs(r, 9).reshape(3, 3) * _u(r, 0.5e-6, 2e-6, (3, 3)),
                "pairs": ["xy", "xz", "yz"]}
    if name == "temp_rate":
        return {"q_dps_per_c_per_min": _signs(r, 3) * _u(r, 0.05, 0.2, 3)}
    if name == "bias_quadratic_temp":
        return {"c_dps_per_c2": _signs(r, 3) * _u(r, 1e-4, 3e-4, 3), "T0_c": T_REF}
    if name == "hysteresis":
        return {"h_dps": _signs(r, 3) * _u(r, 0.02, 0.05, 3), "dT_switch_c": float(_u(r, 2.0, 5.0))}
    if name == "vibration_rectification":
        return {"V_dps": _signs(r, 9).reshape(3, 3) * _u(r, 0.03, 0.15, (3, 3)),
                "ref_speed_dps": 400.0}
    if name == "die_lag_curved":
        return {"tau_die_s": float(_u(r, 300.0, 1200.0)),
                "b1_die_dps_per_c": _signs(r, 3) * _u(r, 0.02, 0.05, 3),     # replaces base b1
                "c2_dps_per_c2": _signs(r, 3) * _u(r, 1e-4, 3e-4, 3),        # added to base b2
                "c3_dps_per_c3": _signs(r, 3) * _u(r, 0.5e-6, 2e-6, 3),
                "s1_die_per_c": _signs(r, 3) * _u(r, 100e-6, 400e-6, 3),     # replaces base s1
                "s2_die_per_c2": _signs(r, 3) * _u(r, 0.3e-6, 1e-6, 3)}      # added to base s2
    if name == "scale_warmup":
        return {"s": _signs(r, 3) * _u(r, 300e-6, 1000e-6, 3), "tau_s": float(_u(r, 600.0, 1800.0))}
    if name == "scale_temp_rate":
        return {"q_per_c_per_min": _signs(r, 3) * _u(r, 500e-6, 2000e-6, 3)}
    if name == "misalign_warp_tanh":
        Mw = _signs(r, 9).reshape(3, 3) * _u(r, 0.5e-3, 2e-3, (3, 3))
        Mw[np.diag_indices(3)] = 0.0
        return {"Mw_rad": Mw, "T_g_c": float(_u(r, 10.0, 40.0)), "W_c": float(_u(r, 8.0, 15.0))}
    if name == "bias_bump_temp":
        return {"h_dps": _signs(r, 3) * _u(r, 0.05, 0.2, 3), "T_b_c": float(_u(r, 0.0, 40.0)),
                "sigma_c": float(_u(r, 5.0, 10.0))}
    if name == "bias_tanh_temp":
        return {"a_dps": _signs(r, 3) * _u(r, 0.03, 0.1, 3), "T_t_c": float(_u(r, 0.0, 40.0)),
                "w_c": float(_u(r, 3.0, 8.0))}
    if name == "scale_low_rate_tanh":
        return {"a_dps": _signs(r, 3) * _u(r, 0.05, 0.2, 3), "W_dps": _u(r, 20.0, 80.0, 3)}
    if name == "warmup_two_exp":
        return {"A1_dps": _signs(r, 3) * _u(r, 0.1, 0.3, 3), "tau1_s": float(_u(r, 120.0, 300.0)),
                "A2_dps": _signs(r, 3) * _u(r, 0.1, 0.3, 3), "tau2_s": float(_u(r, 1800.0, 3600.0))}
    if name == "warmup_power_law":
        return {"A_dps": _signs(r, 3) * _u(r, 0.2, 0.4, 3), "t0_s": float(_u(r, 30.0, 120.0)),
                "p": float(_u(r, 0.3, 0.7))}
    if name == "bias_step_temp":
        return {"step_dps": _signs(r, 3) * _u(r, 0.03, 0.1, 3), "T_switch_c": float(_u(r, 0.0, 45.0)),
                "hysteresis_c": float(_u(r, 1.0, 4.0))}
    if name == "bias_step_time":
        return {"step_dps": _signs(r, 3) * _u(r, 0.03, 0.1, 3), "t_step_s": float(_u(r, 1200.0, 3600.0))}
    if name == "motor_heating_bias":
        return {"H_dps": _signs(r, 3) * _u(r, 0.2, 0.5, 3), "tau_s": float(_u(r, 180.0, 600.0)),
                "ref_speed_dps": 400.0, "exponent": 2.0}
    if name == "table_angle_bias":
        return {"S_dps": _signs(r, 3) * _u(r, 0.02, 0.06, 3)}
    # third set: sized on the unit's own 20 s hold-mean floor F = ARW/sqrt(20 s) (per axis, from
    # the drawn ARW), so that every unit lands in the intended detectability band
    F = _floor20(seed)
    if name == "rate_band_bias":
        gamma = float(_u(r, 3.0, 8.0))                              # half width at half maximum
        level = 100.0 if r.random() < 0.5 else 200.0
        r0 = level + float(_u(r, -0.5, 0.5)) * gamma
        m = _u(r, 18.0, 50.0, 3)
        return {"h_dps": _signs(r, 3) * m * F, "r0_dps": r0, "gamma_dps": gamma,
                "near_level_dps": level, "peak_over_floor20": m}
    if name == "scale_range_switch":
        lo, hi = (100.0, 200.0) if r.random() < 0.5 else (200.0, 400.0)
        u_th = lo + (hi - lo) * float(_u(r, 0.2, 0.8))
        m = _u(r, 18.0, 45.0, 3)                                   # scale step x 400 over F
        return {"u_th_dps": u_th, "ds": _signs(r, 3) * m * F / 400.0,
                "db_dps": _signs(r, 3) * _u(r, 0.05, 0.2, 3) * m * F, "between_levels_dps": [lo, hi],
                "scale_step_at_400_over_floor20": m}
    if name == "cross_axis_quadratic":
        m = _u(r, 15.0, 48.0, (3, 3))
        Q = _signs(r, 9).reshape(3, 3) * m * F[:, None] / 400.0 ** 2
        Q[np.diag_indices(3)] = 0.0
        m[np.diag_indices(3)] = 0.0
        return {"q_per_dps": Q, "at_400_over_floor20": m}
    if name == "warmup_selfheat":
        tau = float(_u(r, 900.0, 1500.0))
        return {"A_dps": _signs(r, 3) * _u(r, 0.15, 0.35, 3), "tau_s": tau,
                "self_heat_c": float(_u(r, 2.0, 5.0)), "tau_heat_s": tau * float(_u(r, 0.8, 1.25))}
    if name == "slow_pole":
        return {"k": _u(r, 1e-3, 4e-3, 3), "tau_s": float(_u(r, 2.0, 8.0))}
    if name == "rotation_heating":
        return {"H_dps": _signs(r, 3) * _u(r, 35.0, 80.0, 3) * F, "tau_s": float(_u(r, 30.0, 240.0)),
                "ref_speed_dps": 400.0, "exponent": 1.0, "temp_sensor_fraction": 0.0}
    if name == "temp_hysteresis_play":
        m = _u(r, 30.0, 60.0, 3)                                   # 2h over F
        return {"h_dps": _signs(r, 3) * m * F / 2.0, "width_c": float(_u(r, 2.0, 5.0)),
                "storage_c": ROOM_T, "two_h_over_floor20": m}
    if name == "mount_bias_shift":
        return {"sigma_dps": float(_u(r, 12.0, 35.0)) * _u(r, 0.8, 1.2, 3) * F}
    # fourth set
    if name == "slow_pole_strong":
        # k sized so that after the smallest step of the default order (0 -> +10 deg/s) the settling
        # moves the 20 s hold mean by m = 20-40 floors; a 100 deg/s step moves it about 10 times more
        tau = float(_u(r, 5.5, 6.5))
        m = _u(r, 20.0, 40.0, 3)
        return {"k": m * F / _pole_hold_shift(10.0, tau), "tau_s": tau,
                "hold_shift_at_10_step_over_floor20": m}
    if name == "rate_band_bias_wide":
        m = _u(r, 20.0, 50.0, 3)
        return {"h_dps": _signs(r, 3) * m * F, "centre_dps": float(_u(r, 145.0, 155.0)),
                "fwhm_dps": float(_u(r, 36.0, 44.0)), "shape": "gauss", "peak_over_floor20": m}
    if name == "g_sensitivity_temp":
        G0 = _u(r, -0.03, 0.03, (3, 3))
        G0[np.diag_indices(3)] = _signs(r, 3) * _u(r, 0.08, 0.2, 3)
        rel = _signs(r, 9).reshape(3, 3) * _u(r, 2e-3, 6e-3, (3, 3))     # relative change per degC
        return {"G0_dps_per_g": G0, "G1_dps_per_g_per_c": G0 * rel, "T0_c": T_REF}
    if name == "session_bias_step":
        return {"step_dps": _signs(r, 3) * _u(r, 0.05, 0.2, 3), "sessions": [1]}
    raise ValueError(f"unknown effect {name!r}; known: {sorted(EFFECTS)}")


def _pole_hold_shift(step_dps, tau, accel_dps2=200.0, hold_s=20.0):
    """|Hold-mean shift| per unit k of e = k (lag(u, tau) - u) after a step of step_dps into the
    hold, ramped at accel_dps2 from a settled lag: a tau (1 - exp(-step/(a tau))) at the ramp's
    end, decaying as exp(-t/tau) over the hold."""
    at = accel_dps2 * tau
    return at * (1.0 - math.exp(-step_dps / at)) * tau / hold_s * (1.0 - math.exp(-hold_s / tau))


def _floor20(seed):
    """Per-axis std of a 20 s mean of the unit's drawn white noise, ARW/sqrt(20 s) (deg/s)."""
    return np.asarray(_draw_noise(seed, "white")["arw_dps_rthz"], float) / math.sqrt(20.0)


def make_unit(effect: str = "none", protocol: str = "turntable3", noise: str = "white",
              seed: int = 0, **overrides) -> UnitSpec:
    """Draw one unit's parameters, deterministically from ``seed``.

    ``overrides`` replace drawn parameters: a base key (e.g. ``b1=[...]``,
    ``tau_sensor_s=100``), a noise key (``arw_dps_rthz=...``) or an effect parameter as
    ``<effect>__<key>`` (e.g. ``warmup__tau_s=1200``)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; known: {PROTOCOLS}")
    if noise not in NOISES:
        raise ValueError(f"unknown noise {noise!r}; known: {NOISES}")
    names = [e for e in effect.split("+") if e]
    for e in names:
        if e not in EFFECTS:
            raise ValueError(f"unknown effect {e!r}; known: {sorted(EFFECTS)}")
    if "die_lag" in names and "die_lag_curved" in names:
        raise ValueError("die_lag and die_lag_curved are two models of the same die: choose one")
    params = {"base": _draw_base(seed), "noise": _draw_noise(seed, noise), "effects": {}}
    for e in names:
        if e != "none":
            params["effects"][e] = _draw_effect(seed, e)
    for k, v in overrides.items():
        if "__" in k:
            e, kk = k.split("__", 1)
            params["effects"].setdefault(e, {})[kk] = np.asarray(v) if isinstance(v, (list, tuple)) else v
        elif k == "imu_radius_m":
            # distance of the IMU from the rig axis, same direction as drawn; 0 puts it on the axis
            d = np.asarray(params["base"]["imu_offset_m"], float)
            params["base"]["imu_offset_m"] = d / np.linalg.norm(d) * float(v)
            params["base"]["imu_radius_m"] = float(v)
        elif k in params["base"]:
            params["base"][k] = np.asarray(v) if isinstance(v, (list, tuple)) else v
        elif k in params["noise"] or k in ("gm_sigma_dps", "gm_tau_s", "rrw_dps_rts"):
            params["noise"][k] = np.asarray(v) if isinstance(v, (list, tuple)) else v
        else:
            raise ValueError(f"unknown unit override {k!r}")
    return UnitSpec(effect="+".join(names) if names else "none", protocol=protocol,
                    noise=noise, seed=int(seed), params=params)


def _b1(unit):
    eff = unit.params["effects"]
    if "die_lag" in eff:
        return np.asarray(eff["die_lag"]["b1_die_dps_per_c"], float)
    if "die_lag_curved" in unit.effects:
        return np.asarray(eff["die_lag_curved"]["b1_die_dps_per_c"], float)
    return np.asarray(unit.params["base"]["b1"], float)


def _die_curves(unit):
    """die_lag_curved: scale and bias polynomials in dT = Td - 25, lowest power first."""
    b = unit.params["base"]
    ep = unit.params["effects"]["die_lag_curved"]
    def f(x):
        return np.asarray(x, float)
    scale = [f(b["s0"]), f(ep["s1_die_per_c"]), f(b["s2"]) + f(ep["s2_die_per_c2"])]
    bias = [f(b["b0"]), f(ep["b1_die_dps_per_c"]), f(b["b2"]) + f(ep["c2_dps_per_c2"]),
            f(ep["c3_dps_per_c3"])]
    return scale, bias


def _poly(coeffs, dT):
    """sum_k c_k dT^k with c_k (3,) and dT (n,1) or scalar."""
    out = 0.0
    for k, c in enumerate(coeffs):
        out = out + c * dT ** k
    return out


def K_of_T(unit, T):
    """True K at (die/sensor) temperature T (scalar) -> (3,3)."""
    b = unit.params["base"]
    dT = T - T_REF
    if "die_lag_curved" in unit.effects:
        return np.eye(3) + np.diag(_poly(_die_curves(unit)[0], dT)) + np.asarray(b["M"])
    s = b["s0"] + b["s1"] * dT + b["s2"] * dT * dT
    return np.eye(3) + np.diag(s) + np.asarray(b["M"])


def B_of_T(unit, T):
    b = unit.params["base"]
    dT = T - T_REF
    if "die_lag_curved" in unit.effects:
        return _poly(_die_curves(unit)[1], dT)
    return np.asarray(b["b0"]) + _b1(unit) * dT + np.asarray(b["b2"]) * dT * dT


# --------------------------------------------------------------------------------------
# protocol timelines
# --------------------------------------------------------------------------------------
class _Timeline:
    def __init__(self, T0):
        self.phases: list[dict] = []
        self.t = 0.0
        self.knots_t = [0.0]
        self.knots_T = [float(T0)]
        self.mounts: list[dict] = []

    def mount(self, label, R):
        self.mounts.append({"label": label, "R": R})
        return len(self.mounts) - 1

    def add(self, kind, dur, mount, r0=0.0, r1=None, **extra):
        if dur <= 0:
            return
        r1 = r0 if r1 is None else r1
        self.phases.append(dict(kind=kind, t0=self.t, t1=self.t + dur, mount=mount,
                                r0=float(r0), r1=float(r1), **extra))
        self.t += dur

    def chamber_ramp(self, T_to, rate_c_per_s):
        T_from = self.knots_T[-1]
        dur = abs(T_to - T_from) / rate_c_per_s
        if self.knots_t[-1] < self.t:
            self.knots_t.append(self.t)
            self.knots_T.append(T_from)
        self.knots_t.append(self.t + dur)
        self.knots_T.append(float(T_to))
        return dur

    def rate_change(self, r_from, r_to, accel, mount, **extra):
        if r_from != r_to:
            self.add("rate_ramp", abs(r_to - r_from) / accel, mount, r_from, r_to, **extra)

    def handling(self, m_from, m_to, rng, still_s=3.0):
        self.add("rest", still_s, m_from)
        dur = float(rng.uniform(8.0, 12.0))
        nb = 3
        bump = {
            "amp_rad": rng.uniform(1.0, 4.0, (3, nb)) * D2R * _signs(rng, 3 * nb).reshape(3, nb),
            "freq_hz": rng.uniform(0.3, 1.5, (3, nb)),
            "phase": rng.uniform(0, 2 * np.pi, (3, nb)),
            "acc_amp_g": rng.uniform(0.02, 0.1, (3, nb)),
            "acc_freq_hz": rng.uniform(0.5, 3.0, (3, nb)),
            "acc_phase": rng.uniform(0, 2 * np.pi, (3, nb)),
        }
        self.add("handling", dur, m_from, 0.0, 0.0, to_mount=m_to, bump=bump)
        self.add("rest", still_s, m_to)


def _protocol_defaults(protocol):
    common = {"sensor_offset": True}
    if protocol in ("turntable3", "turntable6"):
        return {**common,
                "temps": [-20.0, 5.0, 30.0, 55.0], "rates": [10.0, 50.0, 100.0, 200.0, 400.0],
                "hold_s": 20.0, "table_accel_dps2": 200.0, "chamber_rate_c_per_min": 8.0,
                "soak_s": 480.0, "initial_rest_s": 60.0,
                "mounts": ["+x", "+y", "+z"] if protocol == "turntable3"
                else ["+x", "-x", "+y", "-y", "+z", "-z"],
                "fixture_misalign_deg": 0.0}
    if protocol == "sweep":
        return {**common, "sweep_low_c": -20.0, "sweep_high_c": 60.0, "ramp_c_per_h": 30.0,
                "dwell_s": 1200.0, "sweep_rate_dps": 0.0, "mount": "+z"}
    if protocol == "servo":
        return {**common, "servo_speed_dps": 3.0 / D2R, "servo_revs": 3, "ripple": 0.005,
                "ripple_harmonic": 1, "servo_accel_dps2": 600.0, "pause_s": 3.0,
                "initial_rest_s": 5.0, "servo_temp_c": 25.0, "misalign_deg": [2.0, 6.0],
                "servo_six_mounts": False}
    raise ValueError(protocol)


def _ordered_temps(temps, order):
    """The order the chamber visits the set points. "default" keeps the list as given."""
    if isinstance(order, (list, tuple, np.ndarray)):
        pts = [float(x) for x in order]
        if not pts or any(x not in temps for x in pts):
            raise ValueError(f"an explicit temp_order must list set points of temps {temps}")
        return pts
    if not isinstance(order, str):
        raise ValueError(f"temp_order must be one of {TEMP_ORDERS} or a list of set points")
    if order == "default":
        return list(temps)
    up = sorted(temps)
    if order == "ascending":
        return up
    if order == "descending":
        return up[::-1]
    if order == "updown":             # up through every other point, back down through the rest
        return up[0::2] + up[1::2][::-1]
    if order == "downup":
        dn = up[::-1]
        return dn[0::2] + dn[1::2][::-1]
    if order == "revisit":            # up through every point, then the second-highest again,
        return up + up[-2:-1]         # from above (added later, for a protocol that revisits)
    if order == "zigzag":             # second-lowest first, then alternately the highest and the
        if len(up) < 3:               # lowest of those left: -20/5/30/55 -> 5, 55, -20, 30
            return up
        out, rest, hi = [up[1]], up[:1] + up[2:], True
        while rest:
            out.append(rest.pop(-1 if hi else 0))
            hi = not hi
        return out
    raise ValueError(f"unknown temp_order {order!r}; known: {TEMP_ORDERS}")


def _ordered_rates(seq, order, rng):
    """The order of one mount's holds. "default": 0, +r1, -r1, +r2, -r2, ...; a list is used as
    given (signed deg/s); "shuffled" draws a new permutation from rng for every call."""
    if not isinstance(order, str):
        return [float(x) for x in order]
    if order == "default":
        return seq
    if order == "reversed":
        return seq[::-1]
    if order == "shuffled":
        return [seq[i] for i in rng.permutation(len(seq))]
    if order == "ascending":
        return sorted(seq)
    if order == "descending":
        return sorted(seq, reverse=True)
    raise ValueError(f"unknown rate_order {order!r}; known: {RATE_ORDERS} or a list of rates")


def _build_timeline(protocol, pp, rng, order_rng=None):
    if protocol in ("turntable3", "turntable6"):
        temps = _ordered_temps([float(x) for x in pp["temps"]], pp.get("temp_order", "default"))
        tl = _Timeline(temps[0])
        mis = float(pp["fixture_misalign_deg"])
        mids = {}
        for lab in pp["mounts"]:
            R = _mount_R(lab)
            if mis > 0:
                v = rng.normal(size=3)
                R = R @ _rotvec_to_R(v / np.linalg.norm(v) * mis * D2R * rng.uniform(0.5, 1.0))
            mids[lab] = tl.mount(lab, R)
        labels = list(pp["mounts"])
        acc = float(pp["table_accel_dps2"])
        hold = float(pp["hold_s"])
        seq = [0.0]
        for r in pp["rates"]:
            seq += [float(r), -float(r)]
        cur_m = mids[labels[0]]
        tl.add("rest", float(pp["initial_rest_s"]), cur_m, setpoint=temps[0])
        for it, T in enumerate(temps):
            if it > 0:
                nm = mids[labels[0]]
                if nm != cur_m:
                    tl.handling(cur_m, nm, rng)
                    cur_m = nm
                dur = tl.chamber_ramp(T, float(pp["chamber_rate_c_per_min"]) / 60.0)
                tl.add("chamber_ramp", dur, cur_m, setpoint=T)
                tl.add("soak", float(pp["soak_s"]), cur_m, setpoint=T)
            for im, lab in enumerate(labels):
                m = mids[lab]
                if m != cur_m:
                    tl.handling(cur_m, m, rng)
                    cur_m = m
                r_prev = 0.0
                for r in _ordered_rates(seq, pp.get("rate_order", "default"), order_rng):
                    tl.rate_change(r_prev, r, acc, m, setpoint=T)
                    tl.add("hold", hold, m, r, setpoint=T)
                    r_prev = r
                tl.rate_change(r_prev, 0.0, acc, m, setpoint=T)
        tl.add("rest", 5.0, cur_m, setpoint=temps[-1])
        return tl
    if protocol == "sweep":
        lo, hi = float(pp["sweep_low_c"]), float(pp["sweep_high_c"])
        rate = float(pp["ramp_c_per_h"]) / 3600.0
        tl = _Timeline(lo)
        m = tl.mount(pp["mount"], _mount_R(pp["mount"]))
        w = float(pp["sweep_rate_dps"])
        dw = float(pp["dwell_s"])
        tl.add("dwell", dw, m, w, setpoint=lo)
        tl.add("temp_ramp_up", tl.chamber_ramp(hi, rate), m, w)
        tl.add("dwell", dw, m, w, setpoint=hi)
        tl.add("temp_ramp_down", tl.chamber_ramp(lo, rate), m, w)
        tl.add("dwell", dw, m, w, setpoint=lo)
        return tl
    if protocol == "servo":
        tl = _Timeline(float(pp["servo_temp_c"]))
        w = float(pp["servo_speed_dps"])
        revs = int(pp["servo_revs"])
        acc = float(pp["servo_accel_dps2"])
        lo_m, hi_m = pp["misalign_deg"]
        if pp["servo_six_mounts"]:
            plan = [("+x", [1]), ("-x", [1]), ("+y", [1]), ("-y", [1]), ("+z", [1]), ("-z", [1])]
        else:
            plan = [("+x", [1, -1]), ("+y", [1, -1]), ("+z", [1, -1])]
        mids = []
        for lab, _ in plan:
            v = rng.normal(size=3)
            ang = rng.uniform(lo_m, hi_m)
            err = v / np.linalg.norm(v) * ang * D2R
            mids.append(tl.mount(lab, _mount_R(lab) @ _rotvec_to_R(err)))
            tl.mounts[-1]["misalign_rotvec_rad"] = err
        cur = mids[0]
        tl.add("rest", float(pp["initial_rest_s"]), cur)
        T_rev = 360.0 / w
        for (lab, dirs), m in zip(plan, mids):
            if m != cur:
                tl.handling(cur, m, rng)
                cur = m
            for sgn in dirs:
                r = sgn * w
                tl.rate_change(0.0, r, acc, m)
                tl.add("rotation", revs * T_rev, m, r, revs=revs,
                       ripple_phase=float(rng.uniform(0, 2 * np.pi)))
                tl.rate_change(r, 0.0, acc, m)
                tl.add("rest", float(pp["pause_s"]), m)
        return tl
    raise ValueError(protocol)


# --------------------------------------------------------------------------------------
# noise
# --------------------------------------------------------------------------------------
def _ar1(n, phi, sig_innov, x0, z):
    """x[k] = phi x[k-1] + sig_innov z[k], x[-1] = x0; vectorised in blocks."""
    out = np.empty(n)
    lphi = -math.log(phi) if phi < 1 else 0.0
    L = n if lphi == 0 else max(1, int(30.0 / lphi))
    x = x0
    for s in range(0, n, L):
        e = min(n, s + L)
        k = np.arange(1, e - s + 1, dtype=float)
        pw = np.exp(-lphi * k)                      # phi^k
        S = np.cumsum(sig_innov * z[s:e] / pw)      # sum phi^-j q_j
        out[s:e] = pw * (x + S)
        x = out[e - 1]
    return out


def _noise(unit, n, fs, rng):
    npar = unit.params["noise"]
    arw = np.asarray(npar["arw_dps_rthz"], float)
    w = rng.standard_normal((n, 3)) * (arw * math.sqrt(fs))
    if unit.noise == "coloured":
        dt = 1.0 / fs
        for a in range(3):
            sig = float(npar["gm_sigma_dps"][a])
            tau = float(npar["gm_tau_s"][a])
            phi = math.exp(-dt / tau)
            z = rng.standard_normal(n)
            x0 = rng.standard_normal() * sig
            w[:, a] += _ar1(n, phi, sig * math.sqrt(1 - phi * phi), x0, z)
            q = float(npar["rrw_dps_rts"][a])
            if q > 0:
                w[:, a] += np.cumsum(rng.standard_normal(n)) * q * math.sqrt(dt)
    return w


def _noise_floor(unit, hold_s):
    npar = unit.params["noise"]
    arw = np.asarray(npar["arw_dps_rthz"], float)
    var = arw ** 2 / hold_s
    white = np.sqrt(var)
    if unit.noise == "coloured":
        sig = np.asarray(npar["gm_sigma_dps"], float)
        tau = np.asarray(npar["gm_tau_s"], float)
        x = hold_s / tau
        var = var + sig ** 2 * 2.0 / x ** 2 * (x - 1 + np.exp(-x))
    tot = np.sqrt(var)
    return {"hold_s": hold_s, "white_hold_mean_std_dps": white, "hold_mean_std_dps": tot,
            "rms_dps": float(np.sqrt(np.mean(var))),
            "note": "std of a hold mean (white + Gauss-Markov over one hold); the GM part "
                    "is correlated between neighbouring holds"}


# --------------------------------------------------------------------------------------
# session
# --------------------------------------------------------------------------------------
def simulate_session(unit: UnitSpec, session: int = 0, seed: int = 0, rate_hz: float = 25.0,
                     **overrides) -> tuple[dict, dict]:
    """Simulate one session; returns (columns, info).  See write_session."""
    pp = _protocol_defaults(unit.protocol)
    # visit-order overrides of the turntables; recorded in protocol_params only when given
    extra = (("rate_order", "temp_order", "settle_c", "settle_tau_s")
             if unit.protocol.startswith("turntable") else ())
    for k, v in overrides.items():
        if k not in pp and k not in extra:
            raise ValueError(f"unknown override {k!r} for protocol {unit.protocol}; "
                             f"known: {sorted(pp) + list(extra)}")
        pp[k] = v
    fs = float(rate_hz)
    rs = _rng(unit.seed, "session", session, seed)
    r_tl = _rng(unit.seed, "timeline", session, seed)
    r_ord = _rng(unit.seed, "rate_order", session, seed)          # only "shuffled" draws from it
    tl = _build_timeline(unit.protocol, pp, r_tl, r_ord)
    base = unit.params["base"]
    eff = unit.params["effects"]

    t_offset = float(rs.uniform(1.0, 8.0))
    N = int(math.floor(tl.t * fs))
    tr = np.arange(N) / fs                                  # relative to power-on
    # ---------------- kinematics per phase ----------------
    ref = np.zeros(N)
    rig_rate = np.zeros(N)                                  # true rig rate (deg/s)
    omega = np.zeros((N, 3))                                # true body rate (deg/s)
    fspec = np.zeros((N, 3))                                # specific force (g)
    axis_b = np.zeros((N, 3))                               # rig axis in body frame
    mount_idx = np.zeros(N, dtype=np.int64)
    p_b = np.asarray(base["imu_offset_m"], float) if pp["sensor_offset"] else np.zeros(3)
    t0s = np.array([ph["t0"] for ph in tl.phases])
    starts = np.searchsorted(tr, t0s, side="left")
    ends = np.append(starts[1:], N)
    ez = np.array([0.0, 0.0, 1.0])
    ripple = float(pp.get("ripple", 0.0))
    rip_h = int(pp.get("ripple_harmonic", 1))
    for ph, i0, i1 in zip(tl.phases, starts, ends):
        if i1 <= i0:
            continue
        tt = tr[i0:i1] - ph["t0"]
        D = ph["t1"] - ph["t0"]
        R = tl.mounts[ph["mount"]]["R"]
        mount_idx[i0:i1] = ph["mount"]
        if ph["kind"] != "handling":
            a = R.T @ ez
            axis_b[i0:i1] = a
            r = ph["r0"] + (ph["r1"] - ph["r0"]) * tt / D
            al = np.full_like(tt, (ph["r1"] - ph["r0"]) / D)
            ref[i0:i1] = r
            if ph["kind"] == "rotation" and ripple > 0:
                T_rev = 360.0 / abs(ph["r0"])
                arg = 2 * np.pi * rip_h * tt / T_rev + ph["ripple_phase"]
                al = r * ripple * 2 * np.pi * rip_h / T_rev * np.cos(arg)
                r = r * (1.0 + ripple * np.sin(arg))
            rig_rate[i0:i1] = r
            omega[i0:i1] = r[:, None] * a[None, :]
            p_perp = p_b - a * (a @ p_b)
            axp = np.cross(a, p_b)
            fspec[i0:i1] = (a[None, :]
                            + (-(r * D2R) ** 2)[:, None] * p_perp[None, :] / G0
                            + (al * D2R)[:, None] * axp[None, :] / G0)
        else:
            R_new = tl.mounts[ph["to_mount"]]["R"]
            Q = R.T @ R_new
            rv = _R_to_rotvec(Q)
            th = np.linalg.norm(rv)
            n = rv / th if th > 0 else np.zeros(3)
            u = tt / D
            s = u - np.sin(2 * np.pi * u) / (2 * np.pi)
            sd = (1 - np.cos(2 * np.pi * u)) / D
            bp = ph["bump"]
            win = np.sin(np.pi * u) ** 2
            wind = np.pi / D * np.sin(2 * np.pi * u)
            arg = 2 * np.pi * bp["freq_hz"][None, :, :] * tt[:, None, None] + bp["phase"][None]
            sw = np.sum(bp["amp_rad"][None] * np.sin(arg), axis=2)             # (n,3)
            cw = np.sum(bp["amp_rad"][None] * 2 * np.pi * bp["freq_hz"][None] * np.cos(arg), axis=2)
            e = win[:, None] * sw
            ed = wind[:, None] * sw + win[:, None] * cw
            main_rv = (th * s)[:, None] * n[None, :]
            g_old = R.T @ ez
            f_g = _rotate(-e, _rotate(-main_rv, np.broadcast_to(g_old, (len(tt), 3))))
            w_main = (th * sd)[:, None] * n[None, :]
            om = _rotate(-e, w_main) + _right_jacobian_apply(e, ed)           # rad/s
            omega[i0:i1] = om / D2R
            arg2 = 2 * np.pi * bp["acc_freq_hz"][None] * tt[:, None, None] + bp["acc_phase"][None]
            fh = win[:, None] * np.sum(bp["acc_amp_g"][None] * np.sin(arg2), axis=2)
            fspec[i0:i1] = f_g + fh
            axis_b[i0:i1] = f_g                                               # approx. up
    # ---------------- thermal ----------------
    curved = "die_lag_curved" in unit.effects
    tau_d = float(eff["die_lag"]["tau_die_s"]) if "die_lag" in eff else (
        float(eff["die_lag_curved"]["tau_die_s"]) if curved else None)
    Tc, Ts, dTs, Td = _thermal(tl.knots_t, tl.knots_T, float(base["tau_sensor_s"]), tau_d, tr)
    settle = None
    if float(pp.get("settle_c", 0.0)) != 0.0:
        # the package still settling at each new set point: a share f of its heat path runs
        # through the fixture, a slower mass that follows the chamber with tau_p; the rest is the
        # usual sensor lag. Both paths start equilibrated, and a lagging die follows the mix
        sc, tau_p = float(pp["settle_c"]), float(pp.get("settle_tau_s", 300.0))
        f, left = _settle_fraction(sc, tau_p)
        _, Tp, dTp, Tdp = _thermal(tl.knots_t, tl.knots_T, tau_p, tau_d, tr)
        Ts = (1.0 - f) * Ts + f * Tp
        dTs = (1.0 - f) * dTs + f * dTp
        if Td is not None:
            Td = (1.0 - f) * Td + f * Tdp
        settle = {"model": "Ts = (1 - f) lag(Tc, tau_sensor_s) + f lag(Tc, settle_tau_s): a share f of the "
                           "package's heat path runs through the fixture, which follows the chamber slowly",
                  "settle_c": sc, "settle_tau_s": tau_p, "fixture_share_f": f,
                  "fixture_lag_left_after_default_25C_step_c": left,
                  "reference": "f = settle_c / (what a lag of settle_tau_s still lacks at the first hold after "
                               "a 25 degC step at 8 degC/min and a 480 s soak); larger steps, faster ramps "
                               "or shorter soaks leave more. Realised offsets: info['setpoint_visits']"}
    T_pkg = Ts                                              # chamber and fixture only
    self_heat = None
    if "warmup_selfheat" in unit.effects:
        # the powered board heats the sensor: Ts = (chamber lag) + dT_self (1 - exp(-t/tau_heat)),
        # and a lagging die (die_lag, die_lag_curved) follows that rise through its own lag
        ep = eff["warmup_selfheat"]
        dTh, th = float(ep["self_heat_c"]), float(ep["tau_heat_s"])
        ex = np.exp(-tr / th)
        rise = dTh * (1.0 - ex)
        Ts = Ts + rise
        dTs = dTs + dTh / th * ex
        if Td is not None:
            td = tau_d if abs(tau_d - th) > 1e-6 * th else tau_d * (1 + 1e-6)
            Td = Td + dTh * (1.0 - (th * ex - td * np.exp(-tr / td)) / (th - td))
        self_heat = {"model": "Ts = chamber lag (tau_sensor_s) + self_heat_c (1 - exp(-t/tau_heat_s)), "
                              "t = time since power-on",
                     "self_heat_c": dTh, "tau_heat_s": th, "rise_at_end_c": float(rise[-1]),
                     "max_rate_c_per_min": dTh / th * 60.0}
    Tk = Td if Td is not None else Ts
    dT = (Tk - T_REF)[:, None]
    # the temperature (and its rate) that the unit's other temperature effects feel: the die
    # for die_lag_curved (tau_d dTd/dt = Ts - Td), the true sensor otherwise
    T_eff = Td if curved else Ts
    dT_eff = (Ts - Td) / tau_d if curved else dTs
    # ---------------- base sensor ----------------
    M = np.asarray(base["M"], float)
    if curved:
        s_curve, b_curve = _die_curves(unit)
        s_T = _poly([c[None] for c in s_curve], dT)
        bias = _poly([c[None] for c in b_curve], dT)
    else:
        s_T = base["s0"][None] + base["s1"][None] * dT + base["s2"][None] * dT ** 2
        bias = base["b0"][None] + _b1(unit)[None] * dT + base["b2"][None] * dT ** 2
    u_lin = omega + s_T * omega + omega @ M.T                   # K(T) w_true
    gyro = u_lin + bias
    # ---------------- effects ----------------
    contrib = {}
    truth_eff = {}
    play_state = None
    for name in unit.effects:
        ep = eff[name]
        e = np.zeros((N, 3))
        if name == "g_sensitivity":
            e = fspec @ np.asarray(ep["G_dps_per_g"]).T
        elif name == "g_squared":
            e = (fspec ** 2) @ np.asarray(ep["G2_dps_per_g2"]).T
        elif name == "die_lag":
            pass                                        # acts through Tk above
        elif name == "die_lag_curved":
            # acts through Tk and the curves above; reported as what the lag does: the same
            # curves felt at Td minus felt at the sensor temperature Ts
            dTs_ = (Ts - T_REF)[:, None]
            s_s = _poly([c[None] for c in s_curve], dTs_)
            e = (u_lin + bias) - (omega + s_s * omega + omega @ M.T
                                  + _poly([c[None] for c in b_curve], dTs_))
            contrib[name] = e
            truth_eff[name] = {"bias_poly_dps": b_curve, "scale_poly": s_curve,
                               "poly_variable": "Td - 25 degC, lowest power first"}
            continue                                    # already in gyro
        elif name == "warmup":
            e = np.asarray(ep["A_dps"])[None] * np.exp(-tr / float(ep["tau_s"]))[:, None]
        elif name == "bias_ramp":
            e = np.asarray(ep["d_dps_per_h"])[None] * (tr / 3600.0)[:, None]
        elif name == "run_to_run_bias":
            off = _rng(unit.seed, "run_to_run", session).standard_normal(3) * np.asarray(ep["sigma_dps"])
            e = np.broadcast_to(off, (N, 3)).copy()
            truth_eff[name] = {"session_offset_dps": off}
        elif name == "scale_quadratic":
            e = np.asarray(ep["k_per_dps"])[None] * u_lin ** 2
        elif name == "scale_asymmetry":
            e = np.asarray(ep["k"])[None] * np.abs(u_lin)
        elif name == "scale_cubic":
            e = np.asarray(ep["k_per_dps2"])[None] * u_lin ** 3
        elif name == "rate_dependent_bias_sat":
            W = np.asarray(ep["W_dps"])[None]
            nn = float(ep["order"])
            e = u_lin / (1.0 + (np.abs(u_lin) / W) ** nn) ** (1.0 / nn) - u_lin
        elif name == "cross_coupling":
            C = np.asarray(ep["C_per_dps"])
            prods = np.stack([u_lin[:, 0] * u_lin[:, 1], u_lin[:, 0] * u_lin[:, 2],
                              u_lin[:, 1] * u_lin[:, 2]], axis=1)
            e = prods @ C.T
        elif name == "temp_rate":
            e = np.asarray(ep["q_dps_per_c_per_min"])[None] * (dT_eff * 60.0)[:, None]
        elif name == "bias_quadratic_temp":
            e = np.asarray(ep["c_dps_per_c2"])[None] * ((T_eff - float(ep["T0_c"])) ** 2)[:, None]
        elif name == "hysteresis":
            state = _duhem(T_eff, float(ep["dT_switch_c"]), -1.0 if T_eff[0] < ROOM_T else 1.0)
            e = np.asarray(ep["h_dps"])[None] * state[:, None]
            truth_eff[name] = {"initial_state": -1.0 if T_eff[0] < ROOM_T else 1.0}
        elif name == "vibration_rectification":
            P = (rig_rate / float(ep["ref_speed_dps"])) ** 2
            e = ((axis_b ** 2) @ np.asarray(ep["V_dps"]).T) * P[:, None]
        elif name == "scale_warmup":
            e = u_lin * np.asarray(ep["s"])[None] * np.exp(-tr / float(ep["tau_s"]))[:, None]
        elif name == "scale_temp_rate":
            e = u_lin * np.asarray(ep["q_per_c_per_min"])[None] * (dT_eff * 60.0)[:, None]
        elif name == "misalign_warp_tanh":
            x = np.tanh((T_eff - float(ep["T_g_c"])) / float(ep["W_c"]))
            e = (omega @ np.asarray(ep["Mw_rad"]).T) * x[:, None]
        elif name == "bias_bump_temp":
            x = np.exp(-0.5 * ((T_eff - float(ep["T_b_c"])) / float(ep["sigma_c"])) ** 2)
            e = np.asarray(ep["h_dps"])[None] * x[:, None]
        elif name == "bias_tanh_temp":
            x = np.tanh((T_eff - float(ep["T_t_c"])) / float(ep["w_c"]))
            e = np.asarray(ep["a_dps"])[None] * x[:, None]
        elif name == "scale_low_rate_tanh":
            e = np.asarray(ep["a_dps"])[None] * np.tanh(u_lin / np.asarray(ep["W_dps"])[None])
        elif name == "warmup_two_exp":
            e = (np.asarray(ep["A1_dps"])[None] * np.exp(-tr / float(ep["tau1_s"]))[:, None]
                 + np.asarray(ep["A2_dps"])[None] * np.exp(-tr / float(ep["tau2_s"]))[:, None])
        elif name == "warmup_power_law":
            x = (1.0 + tr / float(ep["t0_s"])) ** (-float(ep["p"]))
            e = np.asarray(ep["A_dps"])[None] * x[:, None]
        elif name == "bias_step_temp":
            # the firmware reads its sensor (Ts, even when the die lags), so the switch follows Ts
            Tsw, hw = float(ep["T_switch_c"]), float(ep["hysteresis_c"])
            state, s0 = _schmitt(Ts, Tsw, hw)
            e = np.asarray(ep["step_dps"])[None] * state[:, None]
            truth_eff[name] = {"initial_state": s0, "switch_up_at_c": Tsw + hw / 2,
                               "switch_down_at_c": Tsw - hw / 2}
        elif name == "bias_step_time":
            e = np.asarray(ep["step_dps"])[None] * (tr >= float(ep["t_step_s"]))[:, None]
        elif name == "motor_heating_bias":
            P = (np.abs(rig_rate) / float(ep["ref_speed_dps"])) ** float(ep["exponent"])
            h = _lag(P, float(ep["tau_s"]), 1.0 / fs)
            e = np.asarray(ep["H_dps"])[None] * h[:, None]
        elif name == "table_angle_bias":
            th0 = float(_rng(unit.seed, "table_angle", session, seed).uniform(0.0, 360.0))
            th = th0 + np.concatenate([[0.0], np.cumsum(0.5 * (rig_rate[1:] + rig_rate[:-1]))]) / fs
            # a lab-fixed horizontal field seen in the turning table frame, then in the body
            f_rig = np.stack([np.cos(th * D2R), -np.sin(th * D2R), np.zeros(N)], axis=1)
            f_body = np.zeros((N, 3))
            for m, mt in enumerate(tl.mounts):
                sel = mount_idx == m
                f_body[sel] = f_rig[sel] @ mt["R"]                      # R^T v, row-wise
            e = np.asarray(ep["S_dps"])[None] * f_body
            truth_eff[name] = {"table_angle_at_power_on_deg": th0,
                               "field_in_rig_frame": "(cos th, -sin th, 0), th = table angle"}
        elif name == "rate_band_bias":
            x = (np.abs(omega) - float(ep["r0_dps"])) / float(ep["gamma_dps"])
            e = np.asarray(ep["h_dps"])[None] / (1.0 + x ** 2)
        elif name == "scale_range_switch":
            on = np.abs(u_lin) > float(ep["u_th_dps"])
            e = on * (np.asarray(ep["ds"])[None] * u_lin + np.asarray(ep["db_dps"])[None])
        elif name == "cross_axis_quadratic":
            e = (omega ** 2) @ np.asarray(ep["q_per_dps"]).T
        elif name == "warmup_selfheat":
            e = np.asarray(ep["A_dps"])[None] * np.exp(-tr / float(ep["tau_s"]))[:, None]
            truth_eff[name] = {"bias_model": "A exp(-t/tau) + the base B(Ts), Ts including the "
                                             "self-heating; no dT/dt term",
                               "self_heating_rise_at_end_c": self_heat["rise_at_end_c"]}
        elif name in ("slow_pole", "slow_pole_strong"):
            tau_p = float(ep["tau_s"])
            lagged = np.stack([_lag(np.ascontiguousarray(u_lin[:, a]), tau_p, 1.0 / fs)
                               for a in range(3)], axis=1)
            e = np.asarray(ep["k"])[None] * (lagged - u_lin)
            if name == "slow_pole_strong":
                acc_n, hold_n = float(pp.get("table_accel_dps2", 200.0)), float(pp.get("hold_s", 20.0))
                truth_eff[name] = {
                    "hold_mean_shift_after_step_dps": {
                        f"{d:g}": np.asarray(ep["k"], float) * _pole_hold_shift(d, tau_p, acc_n, hold_n)
                        for d in (10.0, 20.0, 100.0, 800.0)},
                    "shift_rule": "|k| a tau (1 - exp(-step/(a tau))) (tau/hold)(1 - exp(-hold/tau)), from a "
                                  "settled lag, a = table_accel_dps2; the sign is -sign(step)"}
        elif name == "rotation_heating":
            P = (np.linalg.norm(omega, axis=1) / float(ep["ref_speed_dps"])) ** float(ep["exponent"])
            h = _lag(P, float(ep["tau_s"]), 1.0 / fs)
            e = np.asarray(ep["H_dps"])[None] * h[:, None]
            truth_eff[name] = {"heat_state": "tau dh/dt = (|w|/400)^exponent - h, h(0) = 0 at power-on",
                               "logged_temperature_sees": "none of it"}
        elif name == "temp_hysteresis_play":
            s_play, s0, P0 = _play_direction(T_eff, float(ep["width_c"]), float(ep["storage_c"]))
            play_state = s_play
            e = np.asarray(ep["h_dps"])[None] * s_play[:, None]
            truth_eff[name] = {"initial_state": s0, "initial_play_position_c": P0,
                               "n_switches": int(np.sum(s_play[1:] != s_play[:-1]))}
        elif name == "mount_bias_shift":
            hand = [(i0, i1) for ph, i0, i1 in zip(tl.phases, starts, ends)
                    if ph["kind"] == "handling" and i1 > i0]
            shifts = (_rng(unit.seed, "mount_shift", session, seed).standard_normal((len(hand) + 1, 3))
                      * np.asarray(ep["sigma_dps"])[None])
            bounds = [(0, hand[0][0] if hand else N)]
            bounds += [(hand[k][1], hand[k + 1][0] if k + 1 < len(hand) else N) for k in range(len(hand))]
            stretches = []
            for (a0, a1), sh in zip(bounds, shifts):
                e[a0:a1] = sh                                  # zero while in the hand
                if a1 > a0:
                    stretches.append({"t_start": float(tr[a0] + t_offset), "t_end": float(tr[a1 - 1] + t_offset),
                                      "mount": tl.mounts[mount_idx[a0]]["label"], "shift_dps": sh})
            truth_eff[name] = {"stretches": stretches,
                               "rule": "a new shift from the end of each handling phase; 0 during handling"}
        elif name == "rate_band_bias_wide":
            c0, fw, shp = float(ep["centre_dps"]), float(ep["fwhm_dps"]), str(ep["shape"])
            e = np.asarray(ep["h_dps"])[None] * _band(np.abs(omega), c0, fw, shp)
            truth_eff[name] = {"factor_at_levels": {f"{L:g}": _band(L, c0, fw, shp) for L in _levels(unit, pp)},
                               "rate_followed": "the true own-axis rate |w_a| (a physical resonance)"}
        elif name == "g_sensitivity_temp":
            Ga, Gb = np.asarray(ep["G0_dps_per_g"], float), np.asarray(ep["G1_dps_per_g_per_c"], float)
            T0 = float(ep["T0_c"])
            e = fspec @ Ga.T + (T_eff - T0)[:, None] * (fspec @ Gb.T)
            truth_eff[name] = {"G_vs_temperature": [{"T_c": T, "G_dps_per_g": Ga + Gb * (T - T0)}
                                                    for T in _truth_grid(unit.protocol, pp)],
                               "temperature": "die" if curved else "sensor (true, noise-free)"}
        elif name == "session_bias_step":
            present = int(session) in [int(x) for x in np.atleast_1d(ep["sessions"])]
            off = np.asarray(ep["step_dps"], float) * (1.0 if present else 0.0)
            e = np.broadcast_to(off, (N, 3)).copy()
            truth_eff[name] = {"present_in_this_session": present, "offset_this_session_dps": off}
        contrib[name] = e
        gyro = gyro + e
    # ---------------- noise ----------------
    r_noise = _rng(unit.seed, "noise_session", session, seed)
    gyro = gyro + _noise(unit, N, fs, r_noise)
    r_t = _rng(unit.seed, "temp_session", session, seed)
    temp = Ts + r_t.standard_normal(N) * float(base["temp_noise_c"])
    lsb = float(base["temp_lsb_c"])
    if lsb > 0:
        temp = np.round(temp / lsb) * lsb
    r_a = _rng(unit.seed, "accel_session", session, seed)
    vib_g = 0.01 * (rig_rate / 400.0) ** 2
    acc = ((1.0 + np.asarray(base["accel_scale"]))[None] * fspec + np.asarray(base["accel_bias_g"])[None]
           + r_a.standard_normal((N, 3)) * (float(base["accel_noise_g"]) + vib_g)[:, None])
    t = t_offset + tr
    labels = np.array([m["label"] for m in tl.mounts], dtype=object)
    cols = {
        "t": t, "gyro_x": gyro[:, 0], "gyro_y": gyro[:, 1], "gyro_z": gyro[:, 2],
        "temp": temp, "ref_rate": ref.copy(), "mount": labels[mount_idx],
        "accel_x": acc[:, 0].astype(np.float32), "accel_y": acc[:, 1].astype(np.float32),
        "accel_z": acc[:, 2].astype(np.float32),
    }
    # ---------------- truth ----------------
    hold_s = float(pp.get("hold_s", 20.0)) if unit.protocol.startswith("turntable") else (
        float(pp["servo_revs"]) * 360.0 / float(pp["servo_speed_dps"]) if unit.protocol == "servo"
        else 20.0)
    grid = _truth_grid(unit.protocol, pp)
    phases = [{"kind": ph["kind"], "t_start": ph["t0"] + t_offset, "t_end": ph["t1"] + t_offset,
               "mount": tl.mounts[ph["mount"]]["label"], "ref_rate_start": ph["r0"],
               "ref_rate_end": ph["r1"],
               **({"setpoint_c": ph["setpoint"]} if "setpoint" in ph else {}),
               **({"to_mount": tl.mounts[ph["to_mount"]]["label"]} if "to_mount" in ph else {}),
               **({"revs": ph["revs"], "ripple_phase": ph["ripple_phase"]} if "revs" in ph else {})}
              for ph in tl.phases]
    info = {
        "generator": "benchmarks.zoo.generator",
        "protocol": unit.protocol,
        "effect": unit.effect,
        "effects": unit.effects,
        "effect_descriptions": {e: EFFECTS[e] for e in (unit.effects or ["none"])},
        "unit_seed": unit.seed, "session": int(session), "session_seed": int(seed),
        "rate_hz": fs, "n_rows": int(N), "t_first": float(t[0]), "t_last": float(t[-1]),
        "power_on_t": float(t[0]), "duration_s": float(tr[-1]),
        "protocol_params": pp,
        "model": "w = K(T_k) w_true + B(T_k) + effects + noise; K = I + diag(s0+s1 dT+s2 dT^2) + M; "
                 "B = b0 + b1 dT + b2 dT^2; dT = T_k - 25; T_k = "
                 + ("die temperature (lagging the sensor)" if tau_d is not None else
                    "true (noise-free) sensor temperature"),
        "temperature_driving_K_B": "die" if tau_d is not None else "sensor",
        **({"model_die_curves": "die_lag_curved: K = I + diag(s0 + s1_die dT + (s2 + s2_die) dT^2) + M, "
                                "B = b0 + b1_die dT + (b2 + c2) dT^2 + c3 dT^3, dT = Td - 25; "
                                "tau_d dTd/dt = Ts - Td",
            "temperature_driving_effects": "die (every temperature effect but bias_step_temp, "
                                           "which switches on the sensor reading)"}
           if curved else {}),
        "base": {**base, "b1_effective": _b1(unit)},
        "K_B_vs_temperature": [{"T_c": T, "K": K_of_T(unit, T), "B_dps": B_of_T(unit, T)}
                               for T in grid],
        "effect_params": {**eff, **{k: {**eff.get(k, {}), **v} for k, v in truth_eff.items()}},
        "effect_rms_dps": {k: np.sqrt(np.mean(v ** 2, axis=0)) for k, v in contrib.items()},
        "effect_max_abs_dps": {k: np.max(np.abs(v), axis=0) for k, v in contrib.items()},
        "noise": unit.params["noise"],
        "noise_floor_hint": _noise_floor(unit, hold_s)["rms_dps"],
        "noise_floor_detail": _noise_floor(unit, hold_s),
        "thermal": {"tau_sensor_s": float(base["tau_sensor_s"]), "tau_die_s": tau_d,
                    "chamber_knots_t": [k + t_offset for k in tl.knots_t],
                    "chamber_knots_c": tl.knots_T,
                    "temp_noise_c": float(base["temp_noise_c"]), "temp_lsb_c": lsb,
                    **({"self_heating": self_heat} if self_heat is not None else {}),
                    **({"settling": settle} if settle is not None else {})},
        "mounts": [{"label": m["label"], "R_body_to_rig": m["R"],
                    **({"misalign_rotvec_rad": m["misalign_rotvec_rad"]}
                       if "misalign_rotvec_rad" in m else {})} for m in tl.mounts],
        "phases": phases,
    }
    # the fourth set's session options also record every set point visit (how it was approached,
    # how far the package still was from the set point); other sessions keep their truth as it was
    if unit.protocol.startswith("turntable") and (
            "settle_c" in pp or "settle_tau_s" in pp
            or not isinstance(pp.get("temp_order", "default"), str) or pp.get("temp_order") == "zigzag"):
        info["setpoint_visits"] = _visits(tl, starts, ends, tr, t_offset, T_pkg, play_state)
    return cols, _jsonable(info)


def _visits(tl, starts, ends, tr, t_offset, T_pkg, play_state):
    """One record per set point visit (the holds between two chamber ramps): approach side, and the
    package temperature (chamber and fixture, without self-heating) against the set point."""
    raw = []
    cur = None
    prev = ROOM_T                                        # the power-on story: stored at 22 degC
    for ph, i0, i1 in zip(tl.phases, starts, ends):
        if ph["kind"] == "chamber_ramp":
            cur = None
        if ph["kind"] != "hold" or i1 <= i0:
            continue
        if cur is None:
            T = float(ph["setpoint"])
            cur = {"setpoint_c": T, "approached_from": "below" if T > prev else "above",
                   "power_on_here": not raw, "i0": i0}
            raw.append(cur)
            prev = T
        cur["i1"] = i1 - 1
    out = []
    for v in raw:
        a, b = v.pop("i0"), v.pop("i1")
        T = v["setpoint_c"]
        v.update({"t_first_hold": float(tr[a] + t_offset), "t_last_hold_end": float(tr[b] + t_offset),
                  "package_minus_setpoint_at_first_hold_c": float(T_pkg[a] - T),
                  "package_minus_setpoint_at_last_hold_end_c": float(T_pkg[b] - T),
                  "package_moves_within_visit_c": float(T_pkg[b] - T_pkg[a])})
        if play_state is not None:
            v["temp_hysteresis_play_state"] = float(play_state[a])
            v["temp_hysteresis_play_state_at_end"] = float(play_state[b])
        out.append(v)
    return out


def _truth_grid(protocol, pp):
    """Temperatures where the truth gives K and B: the set points, a 5 degC grid, or 25 degC."""
    if protocol.startswith("turntable"):
        return [float(x) for x in pp["temps"]]
    if protocol == "sweep":
        return list(np.arange(float(pp["sweep_low_c"]), float(pp["sweep_high_c"]) + 1e-9, 5.0))
    return [float(pp["servo_temp_c"])]


def _levels(unit, pp):
    """The |rate| levels a session holds: 0 and the turntable rates, the sweep rate, the servo speed."""
    if unit.protocol.startswith("turntable"):
        return [0.0] + [abs(float(x)) for x in pp["rates"]]
    if unit.protocol == "sweep":
        return [abs(float(pp["sweep_rate_dps"]))]
    return [abs(float(pp["servo_speed_dps"]))]


def _band(x, centre, fwhm, shape):
    """Peak-1 bump of full width at half maximum fwhm: "gauss" or "lorentz"."""
    z = (np.asarray(x, float) - centre) / fwhm
    if shape == "gauss":
        return np.exp(-4.0 * math.log(2.0) * z * z)
    if shape == "lorentz":
        return 1.0 / (1.0 + 4.0 * z * z)
    raise ValueError(f"rate_band_bias_wide shape must be 'gauss' or 'lorentz', not {shape!r}")


def _settle_fraction(settle_c, tau_p):
    """Share f of the package's heat path through the fixture (tau_p) such that a lag of tau_p
    after a 25 degC step of the default protocol (8 degC/min, then a 480 s soak) still leaves
    settle_c at the first hold: f = settle_c / left. Returns (f, left)."""
    if not (settle_c > 0.0 and tau_p > 0.0):
        raise ValueError("settle_c and settle_tau_s must be positive")
    r, soak = 8.0 / 60.0, 480.0
    left = r * tau_p * (1.0 - math.exp(-25.0 / r / tau_p)) * math.exp(-soak / tau_p)
    if settle_c > left:
        raise ValueError(f"settle_c={settle_c} C needs more than the whole heat path through a fixture of "
                         f"tau {tau_p:.0f} s (at most {left:.2f} C left after the default soak): "
                         "use a longer settle_tau_s")
    return settle_c / left, left


def _lag(x, tau, dt):
    """First-order lag tau dy/dt = x - y of a sampled input, exact for x linear between
    samples (first-order hold); y starts at x[0]."""
    e = math.exp(-dt / tau)
    c = tau * (1.0 - e) / dt
    inn = (1.0 - c) * x
    inn[1:] += (c - e) * x[:-1]
    inn[0] += (c - e) * x[0]
    return _ar1(len(x), e, 1.0, float(x[0]), inn)


def _schmitt(T, T_switch, width):
    """Two-state switch with hysteresis: 1 once T >= T_switch + width/2, 0 once
    T <= T_switch - width/2, unchanged in between; starts from the side of T_switch T[0] is on."""
    s0 = 1.0 if T[0] >= T_switch else 0.0
    ev = np.where(T >= T_switch + width / 2, 1.0, np.where(T <= T_switch - width / 2, 0.0, np.nan))
    idx = np.where(np.isnan(ev), -1, np.arange(len(T)))
    last = np.maximum.accumulate(idx)
    state = np.where(last >= 0, ev[np.maximum(last, 0)], s0)
    return state, s0


def _play_direction(T, width, storage_c):
    """Direction (+1/-1) of the last motion of a play (backlash) operator of width `width` on T:
    P = clamp(P_prev, T - width/2, T + width/2); s flips only after T has travelled `width` in
    the new direction, and keeps its state while T is still.  Power-on state from storage:
    stored at storage_c after cooling down (s = -1, P = storage_c + width/2), then brought
    monotonically to T[0] before power-on."""
    r = width / 2.0
    P = storage_c + r
    s = -1.0
    T0 = float(T[0])
    if T0 - r > P:
        P, s = T0 - r, 1.0
    elif T0 + r < P:
        P, s = T0 + r, -1.0
    s0, P0 = s, P
    out = np.empty(len(T))
    # only samples that reach outside the current band matter: a plain loop over floats
    for i, x in enumerate(T.tolist()):
        if x - r > P:
            P, s = x - r, 1.0
        elif x + r < P:
            P, s = x + r, -1.0
        out[i] = s
    return out, s0, P0


def _duhem(T, dT_switch, s0):
    """Hysteresis state in [-1, 1]: relaxes toward sign(dT/dt) over dT_switch of travel."""
    d = np.diff(T, prepend=T[0])
    d = np.where(np.abs(d) < 1e-9, 0.0, d)
    sg = np.sign(d)
    # forward-fill zero signs with the previous non-zero sign (zero steps change nothing)
    nz = np.nonzero(sg)[0]
    out = np.full(len(T), float(s0))
    if len(nz) == 0:
        return out
    U = np.cumsum(np.abs(d))
    change = nz[np.r_[True, sg[nz][1:] != sg[nz][:-1]]]
    bounds = np.append(change, len(T))
    state = float(s0)
    out[:bounds[0]] = state
    for k in range(len(change)):
        i0, i1 = bounds[k], bounds[k + 1]
        tgt = sg[i0]
        Ustart = U[i0 - 1] if i0 > 0 else 0.0
        seg = tgt + (state - tgt) * np.exp(-(U[i0:i1] - Ustart) / dT_switch)
        out[i0:i1] = seg
        state = float(seg[-1])
    return out


def write_session(unit: UnitSpec, path, session: int = 0, seed: int = 0, rate_hz: float = 25.0,
                  **overrides) -> dict:
    """Write one session of ``unit`` as a Parquet rig log (per the contract); return its truth.

    ``overrides`` are protocol parameters (see ``_protocol_defaults``), e.g.
    ``ramp_c_per_h=45`` for a sweep, ``temps=[-20, 10, 40]``, ``hold_s=25``; on turntables also
    ``rate_order`` (one of RATE_ORDERS or a list of signed rates) and ``temp_order`` (one of
    TEMP_ORDERS)."""
    cols, info = simulate_session(unit, session=session, seed=seed, rate_hz=rate_hz, **overrides)
    arrays = [pa.array(cols["t"], pa.float64()),
              pa.array(cols["gyro_x"], pa.float64()), pa.array(cols["gyro_y"], pa.float64()),
              pa.array(cols["gyro_z"], pa.float64()), pa.array(cols["temp"], pa.float64()),
              pa.array(cols["ref_rate"], pa.float64()),
              pa.array(cols["mount"].tolist(), pa.string()),
              pa.array(cols["accel_x"], pa.float32()), pa.array(cols["accel_y"], pa.float32()),
              pa.array(cols["accel_z"], pa.float32())]
    names = ["t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "mount",
             "accel_x", "accel_y", "accel_z"]
    table = pa.Table.from_arrays(arrays, names=names)
    pq.write_table(table, str(path), compression="zstd", use_dictionary=["mount"])
    info["path"] = str(path)
    return info


if __name__ == "__main__":          # tiny smoke run: python -m benchmarks.zoo.generator OUT.parquet
    import sys
    u = make_unit("warmup", "turntable3", "white", seed=7)
    inf = write_session(u, sys.argv[1] if len(sys.argv) > 1 else "/tmp/zoo_smoke.parquet", 0, 1)
    print(json.dumps({k: inf[k] for k in ("protocol", "effect", "n_rows", "noise_floor_hint")}))
