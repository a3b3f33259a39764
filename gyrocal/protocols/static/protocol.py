"""The static protocol as a registered :class:`gyrocal.protocols.registry.Protocol`: the
sweep's windows (one per burst where a logger records in bursts) as observations at one
temperature, and the sweep's static stretches for the noise characterisation."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..registry import Protocol, SettingsView, register
from ..sweep.protocol import segment_sweep, static_windows
from .defaults import DEFAULTS

if TYPE_CHECKING:
    import numpy as np

    from ...io.holds import Segmentation
    from ...io.log import RigLog


class Static(Protocol):
    name = "static"
    description = (
        "a unit lying still (a noise recording): windows at one temperature, the bias and the noise terms"
    )
    defaults = DEFAULTS
    timed_holds = False
    one_temperature = True
    without = ("ref_rate",)

    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        return segment_sweep(log, settings.protocol_options("static"), name="static")

    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        return static_windows(seg, max_temp_rate)


STATIC = register(Static())
