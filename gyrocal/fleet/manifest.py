"""The device manifest (contract section 3), read and checked against its schema
(``gyrocal/io/schemas/manifest.schema.yaml``, one row).

Kept light (no numpy or pandas): the workflow reads the manifest every time it plans, for
every unit of a fleet.
"""

from __future__ import annotations

import csv
import os
from fnmatch import fnmatchcase
from pathlib import Path

from ..io import schema
from ..io.errors import ConfigError, CorruptFileError

_ROW = schema.load("manifest")
COLUMNS = tuple(_ROW["required"])
OPTIONAL = tuple(c for c in _ROW["properties"] if c not in COLUMNS)  # the model column


def _pattern(column: str) -> str:
    """A column's pattern without its anchors, as the workflow's wildcards take it."""
    return _ROW["properties"][column]["pattern"].removeprefix("^").removesuffix("$")


DEVICE_PATTERN = _pattern("device")
BATCH_PATTERN = _pattern("batch")
SESSION_PATTERN = _pattern("session")


def read_manifest(path) -> list[dict[str, str]]:
    """Rows of a manifest, each with ``log``: the path resolved against the manifest's
    folder, or a URL (``s3://bucket/key``, anything with ``://``) as written, for the
    workflow to retrieve through Snakemake's storage plugins (docs/cluster.md). Raises
    :class:`ConfigError` naming the row and column of the first problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CorruptFileError("no such file", source=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CorruptFileError(f"cannot read ({exc})", source=path) from None
    reader = csv.DictReader(text.splitlines(), delimiter="\t")
    header = reader.fieldnames or []
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ConfigError(
            f"manifest lacks column{'s' if len(missing) > 1 else ''} "
            f"{', '.join(missing)} (tab-separated, header {' '.join(COLUMNS)})",
            source=path,
        )
    rows, seen = [], {}
    present = COLUMNS + tuple(c for c in OPTIONAL if c in header)
    valid = {c: set() for c in present}  # each value checked once: batches, sessions repeat
    for line, row in enumerate(reader, start=2):
        if not any((v or "").strip() for v in row.values()):
            continue  # blank line
        row = {c: (row.get(c) or "").strip() for c in present}
        for column, value in row.items():
            if value not in valid[column]:
                try:
                    schema.check(value, "manifest", column)
                except ConfigError as exc:
                    raise ConfigError(f"line {line}: {exc}", source=path) from None
                valid[column].add(value)
        key = (row["device"], row["session"])
        if key in seen:
            raise ConfigError(
                f"line {line}: device {row['device']} session {row['session']} "
                f"is listed twice (first on line {seen[key]})",
                source=path,
            )
        seen[key] = line
        # Normalising would also fold a URL's "//" (s3://b/k -> s3:/b/k).
        row["log"] = row["path"] if "://" in row["path"] else os.path.normpath(path.parent / row["path"])
        row.setdefault("model", "")
        rows.append(row)
    if not rows:
        raise ConfigError("manifest lists no logs", source=path)
    return rows


PATTERN_CHARACTERS = "*?["


def model_entry(row: dict[str, str], models: dict, *, source=None) -> str | None:
    """The key of the config's ``models:`` entry a manifest row's unit takes: the one its
    ``model`` column names, else its device's, its batch's, the first pattern of devices
    (shell-style) that matches it; None for the fleet-wide model."""
    unread = [k for k in models if not isinstance(k, str)]
    if unread:
        what = "true or false" if isinstance(unread[0], bool) else "null" if unread[0] is None else "a number"
        raise ConfigError(
            f"models: the key {unread[0]!r} is read as {what}, not a name: quote it ('{unread[0]}')",
            source=source,
        )
    named = row.get("model")
    if named:
        if named not in models:
            raise ConfigError(
                f"device {row['device']} session {row['session']}: the manifest's model "
                f"column names {named!r}, which the config's models: does not have"
                f"{'; it has ' + ', '.join(map(str, models)) if models else ''}",
                source=source,
            )
        return named
    for key in (row["device"], row["batch"]):
        if key in models:
            return key
    return next(
        (
            key
            for key in models
            if any(c in key for c in PATTERN_CHARACTERS) and fnmatchcase(row["device"], key)
        ),
        None,
    )


def shard(rows: list[dict[str, str]], size: int) -> list[list[dict[str, str]]]:
    """The rows of a manifest in shards of at most ``size`` rows, each a workflow run of its
    own (docs/cluster.md: planning grows with the manifest). A batch stays whole where it
    fits (the batch's audits see all of it) and a device's sessions within a batch stay
    together (the diagnosis judges one session on the other, the drift page compares
    them); a batch larger than a shard is split between devices. Batches come in the order
    of their first row, a batch's devices likewise. A device calibrated in two batches may
    land in two shards, where the workflow does not pair its sessions (docs/cluster.md)."""
    if size < 1:
        raise ConfigError(f"a shard holds at least one row, not {size}")
    batches: dict[str, dict[str, list]] = {}
    for row in rows:
        batches.setdefault(row["batch"], {}).setdefault(row["device"], []).append(row)
    shards, current = [], []
    for devices in batches.values():
        if current and len(current) + sum(map(len, devices.values())) > size:
            shards.append(current)
            current = []
        for sessions in devices.values():
            if current and len(current) + len(sessions) > size:
                shards.append(current)
                current = []
            current.extend(sessions)
    if current:
        shards.append(current)
    return shards


def write_shards(rows: list[dict[str, str]], size: int, out) -> list[Path]:
    """:func:`shard` written as manifests ``shard-0001.tsv``, ... into ``out``, each log's
    path resolved (a shard's folder is not the manifest's), replacing earlier shards. A
    shard whose rows are unchanged keeps its file as it was: the workflow that reads it
    sees nothing new to do."""
    from ..io import atomic

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    named = any(r.get("model") for r in rows)  # the model column, where a row names one
    header = COLUMNS + (("model",) if named else ())
    for k, rows_k in enumerate(shard(rows, size), start=1):
        # a shard lies in another folder than the manifest: each log by its absolute path
        lines = ["\t".join(header)] + [
            "\t".join(
                [
                    *(r[c] for c in COLUMNS[:-1]),
                    r["log"] if "://" in r["log"] else os.path.abspath(r["log"]),
                    *((r.get("model") or "",) if named else ()),
                ]
            )
            for r in rows_k
        ]
        path, text = out / f"shard-{k:04d}.tsv", "\n".join(lines) + "\n"
        if not path.is_file() or path.read_text() != text:
            atomic.write_text(path, text)
        paths.append(path)
    for old in set(out.glob("shard-*.tsv")) - set(paths):
        old.unlink()
    return paths
