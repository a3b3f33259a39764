"""End-of-line limits (:class:`SpecLimits`, from the config's ``spec``: every key checked)
and the parameter patterns they are written with (``scale.x``, ``bias.*``).
"""

from __future__ import annotations

import fnmatch
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ..io.errors import ConfigError

NOISE_LIMITS = {
    "arw": ("angle random walk", "deg/√h"),
    "bias_instability": ("bias instability", "deg/h"),
    "rrw": ("rate random walk", "deg/h/√h"),
    "quantisation": ("quantisation noise", "arcsec"),
}
_PATTERN = re.compile(r"^[A-Za-z0-9_*?]+(\.[A-Za-z0-9_*?]+)*$")


def check_patterns(patterns: Iterable[str], key: str) -> None:
    """Parameter patterns (``scale.x``, ``bias.*``) must be well formed and their first
    part must name a registered term, so that a typo is refused rather than never checked."""
    from ..terms import TERMS

    for p in patterns:
        if not isinstance(p, str) or not _PATTERN.match(p):
            raise ConfigError(f"{key}: {p!r} is not a parameter name or pattern like 'scale.x' or 'bias.*'")
        term = p.split(".")[0]
        if not any(fnmatch.fnmatchcase(t, term) for t in TERMS):
            raise ConfigError(f"{key}: {p!r} names no known term (known: {', '.join(sorted(TERMS))})")


def match_pattern(patterns: Iterable[str], name: str) -> str | None:
    """The pattern that governs ``name``: an exact name first, else the matching pattern with
    the most literal characters (``scale.x*`` before ``scale.*`` before ``*``), else None."""
    best, best_key = None, None
    for p in patterns:
        if not fnmatch.fnmatchcase(name, p):
            continue
        key = (p == name, len(p) - p.count("*") - p.count("?"))
        if best_key is None or key > best_key:
            best, best_key = p, key
    return best


