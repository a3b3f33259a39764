"""Independent generator of static gyro recordings with known truth.

Written from the log contract (/work/shared/spec/log-format.md) and the physics only,
without reading gyrocal, so that it can test gyrocal.  numpy, pandas and pyarrow only.

Two kinds of recording, both of an IMU lying still (true rate 0 plus Earth rotation):

* ``chamber_burst_log``: thermal-vacuum chamber, temperature falling exponentially, 5-s
  bursts at 50 Hz every 5 min, raw driver output (integer ms, rad/s x driver factor,
  temperature counts) plus a hand log of the chamber display.
* ``host_stamped_log``: consumer IMU at a steady 25 degC, ~100 Hz, stamped on arrival at
  the host (jitter and stalls), deg/s and degC.

``to_contract`` / ``write_contract`` give the same samples in the contract's columns and
units.  Every recording carries a JSON-able ``truth`` dict (see NOTE.md).  Same seed, same
parameters -> same arrays and same file bytes.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

__all__ = [
    "NoiseModel", "Recording", "EARTH_RATE_DEG_H", "TAUS_S",
    "earth_rate_body", "simulate_noise", "overlapping_adev",
    "chamber_burst_log", "host_stamped_log",
    "to_contract", "write_raw", "write_contract",
]

GENERATOR_VERSION = "tests.chamber.generator/1"
EARTH_RATE_RAD_S = 7.2921159e-5                       # sidereal rotation rate (WGS-84)
EARTH_RATE_DEG_H = np.degrees(EARTH_RATE_RAD_S) * 3600.0   # 15.041 deg/h
TAUS_S = (1.0, 10.0, 100.0)                            # taus the truth reports ADEV at

FORMULAS = {
    "white": "AVAR = N^2/tau, N = ARW[deg/rt-h]/60 in deg/s/rt-s; per-sample sigma = N*sqrt(fs)",
    "quantization": "rounding to q deg/s acts as white noise of variance q^2/12 per sample: "
                    "AVAR = q^2/(12*fs*tau)",
    "rrw": "AVAR = K^2*tau/3, K = RRW[deg/h/rt-h]/216000 in deg/s/rt-s",
    "gauss_markov": "per term (variance s^2, correlation time T, x = tau/T): "
                    "AVAR = s^2/x^2*(2x - 3 + 4exp(-x) - exp(-2x))",
    "bias_instability": "sum of Gauss-Markov terms, T log-spaced with ratio r over a band, "
                        "equal s^2 = B^2*ln(r)/pi so the PSD ~ B^2/(2*pi*f) two-sided "
                        "(flicker, IEEE-952) in the band; ADEV plateau ~ sqrt(2ln2/pi)*B = 0.664*B",
    "total": "independent processes: AVARs add; ADEV = sqrt(sum)",
}


# --------------------------------------------------------------------------- noise model
@dataclass(frozen=True)
class NoiseModel:
    """Per-axis gyro noise, identical statistics on x, y, z, independent realisations.

    Defaults are MPU-6050-class figures (see NOTE.md): 0.005 deg/s/rt-Hz rate noise
    density = 0.3 deg/rt-h ARW, B = 10 deg/h, K = 30 deg/h/rt-h, 131 LSB per deg/s.
    """
    arw_deg_rt_h: float = 0.3
    bi_deg_h: float = 10.0                 # IEEE-952 flicker coefficient B (not the plateau)
    bi_tc_s: tuple = (1.0, 1000.0)         # band of Gauss-Markov correlation times
    bi_terms: int = 5                      # log-spaced terms across the band (>= 2)
    rrw_deg_h_rt_h: float = 30.0
    lsb_deg_s: float | None = 1.0 / 131.0  # output quantisation; None = unquantised
    bi_gm: tuple | None = None             # explicit ((tc_s, sigma_deg_s), ...) overrides

    @classmethod
    def from_truth(cls, truth: dict) -> "NoiseModel":
        """Rebuild the model from a truth dict (or its JSON)."""
        m = dict(truth["noise"]["model"])
        m["bi_tc_s"] = tuple(m["bi_tc_s"])
        if m.get("bi_gm") is not None:
            m["bi_gm"] = tuple(tuple(p) for p in m["bi_gm"])
        return cls(**m)

    @property
    def n_deg_rt_s(self) -> float:         # ARW as deg/s/rt-s (= deg/s/rt-Hz)
        return self.arw_deg_rt_h / 60.0

    @property
    def k_deg_rt_s3(self) -> float:        # RRW as deg/s/rt-s
        return self.rrw_deg_h_rt_h / 3600.0 / 60.0

    def gm_terms(self) -> list[tuple[float, float]]:
        """(correlation time s, stationary sigma deg/s) of each Gauss-Markov term."""
        if self.bi_gm is not None:
            return [(float(tc), float(s)) for tc, s in self.bi_gm]
        if self.bi_deg_h == 0 or self.bi_terms == 0:
            return []
        if self.bi_terms < 2:
            raise ValueError("bi_terms must be >= 2 (or give bi_gm explicitly)")
        tcs = np.geomspace(self.bi_tc_s[0], self.bi_tc_s[1], self.bi_terms)
        ln_r = np.log(tcs[1] / tcs[0])
        b = self.bi_deg_h / 3600.0
        # one-sided PSD of the sum ~ s^2/(f ln r); IEEE-952 flicker is B^2/(2 pi f) two-sided,
        # i.e. B^2/(pi f) one-sided, hence s^2 = B^2 ln(r)/pi
        sigma = b * np.sqrt(ln_r / np.pi)
        return [(float(tc), float(sigma)) for tc in tcs]

    def avar_components(self, tau, fs: float) -> dict:
        """Analytic Allan variance of each process, (deg/s)^2, at tau (s) for rate fs (Hz)."""
        tau = np.asarray(tau, dtype=float)
        out = {"white": self.n_deg_rt_s ** 2 / tau,
               "quantization": (0.0 if self.lsb_deg_s is None else self.lsb_deg_s ** 2 / 12.0)
               / (fs * tau) + 0.0 * tau,
               "rrw": self.k_deg_rt_s3 ** 2 * tau / 3.0}
        bi = 0.0 * tau
        for tc, s in self.gm_terms():
            x = tau / tc
            # series for small x avoids cancellation in 2x - 3 + 4e^-x - e^-2x
            g = np.where(x < 1e-3, 2 * x ** 3 / 3 - x ** 4 / 2,
                         2 * x - 3 + 4 * np.exp(-x) - np.exp(-2 * x))
            bi = bi + s ** 2 * g / x ** 2
        out["bias_instability"] = bi
        return out

    def adev(self, tau, fs: float):
        """Analytic total Allan deviation, deg/s."""
        return np.sqrt(sum(self.avar_components(tau, fs).values()))

    def truth(self, fs: float, taus=TAUS_S) -> dict:
        taus = np.asarray(taus, dtype=float)
        comp = self.avar_components(taus, fs)
        grid = np.geomspace(0.1, 1e4, 2001)
        curve = self.adev(grid, fs)
        i = int(np.argmin(curve))
        return {
            "noise": {
                "arw_deg_rt_h": self.arw_deg_rt_h,
                "white_sigma_per_sample_deg_s": self.n_deg_rt_s * np.sqrt(fs),
                # B is meaningless when the Gauss-Markov terms are given explicitly
                "bias_instability_deg_h": None if self.bi_gm is not None else self.bi_deg_h,
                "bias_instability_plateau_deg_h": None if self.bi_gm is not None
                else float(np.sqrt(2 * np.log(2) / np.pi) * self.bi_deg_h),
                "bi_model": "sum of first-order Gauss-Markov processes (flicker approximation)",
                "bi_gauss_markov": [{"tc_s": tc, "sigma_deg_s": s} for tc, s in self.gm_terms()],
                "rrw_deg_h_rt_h": self.rrw_deg_h_rt_h,
                "quantization_deg_s": self.lsb_deg_s,
            },
            "allan": {
                "applies_to": "gyro noise of one axis at constant temperature (the bias "
                              "polynomial and Earth rate are constants there and drop out)",
                "sample_rate_hz": fs,
                "tau_s": taus.tolist(),
                "adev_deg_s": np.sqrt(sum(comp.values())).tolist(),
                "adev_deg_h": (3600 * np.sqrt(sum(comp.values()))).tolist(),
                "components_deg_h": {k: (3600 * np.sqrt(v)).tolist() for k, v in comp.items()},
                "adev_min_deg_h": float(3600 * curve[i]),
                "tau_at_min_s": float(grid[i]),
                "formulas": FORMULAS,
            },
        }


def _gauss_markov(t: np.ndarray, tc: float, sigma: float, z: np.ndarray) -> np.ndarray:
    """Exact discretisation of a stationary first-order Gauss-Markov process at times t.

    x_k = a_k x_{k-1} + sigma*sqrt(1-a_k^2) z_k, a_k = exp(-dt_k/tc), valid for any
    (irregular) steps, so bursts separated by minutes stay correlated correctly.
    Vectorised with x_k = e^{-u_k} * cumsum(e_j e^{u_j}) (u = t/tc); the run is cut into
    blocks where u spans < 500 so e^u cannot overflow (one loop turn per block).
    """
    n = t.size
    dt = np.diff(t)
    a = np.exp(-dt / tc)
    e = np.empty(n)
    e[0] = sigma * z[0]                                   # stationary start
    e[1:] = sigma * np.sqrt(-np.expm1(-2.0 * dt / tc)) * z[1:]
    u = (t - t[0]) / tc
    x = np.empty(n)
    i = 0
    while i < n:
        j = max(int(np.searchsorted(u, u[i] + 500.0, side="right")), i + 1)
        g = np.exp(u[i:j] - u[i])
        c = e[i:j] * g
        if i > 0:
            c[0] += a[i - 1] * x[i - 1]                   # carry the state across blocks
        x[i:j] = np.cumsum(c) / g
        i = j
    return x


def simulate_noise(t, model: NoiseModel, fs: float, rng: np.random.Generator) -> np.ndarray:
    """Noise (deg/s), shape (len(t), 3), at sample times t (s, may be irregular/bursty).

    White noise is per sample with sigma = N*sqrt(fs); Gauss-Markov and rate random walk
    evolve in continuous time, also across gaps.  Quantisation is applied later, to the
    whole output.  The RRW starts at 0 (bias at t0 is the polynomial + GM state).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    out = np.empty((n, 3))
    dt = np.diff(t, prepend=t[0])
    for ax in range(3):                                    # one loop turn per axis
        y = model.n_deg_rt_s * np.sqrt(fs) * rng.standard_normal(n)
        y += np.cumsum(model.k_deg_rt_s3 * np.sqrt(dt) * rng.standard_normal(n))
        for tc, s in model.gm_terms():
            y += _gauss_markov(t, tc, s, rng.standard_normal(n))
        out[:, ax] = y
    return out


