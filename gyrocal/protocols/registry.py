"""The protocols gyrocal calibrates: what a protocol provides (:class:`Protocol`) and the
registry that names them, as the terms are named (:mod:`gyrocal.terms`).

A protocol says how a log of it becomes observations in the common hold schema
(:mod:`gyrocal.io.holds`), where the sensor sat still (the noise characterisation's static
stretches), how it is calibrated and validated when not by the common model, what the
report shows of its own methods, and what the fleet may do with it. Everything else asks
the registry (:func:`get`); no other module compares a protocol's name.

A built-in protocol is a package of the same shape (``gyrocal/protocols/turntable``,
``…/servo``, ``…/sweep``, ``…/ferraris``, ``…/static``): its ``defaults`` module holds its
settings by default, its ``protocol`` module defines the :class:`Protocol` and registers
it. They are imported on first use, so a turntable job never loads the servo's or the
sweep's code, and reading the settings loads none.
"""

from __future__ import annotations

import copy
import importlib
import typing
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, TypedDict

from ..io import schema
from ..io.errors import ConfigError, GyrocalError

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

    from ..calibration.file import Calibration
    from ..fit.validate import Validation
    from ..io.holds import Segmentation
    from ..io.log import RigLog

DEFAULT = "turntable"
BUILTIN = {
    name: f"gyrocal.protocols.{name}.protocol"
    for name in ("turntable", "servo", "sweep", "ferraris", "static")
}
_REGISTRY: dict[str, Protocol] = {}


class SegmentationSettings(typing.Protocol):
    """The config's top-level ``segmentation:`` settings as the protocol that owns them
    reads them (:meth:`Protocol.segmentation_settings`)."""

    @property
    def max_temp_rate(self) -> float:
        """°C/min: the steadiest temperature a static stretch may drift at, for the noise
        characterisation of every protocol."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """The settings as the config writes them (the settings hash reads this)."""
        ...


class ModelView(typing.Protocol):
    @property
    def reference_temperature(self) -> float: ...


class SettingsView(typing.Protocol):
    """What a protocol reads of a run's settings (:class:`gyrocal.pipeline.config.Settings`)."""

    @property
    def segmentation(self) -> SegmentationSettings: ...

    @property
    def model(self) -> ModelView: ...

    def protocol_options(self, protocol: str) -> dict[str, Any]: ...


class ProtocolDefaults(TypedDict):
    """A protocol's settings by default, which the config's ``protocols.<name>`` overrides
    key by key: its segmenter's options, its model and its diagnosis."""

    options: dict[str, Any]
    model: dict[str, Any]
    diagnosis: dict[str, Any]


class OwnAnalysis(NamedTuple):
    """A protocol's own methods on its observations, for the report: JSON-plain results
    (None: it has none beside the common ones) and SVG figures."""

    results: Mapping[str, Any] | None
    figures: list[str]


class Protocol(ABC):
    """One calibration protocol: what a subclass defines and the registry hands out.

    Two methods every protocol has: :meth:`segment` and :meth:`static`. The optional parts
    are None unless the protocol has them (a subclass defines them as methods), and the
    attributes say what the rest of gyrocal may do with its results."""

    name: ClassVar[str]
    description: ClassVar[str]

    # The protocol's own calibration and validation, in place of the common model's fit and
    # leave-temperature-out validation: calibrate(obs, settings, meta, provenance) and
    # validate(obs, cal).
    calibrate: Callable[[pd.DataFrame, SettingsView, dict, dict], Calibration] | None = None
    validate: Callable[[pd.DataFrame, Calibration], Validation] | None = None
    # Its own methods for the report: analysis(obs).
    analysis: Callable[[pd.DataFrame], OwnAnalysis] | None = None
    # The figure of its own validation's hold table (a servo's revolution errors), in place
    # of the common validation's figures: validation_figure(holds) -> SVG.
    validation_figure: Callable[[pd.DataFrame], str] | None = None
    # The block length (s) its segmenter starts from, when it works from block statistics
    # (gyrocal.io.blocks): they are made while the log is read, and a log too large to keep
    # in memory is read again for what needs samples. None: the segmenter reads whole
    # columns, and the log is kept in memory.
    reading_blocks: Callable[[SettingsView], float] | None = None

    # The unit report's own parts (templates under gyrocal/report/templates/protocols):
    # sections 2-3 in place of the common ones, a section 5a of its own methods, and how
    # the headline names its validated RMS.
    report_sections: ClassVar[str | None] = None
    report_section: ClassVar[str | None] = None
    validated_as: ClassVar[str | None] = None

    # Columns of the log read where it has them (the mount, the accelerometer): what the
    # segmenter and the observations use beyond the required ones.
    optional_columns: ClassVar[tuple[str, ...]] = ("mount", "accel_x", "accel_y", "accel_z")

    # Whether static stretches follow the table's turning: an output still settling from
    # the last rate (a slow pole) is trimmed from each before the noise model reads it
    # (:func:`gyrocal.fit.floor.settled_start`).
    static_after_turning: ClassVar[bool] = False

    # The config's top-level settings are this protocol's (segmentation:, model:,
    # diagnosis:); the others take theirs from ``protocols.<name>`` over ``defaults``.
    top_level_settings: ClassVar[bool] = False
    defaults: ClassVar[ProtocolDefaults | None] = None
    # Observations carry the true rate vector, so a calibration can be re-validated on
    # another session (drift audits, the diagnosis' other session). A servo's hand mount
    # leaves the rate's direction unknown.
    known_rate: ClassVar[bool] = True
    # Calibrations are temperature grids of one model, comparable across a batch and across
    # a device's sessions: the fleet's outlier table and drift pages.
    fleet_audits: ClassVar[bool] = False
    # Each hold turns one sensor axis (its mount) about the rig axis, which points up:
    # gravity shows along the mount on the accelerometer, and a balanced protocol turns
    # every axis both ways (the plausibility review checks both).
    axis_mounts: ClassVar[bool] = False
    # Contract columns the protocol can do without (a hand has no encoder; a bench session
    # may log no temperature): read when present, otherwise ref_rate reads 0 and temp the
    # model's reference temperature, and the calibration's warnings say so.
    without: ClassVar[tuple[str, ...]] = ()
    # The protocol runs at one temperature by design: one temperature point is no warning.
    one_temperature: ClassVar[bool] = False
    # Its holds last as long as the rig held them (a sweep's windows have a set length):
    # their typical length tells the time base's unit (the plausibility review).
    timed_holds: ClassVar[bool] = True

    @abstractmethod
    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        """The log's observations, in the hold schema (:mod:`gyrocal.io.holds`)."""

    @abstractmethod
    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        """(t_start, t_end) of the stretches where the sensor sat still at a temperature
        drifting no faster than ``max_temp_rate`` °C/min."""

    def segmentation_settings(self, values: Mapping[str, Any] | None) -> SegmentationSettings | None:
        """The config's ``segmentation:`` section read as this protocol's settings, checked
        against the config schema (``values`` None: the defaults), by the protocol whose
        settings are the top-level ones (:func:`top_level`); None for the others, whose
        settings are ``protocols.<name>``."""
        return None

    def __repr__(self) -> str:
        return f"<protocol {self.name}>"


