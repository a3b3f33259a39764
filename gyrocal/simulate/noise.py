"""Coloured gyro rate noise with the IEEE Std 952 terms, at levels users know as sensor grades.

Every level is given in the units ``gyrocal.fit.noise.NoiseTerms`` reports, so a fitted unit can be
re-simulated and a simulated one checked: ``arw`` deg/sqrt(h), ``bias_instability`` deg/h,
``rrw`` deg/h/sqrt(h), ``quantisation`` arcsec. Components (rate in deg/s, sampling ``rate`` Hz):

* white rate noise (ARW): independent samples of std N sqrt(rate), so sigma^2(tau) = N^2 / tau;
* flicker rate noise (bias instability): white Gaussian spectrum shaped in the Fourier domain to
  the PSD S(f) = B^2 / (2 pi |f|) (IEEE Std 952, table C.1; two-sided like S = N^2 for white
  noise, so the one-sided density is B^2 / (pi f)) between 1/T and rate/2,
  whose Allan plateau is sqrt(2 ln 2 / pi) B = 0.664 B for 1/T << 1/tau << rate; the
  generated record is longer than requested (a power-of-two FFT at least twice n) and cut, so
  the circular wrap of the FFT does not join the ends;
* rate random walk: cumulative sum of steps of std K / sqrt(rate), so sigma^2(tau) = K^2 tau / 3;
* angle quantisation: rate = difference of white angle errors of std Q times rate, so
  sigma^2(tau) = 3 Q^2 / tau^2 exactly (IEEE Std 952 quantisation noise).
"""

from __future__ import annotations

import math
from typing import TypedDict

import numpy as np

from ..io.errors import ConfigError

__all__ = ["GRADES", "coloured_noise", "noise_levels", "add_coloured_noise"]

# Typical datasheet / published Allan-analysis ranges, middle of each class:
# low  — consumer MEMS (phone/drone IMUs): noise density ~0.005-0.01 deg/s/sqrt(Hz), i.e.
#        ARW 0.3-0.6 deg/sqrt(h); in-run bias instability 10-50 deg/h; RRW tens to hundreds.
# mid  — industrial MEMS IMUs: ARW 0.15-0.35 deg/sqrt(h); bias instability 2-10 deg/h.
# high — tactical-grade MEMS: ARW 0.05-0.15 deg/sqrt(h); bias instability 0.3-1 deg/h.
# RRW values put the Allan minimum at a few hundred to about a thousand seconds, as reported.
GRADES = {
    "low": {"arw": 0.5, "bias_instability": 30.0, "rrw": 100.0, "quantisation": 0.0},
    "mid": {"arw": 0.25, "bias_instability": 6.0, "rrw": 20.0, "quantisation": 0.0},
    "high": {"arw": 0.1, "bias_instability": 0.5, "rrw": 1.0, "quantisation": 0.0},
}


def _flicker(rng: np.random.Generator, n: int, rate: float, b_si: float, axes: int) -> np.ndarray:
    size = 1 << max(int(math.ceil(math.log2(2 * n))), 1)
    f = np.fft.rfftfreq(size, d=1.0 / rate)
    # E|X_j|^2 = S1(f_j) size rate / 2 gives the one-sided PSD S1 = B^2 / (pi f) after irfft
    amp = np.zeros_like(f)
    amp[1:] = np.sqrt(b_si**2 / (math.pi * f[1:]) * size * rate / 2.0)
    spec = (rng.standard_normal((axes, f.size)) + 1j * rng.standard_normal((axes, f.size))) / math.sqrt(2)
    spec *= amp
    spec[:, -1] = spec[:, -1].real * math.sqrt(2)  # Nyquist bin is real: keep its variance
    return np.fft.irfft(spec, n=size, axis=1)[:, :n].T


