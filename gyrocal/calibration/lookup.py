"""Which calibration to use: the one of a unit closest to a date (contract section 6).

``gyrocal lookup CALDIR DEVICE [--date D] [--before|--after] [--max-days N]`` searches a
folder of calibration files: the workflow's ``CALDIR/{batch}/{device}/{session}/
calibration.json`` and any other ``*.json`` of format ``gyrocal.calibration/1`` below it.
A file's own ``device`` and ``session`` decide; the layout's folder names stand in only
when the file leaves them empty. Failure records (``gyrocal.failure/1``) and files that
cannot be read or parsed are skipped and counted; hidden folders are not searched.

The choice is deterministic, never depending on today's date or on the order files are
listed: without a date the latest session; with one the nearest session (``before``: on or
before it, ``after``: on or after it); ties go to the earlier session, then to the path.
A nearest session more than ``max_days`` away is returned with a warning.
"""

from __future__ import annotations

import argparse
import datetime as dt
import glob
import json
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from ..io import formats
from ..io.errors import ConfigError, GyrocalError, InputError

if TYPE_CHECKING:
    from .file import Calibration

FORMAT_FAMILY = formats.CALIBRATION.split("/")[0]
FAILURE_FORMAT = formats.FAILURE

DEFAULT_MAX_DAYS = 30
DIRECTIONS = (None, "before", "after")
_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
# Bytes every calibration or failure record holds; other JSON (validation, diagnosis) is
# passed over without parsing it.
_MARKERS = (b'"' + FORMAT_FAMILY.encode(), b'"' + FAILURE_FORMAT.split("/")[0].encode())


class NoCalibrationError(InputError):
    """No calibration file of the device satisfies the lookup."""


class LookupRecord(TypedDict):
    """A lookup's result, JSON-plain: what ``gyrocal lookup --json`` prints."""

    path: str
    caldir: str
    device: str
    batch: str | None
    session: str
    protocol: str | None
    date: str | None  # the date asked for, ISO
    direction: str | None  # "before", "after" or None: either
    days_away: int | None
    max_days: float
    warning: str | None
    candidates: int
    skipped: dict[str, int]


@dataclass(frozen=True)
class LookupResult:
    """The chosen calibration and how far its session is from the date asked for."""

    path: Path
    calibration: Calibration
    session: str
    days_away: int | None  # session minus the date, days (negative: before); None without a date
    warning: str | None
    candidates: int = 0  # the device's readable calibration files
    skipped: dict[str, int] = field(default_factory=dict)  # failed_sessions, unreadable: counts
    source: str = "scan"  # "registry" where the folder's registry answered
    note: str | None = None  # why a registry there did not answer

    def record(
        self, caldir, device: str, date: dt.date | None, direction: str | None, max_days: float
    ) -> LookupRecord:
        """What ``gyrocal lookup --json`` prints."""
        meta = self.calibration.meta
        return {
            "path": str(self.path),
            "caldir": str(caldir),
            "device": device,
            "batch": meta.get("batch"),
            "session": self.session,
            "protocol": meta.get("protocol"),
            "date": date.isoformat() if date else None,
            "direction": direction,
            "days_away": self.days_away,
            "max_days": max_days,
            "warning": self.warning,
            "candidates": self.candidates,
            "skipped": dict(self.skipped),
        }


@dataclass(frozen=True)
class _Entry:
    path: Path
    rel: str  # path relative to CALDIR, '/'-separated: the deterministic tie-break
    session: str
    date: dt.date
    doc: dict


def parse_date(value, what: str = "date") -> dt.date:
    """A ``YYYY-MM-DD`` string (or a date) as a date; anything else is a ConfigError."""
    if isinstance(value, dt.datetime):
        return value.date()
    if isinstance(value, dt.date):
        return value
    if isinstance(value, str) and _DATE.fullmatch(value):
        try:
            return dt.date.fromisoformat(value)
        except ValueError:
            pass
    raise ConfigError(f"{what} {value!r} is not a date YYYY-MM-DD")


