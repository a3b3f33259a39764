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
        """The soaks and rate-0 holds segmentation found (handling motion already rejected),
        inside its stable-temperature periods."""
        from ...fit.floor import MERGE_GAP_S, intersect_intervals, merge_intervals

        s = seg.segments
        pick = (s["kind"] == "soak") | ((s["kind"] == "hold") & (s["ref_rate"] == 0))
        t0, t1 = merge_intervals(
            s.loc[pick, "t_start"].to_numpy(float), s.loc[pick, "t_end"].to_numpy(float), MERGE_GAP_S
        )
        st = seg.stable_periods
        return intersect_intervals(t0, t1, st["t_start"].to_numpy(float), st["t_end"].to_numpy(float))

    def reading_blocks(self, settings: SettingsView) -> float:
        return _config(settings).block_s

    def segmentation_settings(self, values: Mapping[str, Any] | None) -> SegmentConfig:
        # None: the schema's defaults, without loading the validator
        return SegmentConfig() if values is None else SegmentConfig.from_dict(values)


TURNTABLE = register(Turntable())
