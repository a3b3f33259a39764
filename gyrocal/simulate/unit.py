"""Ground truth of a simulated gyro unit and its measurement physics.

Output model (seed 000, Eq 8 and 12, with Eq 9-10's temperature dependence made explicit):

    w = K(T) w_true + B(T) + v,        K(T) = diag(s(T)) (I + M)

s(T) is linear in ΔT = T − T_ref (seed 000, Fig. 4), B(T) is a cubic in ΔT, M is the
constant cross-axis matrix (package misalignment and non-orthogonality, zero diagonal), v is
white noise. The electronics then low-pass, saturate at the full-scale range and quantise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..io.errors import ConfigError

EFFECTS = {
    "scale_quadratic": (3,),
    "scale_cubic": (3,),
    "scale_asymmetry": (3,),
    "g_sensitivity": (3, 3),
    "temp_rate": (3,),
    "warmup": (3,),
}  # field -> shape

# Seed 000, Eq 23: the unit's K_g at 25 °C, reordered as the 3x3 K and B of Eq 11-12.
SEED000_K25 = np.array(
    [[1.0005, -0.0188, 0.0012], [0.0187, 1.0005, 5.2027e-4], [-0.0011, -7.5133e-4, 1.0017]]
)
SEED000_B25 = np.array([-0.0303, -0.0435, -0.0261])


@dataclass(frozen=True)
class GyroUnit:
    """Electrical error parameters of one unit; all rates in deg/s, temperatures in °C."""

    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    scale_tc: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 1/°C
    misalignment: tuple[tuple[float, ...], ...] = ((0.0,) * 3,) * 3  # zero diagonal
    bias_poly: tuple[tuple[float, ...], ...] = ((0.0,) * 4,) * 3  # per axis: c0..c3 in ΔT^k
    t_ref: float = 25.0
    noise_density: float = 0.007  # deg/s/√Hz, white
    lsb: float = 500.0 / 32768.0  # deg/s per count
    full_scale: float = 500.0  # deg/s
    bandwidth_hz: float = 40.0  # first-order anti-alias filter
    accel_noise: float = 0.002  # g per sample
    # Effects beyond the seed-000 model; each matches the library term of the same name.
    scale_quadratic: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 1/(deg/s)
    scale_cubic: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 1/(deg/s)²
    scale_asymmetry: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 1
    g_sensitivity: tuple[tuple[float, ...], ...] = ((0.0,) * 3,) * 3  # deg/s/g
    temp_rate: tuple[float, float, float] = (0.0, 0.0, 0.0)  # deg/s per °C/min
    # Beyond the library: a bias settling after power-on, A exp(-t / warmup_tau_s).
    warmup: tuple[float, float, float] = (0.0, 0.0, 0.0)  # deg/s at power-on
    warmup_tau_s: float = 900.0

    def K(self, temp) -> np.ndarray:
        """K(T) for scalar or array T: shape (..., 3, 3)."""
        dT = np.asarray(temp, dtype=float)[..., None] - self.t_ref
        s = np.asarray(self.scale) * (1.0 + np.asarray(self.scale_tc) * dT)
        return s[..., :, None] * (np.eye(3) + np.asarray(self.misalignment))

    def B(self, temp) -> np.ndarray:
        """B(T) in deg/s for scalar or array T: shape (..., 3)."""
        dT = np.asarray(temp, dtype=float)[..., None] - self.t_ref
        c = np.asarray(self.bias_poly)
        return c[:, 0] + dT * (c[:, 1] + dT * (c[:, 2] + dT * c[:, 3]))

    def effects(
        self,
        w_true: np.ndarray,
        specific_force: np.ndarray,
        temp_rate: np.ndarray,
        t: np.ndarray | None = None,
    ) -> np.ndarray:
        """Error (n, 3) of the effects beyond K and B, in the library's term conventions;
        ``t``, seconds since power-on, for the warm-up (none without it)."""
        e = (
            np.asarray(self.scale_quadratic) * w_true**2
            + np.asarray(self.scale_cubic) * w_true**3
            + np.asarray(self.scale_asymmetry) * np.abs(w_true)
        )
        e += specific_force @ np.asarray(self.g_sensitivity).T
        e += np.asarray(temp_rate, dtype=float)[:, None] * np.asarray(self.temp_rate)
        if t is not None and np.any(self.warmup):
            e += np.exp(-np.asarray(t, dtype=float) / self.warmup_tau_s)[:, None] * np.asarray(self.warmup)
        return e

    def with_effects(self, effects: dict | None) -> GyroUnit:
        """This unit with the effects beyond the seed-000 model set, e.g.
        ``{"scale_quadratic": [1e-6, 0, 0]}`` (names and shapes checked)."""
        changes = {}
        for name, value in (effects or {}).items():
            if name not in EFFECTS:
                raise ConfigError(f"unknown simulated effect {name!r}; known: {', '.join(EFFECTS)}")
            try:
                array = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                array = None
            if array is None or array.shape != EFFECTS[name] or not np.isfinite(array).all():
                raise ConfigError(
                    f"simulated effect {name} must be {EFFECTS[name][0]} finite numbers"
                    + (" per row, 3 rows" if len(EFFECTS[name]) == 2 else "")
                )
            changes[name] = _tuples(array) if array.ndim == 2 else tuple(float(x) for x in array)
        return replace(self, **changes)

    def noise_std(self, sample_rate: float) -> float:
        """Per-sample white-noise standard deviation over the Nyquist band."""
        return self.noise_density * np.sqrt(sample_rate / 2.0)

    def to_dict(self) -> dict[str, Any]:
        return {k: (np.asarray(v).tolist() if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> GyroUnit:
        def tup(v):
            return tuple(tup(x) for x in v) if isinstance(v, list) else v

        return cls(**{k: tup(v) for k, v in d.items()})

    @classmethod
    def seed000(cls, **overrides) -> GyroUnit:
        """The unit of seed 000 at 25 °C (Eq 23), with plausible temperature coefficients."""
        scale = np.diag(SEED000_K25)
        mis = SEED000_K25 / scale[:, None] - np.eye(3)
        bias = np.zeros((3, 4))
        bias[:, 0] = SEED000_B25
        bias[:, 1] = (4e-4, -6e-4, 3e-4)
        bias[:, 2] = (6e-6, -4e-6, 8e-6)
        bias[:, 3] = (-4e-8, 3e-8, 2e-8)
        base = dict(
            scale=tuple(scale),
            scale_tc=(3e-5, -2e-5, 4e-5),
            misalignment=_tuples(mis),
            bias_poly=_tuples(bias),
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def random(cls, rng: np.random.Generator, **overrides) -> GyroUnit:
        """A production unit: seed 000's unit with unit-to-unit spread of every parameter."""
        ref = cls.seed000()
        scale = np.asarray(ref.scale) + rng.normal(0, 1e-3, 3)
        mis = np.asarray(ref.misalignment) + rng.normal(0, 1e-3, (3, 3))
        np.fill_diagonal(mis, 0.0)
        bias = np.column_stack(
            [
                rng.normal(0, 0.03, 3),
                rng.normal(0, 1.5e-3, 3),
                rng.normal(0, 1.5e-5, 3),
                rng.normal(0, 4e-8, 3),
            ]
        )
        base = dict(
            scale=tuple(scale),
            scale_tc=tuple(rng.normal(0, 3e-5, 3)),
            misalignment=_tuples(mis),
            bias_poly=_tuples(bias),
        )
        base.update(overrides)
        return cls(**base)


