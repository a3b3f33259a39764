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


EXPRESSION_KEYS = frozenset({"formula", "parameters", "profile", "scope"})


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
        if not isinstance(expressions, dict) or not all(
                isinstance(v, str) or (isinstance(v, dict) and isinstance(v.get("formula"), str)
                                       and set(v) <= EXPRESSION_KEYS) for v in expressions.values()):
            raise ConfigError(f"{key}.expressions must map names to formulas, or to mappings of "
                              f"{', '.join(sorted(EXPRESSION_KEYS))} (formula required)")
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
        return self.terms + tuple(
            {"name": "expression", "label": label,
             **({"formula": value} if isinstance(value, str) else value)}
            for label, value in self.expressions)

    def with_terms(self, extra: tuple) -> ModelSettings:
        """The model with ``extra`` terms added. A term of the same identity as one already
        in the model replaces it in place (a new degree, an expression's new formula)."""
        terms, expressions = list(self.terms), dict(self.expressions)
        for spec in extra:
            term = make_term(spec)
            if term.name == "expression" and term.label in expressions:
                spec = {k: v for k, v in term.spec().items() if k not in ("name", "label")}
                expressions[term.label] = spec["formula"] if set(spec) == {"formula"} else spec
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


# What the servo and sweep protocols fit and try by default; ``protocols:`` in the config
# overrides any of it. Sweep: seed 003's conventional drift model (linear in ΔT, fitted
# jointly over the sweep) with its modified model (Eq 16, + ΔT²) as the candidate and the
# ladder's step. Servo: the 12-parameter model on whole-revolution means (the hand-mounting
# tilt of each axis lands in the misalignment), beside the paper's own six-parameter fit.
PROTOCOL_DEFAULTS = {
    "servo": {"options": {}, "model": {"terms": list(DEFAULT_TERMS)}, "diagnosis": {}},
    "sweep": {"options": {"window_s": 20.0, "point_span": 10.0},
              "model": {"kind": "continuous", "terms": ["bias", "bias_temp_poly(degree=1)"]},
              "diagnosis": {"candidates": ["bias_temp_poly(degree=2)"],
                            "ladder": [{"name": "modified: + ΔT² (seed 003 Eq 16)",
                                        "add": ["bias_temp_poly(degree=2)"]}]}},
}
PROTOCOL_OPTIONS = {"servo": {"min_revolutions"},
                    "sweep": {"window_s", "point_span", "motion_factor", "settle_windows", "fill",
                              "min_span", "min_windows"}}


