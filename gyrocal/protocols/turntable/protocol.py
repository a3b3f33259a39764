"""The turntable protocol (seed 000) as a registered :class:`gyrocal.protocols.registry.Protocol`:
its holds are calibrated and validated by the common model, and its calibrations, one
temperature grid per unit, are what the fleet compares across a batch and over time."""

from __future__ import annotations

from ...fit.floor import MERGE_GAP_S, intersect_intervals, merge_intervals
from ..registry import Protocol, register


def _segment(log, settings):
    from .segment import segment  # on use: a report reads the protocol without segmentation

    return segment(log, settings.segmentation)


def static(log, seg, max_temp_rate: float):
    """The soaks and rate-0 holds segmentation found (handling motion already rejected),
    inside its stable-temperature periods."""
    s = seg.segments
    pick = (s["kind"] == "soak") | ((s["kind"] == "hold") & (s["ref_rate"] == 0))
    t0, t1 = merge_intervals(
        s.loc[pick, "t_start"].to_numpy(float), s.loc[pick, "t_end"].to_numpy(float), MERGE_GAP_S
    )
    st = seg.stable_periods
    return intersect_intervals(t0, t1, st["t_start"].to_numpy(float), st["t_end"].to_numpy(float))


TURNTABLE = register(
    Protocol(
        "turntable",
        "multi-temperature turntable: soaks, constant-rate holds on several mounts (seed 000)",
        segment=_segment,
        static=static,
        top_level_settings=True,
        fleet_audits=True,
        axis_mounts=True,
        reading_blocks=lambda settings: settings.segmentation.block_s,
    )
)