def _session_date(session) -> dt.date | None:
    try:
        return parse_date(session)
    except ConfigError:
        return None


def _json_files(caldir: Path):
    """``*.json`` below ``caldir`` in a fixed order, hidden folders left out."""
    for root, dirs, files in os.walk(caldir):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            if name.endswith(".json"):
                yield Path(root) / name


def _layout(path: Path, caldir: Path) -> tuple[str | None, str | None]:
    """Device and session from the workflow layout ``{batch}/{device}/{session}/calibration.json``."""
    parts = path.relative_to(caldir).parts
    if len(parts) == 4 and parts[-1] == "calibration.json":
        return parts[1], parts[2]
    return None, None


def _scan(caldir: Path, device: str):
    """The device's calibration entries, how many calibration files there are, and what
    was skipped. Only files that mention the device (as a JSON string, or by the layout's
    folder) are parsed: a fleet's folder is searched at the speed of reading it."""
    entries, failed, unreadable, files = [], set(), [], 0
    needle = json.dumps(device).encode()
    for path in _json_files(caldir):
        try:
            raw = path.read_bytes()
        except OSError as exc:
            unreadable.append(f"{path}: cannot read ({exc.strerror})")
            continue
        calibration, failure = (m in raw for m in _MARKERS)
        if not (calibration or failure):
            continue
        files += calibration
        layout_device, layout_session = _layout(path, caldir)
        if needle not in raw and layout_device != device:
            continue
        try:
            doc = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            unreadable.append(f"{path}: not valid JSON")
            continue
        if not isinstance(doc, dict) or not isinstance(doc.get("format"), str):
            continue
        owner = doc.get("device") or layout_device
        session = doc.get("session") or layout_session
        if owner != device:
            continue
        if doc["format"] == FAILURE_FORMAT:
            failed.add(str(session))
            continue
        if doc["format"].split("/")[0] != FORMAT_FAMILY:
            continue
        date = _session_date(session)
        if date is None:
            unreadable.append(f"{path}: session {session!r} is not a date YYYY-MM-DD")
            continue
        entries.append(_Entry(path, path.relative_to(caldir).as_posix(), str(session), date, doc))
    return entries, files, sorted(failed), unreadable


def _devices(caldir: Path) -> list[str]:
    """Every device with a calibration file below ``caldir`` (for the message when the one
    asked for has none: a misspelt name shows)."""
    found = set()
    for path in _json_files(caldir):
        try:
            raw = path.read_bytes()
            if _MARKERS[0] not in raw:
                continue
            doc = json.loads(raw)
        except (OSError, ValueError, UnicodeDecodeError):
            continue
        if isinstance(doc, dict) and str(doc.get("format", "")).split("/")[0] == FORMAT_FAMILY:
            found.add(str(doc.get("device") or _layout(path, caldir)[0]))
    return sorted(found)


def _check_max_days(max_days) -> float:
    if isinstance(max_days, bool) or not isinstance(max_days, (int, float)) or not max_days >= 0:
        raise ConfigError(f"max_days must be a non-negative number of days, got {max_days!r}")
    return max_days


