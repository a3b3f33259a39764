"""The config and manifest schemas (``gyrocal/io/schemas/*.schema.yaml``): the one place that
holds the settings' bounds and defaults.

The workflow checks its whole config and the library each section with :func:`check`, so
a bad value gets the same one-line :class:`ConfigError` naming its key, from the workflow
or the command line.
"""

from __future__ import annotations

import copy
import math
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from .errors import ConfigError

if TYPE_CHECKING:
    import jsonschema

FOLDER = Path(__file__).with_name("schemas")

# libyaml's safe loader where PyYAML was built with it: the pure-Python one takes a fifth
# of a second over the config schema, at every start of a command.
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_TYPE_NAMES = {
    "number": "a number",
    "integer": "a whole number",
    "string": "a string",
    "array": "a list",
    "object": "a mapping",
    "boolean": "true or false",
    "null": "null",
}
_BOUNDS = {
    "minimum": "at least",
    "exclusiveMinimum": "more than",
    "maximum": "at most",
    "exclusiveMaximum": "less than",
}


def refuse_duplicate_keys(text: str, source=None) -> None:
    """Raise :class:`ConfigError` where a YAML mapping names a key twice: YAML keeps the last
    and drops the first without a word (a second ``models:`` pasted below a first would
    take every unit's own model away)."""
    try:
        root = yaml.compose(text, Loader=SAFE_LOADER)
    except yaml.YAMLError:
        return  # the load that follows says what is wrong
    stack = [root] if root is not None else []
    while stack:
        node = stack.pop()
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key, value in node.value:
                name = getattr(key, "value", None)
                if isinstance(name, str) and name in seen:
                    raise ConfigError(
                        f"line {key.start_mark.line + 1}: {name} is given twice (first on "
                        f"line {seen[name]}); YAML would keep only the second: merge them",
                        source=source,
                    )
                seen[name] = key.start_mark.line + 1
                stack.append(value)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)


@cache
def load(name: str) -> dict[str, Any]:
    """The schema ``name`` (``config`` or ``manifest``)."""
    return yaml.load((FOLDER / f"{name}.schema.yaml").read_text(), Loader=SAFE_LOADER)


def section(name: str, path: str = "") -> dict[str, Any]:
    """The part of schema ``name`` that describes the settings at the dotted ``path``."""
    part = load(name)
    for key in filter(None, path.split(".")):
        part = part["properties"][key]
    return part


@cache
def _validator_class():
    """The validator, made on the first check: jsonschema's import is a tenth of a second
    that reading the defaults (a report, the workflow's planning) does not need."""
    import jsonschema

    # A number is finite and not a boolean, a whole number an int: YAML reads .inf, .nan,
    # true and 3.0 as numbers, and none of them is a setting. A list may be a tuple: the
    # library's callers pass either.
    types = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine_many(
        {
            "number": lambda _, v: (
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            ),
            "integer": lambda _, v: isinstance(v, int) and not isinstance(v, bool),
            "array": lambda _, v: isinstance(v, (list, tuple)),
        }
    )
    return jsonschema.validators.extend(jsonschema.Draft202012Validator, type_checker=types)


@cache
def _validator(name: str, path: str):
    # The section is checked with the whole schema as its root, for its $refs to resolve.
    validator = _validator_class()
    root = validator(load(name), format_checker=validator.FORMAT_CHECKER)
    return root.evolve(schema=section(name, path)) if path else root


def defaults(name: str, path: str = "") -> dict[str, Any]:
    """The defaults the schema gives the settings of one section."""
    return {
        key: copy.deepcopy(prop["default"])
        for key, prop in section(name, path).get("properties", {}).items()
        if "default" in prop
    }


def check(
    values, name: str = "config", path: str = "", *, key: str | None = None, source=None
) -> dict[str, Any]:
    """``values`` checked against the section ``path`` of schema ``name``: a copy with the
    schema's defaults filled in. The first violation raises :class:`ConfigError` naming its
    key, written from ``key`` (the section's path unless given).

    Defaults fill the sections written out under ``properties``; a ``$ref`` (a protocol's
    override of the model) is left as given, what it leaves out being the protocol's."""
    import jsonschema

    error = jsonschema.exceptions.best_match(_validator(name, path).iter_errors(values))
    if error is not None:
        raise ConfigError(_message(error, path if key is None else key), source=source)
    values = copy.deepcopy(values)
    _fill(values, section(name, path))
    return values


def _fill(values, part: dict) -> None:
    if not isinstance(values, dict):
        return
    for key, prop in part.get("properties", {}).items():
        if key not in values and "default" in prop:
            values[key] = copy.deepcopy(prop["default"])
        if key in values:
            _fill(values[key], prop)


def _join(key: str, path) -> str:
    for part in path:
        key = f"{key}[{part}]" if isinstance(part, int) else f"{key}.{part}" if key else str(part)
    return key


def _message(error: jsonschema.ValidationError, key: str = "") -> str:
    """One line naming the key (``key`` then the error's path) and what is wrong with it."""
    key, kind, value, part = _join(key, error.absolute_path), error.validator, error.instance, error.schema
    if kind == "additionalProperties" and part.get("additionalProperties") is False:
        unknown = sorted(set(value) - set(part.get("properties", {})))
        return f"unknown setting {_join(key, unknown[:1])}; known: {', '.join(sorted(part['properties']))}"
    if kind == "required":
        return f"missing setting {_join(key, [r for r in error.validator_value if r not in value][:1])}"
    return f"{key} {_phrase(error)}".strip()


def _phrase(error: jsonschema.ValidationError) -> str:
    kind, value, part, bound = error.validator, error.instance, error.schema, error.validator_value
    if "errorMessage" in part:  # the schema's own wording for this setting
        return f"{value!r} {part['errorMessage']}"
    if kind == "type":
        names = [bound] if isinstance(bound, str) else bound
        return f"must be {' or '.join(_TYPE_NAMES[n] for n in names)}, got {value!r}"
    if kind in _BOUNDS:
        return f"must be {_BOUNDS[kind]} {bound:g}, got {value!r}"
    if kind == "enum":
        title = f"{part['title']} " if "title" in part else ""
        choices = ", ".join("null" if c is None else str(c) for c in bound)
        return f"{title}{value!r} is not known; choose one of {choices}"
    if kind in ("minItems", "maxItems"):
        items = f"{bound} item{'s' if bound != 1 else ''}"
        if part.get("minItems") == part.get("maxItems"):
            return f"must hold {items}, got {value!r}"
        return f"must hold {'at least' if kind == 'minItems' else 'at most'} {items}, got {value!r}"
    if kind == "pattern":
        return f"{value!r} does not match {bound}"
    if kind == "minLength" and bound == 1:
        return f"{value!r} is empty"
    if kind in ("oneOf", "anyOf") and "description" in part:
        return f"must be {part['description']}, got {value!r}"
    return error.message
