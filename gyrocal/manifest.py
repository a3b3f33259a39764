"""The device manifest (contract section 3), read and checked.

Deliberately light (standard library only): the workflow reads the manifest every time it
plans, for every unit of a fleet.
"""

from __future__ import annotations

import csv
import datetime as dt
import os
import re
from pathlib import Path

from .errors import ConfigError, CorruptFileError

COLUMNS = ("device", "batch", "session", "protocol", "path")
DEVICE_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}"
BATCH_PATTERN = r"[^/\\\t\n]+"
SESSION_PATTERN = r"\d{4}-\d{2}-\d{2}"
PROTOCOLS = ("turntable", "servo", "sweep")
_DEVICE = re.compile(DEVICE_PATTERN)
_BATCH = re.compile(BATCH_PATTERN)


def _complaint(path, line: int, row: dict):
    def bad(column: str, why: str):
        raise ConfigError(f"line {line}: {column} {row[column]!r} {why}", source=path)
    return bad


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
        raise ConfigError(f"manifest lacks column{'s' if len(missing) > 1 else ''} "
                          f"{', '.join(missing)} (tab-separated, header {' '.join(COLUMNS)})",
                          source=path)
    rows, seen = [], {}
    for line, row in enumerate(reader, start=2):
        if not any((v or "").strip() for v in row.values()):
            continue  # blank line
        row = {c: (row.get(c) or "").strip() for c in COLUMNS}
        bad = _complaint(path, line, row)

        if not _DEVICE.fullmatch(row["device"]):
            bad("device", f"does not match ^{DEVICE_PATTERN}$")
        if not _BATCH.fullmatch(row["batch"]):
            bad("batch", "must be non-empty without slashes or tabs")
        try:
            if not re.fullmatch(SESSION_PATTERN, row["session"]):
                raise ValueError
            dt.date.fromisoformat(row["session"])
        except ValueError:
            bad("session", "is not an ISO date YYYY-MM-DD")
        if row["protocol"] not in PROTOCOLS:
            bad("protocol", f"is not one of {', '.join(PROTOCOLS)}")
        if not row["path"]:
            bad("path", "is empty")
        key = (row["device"], row["session"])
        if key in seen:
            raise ConfigError(f"line {line}: device {row['device']} session {row['session']} "
                              f"is listed twice (first on line {seen[key]})", source=path)
        seen[key] = line
        # Normalising would also fold a URL's "//" (s3://b/k -> s3:/b/k).
        row["log"] = row["path"] if "://" in row["path"] else os.path.normpath(path.parent / row["path"])
        rows.append(row)
    if not rows:
        raise ConfigError("manifest lists no logs", source=path)
    return rows