def find_calibration(
    caldir,
    device: str,
    date=None,
    direction: str | None = None,
    max_days: float = DEFAULT_MAX_DAYS,
    *,
    registry: str | None = None,
) -> LookupResult:
    """The calibration of ``device`` below ``caldir`` closest to ``date``.

    ``date``: ``YYYY-MM-DD`` or a date; None picks the latest session. ``direction``:
    None (either side), ``"before"`` (session on or before the date) or ``"after"`` (on or
    after). The answer comes from the folder's registry (``registry``, a database URL or
    file, else ``CALDIR/registry.sqlite`` where there is one: :mod:`.registry`), else from
    reading the folder's files; both choose alike. Raises :class:`NoCalibrationError`
    naming the device and what was searched.
    """
    caldir = Path(caldir)
    if not caldir.is_dir():
        raise InputError("is not a folder of calibration files", source=caldir)
    if direction not in DIRECTIONS:
        raise ConfigError(f"lookup direction must be before or after, got {direction!r}")
    date = None if date is None else parse_date(date)
    if direction and date is None:
        raise ConfigError(f"looking {direction} a date needs the date (--date YYYY-MM-DD)")
    max_days = _check_max_days(max_days)
    if registry is None and (caldir / _registry().DEFAULT_NAME).is_file():
        registry = str(caldir / _registry().DEFAULT_NAME)
    note = None
    if registry is not None:
        found = _from_registry(caldir, registry, device, date, direction, max_days)
        if isinstance(found, LookupResult):
            return found
        note = found  # the registry is behind the folder: the files answer

    entries, files, failed, unreadable = _scan(caldir, device)
    readable = []
    for entry in entries:  # only the device's files are parsed in full
        try:
            readable.append((entry, _calibration().from_dict(entry.doc, source=entry.path)))
        except GyrocalError as exc:
            unreadable.append(str(exc))
    skipped = {"failed_sessions": len(failed), "unreadable": len(unreadable)}
    pool = [(entry.date, entry.rel, (entry, cal)) for entry, cal in readable]

    def none_found(problem: str):
        devices = _devices(caldir)
        searched = (
            f"searched {files} calibration file{'s' * (files != 1)} of {len(devices)} "
            f"device{'s' * (len(devices) != 1)}{_some(devices)}"
        )
        _none_found(caldir, device, problem, [searched], failed, unreadable)

    (entry, cal), days, warning = _choose(pool, device, date, direction, max_days, none_found)
    return LookupResult(entry.path, cal, entry.session, days, warning, len(readable), skipped, "scan", note)


def _choose(pool, device, date, direction, max_days, none_found):
    """The deterministic choice among ``pool``'s (session date, path, payload): without a
    date the latest session, with one the nearest on the side asked for; ties to the
    earlier session, then the path. Returns (payload, days away, warning)."""
    if not pool:
        none_found("in this folder")
    key: Callable[[tuple], tuple]
    if date is None:
        key = lambda c: (-c[0].toordinal(), c[1])  # noqa: E731  latest first
        chosen = pool
    else:
        chosen = [
            c
            for c in pool
            if direction is None
            or (direction == "before" and c[0] <= date)
            or (direction == "after" and c[0] >= date)
        ]
        if not chosen:
            sessions = sorted(c[0] for c in pool)
            none_found(
                f"on or {direction} {date.isoformat()} (its {len(pool)} session"
                f"{'s are' if len(pool) > 1 else ' is'} from {sessions[0]} to {sessions[-1]})"
            )
        key = lambda c: (abs((c[0] - date).days), c[0], c[1])  # noqa: E731
    session_date, _, payload = min(chosen, key=key)
    days = None if date is None else (session_date - date).days
    warning = None
    if days is not None and abs(days) > max_days:
        side = "before" if days < 0 else "after"
        warning = (
            f"the nearest calibration of {device} (session {session_date.isoformat()}) is "
            f"{abs(days)} days {side} {date.isoformat()}, more than {max_days:g}"
        )
    return payload, days, warning


def _none_found(caldir, device, problem, searched: list[str], failed, unreadable):
    """The error that no calibration serves: what was searched (``searched``'s notes), then
    the device's failed sessions and unreadable files."""
    notes = list(searched)
    if failed:
        notes.append(f"{device} failed in session{'s' * (len(failed) > 1)} {', '.join(failed)}")
    if unreadable:
        notes.append(f"{len(unreadable)} unreadable (first: {unreadable[0]})")
    raise NoCalibrationError(
        f"no calibration of device {device} {problem}: {'; '.join(notes)}", source=caldir
    )


