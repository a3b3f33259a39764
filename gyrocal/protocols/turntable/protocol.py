"""The turntable protocol (seed 000) as a registered :class:`gyrocal.protocols.registry.Protocol`:
its holds are calibrated and validated by the common model, and its calibrations, one
temperature grid per unit, are what the fleet compares across a batch and over time. Its
settings are the config's top-level ones (``segmentation:``: :class:`.config.SegmentConfig`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, cast

from ..registry import Protocol, SettingsView, register
from .config import SegmentConfig

if TYPE_CHECKING:
    import numpy as np

    from ...io.holds import Segmentation
    from ...io.log import RigLog


def _config(settings: SettingsView) -> SegmentConfig:
    """The segmentation settings, which this protocol made (:meth:`Turntable.segmentation_settings`)."""
    return cast(SegmentConfig, settings.segmentation)


class Turntable(Protocol):
    name = "turntable"
    description = "multi-temperature turntable: soaks, constant-rate holds on several mounts (seed 000)"
    top_level_settings = True
    fleet_audits = True
    axis_mounts = True
    static_after_turning = True

    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        from .segment import segment  # on use: a report reads the protocol without segmentation

        return segment(log, _config(settings))

    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        """The soaks and the rate-0 holds segmentation kept (handling motion already
        rejected) whose output does not settle within them, inside its stable-temperature
        periods: a hold right after a step of the table's rate, whose output still follows
        that step (a slow pole), is shaped by the effect and would make the floor of it."""
        import numpy as np

        from ...fit.floor import MERGE_GAP_S, intersect_intervals, merge_intervals

        s = seg.segments
        soaks = s[s["kind"] == "soak"]
        still = _settled_rate_zero_holds(seg.observations)
        t0, t1 = merge_intervals(
            np.r_[soaks["t_start"].to_numpy(float), still["t_start"].to_numpy(float)],
            np.r_[soaks["t_end"].to_numpy(float), still["t_end"].to_numpy(float)],
            MERGE_GAP_S,
        )
        st = seg.stable_periods
        return intersect_intervals(t0, t1, st["t_start"].to_numpy(float), st["t_end"].to_numpy(float))

    def reading_blocks(self, settings: SettingsView) -> float:
        return _config(settings).block_s

    def segmentation_settings(self, values: Mapping[str, Any] | None) -> SegmentConfig:
        # None: the schema's defaults, without loading the validator
        return SegmentConfig() if values is None else SegmentConfig.from_dict(values)


SETTLED_SIGMAS = 5.0  # a rate-0 hold's halves this many of their own σ apart: settling


def _settled_rate_zero_holds(obs):
    """The rate-0 holds whose output's change from the first half to the second
    (``settle_*``) is within :data:`SETTLED_SIGMAS` of the halves' own noise on every axis."""
    import numpy as np

    if obs is None or obs.empty or "settle_x" not in obs:
        return obs.iloc[:0] if obs is not None else obs
    zero = obs[obs["ref_rate"] == 0]
    noise = np.sqrt(4.0 / zero["n"].to_numpy(float))
    settled = np.ones(len(zero), dtype=bool)
    for a in ("x", "y", "z"):
        change = np.abs(zero[f"settle_{a}"].to_numpy(float))
        settled &= ~(change > SETTLED_SIGMAS * zero[f"std_{a}"].to_numpy(float) * noise)
    return zero[settled]


TURNTABLE = register(Turntable())
