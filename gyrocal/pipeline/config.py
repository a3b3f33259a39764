"""Settings of a calibration run: segmentation knobs and the model, from YAML or dicts.

The top-level ``segmentation:`` section is read by the protocol that owns the top-level
settings (:meth:`gyrocal.protocols.registry.Protocol.segmentation_settings`); the other
protocols' options are their ``protocols.<name>`` sections over their defaults.

Every key is checked against the config schema (``gyrocal/io/schemas/config.schema.yaml``, which
holds the bounds and defaults; :mod:`gyrocal.io.schema`): an unknown key or a bad value is a
:class:`ConfigError` naming it. The settings hash (``sha256``) goes into each calibration
file, so a file says which settings made it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from ..fit.model import DEFAULT_TERMS, Model
from ..io import schema
from ..io.errors import ConfigError, CorruptFileError
from ..protocols import registry
from ..protocols.registry import ProtocolDefaults, SegmentationSettings
from ..terms import make_term
from ..terms.user import load_term_file

_MODEL = schema.defaults("config", "model")
_DIAGNOSIS = schema.defaults("config", "diagnosis")


@dataclass(frozen=True)
class ModelSettings:
    """The error model and how it is carried across temperature (the schema's ``model:``)."""

    terms: tuple = DEFAULT_TERMS
    kind: str = _MODEL["kind"]
    interpolation: str = _MODEL["interpolation"]
    degree: int = _MODEL["degree"]
    reference_temperature: float = _MODEL["reference_temperature"]
    term_files: tuple = tuple(_MODEL["term_files"])
    expressions: tuple = tuple(sorted(_MODEL["expressions"].items()))  # (label, formula) pairs

    @classmethod
    def from_dict(cls, values: dict | None, *, key: str = "model") -> ModelSettings:
        values = schema.check(values or {}, "config", "model", key=key)
        term_files = tuple(str(f) for f in values["term_files"])
        for path in term_files:
            load_term_file(path)  # registers its terms before the term list is checked
        settings = cls(
            tuple(values.get("terms", DEFAULT_TERMS)),
            values["kind"],
            values["interpolation"],
            values["degree"],
            float(values["reference_temperature"]),
            term_files,
            tuple(sorted((values["expressions"] or {}).items())),
        )
        settings.build()  # unknown terms, bad parameters, clashes: refused here
        return settings

    def term_specs(self) -> tuple:
        return self.terms + tuple(
            {
                "name": "expression",
                "label": label,
                **({"formula": value} if isinstance(value, str) else value),
            }
            for label, value in self.expressions
        )

    def with_terms(self, extra: tuple) -> ModelSettings:
        """The model with ``extra`` terms added. A term of the same identity as one already
        in the model replaces it in place (a new degree, an expression's new formula)."""
        terms, expressions = list(self.terms), dict(self.expressions)
        for spec in extra:
            term = make_term(spec)
            label = getattr(term, "label", None)  # an expression's (or a restriction of one)
            if term.name == "expression" and label in expressions:
                spec = {k: v for k, v in term.spec().items() if k not in ("name", "label")}
                expressions[label] = spec["formula"] if set(spec) == {"formula"} else spec
                continue
            keys = [make_term(t).identity for t in terms]
            if term.identity in keys:
                terms[keys.index(term.identity)] = term.spec_string()
            else:
                terms.append(term.spec_string())
        return replace(self, terms=tuple(terms), expressions=tuple(sorted(expressions.items())))

    def changed(self, entry: dict, *, key: str = "models") -> ModelSettings:
        """The model as a ``models:`` entry changes it for some units: each of the entry's keys
        replaces this model's, and ``add`` puts terms on its list."""
        values = {**self.to_dict(), **{k: v for k, v in entry.items() if k != "add"}}
        return ModelSettings.from_dict(values, key=key).with_terms(tuple(entry.get("add", ())))

    def build(self) -> Model:
        for path in self.term_files:
            load_term_file(path)
        return Model.from_spec(self.term_specs())

    def to_dict(self) -> dict[str, Any]:
        return {
            "terms": [t if isinstance(t, str) else dict(t) for t in self.terms],
            "kind": self.kind,
            "interpolation": self.interpolation,
            "degree": self.degree,
            "reference_temperature": self.reference_temperature,
            "term_files": list(self.term_files),
            "expressions": dict(self.expressions),
        }


@dataclass(frozen=True)
class DiagnosisSettings:
    """What the diagnosis tries, how sure it must be, and the models it compares (the
    schema's ``diagnosis:``)."""

    significance: float = _DIAGNOSIS["significance"]
    candidates: tuple = tuple(_DIAGNOSIS["candidates"])
    ladder: tuple = tuple(_DIAGNOSIS["ladder"])  # steps: {name, add: [terms], kind}
    turn_on_repeatability: float | None = None  # deg/s, 1 sigma: the sensor's datasheet's
    seating_repeatability: float | None = None  # µrad, 1 sigma (None: the diagnosis' default)

    @classmethod
    def from_dict(cls, values: dict | None, *, key: str = "diagnosis") -> DiagnosisSettings:
        values = schema.check(values or {}, "config", "diagnosis", key=key)
        candidates = tuple(values["candidates"])
        for spec in candidates:
            make_term(spec)
        ladder = []
        for step in values["ladder"]:
            if isinstance(step, str):
                step = {"add": [step]}
            add = tuple(step.get("add", ()))
            for spec in add:
                make_term(spec)
            name = step.get("name") or "+" + " +".join(make_term(a).spec_string() for a in add)
            ladder.append({"name": str(name), "add": add, "kind": step.get("kind")})
        repeatability = values.get("turn_on_repeatability")
        seating = values.get("seating_repeatability")
        return cls(
            float(values["significance"]),
            candidates,
            tuple(ladder),
            None if repeatability is None else float(repeatability),
            None if seating is None else float(seating),
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "significance": self.significance,
            "candidates": list(self.candidates),
            "ladder": [{**step, "add": list(step["add"])} for step in self.ladder],
        }
        if self.turn_on_repeatability is not None:  # unset, the settings' digest stays as it was
            out["turn_on_repeatability"] = self.turn_on_repeatability
        if self.seating_repeatability is not None:
            out["seating_repeatability"] = self.seating_repeatability
        return out


def segmentation_settings(values: dict | None = None) -> SegmentationSettings:
    """The config's ``segmentation:`` section as the top-level protocol reads it."""
    protocol = registry.top_level()
    settings = protocol.segmentation_settings(values)
    if settings is None:
        raise ConfigError(f"protocol {protocol.name} owns the top-level settings but reads no segmentation:")
    return settings


@dataclass(frozen=True)
class Settings:
    segmentation: SegmentationSettings = field(default_factory=segmentation_settings)
    model: ModelSettings = field(default_factory=ModelSettings)
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    protocols: tuple = ()  # (name, {options, model, diagnosis}) overrides, checked
    resolved_for: str | None = None  # the protocol for_protocol() has settled these for
    unit_model: tuple | None = None  # (key, entry): the config's models: entry this unit takes
    fleet_model: ModelSettings | None = None  # the model before the unit's entry, or before drops

    @classmethod
    def from_dict(cls, values: dict | None) -> Settings:
        values = dict(values or {})
        for name in values:
            if name not in ("segmentation", "model", "diagnosis", "protocols", "unit"):
                raise ConfigError(f"unknown setting {name}; known: diagnosis, model, protocols, segmentation")
        model = ModelSettings.from_dict(values.get("model"))  # registers the user's terms first
        unit_model, fleet_model = _unit_model(values.get("unit")), None
        if unit_model is not None:
            fleet_model, model = model, model.changed(unit_model[1], key=f"models.{unit_model[0]}")
        protocols = values.get("protocols") or {}
        if not isinstance(protocols, dict):
            raise ConfigError("protocols must map protocol names to settings")
        checked = []
        for name, section in sorted(protocols.items()):
            own = _own_settings()
            if name not in own:
                raise ConfigError(f"unknown protocol protocols.{name}; known: {', '.join(sorted(own))}")
            section = schema.check(section or {}, "config", f"protocols.{name}")  # options too
            ModelSettings.from_dict(section.get("model"), key=f"protocols.{name}.model")
            DiagnosisSettings.from_dict(section.get("diagnosis"), key=f"protocols.{name}.diagnosis")
            checked.append((name, section))
        return cls(
            segmentation_settings(values.get("segmentation")),
            model,
            DiagnosisSettings.from_dict(values.get("diagnosis")),
            tuple(checked),
            unit_model=unit_model,
            fleet_model=fleet_model,
        )

    def for_protocol(self, protocol: str | None) -> Settings:
        """The settings a log of ``protocol`` is processed with: the turntable's are the
        top-level ones; servo and sweep take their defaults
        (:attr:`gyrocal.protocols.registry.Protocol.defaults`), overridden key by key by
        ``protocols.<name>`` (the significance level is the top-level one unless set)."""
        if protocol is None or self.resolved_for == protocol or protocol not in _own_settings():
            return self
        default = _own_settings()[protocol]
        override = dict(self.protocols).get(protocol, {})
        # The user's term files and one-line terms serve every protocol.
        model_values = {
            **default["model"],
            "term_files": list(self.model.term_files),
            "expressions": dict(self.model.expressions),
            **(override.get("model") or {}),
        }
        diagnosis = {
            "significance": self.diagnosis.significance,
            # the sensor's, whatever the protocol
            "turn_on_repeatability": self.diagnosis.turn_on_repeatability,
            "seating_repeatability": self.diagnosis.seating_repeatability,
            **default["diagnosis"],
            **(override.get("diagnosis") or {}),
        }
        model = fleet = ModelSettings.from_dict(model_values, key=f"protocols.{protocol}.model")
        if self.unit_model is not None:
            model = model.changed(self.unit_model[1], key=f"models.{self.unit_model[0]}")
        return replace(
            self,
            model=model,
            fleet_model=fleet if self.unit_model is not None else None,
            diagnosis=DiagnosisSettings.from_dict(diagnosis, key=f"protocols.{protocol}.diagnosis"),
            resolved_for=protocol,
        )

    def protocol_options(self, protocol: str) -> dict[str, Any]:
        """The options of ``protocol``'s segmenter: its defaults (the config schema's),
        overridden key by key by ``protocols.<name>.options``."""
        own = _own_settings().get(protocol)
        default = own["options"] if own is not None else {}
        return {**default, **(dict(self.protocols).get(protocol, {}).get("options") or {})}

    @classmethod
    def load(cls, path) -> Settings:
        try:
            return cls.from_dict(read_yaml(path))
        except ConfigError as exc:
            if exc.source is not None:
                raise
            raise ConfigError(str(exc), source=path) from None

    @property
    def fleet(self) -> ModelSettings:
        """The fleet's model for this unit: before its ``models:`` entry and before the terms
        its data could not identify were dropped."""
        return self.fleet_model or self.model

    def to_dict(self) -> dict[str, Any]:
        # the fleet's model and the unit's entry, as the workflow hands them to a job
        model = self.fleet if self.unit_model is not None else self.model
        out = {
            "segmentation": self.segmentation.to_dict(),
            "model": model.to_dict(),
            "diagnosis": self.diagnosis.to_dict(),
        }
        if self.protocols:
            out["protocols"] = {name: section for name, section in self.protocols}
        if self.unit_model is not None:
            out["unit"] = {"entry": self.unit_model[0], "model": self.unit_model[1]}
        return out

    @property
    def model_entry(self) -> str | None:
        """The key of the config's ``models:`` entry these settings take (None: the fleet's)."""
        return None if self.unit_model is None else self.unit_model[0]

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _unit_model(values) -> tuple | None:
    """``unit: {entry, model}`` of a unit's settings (the workflow's: the config's ``models:``
    entry the unit takes, :func:`gyrocal.fleet.manifest.model_entry`), checked."""
    if values is None:
        return None
    if not isinstance(values, dict) or set(values) != {"entry", "model"}:
        raise ConfigError("unit must map entry (the models: key) and model (its changes)")
    key = str(values["entry"])
    entry = schema.check({key: values["model"]}, "config", "models")[key]
    return key, entry


def read_yaml(path) -> dict[str, Any]:
    """The mapping of settings a YAML file holds, as written (an empty file: none)."""
    path = Path(path)
    try:
        text = path.read_text()
        schema.refuse_duplicate_keys(text, source=path)
        values = yaml.load(text, Loader=schema.SAFE_LOADER)
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"not valid YAML ({' '.join(str(exc).split())})", source=path) from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise ConfigError("must hold a mapping of settings", source=path)
    return values


def _own_settings() -> dict[str, ProtocolDefaults]:
    """The default settings of each protocol whose settings are not the top-level ones."""
    own = {n: registry.settings_defaults(n) for n in registry.names()}
    return {n: d for n, d in own.items() if d is not None}
