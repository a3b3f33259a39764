"""Segmentation's settings, apart from the segmentation itself, so that reading the settings
(a report's reproduce command, the workflow's planning) does not import the numerical stack."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from ...io import schema

_DEFAULTS = schema.defaults("config", "segmentation")


@dataclass(frozen=True)
class SegmentConfig:
    """Knobs of segmentation; what each means, its default and its bounds are in the config
    schema (``segmentation:``). Rates in deg/s, times in s, temperature rates in °C/min."""

    block_s: float = _DEFAULTS["block_s"]
    rate_tol_abs: float = _DEFAULTS["rate_tol_abs"]
    rate_tol_rel: float = _DEFAULTS["rate_tol_rel"]
    gap_factor: float = _DEFAULTS["gap_factor"]
    gap_bridge_s: float = _DEFAULTS["gap_bridge_s"]
    trim_s: float = _DEFAULTS["trim_s"]
    settle_s: float = _DEFAULTS["settle_s"]
    min_hold_s: float | None = _DEFAULTS["min_hold_s"]
    soak_min_s: float | None = _DEFAULTS["soak_min_s"]
    max_temp_rate: float = _DEFAULTS["max_temp_rate"]
    hold_max_temp_rate: float = _DEFAULTS["hold_max_temp_rate"]
    temp_window_s: float = _DEFAULTS["temp_window_s"]
    temp_gap: float = _DEFAULTS["temp_gap"]
    motion_sigma: float = _DEFAULTS["motion_sigma"]
    motion_floor: float = _DEFAULTS["motion_floor"]
    settling: float = _DEFAULTS["settling"]
    noise_cap: float = _DEFAULTS["noise_cap"]
    mount_min_rate: float = _DEFAULTS["mount_min_rate"]
    agree_scale: float = _DEFAULTS["agree_scale"]
    agree_bias: float = _DEFAULTS["agree_bias"]
    saturation_fraction: float = _DEFAULTS["saturation_fraction"]
    full_scale: float | None = _DEFAULTS["full_scale"]

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None, *, key: str = "segmentation") -> SegmentConfig:
        return cls(**schema.check(dict(values or {}), "config", "segmentation", key=key))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