def overlapping_adev(y, fs: float, taus) -> np.ndarray:
    """Overlapping Allan deviation of a regularly sampled rate y at the given taus.

    theta = integral of y; AVAR(m) = mean((theta[k+2m] - 2 theta[k+m] + theta[k])^2)/(2 tau^2),
    tau = m/fs.  NaN where 2m > len(y).
    """
    y = np.asarray(y, dtype=float)
    theta = np.concatenate(([0.0], np.cumsum(y - y.mean()))) / fs
    out = []
    for tau in np.atleast_1d(taus):
        m = int(round(tau * fs))
        if m < 1 or 2 * m > y.size:
            out.append(np.nan)
            continue
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        out.append(np.sqrt(np.mean(d ** 2) / (2 * (m / fs) ** 2)))
    return np.asarray(out)


# --------------------------------------------------------------------------- helpers
def earth_rate_body(latitude_deg: float = 48.0, orientation=None) -> np.ndarray:
    """Earth rotation seen by a still body, deg/s, shape (3,).

    ``orientation``: 3x3, row i = body axis i expressed in local East-North-Up.  Default
    identity: x east, y north, z up.  Earth rate in ENU is Omega*(0, cos lat, sin lat).
    """
    c = np.eye(3) if orientation is None else np.asarray(orientation, dtype=float)
    lat = np.radians(latitude_deg)
    w_enu = np.degrees(EARTH_RATE_RAD_S) * np.array([0.0, np.cos(lat), np.sin(lat)])
    return c @ w_enu