def _from_registry(caldir: Path, where: str, device: str, date, direction, max_days) -> LookupResult | str:
    """The lookup answered from the registry's rows of the device's files below ``caldir``:
    the same choice as the scan, the chosen file served only if its hash is still the one
    registered. Where the folder's layout holds a calibration file of the device the
    registry does not list, or lacks one it lists, the registry is behind the folder: the
    note that says so is returned instead, and the files answer."""
    registry = _registry()
    under = registry.root_of(caldir)
    backend = registry.connect(where, create=False)
    try:
        rows = registry.device_rows(backend, device, under)
        for row in rows:  # each file as the scan names it: below the folder asked about
            row["rel"] = (Path(row["root"]) / row["path"]).relative_to(under).as_posix()
        behind = _behind(backend, caldir, under, device, rows)
        if behind is not None:
            return (
                f"the registry {registry.shown(where)} is behind {caldir} ({behind}): answered from the "
                f"files; gyrocal registry rebuild {caldir} brings it up to date"
            )
        calibrated = [r for r in rows if r["status"] == "calibrated"]
        failed = sorted({str(r["session"]) for r in rows if r["status"] == "failed"})
        unreadable = [f"{r['path']}: {r['reason']}" for r in rows if r["status"] == "unreadable"]
        # the path below the folder decides ties, as in the scan
        pool = [(registry.EPOCH + dt.timedelta(days=r["session_day"]), r["rel"], r) for r in calibrated]

        def none_found(problem: str):
            searched = [f"searched the registry {registry.shown(where)}"]
            near = registry.devices_near(backend, device)
            if near:
                searched.append(f"devices from there on: {', '.join(near)}")
            _none_found(caldir, device, problem, searched, failed, unreadable)

        row, days, warning = _choose(pool, device, date, direction, max_days, none_found)
    finally:
        backend.close()
    path, raw = registry.served_file(row)
    cal = _calibration().from_dict(json.loads(raw), source=path)
    skipped = {"failed_sessions": len(failed), "unreadable": len(unreadable)}
    return LookupResult(
        caldir / row["rel"], cal, str(row["session"]), days, warning, len(calibrated), skipped, "registry"
    )


def _behind(backend, caldir: Path, under: str, device: str, rows: list[dict]) -> str | None:
    """Where the files below ``caldir`` say more than the registry's ``rows`` of the
    device: a row whose file is gone, or a file of the workflow's layout in a folder of the
    device (``{batch}/{device}/{session}/calibration.json``) that no row lists, whatever
    device it names inside (a file of another device there, an empty file, is listed by
    its own row). The layouts looked at: the folder itself, a batch folder (the folder
    asked about), a day's shards (``*/results``), and each results folder the rows name.
    Globs over a device's folders, not a walk of the tree. None: the registry is up to date."""
    registry = _registry()
    top = Path(under)  # absolute: the rows' roots are
    problems = [f"{row['rel']} listed but gone" for row in rows if not (caldir / row["rel"]).is_file()]
    name = glob.escape(device)
    found: dict[Path, Path] = {}  # each file and the folder it was found from, which keys it
    for pattern in (
        f"*/{name}/*/calibration.json",
        f"{name}/*/calibration.json",
        f"*/results/*/{name}/*/calibration.json",
    ):
        found.update((p, top) for p in top.glob(pattern))
    for root in {r["root"] for r in rows}:
        found.update((p, Path(root)) for p in Path(root).glob(f"*/{name}/*/calibration.json"))
    keys = sorted({registry.key_of(base, p) for p, base in found.items() if p.is_relative_to(top)})
    known = {(r["root"], r["path"]) for r in rows}
    keys = [key for key in keys if key not in known]  # the device's own rows list these
    listed: set[tuple[str, str]] = set()
    with registry.database_errors(backend.location):
        for start in range(0, len(keys), 400):  # two parameters a file, well below the bounds
            chunk = keys[start : start + 400]
            cursor = backend.execute(
                "SELECT root, path FROM unit_sessions WHERE "
                + " OR ".join("(root = ? AND path = ?)" for _ in chunk),
                [v for key in chunk for v in key],
            )
            listed.update(cursor.fetchall())
    for root, path in keys:  # unlisted: unless it is no file the registry lists (an empty one)
        if (root, path) not in listed and registry.file_row(Path(root) / path, path, root) is not None:
            problems.append(f"{(Path(root) / path).relative_to(under).as_posix()} unlisted")
    more = f"; and {len(problems) - 3} more" if len(problems) > 3 else ""
    return "; ".join(problems[:3]) + more if problems else None


