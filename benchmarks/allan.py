"""Benchmark: overlapping Allan deviation of 4.7 million samples (octave taus, m = 1 ... n/2).

Times ``gyrocal.fit.noise.allan_deviation`` on a (n, 3) and a 1-D record of consumer-grade coloured
noise (100 Hz, about 13 h), median and minimum of ``--repeat`` runs, then measures the peak
memory it allocates with tracemalloc in a separate, untimed run (tracemalloc slows allocation).
Reference: an anchor tool took 727.7 s for that many samples; the target is under 2 s.

    python benchmarks/allan.py [--samples 4700000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
import tracemalloc

import numpy as np
from host import cores, cpu_name

from gyrocal.fit.noise import allan_deviation, fit_noise_terms
from gyrocal.simulate.noise import GRADES, coloured_noise

RATE = 100.0


def _time(x: np.ndarray, repeat: int) -> tuple[float, float, int]:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = allan_deviation(x, RATE)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), len(res.tau)


def _peak_mb(x: np.ndarray) -> float:
    tracemalloc.start()
    tracemalloc.reset_peak()
    allan_deviation(x, RATE)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=4_700_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()

    print(
        f"machine: {cpu_name()}, {cores()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}, {platform.platform()}"
    )
    x3 = coloured_noise(np.random.default_rng(0), args.samples, RATE, **GRADES["low"])
    x1 = np.ascontiguousarray(x3[:, 0])
    print(
        f"samples: {args.samples} at {RATE:g} Hz ({args.samples / RATE / 3600:.1f} h), "
        f"input {x3.nbytes / 2**20:.0f} MB (3 axes)"
    )
    for label, x in (("3 axes", x3), ("1 axis", x1)):
        med, best, k = _time(x, args.repeat)
        print(
            f"allan_deviation {label}: median {med:.3f} s, min {best:.3f} s over {args.repeat} runs, "
            f"{k} taus; peak allocated {_peak_mb(x):.0f} MB"
        )
    t0 = time.perf_counter()
    fit = fit_noise_terms(allan_deviation(x3, RATE))
    print(
        f"allan_deviation + fit_noise_terms, 3 axes: {time.perf_counter() - t0:.3f} s; "
        f"ARW {np.round(fit.arw, 3)} deg/sqrt(h), B {np.round(fit.bias_instability, 2)} deg/h, "
        f"RRW {np.round(fit.rrw, 1)} deg/h/sqrt(h) (simulated {GRADES['low']})"
    )


if __name__ == "__main__":
    main()
