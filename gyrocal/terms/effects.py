"""Deterministic gyro errors beyond the seed-000 model, each a term the model can include.

Every term adds to the error ``e = w - w_true`` of each output axis ``a``; ``ω`` is the
true rate in the sensor frame (``rate_x/y/z``, deg/s), ``ΔT = T - t_ref`` (°C), ``dT/dt``
the temperature rate (°C/min), ``f`` the specific force the accelerometer measures (g).
Terms that depend on temperature alone (``varies_with_temperature``) cannot be told apart
from the bias at a single temperature point: they belong in temperature-continuous models,
or describe the drift of the temperature inside a point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.errors import ConfigError
from . import AXES, Term, register_term


def _degree(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 5:
        raise ConfigError(f"term {name}: degree must be an integer from 1 to 5, got {value!r}")
    return value


@register_term("bias_temp_poly")
@dataclass(frozen=True)
class BiasTempPoly(Term):
    """Bias as a polynomial in ΔT: ``e_a += Σ_k c_k ΔT^k`` (seed 003, Eq 16: the modified
    model uses ΔT and ΔT²). [deg/s per °C^k]"""

    degree: int = 2
    t_ref: float = 25.0
    unit = "deg/s/degC^k"
    needs = frozenset({"temp"})
    varies_with_temperature = True

    def __post_init__(self):
        _degree(self.degree, self.name)

    def coefficients(self):
        return [f"{self.name}.{a}.c{k}" for a in AXES for k in range(1, self.degree + 1)]

    def columns(self, data):
        dT = np.asarray(data["temp"], dtype=float) - self.t_ref
        return {f"{self.name}.{a}.c{k}": dT**k for a in AXES for k in range(1, self.degree + 1)}


@register_term("scale_temp_poly")
@dataclass(frozen=True)
class ScaleTempPoly(Term):
    """Scale factor varying with temperature: ``e_a += ω_a Σ_k s_k ΔT^k`` (seed 000 Fig. 4:
    scale linear in temperature; Eq 9). [1/°C^k]"""

    degree: int = 1
    t_ref: float = 25.0
    unit = "1/degC^k"
    needs = frozenset({"temp", "rate_x", "rate_y", "rate_z"})
    varies_with_temperature = True

    def __post_init__(self):
        _degree(self.degree, self.name)

    def coefficients(self):
        return [f"{self.name}.{a}.c{k}" for a in AXES for k in range(1, self.degree + 1)]

    def columns(self, data):
        dT = np.asarray(data["temp"], dtype=float) - self.t_ref
        return {
            f"{self.name}.{a}.c{k}": np.asarray(data[f"rate_{a}"], dtype=float) * dT**k
            for a in AXES
            for k in range(1, self.degree + 1)
        }


@register_term("misalignment_temp")
@dataclass(frozen=True)
class MisalignmentTemp(Term):
    """Cross-axis terms drifting linearly with temperature: ``e_a += ω_b m_ab ΔT``
    (package stress changing with temperature). [1/°C]"""

    t_ref: float = 25.0
    unit = "1/degC"
    needs = frozenset({"temp", "rate_x", "rate_y", "rate_z"})
    varies_with_temperature = True

    def coefficients(self):
        return [f"{self.name}.{a}.{b}" for a in AXES for b in AXES if a != b]

    def columns(self, data):
        dT = np.asarray(data["temp"], dtype=float) - self.t_ref
        return {
            f"{self.name}.{a}.{b}": np.asarray(data[f"rate_{b}"], dtype=float) * dT
            for a in AXES
            for b in AXES
            if a != b
        }


@register_term("temp_rate")
@dataclass(frozen=True)
class TempRate(Term):
    """Bias proportional to the rate of temperature change, ``e_a += c_a dT/dt``: thermal
    gradients across the sensor while it warms or cools (seed 000 Eq 9-10). The rate is the
    slope over a centred window; the window is profiled (2-900 s): a short one follows fast
    changes, a long one averages a coarse temperature sensor's steps. [deg/s per °C/min]"""

    window_s: float = 0.0  # s; 0: the session's (a typical hold), else this window
    unit = "deg/s/(degC/min)"
    needs = frozenset({"temp_rate"})
    profile = {"window_s": (2.0, 900.0)}

    def coefficients(self):
        return [f"{self.name}.{a}" for a in AXES]

    def columns(self, data):
        rate = np.asarray(
            data.temp_rate_over(self.window_s)
            if self.window_s > 0 and getattr(data, "series", None) is not None
            else data["temp_rate"],
            dtype=float,
        )
        return {f"{self.name}.{a}": rate for a in AXES}