def _registry():
    from . import registry  # on demand: a lookup without a registry needs none of it

    return registry


def _calibration():
    from .file import Calibration  # on demand: the CLI registers lookup at start-up

    return Calibration


def _some(names: list[str], shown: int = 5) -> str:
    if not names:
        return ""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return f" ({', '.join(names[:shown])}{more})"


def _days(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of days, got {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a non-negative number of days, got {text!r}")
    return int(value) if value.is_integer() else value


def summary(result: LookupResult, device: str, date: dt.date | None) -> str:
    """One line: device, session, how far from the date, protocol, batch."""
    meta = result.calibration.meta
    if result.days_away is None or date is None:  # days away from a date, when given one
        when = f"latest of {result.candidates}"
    elif result.days_away == 0:
        when = f"on {date.isoformat()}"
    else:
        n = abs(result.days_away)
        when = f"{n} day{'s' * (n != 1)} {'before' if result.days_away < 0 else 'after'} {date.isoformat()}"
    labels = {"failed_sessions": "failed session", "unreadable": "unreadable file"}
    skipped = [f"{v} {labels.get(k, k)}{'s' * (v != 1)}" for k, v in result.skipped.items() if v]
    return (
        f"{device} session {result.session} ({when}), protocol {meta.get('protocol')}, "
        f"batch {meta.get('batch')}" + (f"; skipped {', '.join(skipped)}" if skipped else "")
    )


def cmd_lookup(args) -> int:
    date = None if args.date is None else parse_date(args.date, "--date")
    result = find_calibration(
        args.caldir, args.device, date, args.direction, args.max_days, registry=args.registry
    )
    if result.warning:
        print(f"gyrocal: warning: {result.warning}", file=sys.stderr)
    if result.note:
        print(f"gyrocal: warning: {result.note}", file=sys.stderr)
    elif result.source == "scan":
        print(
            f"gyrocal: hint: {args.caldir} has no registry, so every file was read; "
            f"gyrocal registry rebuild {args.caldir} indexes them for lookups in milliseconds",
            file=sys.stderr,
        )
    if args.json:
        record = result.record(args.caldir, args.device, date, args.direction, args.max_days)
        print(json.dumps(record, indent=2))
    else:
        print(result.path)
        print(f"  {summary(result, args.device, date)}")
    return 0


def add_lookup_parser(subparsers):
    """Register ``gyrocal lookup`` on the CLI's subparsers."""
    p = subparsers.add_parser("lookup", help="the calibration of a unit closest to a date")
    p.add_argument("caldir", help="folder of calibration files (e.g. the workflow's results/)")
    p.add_argument("device", help="the unit's device id, as its calibrations record it")
    p.add_argument("--date", help="YYYY-MM-DD (default: the latest session)")
    side = p.add_mutually_exclusive_group()
    side.add_argument(
        "--before",
        dest="direction",
        action="store_const",
        const="before",
        help="only sessions on or before --date",
    )
    side.add_argument(
        "--after",
        dest="direction",
        action="store_const",
        const="after",
        help="only sessions on or after --date",
    )
    p.add_argument(
        "--max-days",
        type=_days,
        default=DEFAULT_MAX_DAYS,
        help=f"warn when the nearest session is further away (default {DEFAULT_MAX_DAYS})",
    )
    p.add_argument("--json", action="store_true", help="print a JSON record instead")
    p.add_argument(
        "--registry",
        help="the registry to answer from: a postgresql:// URL or an SQLite file "
        "(default CALDIR/registry.sqlite where it exists, else the files are read)",
    )
    p.set_defaults(func=cmd_lookup, direction=None)
    return p