def _tuples(a: np.ndarray):
    return tuple(tuple(float(x) for x in row) for row in np.asarray(a))


@dataclass
class Electronics:
    """Stateful output chain of one unit, so a long log can be rendered chunk by chunk."""

    unit: GyroUnit
    sample_rate: float
    rng: np.random.Generator
    _zi: np.ndarray | None = field(default=None, repr=False)

    def measure(
        self,
        w_true: np.ndarray,
        temp: np.ndarray,
        specific_force: np.ndarray | None = None,
        temp_rate: np.ndarray | None = None,
        t: np.ndarray | None = None,
    ) -> np.ndarray:
        """Gyro output (n, 3) float32 for true rates (n, 3) at die temperatures (n,), with the
        specific force (n, 3, g), the die's temperature rate (n, °C/min) and the time since
        power-on (n, s) the effects read."""
        u = self.unit
        K = u.K(temp)
        ideal = np.einsum("nij,nj->ni", K, w_true) + u.B(temp)
        n = len(w_true)
        ideal += u.effects(
            w_true,
            np.zeros((n, 3)) if specific_force is None else specific_force,
            np.zeros(n) if temp_rate is None else temp_rate,
            t,
        )
        a = np.exp(-2 * np.pi * u.bandwidth_hz / self.sample_rate)
        if self._zi is None:
            self._zi = ideal[0] * a
        out, self._zi = lfilter([1 - a], [1, -a], ideal, axis=0, zi=self._zi[None, :])
        self._zi = self._zi[0]
        out += self.rng.normal(0.0, u.noise_std(self.sample_rate), out.shape)
        np.clip(out, -u.full_scale, u.full_scale, out=out)
        return (np.round(out / u.lsb) * u.lsb).astype(np.float32)