@register_term("temp_lag")
@dataclass(frozen=True)
class TempLag(Term):
    """Bias of a die whose temperature lags the sensor's: ``e_a += c_a (T_τ − T)``, where
    ``T_τ`` is the logged temperature through a first-order lag of time constant ``τ`` (s).

    The sensor reads the package while the bias follows the die (seed 000 Eq 9-10: thermal
    gradients across the sensor); a calibration against the logged temperature then errs by
    the bias's temperature coefficient ``c_a`` times the lag, about ``−c_a τ dT/dt`` on a
    ramp (``temp_rate`` is that first-order form). ``τ`` is found by profiling; ``c_a`` is
    one per session (scope global). [deg/s/°C]"""

    tau: float = 900.0
    unit = "deg/s/degC"
    needs = frozenset({"temp_lag"})
    profile = {"tau": (60.0, 14400.0)}

    def __post_init__(self):
        if isinstance(self.tau, bool) or not isinstance(self.tau, (int, float)) or not self.tau > 0:
            raise ConfigError(f"term {self.name}: tau must be a positive number of seconds, got {self.tau!r}")

    def coefficients(self):
        return [f"{self.name}.{a}" for a in AXES]

    def columns(self, data):
        lagging = data.lag("temp", self.tau) - data.lag("temp", 0)
        return {f"{self.name}.{a}": lagging for a in AXES}


@register_term("die_temperature")
@dataclass(frozen=True)
class DieTemperature(Term):
    """The temperature every temperature dependence of the model is evaluated at: the MEMS
    die's, the logged temperature through a first-order lag of time constant ``τ`` (s).

    The sensor reads the package while the die, where scale and bias are made, follows it
    with a delay (seed 000 Eq 9-10: thermal gradients across the sensor). ``temp_lag``
    writes the first-order consequence of that, ``c (T_τ − T)``; this term moves the whole
    temperature dependence (the grid's interpolation temperature and every term of
    temperature) to ``T_τ``, so a curved dependence is felt at the die too. It adds no
    coefficient; ``τ`` is found by profiling, and ``apply`` and the firmware export run the
    same lag as a filter over the samples. [s]"""

    tau: float = 600.0
    unit = "s"
    needs = frozenset({"temp", "t"})
    profile = {"tau": (30.0, 14400.0)}
    moving_temperature = True

    def __post_init__(self):
        if isinstance(self.tau, bool) or not isinstance(self.tau, (int, float)) or not self.tau > 0:
            raise ConfigError(f"term {self.name}: tau must be a positive number of seconds, got {self.tau!r}")

    def coefficients(self):
        return []

    def columns(self, data):
        return {}

    def transform_inputs(self, data):
        """``data`` with ``temp`` at the die: each hold's mean of the lagged record (the
        logged temperature kept as ``temp_logged``). Samples are filtered by ``apply``."""
        from ..io.errors import MissingInputError
        from .signals import hold_means_of_lag

        if "t_start" not in data:
            return data
        logged = np.asarray(data.get("temp_logged", data["temp"]), dtype=float)
        die = hold_means_of_lag(data, "temp", self.tau)
        if die is None:
            raise MissingInputError(
                "the die temperature needs the session's temperature record, "
                "which these observations lack (segment the log again)"
            )
        return {**data, "temp": die, "temp_logged": logged}

    def sample_transform(self):
        return _DieFilter(self.tau)


class _DieFilter:
    """The die temperature of samples given batch by batch (``t`` in seconds)."""

    def __init__(self, tau: float):
        from .signals import LagFilter

        self.lag = LagFilter(tau)

    def __call__(self, data):
        logged = np.asarray(data["temp"], dtype=float)
        return {**data, "temp": self.lag(data["t"], logged), "temp_logged": logged}


