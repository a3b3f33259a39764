"""``gyrocal import``: what rigs and robots write (CSV, TSV, ROS 2 bags, MCAP) as contract logs.
May import: io.

A source is read and written a batch at a time, so a file of any size converts in a few
tens of MB (docs/import.md has the figure). The output holds the contract's columns in the
contract's units and records where it came from (``gyrocal.import`` in the Parquet
key-value metadata: source name and SHA-256, the map, the gyrocal version), nothing that
changes between runs: the same input gives the same bytes.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .. import __version__
from ..io.atomic import replacing
from ..io.errors import ConfigError, CorruptFileError
from ..io.log import file_digest
from .mapping import TIME_UNITS, ImportMap, load_map
from .sink import METADATA_KEY, LogSink, Summary

__all__ = ["import_log", "Summary", "METADATA_KEY"]


def import_log(
    source, output, map_path=None, *, fmt: str | None = None, sample_rate: float | None = None, sections=None
) -> Summary:
    """Convert ``source`` into the contract log ``output`` (written atomically).

    ``map_path`` is the YAML map; ``fmt``, ``sample_rate`` and ``sections`` are the command
    line's flags, which take precedence over it. Bad input raises an
    :class:`~gyrocal.io.errors.InputError` naming the file and the problem.
    """
    source, output = Path(source), Path(output)
    if not source.exists():
        raise CorruptFileError("no such file or directory", source=source)
    spec = load_map(map_path, source, fmt=fmt, sample_rate=sample_rate, sections=sections)
    if output.resolve() == source.resolve():
        raise ConfigError("the output would overwrite the source", source=output)
    if output.is_dir():
        raise ConfigError("is a directory; give the log's file name", source=output)
    map_name = Path(map_path).name if map_path is not None else "the default map"
    output.parent.mkdir(parents=True, exist_ok=True)
    # the source's SHA-256 on a thread while it converts (a bag directory: all its files)
    with ThreadPoolExecutor(1) as pool, replacing(output) as tmp:
        digest = pool.submit(file_digest, source, "sha256", files="*")
        sink = None
        try:
            if spec.is_tabular:
                from . import tabular

                table = tabular.Table(source, spec)
                spec = tabular.resolve_columns(table, spec, map_name)
                sink = _sink(tmp, source, spec, table.locate, _order_hint(spec, map_name))
                rows = tabular.convert(table, sink)
                extra, mapped, notes = {}, _mapped(spec), []
            else:
                from . import bags

                def make_sink(locate, hint):
                    nonlocal sink
                    sink = _sink(tmp, source, spec, locate, hint)
                    return sink

                sink, rows, extra, mapped, notes = bags.convert(source, spec, make_sink, map_name)
            if spec.sections:
                mapped.append(f"section from {Path(spec.sections_file).name} ({len(spec.sections)} labels)")
            metadata = {
                "gyrocal": __version__,
                "map": _recorded_map(spec),
                "source": {"name": source.name, "format": spec.format, "sha256": digest.result()},
                **extra,
            }
            summary = sink.finish(metadata, rows)
            if spec.section_column:
                mapped.append(f"section from column {spec.section_column} ({len(summary.labels)} labels)")
        except BaseException:
            if sink is not None:
                sink.abort()
            raise
    summary.mapped, summary.notes = mapped, notes
    return summary


def _order_hint(spec: ImportMap, map_name: str):
    """What a table's time-order error adds: a file whose rows go back in time may list
    them in another order (grouped by label, as imucal writes them), which the map can
    undo; equal times cannot be ordered."""
    if spec.sort or not spec.time_column:
        return ""

    def hint(t: float, before: float) -> str:
        if t >= before:
            return ""
        return (
            f"; if the file lists its rows in another order (grouped by label, say), "
            f"sort: true under time in {map_name} orders them by {spec.time_column}"
        )

    return hint


def _sink(path, source, spec: ImportMap, locate, hint="") -> LogSink:
    return LogSink(path, source, locate, spec.sections, spec.sections_file, hint=hint)


def _mapped(spec: ImportMap) -> list[str]:
    """What the table's columns became, for the command's line."""
    if spec.sample_rate is not None:
        index = spec.time_column or "row number"
        out = [f"t = {index} / {spec.sample_rate:g} Hz"]
    else:
        unit = next(u for u, f in TIME_UNITS.items() if f == spec.time_factor)
        out = [f"t from {spec.time_column} ({unit})"]
    if spec.sort:
        out[0] += f", rows ordered by {spec.time_column}"
    out.append(f"gyro from {','.join(spec.gyro)} ({spec.gyro_scale.unit})")
    if spec.accel:
        out.append(f"accel from {','.join(spec.accel)} ({spec.accel_scale.unit})")
    for name, scale in (("temp", spec.temp_scale), ("ref_rate", spec.ref_scale)):
        if getattr(spec, name):
            out.append(f"{name} from {getattr(spec, name)} ({scale.unit})")
    if getattr(spec, "ref_value", None) is not None:
        out.append(f"ref_rate {spec.ref_value:g} deg/s throughout (a static log)")
    if spec.mount:
        out.append(f"mount from {spec.mount}")
    return out


def _recorded_map(spec: ImportMap) -> dict:
    """The map as used, for provenance: the section list by name and content (a path
    would differ between machines)."""
    raw = dict(spec.raw)
    if spec.sections:
        raw["sections"] = {
            "file": Path(spec.sections_file).name,
            "spans": {k: list(v) for k, v in spec.sections.items()},
        }
    return raw
