"""Benchmark: how well any estimator could know the zoo's coloured floor from one sweep.

``benchmarks/floor.py`` compares the floor gyrocal prints with the zoo's truth for a 20-s window
mean, which for coloured units is mostly the Gauss–Markov wander's variance sigma^2 (correlation
time tau_c of 100–1000 s). This script asks what the data of one session can say about that
figure at best: the Cramér–Rao bound on the truth's estimate, from the Whittle Fisher
information of the noise's spectrum (white + Gauss–Markov + rate random walk, all four
parameters unknown or the random walk known), over

* ``dwells``: the sweep's three 20-min static dwells sampled at 5 Hz, each dwell's mean given
  to the temperature model (its zero frequency dropped);
* ``ramps``: the 20-s windows along both ramps (30 and 60 °C/h), a straight line per ramp
  given to the temperature model (frequencies below 2/ramp dropped). This presumes a model
  of temperature that is complete, the floor the issue rules out when an effect is missing;
* ``both``: the two together (their information added).

An efficient, unbiased estimator's floor is then about normal with that standard error, so
its chance to land within 1.3 times the truth either way follows; the zoo's coloured sweeps
are six sessions (three units at two ramps: the effects share each session's noise).

    python benchmarks/floor_bound.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import norm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WINDOW_S = 20.0
BAND = 1.3


def spectrum(p, f):
    """Two-sided PSD of white (density n2) + Gauss–Markov (s2, tau) + random walk (q2)."""
    s2, tau, n2, q2 = p
    return n2 + 2 * s2 * tau / (1 + (2 * np.pi * f * tau) ** 2) + q2 / (2 * np.pi * f) ** 2


def fisher(p, f, blocks, known_rrw):
    """Whittle information of ``blocks`` independent records at Fourier frequencies ``f``."""
    grads = []
    for i in range(4):
        hi, lo = np.array(p, float), np.array(p, float)
        h = 1e-4 * abs(p[i])
        hi[i] += h
        lo[i] -= h
        grads.append((np.log(spectrum(hi, f)) - np.log(spectrum(lo, f))) / (2 * h))
    g = np.array(grads[:3] if known_rrw else grads)
    return blocks * 0.5 * g @ g.T


def truth_variance(arw, s, tau):
    x = WINDOW_S / tau
    return arw**2 / WINDOW_S + s**2 * 2 / x**2 * (x - 1 + np.exp(-x))


def relative_error(noise, source, ramp_s, known_rrw):
    """Cramér–Rao relative standard error of the RMS-over-axes truth."""
    arw, s, tau, q = (
        np.asarray(noise[k], float) for k in ("arw_dps_rthz", "gm_sigma_dps", "gm_tau_s", "rrw_dps_rts")
    )
    # (rate Hz, record length s, records, first Fourier index kept)
    records = {"dwells": [(5.0, 1200.0, 3, 1)], "ramps": [(1 / WINDOW_S, ramp_s, 2, 2)]}
    records["both"] = records["dwells"] + records["ramps"]
    var, dvar = [], []
    for a in range(3):
        # white as a density: a 5-Hz sample's variance arw^2 * 5, a 20-s mean's arw^2 / 20
        white = arw[a] ** 2
        p = [s[a] ** 2, tau[a], white, max(q[a], 1e-7) ** 2]
        cov = np.linalg.inv(
            sum(
                fisher(p, np.arange(first, int(length * rate / 2)) / length, blocks, known_rrw)
                for rate, length, blocks, first in records[source]
            )
        )
        v = truth_variance(arw[a], s[a], tau[a])
        x, dt = WINDOW_S / tau[a], 1e-3 * tau[a]
        grad = np.array(
            [
                2 / x**2 * (x - 1 + np.exp(-x)),  # d v / d s^2
                (truth_variance(arw[a], s[a], tau[a] + dt) - v) / dt,  # d v / d tau
                1 / WINDOW_S,
            ]
        )  # d v / d white
        var.append(v)
        dvar.append(grad @ cov[:3, :3] @ grad)
    truth = np.sqrt(np.mean(var))
    return float(np.sqrt(np.sum(dvar)) / 3 / (2 * truth**2))


def main() -> int:
    from benchmarks.zoo.generator import make_unit

    noises = {
        seed: make_unit(effect="none", protocol="sweep", noise="coloured", seed=seed).params["noise"]
        for seed in (1, 2, 3)
    }
    print("data    random walk  seed  ramp °C/h  relative s.e.  P(within 1.3)")
    for source in ("dwells", "ramps", "both"):
        for known in (False, True):
            p_all = 1.0
            for seed, noise in noises.items():
                for ramp, ramp_s in ((30.0, 9600.0), (60.0, 4800.0)):
                    rel = relative_error(noise, source, ramp_s, known)
                    p = float(2 * norm.cdf(np.log(BAND) / rel) - 1)
                    p_all *= p
                    print(
                        f"{source:7s} {'known' if known else 'fitted':11s} {seed:4d}  {ramp:9.0f}  {rel:13.2f}  {p:13.2f}"
                    )
            print(
                f"{source}, random walk {'known' if known else 'fitted'}: P(all six sessions within "
                f"{BAND}) = {p_all:.2g}\n"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