def register(protocol: Protocol) -> Protocol:
    if protocol.name in _REGISTRY and _REGISTRY[protocol.name] is not protocol:
        raise ConfigError(f"protocol {protocol.name!r} is registered twice")
    _REGISTRY[protocol.name] = protocol
    return protocol


def names() -> tuple[str, ...]:
    """Every protocol this version of gyrocal knows, built-in first."""
    return tuple(BUILTIN) + tuple(n for n in _REGISTRY if n not in BUILTIN)


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


def top_level() -> Protocol:
    """The protocol whose settings are the config's top-level ones: the default."""
    protocol = get(DEFAULT)
    assert protocol.top_level_settings, f"the default protocol {DEFAULT} owns the top-level settings"
    return protocol


def settings_defaults(name: str) -> ProtocolDefaults | None:
    """A protocol's own settings by default (:attr:`Protocol.defaults`), None when the
    config's top-level settings are its own. A built-in protocol's are read from its
    package's ``defaults`` module, so that loading a config imports no protocol's code."""
    if name not in _REGISTRY and name in BUILTIN:
        defaults: ProtocolDefaults | None = importlib.import_module(
            BUILTIN[name].rsplit(".", 1)[0] + ".defaults"
        ).DEFAULTS
        return defaults
    protocol = get(name)
    return None if protocol.top_level_settings else protocol.defaults


def option_defaults(name: str) -> dict[str, Any]:
    """The options of protocol ``name``'s segmenter by default, from the config schema
    (``$defs/<name>_options``): the one place that holds them and their bounds."""
    properties = options_schema(name)["properties"]
    return {key: copy.deepcopy(prop["default"]) for key, prop in properties.items() if "default" in prop}


def options_schema(name: str) -> dict[str, Any]:
    """The config schema's ``protocols.<name>.options``, its reference followed."""
    ref = schema.section("config", f"protocols.{name}")["properties"]["options"]["$ref"]
    part: dict[str, Any] = schema.load("config")
    for key in ref.removeprefix("#/").split("/"):
        part = part[key]
    return part


def checked_options(name: str, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """``options`` of protocol ``name``'s segmenter checked against the config schema (a
    bad value is a one-line :class:`ConfigError` naming it) and completed with the
    schema's defaults."""
    given = schema.check(dict(options or {}), "config", f"protocols.{name}.options")
    return {**option_defaults(name), **given}


def analysis(name: str | None, obs: pd.DataFrame) -> OwnAnalysis:
    """The protocol's own methods on its observations (:attr:`Protocol.analysis`); a
    failure is recorded in the results, since the report's common sections still stand."""
    protocol = get(name)
    if protocol.analysis is None:
        return OwnAnalysis(None, [])
    try:
        return protocol.analysis(obs)
    except GyrocalError as exc:
        return OwnAnalysis({"protocol": protocol.name, "error": str(exc)}, [])