def coloured_noise(
    rng: np.random.Generator,
    n: int,
    rate: float,
    *,
    arw: float,
    bias_instability: float,
    rrw: float,
    quantisation: float = 0.0,
    axes: int = 3,
) -> np.ndarray:
    """(n, axes) rate noise in deg/s with the given IEEE Std 952 levels (units above).

    Independent across axes; the draws come from ``rng`` in a fixed order (white, flicker, random
    walk, quantisation), each component drawn only when its level is non-zero.
    """
    levels = {"arw": arw, "bias_instability": bias_instability, "rrw": rrw, "quantisation": quantisation}
    for key, value in levels.items():
        if not (math.isfinite(float(value)) and value >= 0):
            raise ConfigError(f"noise.{key}: expected a non-negative finite level, found {value}")
    if int(n) < 1 or int(axes) < 1 or not (math.isfinite(float(rate)) and rate > 0):
        raise ConfigError(f"coloured_noise: need n >= 1, axes >= 1, rate > 0; found {n}, {axes}, {rate}")
    n, axes, rate = int(n), int(axes), float(rate)
    out = np.zeros((n, axes))
    if arw > 0:
        out += rng.standard_normal((n, axes)) * (arw / 60.0 * math.sqrt(rate))
    if bias_instability > 0:
        out += _flicker(rng, n, rate, bias_instability / 3600.0, axes)
    if rrw > 0:
        out += np.cumsum(rng.standard_normal((n, axes)), axis=0) * (rrw / 3600.0**1.5 / math.sqrt(rate))
    if quantisation > 0:
        angle = rng.standard_normal((n + 1, axes)) * (quantisation / 3600.0)
        out += np.diff(angle, axis=0) * rate
    return out


class NoiseLevels(TypedDict):
    """Coloured-noise levels (:func:`noise_levels`): the simulated truth's ``coloured_noise``."""

    bias_instability: float  # deg/h
    rrw: float  # deg/h/sqrt(h)
    quantisation: float  # arcsec


def noise_levels(spec) -> NoiseLevels:
    """Coloured-noise levels from a grade name (``low``, ``mid``, ``high``: the bias instability,
    rate random walk and quantisation of :data:`GRADES`) or a mapping of those keys. ARW is not
    taken: every simulated unit already has its white noise (its noise density)."""
    if isinstance(spec, str):
        if spec not in GRADES:
            raise ConfigError(f"noise grade {spec!r}: expected one of {', '.join(GRADES)} or levels")
        spec = GRADES[spec]
    if not isinstance(spec, dict):
        raise ConfigError(f"noise: expected a grade name or a mapping of levels, found {spec!r}")
    keys = ("bias_instability", "rrw", "quantisation")
    unknown = sorted(set(spec) - set(keys) - {"arw"})
    if unknown:
        raise ConfigError(f"noise: unknown level(s) {', '.join(unknown)}; known: {', '.join(keys)}")
    return NoiseLevels(
        bias_instability=float(spec.get("bias_instability", 0.0)),
        rrw=float(spec.get("rrw", 0.0)),
        quantisation=float(spec.get("quantisation", 0.0)),
    )


def add_coloured_noise(path, levels: NoiseLevels, rng: np.random.Generator) -> None:
    """Add bias instability, rate random walk and quantisation noise (``levels`` in the units
    above) to the gyro columns of the log at ``path``, in place. Drawn over the whole log at its
    median sample rate, so the flicker's low frequencies run across the renderers' chunks."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not any(levels.values()):
        return
    table = pq.read_table(path)
    t = table.column("t").to_numpy()
    rate = 1.0 / float(np.median(np.diff(t)))
    noise = coloured_noise(rng, len(t), rate, arw=0.0, **levels)
    for i, axis in enumerate("xyz"):
        name = f"gyro_{axis}"
        column = table.column(name)
        values = column.to_numpy().astype(np.float64) + noise[:, i]
        table = table.set_column(
            table.schema.get_field_index(name), name, pa.array(values.astype(column.type.to_pandas_dtype()))
        )
    pq.write_table(table, path)
