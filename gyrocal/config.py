"""Settings of a calibration run: segmentation knobs and the model, from YAML or dicts.

Every key is checked: an unknown key or a bad value is a :class:`ConfigError` naming it.
The settings hash (``sha256``) goes into each calibration file, so a file says which
settings made it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import yaml

from .errors import ConfigError, CorruptFileError
from .model import DEFAULT_TERMS, Model
from .segment import SegmentConfig
from .terms import make_term
from .thermal import check_method


@dataclass(frozen=True)
class ModelSettings:
    """The error model and how it is carried across temperature."""

    terms: tuple = DEFAULT_TERMS
    interpolation: str = "lagrange3"      # one of thermal.METHODS
    degree: int = 3                       # for interpolation "poly"
    reference_temperature: float = 25.0   # °C; the single-temperature comparison's point

    @classmethod
    def from_dict(cls, values: dict | None, *, key: str = "model") -> ModelSettings:
        values = dict(values or {})
        known = {"terms", "interpolation", "degree", "reference_temperature"}
        for name in values:
            if name not in known:
                raise ConfigError(f"unknown setting {key}.{name}; known: {', '.join(sorted(known))}")
        terms = values.get("terms", DEFAULT_TERMS)
        if isinstance(terms, (str, dict)) or not hasattr(terms, "__iter__"):
            raise ConfigError(f"{key}.terms must be a list of term names or mappings")
        terms = tuple(terms)
        for spec in terms:
            make_term(spec)  # raises on unknown names or bad parameters
        method = values.get("interpolation", "lagrange3")
        degree = values.get("degree", 3)
        check_method(method, degree, where=f"{key}.interpolation")
        ref = values.get("reference_temperature", 25.0)
        if isinstance(ref, bool) or not isinstance(ref, (int, float)) or not math.isfinite(ref):
            raise ConfigError(f"{key}.reference_temperature must be a number, got {ref!r}")
        return cls(terms, method, degree, float(ref))

    def with_terms(self, extra: tuple) -> ModelSettings:
        names = [t if isinstance(t, str) else t.get("name") for t in self.terms]
        added = tuple(t for t in extra if t not in names)
        return replace(self, terms=self.terms + added) if added else self

    def build(self) -> Model:
        return Model.from_spec(self.terms)

    def to_dict(self) -> dict:
        return {"terms": [t if isinstance(t, str) else dict(t) for t in self.terms],
                "interpolation": self.interpolation, "degree": self.degree,
                "reference_temperature": self.reference_temperature}


@dataclass(frozen=True)
class Settings:
    segmentation: SegmentConfig = field(default_factory=SegmentConfig)
    model: ModelSettings = field(default_factory=ModelSettings)

    @classmethod
    def from_dict(cls, values: dict | None) -> Settings:
        values = dict(values or {})
        for name in values:
            if name not in ("segmentation", "model"):
                raise ConfigError(f"unknown setting {name}; known: model, segmentation")
        return cls(SegmentConfig.from_dict(values.get("segmentation")),
                   ModelSettings.from_dict(values.get("model")))

    @classmethod
    def load(cls, path) -> Settings:
        try:
            return cls.from_dict(read_yaml(path))
        except ConfigError as exc:
            if exc.source is not None:
                raise
            raise ConfigError(str(exc), source=path) from None

    def to_dict(self) -> dict:
        return {"segmentation": asdict(self.segmentation), "model": self.model.to_dict()}

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def read_yaml(path) -> dict:
    path = Path(path)
    try:
        values = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"not valid YAML ({' '.join(str(exc).split())})", source=path) from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise ConfigError("must hold a mapping of settings", source=path)
    return values
