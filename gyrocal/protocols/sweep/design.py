"""Designing a sweep test from the datasheet and the chamber (seed 003, Section 3.1).

Eq 18 estimates the drift from two datasheet figures, ΔE = α ΔT + β ΔT. Eq 20 keeps that
drift below the output resolution ΔE_S between temperature jumps:

    ΔT ≤ ΔE_S / (|α| + |β|)                                                   (Eq 20)

Eq 21-24 estimate how long heat takes to cross the chamber's air from the wall to the
table, and Eq 25 asks the period between jumps to be at least that long:

    t_s = C ρ L² / k,      t_p ≥ t_s                                         (Eq 24, 25)

Units of every input are in the field comments. For the L3GD20 the paper finds 0.125 °C
and t_s = 17.5209 "s". The latter is C ρ L²/k with C entered in kJ/(kg·K) next to k in
W/(m·K): the units do not cancel and the figure is in kiloseconds. In SI the same inputs
give 17 521 s (4.9 h). :meth:`SweepDesign.conduction_time` returns seconds;
:meth:`SweepDesign.conduction_time_as_printed` the paper's number. The paper then runs
0.1 °C jumps every 20 s (18 °C/h), which :func:`ramp_rate` gives.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from ...io.errors import ConfigError


@dataclass(frozen=True)
class SweepDesign:
    """Inputs of Eq 20 and 24."""

    resolution: float  # ΔE_S, deg/s per digit (the output's sensitivity)
    zero_rate_tc: float  # α, deg/s per °C ("zero-rate level change vs temperature")
    sensitivity_change: float  # β as the datasheet gives it: % of full scale over the range
    full_scale: float  # deg/s, the range β refers to
    t_min: float  # °C, operating range
    t_max: float  # °C
    specific_heat: float  # C of the chamber air, J/(kg·K)
    density: float  # ρ of the chamber air, kg/m³
    length: float  # L, wall to table centre, m
    conductivity: float  # k of the air, W/(m·K)

    def __post_init__(self):
        for name, value in asdict(self).items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"SweepDesign.{name} must be a finite number, got {value!r}")
        positive = ("resolution", "full_scale", "specific_heat", "density", "length", "conductivity")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ConfigError(f"SweepDesign.{name} must be positive, got {getattr(self, name)!r}")
        if self.t_max <= self.t_min:
            raise ConfigError(f"SweepDesign needs t_max > t_min, got {self.t_min} and {self.t_max}")

    @classmethod
    def l3gd20(cls) -> SweepDesign:
        """The paper's inputs: L3GD20 datasheet (8.75 mdps/digit, ±0.03 dps/°C, 2 % of
        250 dps over −40…85 °C) and chamber SET-Z-021 (C = 1.005 kJ/(kg·K), ρ = 1.293 kg/m³,
        L = 0.6 m, k = 0.0267 W/(m·°C))."""
        return cls(
            resolution=8.75e-3,
            zero_rate_tc=0.03,
            sensitivity_change=2.0,
            full_scale=250.0,
            t_min=-40.0,
            t_max=85.0,
            specific_heat=1005.0,
            density=1.293,
            length=0.6,
            conductivity=0.0267,
        )

    @property
    def sensitivity_tc(self) -> float:
        """β in deg/s per °C: the sensitivity change over the range, spread over it."""
        return self.sensitivity_change / 100.0 * self.full_scale / (self.t_max - self.t_min)

    def jump_interval(self) -> float:
        """Largest temperature jump (°C) whose Eq 18 drift stays within one digit (Eq 20)."""
        return jump_interval(self.resolution, self.zero_rate_tc, self.sensitivity_tc)

    def conduction_time(self) -> float:
        """Eq 24 in SI units: seconds for heat to cross the air to the table centre."""
        return conduction_time(self.specific_heat, self.density, self.length, self.conductivity)

    def conduction_time_as_printed(self) -> float:
        """The paper's figure for Eq 24: C entered in kJ/(kg·K), i.e. the SI time / 1000."""
        return self.conduction_time() / 1000.0

    def summary(self) -> dict[str, Any]:
        """The design's inputs and the figures derived from them, JSON-plain, with units."""
        return dict(
            inputs=asdict(self),
            sensitivity_tc=self.sensitivity_tc,
            jump_interval=self.jump_interval(),
            conduction_time_s=self.conduction_time(),
            conduction_time_as_printed=self.conduction_time_as_printed(),
            sensor_resolution_needed=self.jump_interval() / 2.0,
            units=dict(
                sensitivity_tc="deg/s/°C",
                jump_interval="°C",
                conduction_time_s="s",
                sensor_resolution_needed="°C",
            ),
        )


def datasheet_drift(dT, zero_rate_tc: float, sensitivity_tc: float):
    """Eq 18: the datasheet's rough drift α ΔT + β ΔT (deg/s) for ΔT in °C."""
    return (zero_rate_tc + sensitivity_tc) * dT


def jump_interval(resolution: float, zero_rate_tc: float, sensitivity_tc: float) -> float:
    """Eq 20: ΔE_S / (|α| + |β|) in °C; ΔE_S in deg/s, α and β in deg/s/°C."""
    denominator = abs(zero_rate_tc) + abs(sensitivity_tc)
    if not (resolution > 0 and denominator > 0):
        raise ConfigError(
            f"Eq 20 needs a positive resolution and drift, got {resolution!r}, |α| + |β| = {denominator!r}"
        )
    return resolution / denominator


def conduction_time(specific_heat: float, density: float, length: float, conductivity: float) -> float:
    """Eq 24: t_s = C ρ L² / k in s, with C in J/(kg·K), ρ in kg/m³, L in m, k in W/(m·K)."""
    if min(specific_heat, density, length, conductivity) <= 0:
        raise ConfigError("Eq 24 needs positive specific heat, density, length and conductivity")
    return specific_heat * density * length**2 / conductivity


def ramp_rate(step: float, period: float) -> float:
    """The mean ramp rate (°C/h) of jumps of ``step`` °C every ``period`` s (Eq 20 and 25)."""
    if not (step > 0 and period > 0):
        raise ConfigError(f"ramp rate needs a positive step and period, got {step!r} and {period!r}")
    return step / period * 3600.0