@dataclass(frozen=True)
class Settings:
    segmentation: SegmentConfig = field(default_factory=SegmentConfig)
    model: ModelSettings = field(default_factory=ModelSettings)
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    protocols: tuple = ()       # (name, {options, model, diagnosis}) overrides, checked
    resolved_for: str | None = None   # the protocol for_protocol() has settled these for

    @classmethod
    def from_dict(cls, values: dict | None) -> Settings:
        values = dict(values or {})
        for name in values:
            if name not in ("segmentation", "model", "diagnosis", "protocols"):
                raise ConfigError(f"unknown setting {name}; known: diagnosis, model, protocols, "
                                  "segmentation")
        model = ModelSettings.from_dict(values.get("model"))  # registers the user's terms first
        protocols = values.get("protocols") or {}
        if not isinstance(protocols, dict):
            raise ConfigError("protocols must map protocol names to settings")
        checked = []
        for name, section in sorted(protocols.items()):
            if name not in PROTOCOL_DEFAULTS:
                raise ConfigError(f"unknown protocol protocols.{name}; known: "
                                  f"{', '.join(sorted(PROTOCOL_DEFAULTS))}")
            section = _mapping(section, f"protocols.{name}")
            for key in section:
                if key not in ("options", "model", "diagnosis"):
                    raise ConfigError(f"unknown setting protocols.{name}.{key}; known: "
                                      "diagnosis, model, options")
            for key, value in _mapping(section.get("options"), f"protocols.{name}.options").items():
                if key not in PROTOCOL_OPTIONS[name]:
                    raise ConfigError(f"unknown setting protocols.{name}.options.{key}; known: "
                                      f"{', '.join(sorted(PROTOCOL_OPTIONS[name]))}")
                _check_option(f"protocols.{name}.options.{key}", key, value)
            ModelSettings.from_dict(_mapping(section.get("model"), f"protocols.{name}.model"),
                                    key=f"protocols.{name}.model")
            DiagnosisSettings.from_dict(_mapping(section.get("diagnosis"), f"protocols.{name}.diagnosis"),
                                        key=f"protocols.{name}.diagnosis")
            checked.append((name, section))
        return cls(SegmentConfig.from_dict(values.get("segmentation")), model,
                   DiagnosisSettings.from_dict(values.get("diagnosis")), tuple(checked))

    def for_protocol(self, protocol: str | None) -> Settings:
        """The settings a log of ``protocol`` is processed with: the turntable's are the
        top-level ones; servo and sweep take their defaults, overridden key by key by
        ``protocols.<name>`` (the significance level is the top-level one unless set)."""
        if protocol in (None, "turntable") or protocol not in PROTOCOL_DEFAULTS \
                or self.resolved_for == protocol:
            return self
        default = PROTOCOL_DEFAULTS[protocol]
        override = dict(self.protocols).get(protocol, {})
        # The user's term files and one-line terms serve every protocol.
        model = {**default["model"], "term_files": list(self.model.term_files),
                 "expressions": dict(self.model.expressions), **(override.get("model") or {})}
        diagnosis = {"significance": self.diagnosis.significance, **default["diagnosis"],
                     **(override.get("diagnosis") or {})}
        return replace(self, model=ModelSettings.from_dict(model, key=f"protocols.{protocol}.model"),
                       diagnosis=DiagnosisSettings.from_dict(diagnosis,
                                                             key=f"protocols.{protocol}.diagnosis"),
                       resolved_for=protocol)

    def protocol_options(self, protocol: str) -> dict:
        default = PROTOCOL_DEFAULTS.get(protocol, {}).get("options", {})
        return {**default, **(dict(self.protocols).get(protocol, {}).get("options") or {})}

    @classmethod
    def load(cls, path) -> Settings:
        try:
            return cls.from_dict(read_yaml(path))
        except ConfigError as exc:
            if exc.source is not None:
                raise
            raise ConfigError(str(exc), source=path) from None

    def to_dict(self) -> dict:
        out = {"segmentation": asdict(self.segmentation), "model": self.model.to_dict(),
               "diagnosis": self.diagnosis.to_dict()}
        if self.protocols:
            out["protocols"] = {name: section for name, section in self.protocols}
        return out

    def sha256(self) -> str:
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


# Protocol options: (type, lowest allowed value, whether the lowest is allowed).
OPTION_RANGES = {"window_s": (float, 0.0, False), "point_span": (float, 0.0, False),
                 "motion_factor": (float, 0.0, False), "fill": (float, 0.0, False),
                 "min_span": (float, 0.0, False), "min_windows": (int, 1, True),
                 "settle_windows": (int, 0, True), "min_revolutions": (int, 1, True)}


def _check_option(key: str, name: str, value) -> None:
    kind, low, inclusive = OPTION_RANGES[name]
    ok_type = (isinstance(value, int) if kind is int else isinstance(value, (int, float))) \
        and not isinstance(value, bool)
    if not ok_type or not math.isfinite(value) or value < low or (value == low and not inclusive) \
            or (name == "fill" and value > 1):
        what = "a whole number" if kind is int else "a number"
        bound = f"{'at least' if inclusive else 'above'} {low:g}" + (" and at most 1" if name == "fill" else "")
        raise ConfigError(f"{key} must be {what} {bound}, got {value!r}")


def _mapping(value, key: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key} must be a mapping, got {value!r}")
    return dict(value)


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