class _RatePerAxis(Term):
    """One coefficient per output axis times a function of that axis's own rate."""

    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    @staticmethod
    def shape(rate: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def coefficients(self):
        return [f"{self.name}.{a}" for a in AXES]

    def columns(self, data):
        return {f"{self.name}.{a}": self.shape(np.asarray(data[f"rate_{a}"], dtype=float)) for a in AXES}


@register_term("scale_quadratic")
@dataclass(frozen=True)
class ScaleQuadratic(_RatePerAxis):
    """Even scale-factor nonlinearity, ``e_a += k_a ω_a²``: the same error for both turning
    directions, growing with the square of the rate. [1/(deg/s)]"""

    unit = "1/(deg/s)"

    @staticmethod
    def shape(rate):
        return np.square(rate)


@register_term("scale_cubic")
@dataclass(frozen=True)
class ScaleCubic(_RatePerAxis):
    """Odd scale-factor nonlinearity, ``e_a += k_a ω_a³``: an S-shaped deviation from the
    linear scale at high rates. [1/(deg/s)²]"""

    unit = "1/(deg/s)^2"

    @staticmethod
    def shape(rate):
        return rate**3


@register_term("scale_asymmetry")
@dataclass(frozen=True)
class ScaleAsymmetry(_RatePerAxis):
    """Scale-factor asymmetry, ``e_a += k_a |ω_a|``: a different scale factor for positive
    and negative rates (the scale is ``1 + s ± k``). [1]"""

    unit = "1"

    @staticmethod
    def shape(rate):
        return np.abs(rate)


@register_term("g_sensitivity")
@dataclass(frozen=True)
class GSensitivity(Term):
    """Acceleration (g) sensitivity of the bias, ``e_a += Σ_b G_ab f_b``: the proof mass
    responds to specific force. Needs the accelerometer columns, and mounts facing opposite
    ways (+x and -x, ...) to be told apart from the bias. [deg/s/g]"""

    unit = "deg/s/g"
    needs = frozenset({"accel_x", "accel_y", "accel_z"})

    def coefficients(self):
        return [f"{self.name}.{a}.{b}" for a in AXES for b in AXES]

    def columns(self, data):
        return {
            f"{self.name}.{a}.{b}": np.asarray(data[f"accel_{b}"], dtype=float) for a in AXES for b in AXES
        }


@register_term("g_squared")
@dataclass(frozen=True)
class GSquared(Term):
    """Anisoelasticity: the bias in the square of the specific force, ``e_a += Σ_b K_ab f_b²``
    (a proof mass stiffer along one axis than another rectifies acceleration). Even in the
    force's sign, so mounts facing opposite ways tell it from the g-sensitivity; at rest
    the squares sum to 1 g², so on a still table one column per output is the bias, and a
    protocol sees the part ``drop=`` leaves. [deg/s/g²]"""

    unit = "deg/s/g^2"
    needs = frozenset({"accel_x", "accel_y", "accel_z"})

    def coefficients(self):
        return [f"{self.name}.{a}.{b}" for a in AXES for b in AXES]

    def columns(self, data):
        return {
            f"{self.name}.{a}.{b}": np.asarray(data[f"accel_{b}"], dtype=float) ** 2
            for a in AXES
            for b in AXES
        }


@register_term("misalignment_faces")
@dataclass(frozen=True)
class MisalignmentFaces(Term):
    """The fixture's opposite faces out of parallel, ``e_a += Σ_(b≠a) D_ab s ω_b``, ``s`` the
    mount's facing (+1 on +b, -1 on -b): mounted on its -b face the unit sits at a tilt of its
    own, and the turning rate leaks into the other outputs by a misalignment that differs
    between the two faces. The misalignment fitted is their mean, ``D`` half their
    difference: the rig's, not the sensor's (a calibration applied off the fixture leaves it
    out: its ``sign`` is 0 where no face is known). Told apart only by a protocol that mounts
    both faces of an axis; one set for the session. [1]"""

    unit = "1"
    # the face is the hold's, not an input apply must have (:meth:`.signals.Inputs.__getitem__`)
    needs = frozenset({"rate_x", "rate_y", "rate_z"})
    # the fixture's faces do not change with the chamber's temperature: one set per session,
    # which a point that mounts one face of an axis alone does not leave unfitted
    scope = "global"
    reads_face = True  # the kind of input it reads is the mount (its face)

    def coefficients(self):
        return [f"{self.name}.{a}.{b}" for a in AXES for b in AXES if a != b]

    def columns(self, data):
        sign = np.asarray(data["sign"], dtype=float)
        return {
            f"{self.name}.{a}.{b}": sign * np.asarray(data[f"rate_{b}"], dtype=float)
            for a in AXES
            for b in AXES
            if a != b
        }


# Tried by the diagnosis when not in the model, in this order (ties keep it).
CANDIDATES = (
    "scale_quadratic",
    "scale_cubic",
    "scale_asymmetry",
    "g_sensitivity",
    "g_squared",
    "temp_rate",
    "temp_lag",
    "die_temperature",
    "bias_temp_poly(degree=1)",
    "scale_temp_poly(degree=1)",
    "misalignment_temp",
    "misalignment_faces",
)
