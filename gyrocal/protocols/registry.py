"""The protocols gyrocal calibrates, one :class:`Protocol` object each, registered by name
as the terms are (:mod:`gyrocal.terms`).

A protocol is a package of the same shape (``gyrocal/turntable``, ``gyrocal/servo``,
``gyrocal/sweep``): its ``protocol`` module builds the object and registers it. The object
says how a log of the protocol becomes observations in the common hold schema
(:mod:`gyrocal.io.holds`), where the sensor sat still (the noise characterisation's static
stretches), how it is calibrated and validated when not by the common model, what the
report shows of its own methods, and what the fleet may do with it. Everything else asks
the registry (:func:`get`); no other module compares a protocol's name.

The built-in protocols are imported on first use, so a turntable job never loads the
servo's or the sweep's code.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field

from ..io.errors import ConfigError

DEFAULT = "turntable"
BUILTIN = {
    name: f"gyrocal.protocols.{name}.protocol"
    for name in ("turntable", "servo", "sweep", "ferraris", "static")
}
_REGISTRY: dict[str, Protocol] = {}


@dataclass(frozen=True)
class Protocol:
    """One calibration protocol.

    ``segment(log, settings)`` → :class:`gyrocal.io.holds.Segmentation` of the log's
    observations; ``static(log, seg, max_temp_rate)`` → (t_start, t_end) arrays of the
    stretches where the sensor sat still at a steady temperature. ``calibrate(obs,
    settings, meta, provenance)`` and ``validate(obs, cal)`` replace the common model's fit
    and leave-temperature-out validation where the protocol has its own (None: the common
    ones). ``analysis(obs)`` → (JSON-plain results, SVG figures) of the protocol's own
    methods for the report (None: it has none beside the common ones);
    ``validation_figure(holds)`` → SVG of its own validation's hold table."""

    name: str
    description: str
    segment: Callable
    static: Callable
    calibrate: Callable | None = None
    validate: Callable | None = None
    analysis: Callable | None = None
    # The figure of its own validation's table (a servo's revolution errors), in place of
    # the common validation's figures.
    validation_figure: Callable | None = None
    # The unit report's own parts (templates under gyrocal/report/templates/protocols): sections
    # 2-3 in place of the common ones, a section 5a of its own methods, and how the headline
    # names its validated RMS.
    report_sections: str | None = None
    report_section: str | None = None
    validated_as: str | None = None
    # The config's top-level settings are this protocol's; the others take theirs from
    # ``protocols.<name>`` over ``defaults`` (options, model, diagnosis).
    top_level_settings: bool = False
    defaults: dict = field(default_factory=dict)
    # Observations carry the true rate vector, so a calibration can be re-validated on
    # another session (drift audits, the diagnosis' other session). A servo's hand mount
    # leaves the rate's direction unknown.
    known_rate: bool = True
    # settings -> the block length (s) the segmenter starts from, when it works from block
    # statistics (gyrocal.io.blocks): they are made while the log is read, and a log too large
    # to keep in memory is read again for what needs samples. None: the segmenter reads
    # whole columns, and the log is kept in memory.
    reading_blocks: Callable | None = None
    # Calibrations are temperature grids of one model, comparable across a batch and across
    # a device's sessions: the fleet's outlier table and drift pages.
    fleet_audits: bool = False
    # Each hold turns one sensor axis (its mount) about the rig axis, which points up: gravity
    # shows along the mount on the accelerometer, and a balanced protocol turns every axis
    # both ways (gyrocal.io.plausibility checks both).
    axis_mounts: bool = False
    # Contract columns the protocol can do without (a hand has no encoder; a bench session
    # may log no temperature): read when present, otherwise ref_rate reads 0 and temp the
    # model's reference temperature, and the calibration's warnings say so.
    without: tuple[str, ...] = ()
    # The protocol runs at one temperature by design: one temperature point is no warning.
    one_temperature: bool = False
    # Its holds last as long as the rig held them (a sweep's windows have a set length):
    # their typical length tells the time base's unit (gyrocal.io.plausibility.time_base).
    timed_holds: bool = True


def register(protocol: Protocol) -> Protocol:
    if protocol.name in _REGISTRY and _REGISTRY[protocol.name] is not protocol:
        raise ConfigError(f"protocol {protocol.name!r} is registered twice")
    _REGISTRY[protocol.name] = protocol
    return protocol


def names() -> tuple[str, ...]:
    """Every protocol this version of gyrocal knows, built-in first."""
    return tuple(BUILTIN) + tuple(n for n in _REGISTRY if n not in BUILTIN)


def settings_defaults(name: str) -> dict | None:
    """A protocol's own settings by default (:attr:`Protocol.defaults`), None when the
    config's top-level settings are its own. A built-in protocol's are read from its
    package's ``defaults`` module, so that loading a config imports no protocol's code."""
    if name not in _REGISTRY and name in BUILTIN:
        return importlib.import_module(BUILTIN[name].rsplit(".", 1)[0] + ".defaults").DEFAULTS
    protocol = get(name)
    return None if protocol.top_level_settings else protocol.defaults


def get(name: str | None) -> Protocol:
    """The protocol called ``name`` (None: the default, the turntable)."""
    name = name or DEFAULT
    if name not in _REGISTRY and name in BUILTIN:
        importlib.import_module(BUILTIN[name])
    if name not in _REGISTRY:
        raise ConfigError(
            f"protocol {name!r} is not supported by this version of gyrocal (supported: {', '.join(names())})"
        )
    return _REGISTRY[name]


def analysis(name: str | None, obs) -> tuple[dict | None, list[str]]:
    """The protocol's own methods on its observations (:attr:`Protocol.analysis`); a
    failure is recorded in the results, since the report's common sections still stand."""
    from ..io.errors import GyrocalError

    protocol = get(name)
    if protocol.analysis is None:
        return None, []
    try:
        return protocol.analysis(obs)
    except GyrocalError as exc:
        return {"protocol": protocol.name, "error": str(exc)}, []