def finite_number(value, key: str, *, positive: bool = False, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{key} must be a finite number, got {value!r}")
    if integer and value != int(value):
        raise ConfigError(f"{key} must be a whole number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{key} must be positive, got {value!r}")
    return float(value)


def _range(value, key: str) -> tuple[float, float]:
    """A limit: a number L means ±L; a pair [low, high] an explicit range."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{key} must be a number (±limit) or [low, high], got {value!r}")
        lo, hi = (finite_number(v, key) for v in value)
        if lo > hi:
            raise ConfigError(f"{key}: low {lo:g} exceeds high {hi:g}")
        return lo, hi
    limit = finite_number(value, key, positive=True)
    return -limit, limit


@dataclass(frozen=True)
class SpecLimits:
    """End-of-line limits; any limit left out is not checked.

    ``parameters``: pattern -> (low, high) at ``temperature`` (default: each calibration's
    reference temperature), display units. ``temperature_coefficients``: pattern -> largest
    allowed |d/dT| over the calibrated span (display unit per °C). ``validation_rms`` (deg/s)
    and ``excess`` (validation RMS over the noise floor) from the validation summary.
    ``temperature_span``: the calibrated points must reach both ends (°C), within
    ``temperature_span_tolerance``. ``min_holds``, ``min_hold_share`` (accepted holds over
    candidate holds, 0–1) and ``min_temperature_points`` from the segmentation info.
    ``noise``: the largest axis' IEEE Std 952 term of the session's static data, from the
    calibration file's ``noise`` (:data:`NOISE_LIMITS` names the terms and units).
    ``fail_on_warnings``: true fails a unit with any plausibility warning in its calibration
    file (:mod:`gyrocal.io.plausibility`), a list of codes fails those only.
    """

    parameters: tuple[tuple[str, tuple[float, float]], ...] = ()
    temperature_coefficients: tuple[tuple[str, float], ...] = ()
    temperature: float | None = None
    validation_rms: float | None = None
    excess: float | None = None
    temperature_span: tuple[float, float] | None = None
    temperature_span_tolerance: float = 0.0
    min_holds: int | None = None
    min_hold_share: float | None = None
    min_temperature_points: int | None = None
    noise: tuple[tuple[str, float], ...] = ()
    fail_on_warnings: bool | tuple[str, ...] = False

    KEYS = (
        "parameters",
        "temperature_coefficients",
        "temperature",
        "validation_rms",
        "excess",
        "temperature_span",
        "temperature_span_tolerance",
        "min_holds",
        "min_hold_share",
        "min_temperature_points",
        "noise",
        "fail_on_warnings",
    )

    @classmethod
    def from_dict(cls, d: Mapping | None, key: str = "spec") -> SpecLimits:
        d = {} if d is None else d
        if not isinstance(d, Mapping):
            raise ConfigError(f"{key} must be a mapping, got {type(d).__name__}")
        unknown = sorted(str(k) for k in d if k not in cls.KEYS)
        if unknown:
            raise ConfigError(f"unknown setting {key}.{unknown[0]}; known: {', '.join(cls.KEYS)}")
        out: dict = {}
        for name in ("parameters", "temperature_coefficients"):
            section = d.get(name) or {}
            if not isinstance(section, Mapping):
                raise ConfigError(f"{key}.{name} must be a mapping of parameter patterns to limits")
            check_patterns(section, f"{key}.{name}")
            if name == "parameters":
                out[name] = tuple((p, _range(v, f"{key}.{name}.{p}")) for p, v in section.items())
            else:
                out[name] = tuple(
                    (p, finite_number(v, f"{key}.{name}.{p}", positive=True)) for p, v in section.items()
                )
        section = d.get("noise") or {}
        if not isinstance(section, Mapping) or any(k not in NOISE_LIMITS for k in section):
            raise ConfigError(f"{key}.noise must map noise terms ({', '.join(NOISE_LIMITS)}) to limits")
        out["noise"] = tuple(
            (k, finite_number(v, f"{key}.noise.{k}", positive=True)) for k, v in section.items()
        )
        for name in ("temperature", "validation_rms", "excess", "min_hold_share"):
            if d.get(name) is not None:
                out[name] = finite_number(d[name], f"{key}.{name}", positive=name != "temperature")
        if out.get("min_hold_share", 0.0) > 1.0:
            raise ConfigError(f"{key}.min_hold_share is a share (0 to 1), got {d['min_hold_share']!r}")
        for name in ("min_holds", "min_temperature_points"):
            if d.get(name) is not None:
                out[name] = int(finite_number(d[name], f"{key}.{name}", positive=True, integer=True))
        if d.get("temperature_span") is not None:
            span = d["temperature_span"]
            if not isinstance(span, (list, tuple)) or len(span) != 2:
                raise ConfigError(f"{key}.temperature_span must be [low, high] in °C, got {span!r}")
            out["temperature_span"] = _range(span, f"{key}.temperature_span")
        if d.get("temperature_span_tolerance") is not None:
            tol = finite_number(d["temperature_span_tolerance"], f"{key}.temperature_span_tolerance")
            if tol < 0:
                raise ConfigError(f"{key}.temperature_span_tolerance must be at least 0, got {tol!r}")
            out["temperature_span_tolerance"] = tol
        if d.get("fail_on_warnings") is not None:
            out["fail_on_warnings"] = _warning_codes(d["fail_on_warnings"], f"{key}.fail_on_warnings")
        return cls(**out)

    def to_dict(self) -> dict[str, Any]:
        d = {
            "parameters": {p: (list(r) if r[0] != -r[1] else r[1]) for p, r in self.parameters},
            "temperature_coefficients": dict(self.temperature_coefficients),
        }
        if self.noise:
            d["noise"] = dict(self.noise)
        for name in self.KEYS[2:-2]:
            value = getattr(self, name)
            if value is not None:
                d[name] = list(value) if isinstance(value, tuple) else value
        if self.fail_on_warnings:
            w = self.fail_on_warnings
            d["fail_on_warnings"] = list(w) if isinstance(w, tuple) else w
        return d


def _warning_codes(value, key: str) -> bool | tuple[str, ...]:
    """true, false, or a list of plausibility warning codes (each checked: a typo is refused)."""
    from ..io.plausibility import CODES

    if isinstance(value, bool):
        return value
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{key} must be true, false or a list of warning codes, got {value!r}")
    unknown = [v for v in value if v not in CODES]
    if unknown:
        raise ConfigError(f"{key}: {unknown[0]!r} is no warning code (known: {', '.join(CODES)})")
    return tuple(value)
