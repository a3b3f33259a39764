"""The static protocol as a registered :class:`gyrocal.protocols.registry.Protocol`: the
sweep's windows (one per burst where a logger records in bursts) as observations at one
temperature, and the sweep's static stretches for the noise characterisation."""

from __future__ import annotations

from ..registry import Protocol, register
from ..sweep.protocol import segment_sweep, static
from .defaults import DEFAULTS

STATIC = register(
    Protocol(
        "static",
        "a unit lying still (a noise recording): windows at one temperature, the bias and the noise terms",
        segment=lambda log, settings: segment_sweep(log, settings.protocol_options("static"), name="static"),
        static=static,
        defaults=DEFAULTS,
        timed_holds=False,
        one_temperature=True,
        without=("ref_rate",),
    )
)