def _up_axis(orientation) -> str:
    c = np.eye(3) if orientation is None else np.asarray(orientation, dtype=float)
    up = c[:, 2]                                            # body components of "up"
    i = int(np.argmax(np.abs(up)))
    return ("+" if up[i] > 0 else "-") + "xyz"[i]


def _bias(dtemp, b0, b1, b2) -> np.ndarray:
    """b0 + b1 dT + b2 dT^2 per axis, deg/s, shape (n, 3)."""
    d = np.asarray(dtemp, dtype=float)[:, None]
    return np.asarray(b0)[None] + np.asarray(b1)[None] * d + np.asarray(b2)[None] * d ** 2


def _quantise(w, lsb):
    return w if lsb is None else np.round(w / lsb) * lsb


def _to_resolution(x, res):
    """Round to a decimal resolution (0.1, 0.01 degC) and to the nearest double of it,
    so that 13.2 is stored as 13.2, not 13.200000000000001."""
    return np.round(np.round(np.asarray(x) / res) * res, 12)


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, np.generic):
        return o.item()
    return o


def _streams(seed: int, n: int) -> list[np.random.Generator]:
    """Independent named sub-streams: a change in one effect does not shift the others."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(n)]


@dataclass
class Recording:
    kind: str                         # "chamber_burst" or "host_stamped"
    raw: pd.DataFrame                 # as recorded
    truth: dict                       # JSON-able
    samples: pd.DataFrame             # per-sample truth (noise-free signal, true times...)
    hand: pd.DataFrame | None = None  # chamber hand log
    stem: str = field(default="")


# Defaults shared by both kinds: deg/s, deg/s/degC, deg/s/degC^2 (see NOTE.md)
B0 = (0.8, -1.2, 0.4)
B1 = (0.02, -0.03, 0.015)
B2 = (2e-4, -1e-4, 3e-4)


# --------------------------------------------------------------------------- (a) chamber
def chamber_burst_log(seed: int = 1, *, latitude_deg: float = 48.0, orientation=None,
                      t_start_c: float = 22.0, t_end_c: float = 10.0,
                      tau_chamber_s: float = 1800.0, duration_s: float = 7200.0,
                      burst_period_s: float = 300.0, burst_length_s: float = 5.0,
                      rate_hz: float = 50.0, die_lag_s: float | None = None,
                      self_heating_c: float = 0.0, temp_noise_c: float = 0.02,
                      b0=B0, b1=B1, b2=B2, t_ref_c: float = 25.0,
                      noise: NoiseModel = NoiseModel(), driver_factor: float = 2.0,
                      temp_lsb_per_c: float = 340.0, temp_offset_c: float = 36.53,
                      t0_ms: int = 734_512_000, hand_period_s: float = 600.0,
                      hand_resolution_c: float = 0.1) -> Recording:
    """Thermal-vacuum chamber burst log of a still IMU (raw driver output).

    Chamber air: T(t) = t_end + (t_start - t_end) exp(-t/tau_chamber); the unit's sensor
    reads air + self_heating; the gyro die (which sets the bias) equals the sensor or, with
    ``die_lag_s``, lags it by a first-order time constant.  Bursts of ``burst_length_s`` at
    ``rate_hz`` start every ``burst_period_s`` from 0 to ``duration_s`` inclusive.
    """
    rng_noise, rng_temp = _streams(seed, 2)
    step_ms = 1000.0 / rate_hz
    per_burst = int(round(burst_length_s * rate_hz))
    starts_s = np.arange(0.0, duration_s + 1e-9, burst_period_s)
    n_b = starts_s.size
    # sample clock: integer ms on the logger's clock (rounded if 1000/rate is not integral)
    rel_ms = np.round(starts_s[:, None] * 1000.0 + np.arange(per_burst)[None] * step_ms)
    time_ms = (t0_ms + rel_ms).astype(np.int64).ravel()
    burst = np.repeat(np.arange(n_b, dtype=np.int32), per_burst)
    t = (time_ms - t0_ms) / 1000.0                       # s since the first sample

    def air(tt):
        return t_end_c + (t_start_c - t_end_c) * np.exp(-np.asarray(tt) / tau_chamber_s)

    def die(tt):
        tt = np.asarray(tt, dtype=float)
        if not die_lag_s:
            return air(tt) + self_heating_c
        # dTd/dt = (Ts - Td)/lag with Ts exponential, Td(0) = Ts(0): closed form
        d0, tc, tl = t_start_c - t_end_c, tau_chamber_s, die_lag_s
        if np.isclose(tc, tl):
            shape = (1.0 + tt / tc) * np.exp(-tt / tc)
        else:
            shape = (tc * np.exp(-tt / tc) - tl * np.exp(-tt / tl)) / (tc - tl)
        return t_end_c + self_heating_c + d0 * shape

    sensor_c = air(t) + self_heating_c
    die_c = die(t)
    measured_c = sensor_c + temp_noise_c * rng_temp.standard_normal(t.size)
    temp_counts = np.round(temp_lsb_per_c * (measured_c - temp_offset_c)).astype(np.int16)

    earth = earth_rate_body(latitude_deg, orientation)
    clean = _bias(die_c - t_ref_c, b0, b1, b2) + earth[None]          # deg/s
    w = _quantise(clean + simulate_noise(t, noise, rate_hz, rng_noise), noise.lsb_deg_s)
    g = driver_factor * np.radians(w)                                  # rad/s x factor

    raw = pd.DataFrame({"time_ms": time_ms, "gx": g[:, 0], "gy": g[:, 1], "gz": g[:, 2],
                        "temp_raw": temp_counts, "burst": burst})
    samples = pd.DataFrame({"time_ms": time_ms, "t_s": t, "air_c": air(t), "sensor_c": sensor_c,
                            "measured_c": measured_c, "die_c": die_c,
                            "clean_x": clean[:, 0], "clean_y": clean[:, 1], "clean_z": clean[:, 2]})
    hand_t = np.arange(0.0, duration_s + 1e-9, hand_period_s)
    hand = pd.DataFrame({"time_ms": (t0_ms + np.round(hand_t * 1000)).astype(np.int64),
                         "chamber_c": _to_resolution(air(hand_t), hand_resolution_c)})

    mid = starts_s + (per_burst - 1) * step_ms / 2000.0
    mean_clean = clean.reshape(n_b, per_burst, 3).mean(axis=1)
    truth = {
        "format": GENERATOR_VERSION, "kind": "chamber_burst", "seed": seed,
        "sample_rate_hz": rate_hz,
        "true_rate_deg_s": [0.0, 0.0, 0.0],
        "bias": {"t_ref_c": t_ref_c, "b0_deg_s": list(b0), "b1_deg_s_per_c": list(b1),
                 "b2_deg_s_per_c2": list(b2), "temperature": "die (= sensor unless die_lag_s)",
                 "die_lag_s": die_lag_s},
        "earth": {"latitude_deg": latitude_deg, "omega_deg_h": EARTH_RATE_DEG_H,
                  "orientation_rows_enu": (np.eye(3) if orientation is None
                                           else np.asarray(orientation, float)),
                  "body_deg_s": earth, "up_axis": _up_axis(orientation)},
        "temperature": {"profile": "air = end + (start - end)*exp(-t/tau); sensor = air + self_heating",
                        "start_c": t_start_c, "end_c": t_end_c, "tau_s": tau_chamber_s,
                        "self_heating_c": self_heating_c, "sensor_noise_c": temp_noise_c,
                        "die_lag_s": die_lag_s},
        "raw": {"columns": {"time_ms": "int64 ms since an arbitrary epoch (logger clock)",
                            "gx": "rad/s * driver_factor", "gy": "rad/s * driver_factor",
                            "gz": "rad/s * driver_factor", "temp_raw": "int16 sensor counts",
                            "burst": "burst index"},
                "t0_ms": t0_ms, "driver_factor": driver_factor,
                "temp_counts": {"lsb_per_c": temp_lsb_per_c, "offset_c": temp_offset_c,
                                "counts_at_0c": -temp_lsb_per_c * temp_offset_c,
                                "formula": "counts = round(lsb_per_c*(T - offset_c)); "
                                           "T = counts/lsb_per_c + offset_c"}},
        "bursts": {"period_s": burst_period_s, "length_s": burst_length_s, "rate_hz": rate_hz,
                   "samples_per_burst": per_burst, "n_bursts": n_b,
                   "step_ms": step_ms, "start_ms": (t0_ms + rel_ms[:, 0]).astype(np.int64),
                   "t_mid_s": mid, "sensor_c": air(mid) + self_heating_c, "die_c": die(mid),
                   "expected_deg_s": mean_clean},
        "hand_log": {"period_s": hand_period_s, "resolution_c": hand_resolution_c,
                     "columns": {"time_ms": "logger clock ms", "chamber_c": "chamber display degC"}},
    }
    truth.update(noise.truth(rate_hz))
    truth["noise"]["model"] = asdict(noise)
    return Recording("chamber_burst", raw, _jsonable(truth), samples, hand,
                     stem=f"chamber_burst_seed{seed}")


# --------------------------------------------------------------------------- (b) host
def host_stamped_log(seed: int = 2, *, duration_s: float = 660.0, rate_hz: float = 100.0,
                     clock_ppm: float = 0.0, temp_c: float = 25.0, temp_noise_c: float = 0.02,
                     temp_resolution_c: float = 0.01, latency_mean_ms: float = 6.0,
                     latency_max_ms: float = 66.0, min_step_ms: int = 1,
                     stalls_per_min: float = 3.0, stall_s: tuple = (0.05, 0.42),
                     latitude_deg: float = 48.0, orientation=None,
                     b0=B0, b1=B1, b2=B2, t_ref_c: float = 25.0,
                     noise: NoiseModel = NoiseModel(),
                     epoch_s: float = 1_717_243_200.0) -> Recording:
    """Consumer IMU, static at a steady temperature, stamped on arrival at the host.

    The sample clock is regular (rate_hz*(1+clock_ppm*1e-6) in host time).  Arrival =
    sample time + latency (exponential, mean latency_mean_ms, capped at latency_max_ms),
    except during stalls (Poisson, stalls_per_min, duration uniform in stall_s) when every
    sample due in the window is delivered at its end.  Stamps are whole ms, strictly
    increasing by at least min_step_ms (the host reads its queue one sample at a time).
    """
    rng_noise, rng_temp, rng_lat, rng_stall = _streams(seed, 4)
    fs = rate_hz * (1.0 + clock_ppm * 1e-6)
    n = int(round(duration_s * fs))
    k = np.arange(n)
    ts = k / fs                                                  # true sample times, s

    arrive = ts + np.minimum(rng_lat.exponential(latency_mean_ms, n), latency_max_ms) / 1000.0
    # stall windows: Poisson starts, kept apart so windows never overlap
    # (a dead time of stall_s[1] + 0.2 s after each start, then exponential waiting)
    dead = stall_s[1] + 0.2
    n_max = int(np.ceil(2 * stalls_per_min * duration_s / 60.0)) + 5
    wait = rng_stall.exponential(max(60.0 / max(stalls_per_min, 1e-9) - dead, 1e-3), n_max)
    st_start = np.cumsum(dead + wait) - dead
    st_dur = rng_stall.uniform(stall_s[0], stall_s[1], n_max)
    keep = st_start + st_dur < ts[-1]
    st_start, st_dur = st_start[keep], st_dur[keep]
    idx = np.searchsorted(st_start, arrive, side="right") - 1
    ok = idx >= 0
    stalled = np.zeros(n, dtype=bool)
    stalled[ok] = arrive[ok] < st_start[idx[ok]] + st_dur[idx[ok]]
    arrive[stalled] = (st_start + st_dur)[idx[stalled]]          # delivered in a bunch
    # whole ms, then strictly increasing: a_k = max(a_{k-1} + step, raw_k) as a running max
    ms = np.round(arrive * 1000.0).astype(np.int64)
    stamp_ms = np.maximum.accumulate(ms - min_step_ms * k) + min_step_ms * k
    epoch_ms = int(round(epoch_s * 1000))
    t_host = (epoch_ms + stamp_ms) / 1000.0

    earth = earth_rate_body(latitude_deg, orientation)
    clean = _bias(np.full(n, temp_c - t_ref_c), b0, b1, b2) + earth[None]
    w = _quantise(clean + simulate_noise(ts, noise, fs, rng_noise), noise.lsb_deg_s)
    temp = _to_resolution(temp_c + temp_noise_c * rng_temp.standard_normal(n), temp_resolution_c)

    raw = pd.DataFrame({"t": t_host, "gyro_x": w[:, 0], "gyro_y": w[:, 1], "gyro_z": w[:, 2],
                        "temp": temp})
    samples = pd.DataFrame({"t_sample": epoch_s + ts, "t_stamp": t_host, "stalled": stalled,
                            "clean_x": clean[:, 0], "clean_y": clean[:, 1], "clean_z": clean[:, 2]})
    first = np.flatnonzero(stalled & ~np.r_[False, stalled[:-1]])  # first sample of each bunch
    step = np.diff(stamp_ms)
    truth = {
        "format": GENERATOR_VERSION, "kind": "host_stamped", "seed": seed,
        "sample_rate_hz": rate_hz, "true_sample_rate_hz": fs, "n_samples": n,
        "true_rate_deg_s": [0.0, 0.0, 0.0],
        "bias": {"t_ref_c": t_ref_c, "b0_deg_s": list(b0), "b1_deg_s_per_c": list(b1),
                 "b2_deg_s_per_c2": list(b2), "at_temp_deg_s": clean[0] - earth},
        "earth": {"latitude_deg": latitude_deg, "omega_deg_h": EARTH_RATE_DEG_H,
                  "orientation_rows_enu": (np.eye(3) if orientation is None
                                           else np.asarray(orientation, float)),
                  "body_deg_s": earth, "up_axis": _up_axis(orientation)},
        "expected_deg_s": clean[0],
        "temperature": {"c": temp_c, "sensor_noise_c": temp_noise_c, "resolution_c": temp_resolution_c},
        "raw": {"columns": {"t": "host arrival stamp, s since Unix epoch, whole ms",
                            "gyro_x": "deg/s", "gyro_y": "deg/s", "gyro_z": "deg/s", "temp": "degC"},
                "epoch_s": epoch_s},
        "stamps": {"model": "arrival = sample time + min(Exp(latency_mean), latency_max); "
                            "stall windows deliver their samples at the window end; "
                            "whole ms; a_k = max(a_{k-1} + min_step, arrival_k)",
                   "sample_clock": "regular: t_sample = epoch + k/true_sample_rate_hz",
                   "latency_mean_ms": latency_mean_ms, "latency_max_ms": latency_max_ms,
                   "min_step_ms": min_step_ms,
                   "max_normal_step_ms": 1000.0 / fs + latency_max_ms + 1.0,
                   "expected_mean_step_ms": 1000.0 / fs,
                   "stalls": [{"start_s": float(s), "duration_s": float(d),
                               "n_bunched": int(np.sum(idx[stalled] == i))}
                              for i, (s, d) in enumerate(zip(st_start, st_dur))],
                   "stall_gap_index": first,
                   "observed": {"mean_step_ms": float(step.mean()), "min_step_ms": int(step.min()),
                                "max_step_ms": int(step.max()),
                                "median_step_ms": float(np.median(step))}},
    }
    truth.update(noise.truth(fs))
    truth["noise"]["model"] = asdict(noise)
    return Recording("host_stamped", raw, _jsonable(truth), samples, None,
                     stem=f"host_stamped_seed{seed}")


# --------------------------------------------------------------------------- (c) contract
def to_contract(rec: Recording, units: str = "deg/s") -> pa.Table:
    """The recording in the contract's columns: t (s), gyro_* and ref_rate, temp (degC).

    Purely mechanical: t from the recorded stamps (chamber: time_ms/1000 on the logger's
    clock, host: the arrival stamps), gyro divided by the driver factor, counts to degC,
    ref_rate = 0 (static rig).  No mount column.  Extra raw columns (burst) are carried.
    units="rad/s" keeps gyro in rad/s and sets the gyrocal.units metadata.
    """
    if units not in ("deg/s", "rad/s"):
        raise ValueError("units must be 'deg/s' or 'rad/s'")
    r, tr = rec.raw, rec.truth
    if rec.kind == "chamber_burst":
        f = tr["raw"]["driver_factor"]
        rad = r[["gx", "gy", "gz"]].to_numpy() / f
        gyro = rad if units == "rad/s" else np.degrees(rad)
        tc = tr["raw"]["temp_counts"]
        cols = {"t": r["time_ms"].to_numpy() / 1000.0,
                "temp": r["temp_raw"].to_numpy() / tc["lsb_per_c"] + tc["offset_c"]}
        extra = {"burst": r["burst"].to_numpy()}
    else:
        deg = r[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
        gyro = np.radians(deg) if units == "rad/s" else deg
        cols = {"t": r["t"].to_numpy(), "temp": r["temp"].to_numpy().astype(float)}
        extra = {}
    data = {"t": cols["t"], "gyro_x": gyro[:, 0], "gyro_y": gyro[:, 1], "gyro_z": gyro[:, 2],
            "temp": cols["temp"], "ref_rate": np.zeros(len(r)), **extra}
    table = pa.table(data)
    if units == "rad/s":
        table = table.replace_schema_metadata(
            {"gyrocal.units": json.dumps({"gyro": "rad/s", "ref_rate": "rad/s"})})
    return table


def _write_truth(truth: dict, path: Path) -> None:
    path.write_text(json.dumps(truth, indent=1, sort_keys=True) + "\n")


def write_raw(rec: Recording, out_dir, stem: str | None = None) -> dict:
    """Write the as-recorded log (CSV and Parquet), hand log (chamber), truth JSON and the
    per-sample truth (Parquet).  Returns {role: Path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = stem or rec.stem
    p = {"csv": out / f"{stem}.csv", "parquet": out / f"{stem}.parquet",
         "truth": out / f"{stem}_truth.json", "samples": out / f"{stem}_samples.parquet"}
    # default float format = shortest repr that round-trips: CSV and Parquet hold equal values
    rec.raw.to_csv(p["csv"], index=False, lineterminator="\n")
    pq.write_table(pa.Table.from_pandas(rec.raw, preserve_index=False), p["parquet"])
    pq.write_table(pa.Table.from_pandas(rec.samples, preserve_index=False), p["samples"])
    if rec.hand is not None:
        p["hand"] = out / f"{stem}_hand.csv"
        rec.hand.to_csv(p["hand"], index=False, float_format="%.1f", lineterminator="\n")
    _write_truth(rec.truth, p["truth"])
    return p


def write_contract(rec: Recording, path, units: str = "deg/s") -> Path:
    """Write the contract-form Parquet at ``path`` and its truth beside it (<stem>_truth.json)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(to_contract(rec, units), path)
    _write_truth(rec.truth, path.with_name(path.stem + "_truth.json"))
    return path
