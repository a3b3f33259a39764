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
from .terms.user import load_term_file
from .thermal import check_method


@dataclass(frozen=True)
class ModelSettings:
    """The error model and how it is carried across temperature."""

    terms: tuple = DEFAULT_TERMS
    kind: str = "grid"                    # grid: per point, interpolated; or continuous
    interpolation: str = "lagrange3"      # one of thermal.METHODS (grid models)
    degree: int = 3                       # for interpolation "poly"
    reference_temperature: float = 25.0   # °C; the single-temperature comparison's point
    term_files: tuple = ()                # Python files registering the user's own terms
    expressions: tuple = ()               # (label, formula) pairs: one-line terms

    @classmethod
    def from_dict(cls, values: dict | None, *, key: str = "model") -> ModelSettings:
        values = dict(values or {})
        known = {"terms", "kind", "interpolation", "degree", "reference_temperature",
                 "term_files", "expressions"}
        for name in values:
            if name not in known:
                raise ConfigError(f"unknown setting {key}.{name}; known: {', '.join(sorted(known))}")
        term_files = tuple(str(f) for f in _sequence(values.get("term_files", ()), f"{key}.term_files"))
        for path in term_files:
            load_term_file(path)  # registers its terms before the term list is checked
        expressions = values.get("expressions") or {}
        if not isinstance(expressions, dict) or not all(isinstance(v, str) for v in expressions.values()):
            raise ConfigError(f"{key}.expressions must map names to formulas")
        expressions = tuple(sorted(expressions.items()))
        terms = tuple(_sequence(values.get("terms", DEFAULT_TERMS), f"{key}.terms"))
        kind = values.get("kind", "grid")
        if kind not in ("grid", "continuous"):
            raise ConfigError(f"{key}.kind is {kind!r}; choose grid or continuous")
        method = values.get("interpolation", "lagrange3")
        degree = values.get("degree", 3)
        check_method(method, degree, where=f"{key}.interpolation")
        ref = values.get("reference_temperature", 25.0)
        if isinstance(ref, bool) or not isinstance(ref, (int, float)) or not math.isfinite(ref):
            raise ConfigError(f"{key}.reference_temperature must be a number, got {ref!r}")
        settings = cls(terms, kind, method, degree, float(ref), term_files, expressions)
        settings.build()  # unknown terms, bad parameters, clashes: refused here
        return settings

    def term_specs(self) -> tuple:
        return self.terms + tuple({"name": "expression", "label": label, "formula": formula}
                                  for label, formula in self.expressions)

    def with_terms(self, extra: tuple) -> ModelSettings:
        """The model with ``extra`` terms added. A term of the same identity as one already
        in the model replaces it in place (a new degree, an expression's new formula)."""
        terms, expressions = list(self.terms), dict(self.expressions)
        for spec in extra:
            term = make_term(spec)
            if term.name == "expression" and term.label in expressions:
                expressions[term.label] = term.formula
                continue
            keys = [make_term(t).identity for t in terms]
            if term.identity in keys:
                terms[keys.index(term.identity)] = term.spec_string()
            else:
                terms.append(term.spec_string())
        return replace(self, terms=tuple(terms), expressions=tuple(sorted(expressions.items())))

    def build(self) -> Model:
        for path in self.term_files:
            load_term_file(path)
        return Model.from_spec(self.term_specs())

    def to_dict(self) -> dict:
        return {"terms": [t if isinstance(t, str) else dict(t) for t in self.terms],
                "kind": self.kind, "interpolation": self.interpolation, "degree": self.degree,
                "reference_temperature": self.reference_temperature,
                "term_files": list(self.term_files), "expressions": dict(self.expressions)}


@dataclass(frozen=True)
class DiagnosisSettings:
    """What the diagnosis tries, how sure it must be, and the models it compares."""

    significance: float = 0.01            # family-wise, over all candidates tried
    candidates: tuple = ()                # terms to try besides the library's
    ladder: tuple = ()                    # steps: {name, add: [terms], kind}

    @classmethod
    def from_dict(cls, values: dict | None, *, key: str = "diagnosis") -> DiagnosisSettings:
        values = dict(values or {})
        known = {"significance", "candidates", "ladder"}
        for name in values:
            if name not in known:
                raise ConfigError(f"unknown setting {key}.{name}; known: {', '.join(sorted(known))}")
        alpha = values.get("significance", 0.01)
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha < 1:
            raise ConfigError(f"{key}.significance must be between 0 and 1, got {alpha!r}")
        candidates = tuple(_sequence(values.get("candidates", ()), f"{key}.candidates"))
        for spec in candidates:
            make_term(spec)
        ladder = []
        for i, step in enumerate(_sequence(values.get("ladder", ()), f"{key}.ladder")):
            if isinstance(step, str):
                step = {"add": [step]}
            if not isinstance(step, dict) or set(step) - {"name", "add", "kind"}:
                raise ConfigError(f"{key}.ladder[{i}] must be a term or a mapping of name, add, kind")
            add = tuple(_sequence(step.get("add", ()), f"{key}.ladder[{i}].add"))
            for spec in add:
                make_term(spec)
            kind = step.get("kind")
            if kind not in (None, "grid", "continuous"):
                raise ConfigError(f"{key}.ladder[{i}].kind is {kind!r}; choose grid or continuous")
            name = step.get("name") or "+" + " +".join(make_term(a).spec_string() for a in add)
            ladder.append({"name": str(name), "add": add, "kind": kind})
        return cls(float(alpha), candidates, tuple(ladder))

    def to_dict(self) -> dict:
        return {"significance": self.significance, "candidates": list(self.candidates),
                "ladder": [{**step, "add": list(step["add"])} for step in self.ladder]}


@dataclass(frozen=True)
class Settings:
    segmentation: SegmentConfig = field(default_factory=SegmentConfig)
    model: ModelSettings = field(default_factory=ModelSettings)
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)

    @classmethod
    def from_dict(cls, values: dict | None) -> Settings:
        values = dict(values or {})
        for name in values:
            if name not in ("segmentation", "model", "diagnosis"):
                raise ConfigError(f"unknown setting {name}; known: diagnosis, model, segmentation")
        return cls(SegmentConfig.from_dict(values.get("segmentation")),
                   ModelSettings.from_dict(values.get("model")),
                   DiagnosisSettings.from_dict(values.get("diagnosis")))

    @classmethod
    def load(cls, path) -> Settings:
        try:
            return cls.from_dict(read_yaml(path))
        except ConfigError as exc:
            if exc.source is not None:
                raise
            raise ConfigError(str(exc), source=path) from None

    def to_dict(self) -> dict:
        return {"segmentation": asdict(self.segmentation), "model": self.model.to_dict(),
                "diagnosis": self.diagnosis.to_dict()}

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _sequence(value, key: str) -> list:
    if isinstance(value, (str, dict)) or not hasattr(value, "__iter__"):
        raise ConfigError(f"{key} must be a list")
    return list(value)


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
