"""The import map: which source column or topic becomes which log column, in which unit.

The map is checked whole before any data is read, so a typo in a 5 GB conversion fails in
a millisecond with the key it is about, not after the file has been read. Every value is
converted to the contract's units on import (deg/s, g, °C, s): the log then needs no
``gyrocal.units`` entry and any tool that reads the contract reads it right.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..io import AXES
from ..io.errors import ConfigError
from ..io.log import SECTIONS, UNIT_FACTORS

FORMATS = ("csv", "tsv", "ros2", "mcap")
TABULAR = ("csv", "tsv")
# Factor to the contract's unit, as a log's declared units convert (gyrocal.io.log); "counts"
# takes its factor from the sensitivity.
RATE_UNITS = {**UNIT_FACTORS["gyro"], "counts": None}
ACCEL_UNITS = {"g": 1.0, "m/s^2": UNIT_FACTORS["accel"]["m/s^2"], "mg": 1e-3, "counts": None}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
TEMP_UNITS = ("degC", "K", "degF")
# A temperature in counts, as IMUs report it: (counts - offset) / sensitivity, the
# sensitivity in LSB per degC and the offset in counts (the datasheet's "T = counts / 340
# + 36.53" is sensitivity 340, offset -12420.2).
TEMP_SCALES = {**{u: 1.0 for u in TEMP_UNITS}, "counts": None}
TIME_SOURCES = ("header", "log")

# Keys allowed at each level (strict: an unknown key is most often a typo).
TOP_KEYS = (
    "format",
    "delimiter",
    "decimal",
    "comment",
    "units_row",
    "time",
    "gyro",
    "accel",
    "temp",
    "ref_rate",
    "mount",
    "sections",
    "topics",
)
TABULAR_KEYS = ("gyro", "accel", "temp", "ref_rate", "mount", "delimiter", "decimal", "comment", "units_row")
TRIAD_KEYS = ("x", "y", "z", "unit", "sensitivity", "offset")
TOPIC_KEYS = ("imu", "temperature", "ref_rate")
HELD_KEYS = ("topic", "field", "unit", "sensitivity", "offset")

# Without a map, a table is taken in the contract's own column names and units; its
# optional columns only where the file has them.
CONTRACT_NAMES = {
    "time": {"column": "t", "unit": "s"},
    "gyro": {"x": "gyro_x", "y": "gyro_y", "z": "gyro_z", "unit": "deg/s"},
    "accel": {"x": "accel_x", "y": "accel_y", "z": "accel_z", "unit": "g"},
    "temp": {"column": "temp", "unit": "degC"},
    "ref_rate": {"column": "ref_rate", "unit": "deg/s"},
    "mount": {"column": "mount"},
}

# The suffixes a format is recognised by (after a compression suffix, which Arrow's CSV
# reader undoes on its own).
SUFFIXES = {".csv": "csv", ".tsv": "tsv", ".tab": "tsv", ".mcap": "mcap", ".db3": "ros2"}
COMPRESSED = (".gz", ".bz2", ".zst", ".lz4")


@dataclass(frozen=True)
class Scaled:
    """One source quantity and how to bring it to the contract's unit:
    ``(raw - offset) * factor`` (or, for temperatures, the unit's own conversion)."""

    unit: str
    factor: float = 1.0
    offset: tuple[float, ...] = (0.0,)  # one value, or one per axis

    def apply(self, values, axis: int = 0):
        offset = self.offset[axis if len(self.offset) > 1 else 0]
        if self.unit in TEMP_UNITS:
            if self.unit == "K":
                return values - 273.15
            if self.unit == "degF":
                return (values - 32.0) * (5.0 / 9.0)
            return values
        if offset:
            values = values - offset
        return values * self.factor if self.factor != 1.0 else values


@dataclass(frozen=True)
class Held:
    """A bag topic whose last value is held onto the IMU's samples (temperature, reference)."""

    topic: str
    field: str | None  # None: the message type's own value field
    scale: Scaled


@dataclass(frozen=True)
class ImportMap:
    """A checked map. Column names refer to the source file; ``raw`` is the map as
    normalised, recorded in the output's provenance."""

    format: str
    delimiter: str = ","
    decimal: str = "."  # the decimal separator ("," in much of the world)
    comment: str | None = None  # lines starting with it are skipped
    units_row: bool = False  # a row of units under the header
    sort: bool = False  # order the rows by the time (or index) column
    time_column: str | None = None
    time_factor: float | None = None  # seconds per time unit
    sample_rate: float | None = None  # t = index / rate (index: time_column or row)
    time_source: str = "header"  # bags: header stamp or log (receive) time
    gyro: tuple[str, str, str] | None = None
    gyro_scale: Scaled | None = None
    accel: tuple[str, str, str] | None = None
    accel_scale: Scaled | None = None
    temp: str | None = None
    temp_scale: Scaled | None = None
    ref_rate: str | None = None
    ref_scale: Scaled | None = None
    ref_value: float | None = None  # a constant reference (deg/s): a static log
    mount: str | None = None
    imu_topic: str | None = None
    temperature: Held | None = None
    ref_topic: Held | None = None
    sections: dict[str, tuple[int, int]] | None = None
    sections_file: str | None = None
    section_column: str | None = None  # the annotation as a label on every row
    optional_defaults: bool = False  # no map: optional columns taken only when present
    raw: dict = field(default_factory=dict, compare=False)

    @property
    def is_tabular(self) -> bool:
        return self.format in TABULAR

    def without(self, names) -> ImportMap:
        """The map without the optional quantities ``names`` (accel, temp, ref_rate, mount)."""
        scales = {"accel": "accel_scale", "temp": "temp_scale", "ref_rate": "ref_scale"}
        drop = {n: None for n in names} | {scales[n]: None for n in names if n in scales}
        if "ref_rate" in names:
            drop["ref_value"] = None
        return replace(self, **drop, raw={k: v for k, v in self.raw.items() if k not in names})

    def columns(self) -> dict[str, str]:
        """Source column -> what it is in the map (for messages), tabular formats only."""
        out = {}
        if self.time_column:
            out[self.time_column] = "time.column"
        for name, cols in (("gyro", self.gyro), ("accel", self.accel)):
            for axis, col in zip(AXES, cols or (), strict=False):
                out.setdefault(col, f"{name}.{axis}")
        for name in ("temp", "ref_rate", "mount"):
            if getattr(self, name):
                out.setdefault(getattr(self, name), f"{name}.column")
        if self.section_column:
            out.setdefault(self.section_column, "sections.column")
        return out

    def text_columns(self) -> list[str]:
        """The mapped columns read as text (labels), not numbers."""
        return [c for c in (self.mount, self.section_column) if c]


def format_of(source: Path) -> str | None:
    """The format a source's name or kind says, or None."""
    if source.is_dir():
        return "ros2"
    suffixes = [s.lower() for s in source.suffixes]
    if suffixes and suffixes[-1] in COMPRESSED:
        suffixes = suffixes[:-1]
    return SUFFIXES.get(suffixes[-1]) if suffixes else None


def load_map(
    map_path: str | Path | None,
    source: Path,
    *,
    fmt: str | None = None,
    sample_rate: float | None = None,
    sections: str | Path | None = None,
) -> ImportMap:
    """The checked map from ``map_path`` (YAML; None: none) and the command line's flags,
    which take precedence. Raises a :class:`ConfigError` naming the map file and the key."""
    where = map_path if map_path is not None else "the command line"
    values: dict = {}
    if map_path is not None:
        values = _read_yaml(Path(map_path))
    check = _Checker(where)
    check.keys(values, TOP_KEYS, "the map")
    if fmt is not None:
        values["format"] = fmt
    chosen = values.get("format")
    if chosen is None:
        chosen = format_of(source)
        if chosen is None:
            raise ConfigError(
                f"cannot tell the format from the name; give --format or "
                f"format: in the map ({', '.join(FORMATS)})",
                source=source,
            )
    check.choice(chosen, FORMATS, "format")
    if sample_rate is not None:
        time = dict(values.get("time") or {})
        if "unit" in time:
            raise ConfigError(
                "--sample-rate conflicts with time.unit: a time column in a unit, or a sample rate, not both",
                source=where,
            )
        values["time"] = {**time, "sample_rate": sample_rate}
    if sections is not None:
        values["sections"] = str(sections)
        sections_base = Path()  # the command line's paths are the caller's
    else:
        sections_base = Path(map_path).parent if map_path is not None else Path()
    if chosen in TABULAR:
        optional = map_path is None
        if optional:  # no map: the contract's names, the optional columns where present
            values = {**CONTRACT_NAMES, **{k: v for k, v in values.items() if v is not None}}
        spec = _tabular(values, chosen, check)
        spec["optional_defaults"] = optional
    else:
        spec = _bag(values, chosen, check)
    if values.get("sections") is not None:
        path = values["sections"]
        if isinstance(path, dict):
            check.keys(path, ("column",), "sections")
            if chosen not in TABULAR:
                check.fail(
                    f"sections.column applies to CSV/TSV; give a {chosen} source's "
                    "annotation as a section list"
                )
            spec["section_column"] = check.name(path.get("column"), "sections.column")
        elif not isinstance(path, str) or not path:
            check.fail(
                "sections must be the path of a section list, or {column: NAME}: a "
                "column that labels every row with its section"
            )
        else:
            if spec.get("sort"):
                check.fail(
                    "a section list counts the file's rows as they stand; with "
                    "time.sort give the annotation as a label column "
                    "(sections: {column: NAME})"
                )
            resolved = Path(path) if Path(path).is_absolute() else sections_base / path
            spec["sections"] = read_sections(resolved)
            spec["sections_file"] = str(resolved)
    raw = {k: v for k, v in values.items() if v is not None}
    raw["format"] = chosen
    return ImportMap(format=chosen, raw=raw, **spec)


def _read_text(path: Path, kind: str, what: str, encoding: str) -> str:
    """A small text file the user named, or a one-line error saying which and why."""
    try:
        return path.read_text(encoding=encoding)
    except FileNotFoundError:
        raise ConfigError(f"no such {kind}", source=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(
            f"cannot read {what} ({getattr(exc, 'strerror', None) or exc})", source=path
        ) from None


def _read_yaml(path: Path) -> dict:
    import yaml

    text = _read_text(path, "map file", "the map", "utf-8")
    try:
        values = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(
            f"not valid YAML{at} ({getattr(exc, 'problem', None) or exc})", source=path
        ) from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise ConfigError("the map must be a YAML mapping of keys (format, time, gyro, ...)", source=path)
    return values


class _Checker:
    """Strict checks of map values, each error one line naming the map and the key."""

    def __init__(self, where):
        self.where = where

    def fail(self, message: str):
        raise ConfigError(message, source=self.where)

    def keys(self, values, allowed, what: str) -> None:
        if not isinstance(values, dict):
            self.fail(f"{what} must be a mapping, got {values!r}")
        unknown = [k for k in values if k not in allowed]
        if unknown:
            self.fail(f"unknown key {unknown[0]!r} in {what}; expected one of {', '.join(allowed)}")

    def choice(self, value, allowed, key: str) -> None:
        if value not in allowed:
            self.fail(f"{key}: unknown value {value!r}; expected one of {', '.join(allowed)}")

    def name(self, value, key: str) -> str:
        if not isinstance(value, str) or not value:
            self.fail(
                f"{key} must name a column (a string), got {value!r}; quote names that "
                "YAML reads as numbers or booleans"
            )
        return value

    def number(self, value, key: str, *, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(f"{key} must be a number, got {value!r}")
        if positive and value <= 0:
            self.fail(f"{key} must be positive, got {value!r}")
        return float(value)

    def scale(self, spec: dict, units: dict, key: str, default: str | None = None) -> Scaled:
        """The unit, sensitivity and offset of a rate, an acceleration or a temperature in
        counts."""
        unit = spec.get("unit", default)
        if unit is None:
            self.fail(f"{key}.unit is missing; expected one of {', '.join(units)}")
        self.choice(unit, units, f"{key}.unit")
        sensitivity = spec.get("sensitivity")
        if unit == "counts":
            if sensitivity is None:
                per = "g" if units is ACCEL_UNITS else "degC" if units is TEMP_SCALES else "deg/s"
                self.fail(f"{key}: unit counts needs sensitivity (LSB per {per})")
            factor = 1.0 / self.number(sensitivity, f"{key}.sensitivity", positive=True)
        else:
            if sensitivity is not None:
                self.fail(f"{key}.sensitivity applies to unit counts only, not {unit}")
            factor = units[unit]
        offset = spec.get("offset", 0.0)
        if isinstance(offset, list):
            if len(offset) != 3:
                self.fail(f"{key}.offset takes one number or three (x, y, z), got {len(offset)}")
            offset = tuple(self.number(v, f"{key}.offset") for v in offset)
        else:
            offset = (self.number(offset, f"{key}.offset"),)
        return Scaled(unit, factor, offset)

    def triad(self, spec, key: str, units: dict) -> tuple[tuple[str, str, str], Scaled]:
        self.keys(spec, TRIAD_KEYS, key)
        missing = [a for a in AXES if a not in spec]
        if missing:
            self.fail(f"{key} lacks axis {', '.join(missing)}: map x, y and z to columns")
        cols = tuple(self.name(spec[a], f"{key}.{a}") for a in AXES)
        return cols, self.scale(spec, units, key)


def _tabular(values: dict, fmt: str, check: _Checker) -> dict:
    if values.get("topics") is not None:
        check.fail(f"topics applies to bags and MCAP files, not to {fmt}")
    spec = _text_format(values, fmt, check)
    spec.update(_time_spec(values.get("time"), check))
    if values.get("gyro") is None:
        check.fail("gyro is missing: map x, y, z to columns and give the unit")
    spec["gyro"], spec["gyro_scale"] = check.triad(values["gyro"], "gyro", RATE_UNITS)
    if values.get("accel") is not None:
        spec["accel"], spec["accel_scale"] = check.triad(values["accel"], "accel", ACCEL_UNITS)
    if values.get("temp") is not None:
        spec.update(_temp_spec(values["temp"], check))
    if values.get("ref_rate") is not None:
        spec.update(_ref_rate_spec(values["ref_rate"], check))
    if values.get("mount") is not None:
        check.keys(values["mount"], ("column",), "mount")
        spec["mount"] = check.name(values["mount"].get("column"), "mount.column")
    return spec


def _text_format(values: dict, fmt: str, check: _Checker) -> dict:
    """How the text file is written: delimiter, decimal separator, comment character, and
    whether a row of units follows the header."""
    spec: dict = {"delimiter": "\t" if fmt == "tsv" else ","}
    for key in ("delimiter", "decimal", "comment"):
        d = values.get(key)
        if d is not None:
            if not isinstance(d, str) or len(d) != 1 or d in '"\r\n':
                check.fail(f"{key} must be one character, got {d!r}")
            spec[key] = d
    if spec.get("decimal", ".") == spec["delimiter"]:
        check.fail(
            f"decimal and delimiter are both {spec['delimiter']!r}: a file with decimal "
            'commas separates its columns with another character (delimiter: ";")'
        )
    if spec.get("comment") in (spec["delimiter"], spec.get("decimal", ".")):
        check.fail(f"comment {spec['comment']!r} is also the delimiter or the decimal separator")
    if values.get("units_row") is not None:
        if not isinstance(values["units_row"], bool):
            check.fail(f"units_row must be true or false, got {values['units_row']!r}")
        spec["units_row"] = values["units_row"]
    return spec


def _time_spec(time: dict | None, check: _Checker) -> dict:
    """Where time comes from: a time column and its unit, or a sample rate (with an
    optional sample-index column); and whether to sort the rows by it."""
    if time is None:
        check.fail(
            "time is missing: give time: {column: NAME, unit: s} or a sample rate "
            "(time: {sample_rate: HZ} or --sample-rate)"
        )
    check.keys(time, ("column", "unit", "sample_rate", "sort"), "time")
    spec: dict = {}
    if time.get("sort") is not None:
        if not isinstance(time["sort"], bool):
            check.fail(f"time.sort must be true or false, got {time['sort']!r}")
        if time["sort"] and time.get("column") is None:
            check.fail("time.sort orders the rows by time.column: name the time or sample-index column")
        spec["sort"] = time["sort"]
    if "sample_rate" in time:
        if "unit" in time:
            check.fail("time: give unit (a time column) or sample_rate (a sample index), not both")
        spec["sample_rate"] = check.number(time["sample_rate"], "time.sample_rate", positive=True)
        if time.get("column") is not None:
            spec["time_column"] = check.name(time["column"], "time.column")
    else:
        spec["time_column"] = check.name(time.get("column"), "time.column")
        unit = time.get("unit")
        if unit is None:
            check.fail(f"time.unit is missing; expected one of {', '.join(TIME_UNITS)}")
        check.choice(unit, TIME_UNITS, "time.unit")
        spec["time_factor"] = TIME_UNITS[unit]
    return spec


def _temp_spec(temp, check: _Checker) -> dict:
    """The temperature column and its scale: a unit of temperature (degC, K, degF), or
    counts with their sensitivity and offset."""
    check.keys(temp, ("column", "unit", "sensitivity", "offset"), "temp")
    spec = {"temp": check.name(temp.get("column"), "temp.column")}
    unit = temp.get("unit", "degC")
    check.choice(unit, TEMP_SCALES, "temp.unit")
    if unit == "counts":
        spec["temp_scale"] = check.scale(temp, TEMP_SCALES, "temp")
        if len(spec["temp_scale"].offset) > 1:
            check.fail("temp.offset takes one number (counts)")
    else:
        if "sensitivity" in temp or "offset" in temp:
            check.fail(f"temp.sensitivity and temp.offset apply to unit counts only, not {unit}")
        spec["temp_scale"] = Scaled(unit)
    return spec


def _ref_rate_spec(ref, check: _Checker) -> dict:
    """The reference rate: a column and its scale, or a static log's one value."""
    if not isinstance(ref, dict):
        check.fail("ref_rate takes {column: NAME, unit: ...} or, for a static log, {value: 0}")
    if "value" in ref:
        # A static log's reference: the rate the rig held throughout, in deg/s.
        check.keys(ref, ("value",), "ref_rate")
        return {"ref_value": check.number(ref["value"], "ref_rate.value")}
    check.keys(ref, ("column", "unit", "sensitivity", "offset"), "ref_rate")
    return {
        "ref_rate": check.name(ref.get("column"), "ref_rate.column"),
        "ref_scale": check.scale(ref, RATE_UNITS, "ref_rate"),
    }


def _bag(values: dict, fmt: str, check: _Checker) -> dict:
    for key in TABULAR_KEYS:
        if values.get(key) is not None:
            check.fail(
                f"{key} applies to CSV/TSV; in a {fmt} source a sensor_msgs/msg/Imu gives "
                "the rates (rad/s) and accelerations (m/s^2); map other topics under topics:"
            )
    spec: dict = {}
    time = values.get("time")
    if time is not None:
        check.keys(time, ("source",), "time")
        source = time.get("source", "header")
        check.choice(source, TIME_SOURCES, "time.source")
        spec["time_source"] = source
    topics = values.get("topics") or {}
    check.keys(topics, TOPIC_KEYS, "topics")
    if topics.get("imu") is not None:
        spec["imu_topic"] = check.name(topics["imu"], "topics.imu")
    if topics.get("temperature") is not None:
        spec["temperature"] = _held(topics["temperature"], "topics.temperature", check, TEMP_UNITS, "degC")
    if topics.get("ref_rate") is not None:
        spec["ref_topic"] = _held(topics["ref_rate"], "topics.ref_rate", check, RATE_UNITS, "rad/s")
    return spec


def _held(spec, key: str, check: _Checker, units, default: str) -> Held:
    if isinstance(spec, str):
        spec = {"topic": spec}
    check.keys(spec, HELD_KEYS, key)
    topic = check.name(spec.get("topic"), f"{key}.topic")
    fld = spec.get("field")
    if fld is not None and (not isinstance(fld, str) or not all(fld.split("."))):
        check.fail(f"{key}.field must be a field path such as vector.z, got {fld!r}")
    if units is TEMP_UNITS:
        if "sensitivity" in spec or "offset" in spec:
            check.fail(f"{key} takes topic, field and unit ({', '.join(TEMP_UNITS)})")
        unit = spec.get("unit", default)
        check.choice(unit, TEMP_UNITS, f"{key}.unit")
        scale = Scaled(unit)
    else:
        scale = check.scale(spec, units, key, default)
        if len(scale.offset) > 1:
            check.fail(f"{key}.offset takes one number")
    return Held(topic, fld, scale)


def read_sections(path: Path) -> dict[str, tuple[int, int]]:
    """A section list in imucal's format: JSON ``{"x_p": {"start": i, "end": j}, ...}`` (or
    the column-wise ``{"start": {...}, "end": {...}}`` pandas writes by default), or the CSV
    imucal's examples save (``,start,end`` then a row per label). Sample indices count the
    source's rows from 0; ``end`` is exclusive, as imucal slices (``iloc[start:end]``)."""
    text = _read_text(path, "section list", "the section list", "utf-8-sig")
    if path.suffix.lower() == ".csv":
        rows = [r for r in csv.reader(text.splitlines()) if r]
        if not rows or [c.strip() for c in rows[0][1:]] != ["start", "end"]:
            raise ConfigError("a CSV section list starts with the header ,start,end", source=path)
        entries = {r[0].strip(): {"start": _int_text(r[1:2]), "end": _int_text(r[2:3])} for r in rows[1:]}
    else:
        try:
            entries = json.loads(text)
        except ValueError as exc:
            raise ConfigError(f"not valid JSON ({exc})", source=path) from None
        if (
            isinstance(entries, dict)
            and set(entries) == {"start", "end"}
            and all(isinstance(v, dict) for v in entries.values())
        ):
            entries = {
                k: {"start": entries["start"].get(k), "end": entries["end"].get(k)} for k in entries["start"]
            }
    if not isinstance(entries, dict) or not entries:
        raise ConfigError('a section list maps labels to {"start": i, "end": j}', source=path)
    out: dict[str, tuple[int, int]] = {}
    for label, span in entries.items():
        if label not in SECTIONS:
            raise ConfigError(f"unknown section {label!r}; expected {', '.join(SECTIONS)}", source=path)
        start, end = (span.get("start"), span.get("end")) if isinstance(span, dict) else (None, None)
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (start, end)):
            raise ConfigError(
                f"section {label} needs integer start and end sample indices, got {span!r}", source=path
            )
        if not 0 <= start < end:
            raise ConfigError(
                f"section {label} runs from {start} to {end}; expected 0 <= start < end (end exclusive)",
                source=path,
            )
        out[label] = (start, end)
    spans = sorted((s, e, label) for label, (s, e) in out.items())
    for (s0, e0, a), (s1, _, b) in zip(spans, spans[1:], strict=False):
        if s1 < e0:
            raise ConfigError(f"sections {a} ({s0} to {e0}) and {b} (from {s1}) overlap", source=path)
    return {label: out[label] for label in SECTIONS if label in out}


def _int_text(cells):
    try:
        value = float(cells[0])
    except (IndexError, ValueError):
        return None
    return int(value) if value.is_integer() else value
