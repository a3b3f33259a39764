"""The files of a unit session's results folder, which the stages write and the report
reads: the calibration as a file of its own, the rest as parts of one archive per job
(:data:`CONTAINERS`), the job's log among them."""

from __future__ import annotations

import contextlib
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from . import atomic
from .errors import CorruptFileError
from .tables import read_columns_with_metadata, read_table_with_metadata

if TYPE_CHECKING:
    from .failure import FailureRecord

UNIT_FILES = {
    "observations": "observations.parquet",
    "history": "history.parquet",
    "segments": "segments.parquet",
    "timeline": "timeline.parquet",
    "calibration": "calibration.json",
    "validation": "validation.json",
    "holds": "validation_holds.parquet",
    "table_hold_means": "table_hold_means.parquet",
    "table_samples": "table_samples.parquet",
    "by_temperature": "by_temperature.parquet",
    "diagnosis": "diagnosis.json",
    "residuals": "residuals.parquet",
    "protocol": "protocol.json",
    "free_points": "free_points.parquet",  # continuous models only
}
OPTIONAL_FILES = ("history", "free_points")
# Written by the validation stage beside validation.json (protocol.json: the protocol's own
# methods, the servo's two fits or the sweep's drift models, for the report).
VALIDATION_TABLES = ("holds", "table_hold_means", "table_samples", "by_temperature", "protocol")
DIAGNOSIS_FILES = ("diagnosis", "residuals")


def unit_paths(folder) -> dict[str, Path]:
    return {k: Path(folder) / v for k, v in UNIT_FILES.items()}


def _unit_folder(folder) -> Path:
    """The unit's results folder, given it or its observations' path there."""
    folder = Path(folder)
    return folder.parent if folder.name == UNIT_FILES["observations"] else folder


def read_observation_table(folder):
    """A unit's observation table and its metadata (``folder``: the unit's results folder,
    or its observations' path there). A failure record there raises
    :class:`gyrocal.io.failure.UpstreamFailure`. The session's record beside it is
    :func:`read_history`'s (:func:`gyrocal.terms.signals.read_observations` joins them)."""
    from . import failure

    data, label = _required_bytes(_unit_folder(folder), "observations")
    found = failure.read(label, data=data)
    if found is not None:
        raise failure.UpstreamFailure(found)
    obs, extra = read_table_with_metadata(label, data=data)
    if isinstance(extra.get("info"), dict) and isinstance(extra["info"].get("noise"), dict):
        obs.attrs["static_seconds"] = float(extra["info"]["noise"].get("static_seconds") or 0.0)
    return obs, extra


def read_history(folder):
    """(table, metadata) of the session's record segmentation wrote (``history.parquet``),
    None where it wrote none; ``folder`` as for :func:`read_observation_table`."""
    folder = _unit_folder(folder)
    return read_part_table(folder, "history") if part_exists(folder, "history") else None


# A unit session's files: the calibration, the product `apply` and the user read, stays a
# file of its own, and so does the report; the tables and records each job writes are parts
# of one file per job, a ZIP archive of the same files (stored, not compressed: Parquet is
# compressed already), and so is the job's log (:func:`pack_log`). With Snakemake's record
# of each declared file, a line of 100,000 units a day keeps eight files per unit session
# rather than one per part (25). The stages write the parts as loose files and pack them
# when they are done (:func:`pack`); every reader reads a part where it is, packed or loose.
CONTAINERS = {
    "segmentation.zip": ("observations", "history", "segments", "timeline"),
    "analysis.zip": (
        "validation",
        "holds",
        "table_hold_means",
        "table_samples",
        "by_temperature",
        "protocol",
        "free_points",
        "diagnosis",
        "residuals",
    ),
}
CONTAINER_OF = {key: name for name, keys in CONTAINERS.items() for key in keys}
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # the archive's members carry no date: same bytes every run


def part_label(folder, key: str) -> Path:
    """How messages name a part: ``folder/analysis.zip/validation.json`` once packed."""
    folder = Path(folder)
    loose = folder / UNIT_FILES[key]
    if key in CONTAINER_OF and not loose.exists():
        return folder / CONTAINER_OF[key] / UNIT_FILES[key]
    return loose


def part_bytes(folder, key: str) -> bytes | None:
    """The bytes of one part of a unit's results, loose or packed; None where it has none."""
    loose = Path(folder) / UNIT_FILES[key]
    if loose.exists():
        return loose.read_bytes()
    with _member(folder, key) as member:
        try:
            return None if member is None else member.read()
        except (zipfile.BadZipFile, OSError) as exc:
            raise CorruptFileError(
                f"not a readable archive ({exc})", source=Path(folder) / CONTAINER_OF[key]
            ) from None


def _required_bytes(folder, key: str) -> tuple[bytes, Path]:
    """(The bytes of a part that must be there, how messages name it)."""
    data, label = part_bytes(folder, key), part_label(folder, key)
    if data is None:
        raise CorruptFileError("no such file", source=label)
    return data, label


def part_exists(folder, key: str) -> bool:
    folder = Path(folder)
    if (folder / UNIT_FILES[key]).exists():
        return True
    container = folder / CONTAINER_OF.get(key, "")
    if key not in CONTAINER_OF or not container.is_file():
        return False
    try:
        with zipfile.ZipFile(container) as archive:
            return UNIT_FILES[key] in archive.namelist()
    except (zipfile.BadZipFile, OSError):
        return True  # there, but unreadable: its reader says so


def read_part_table(folder, key: str):
    """(pandas table, metadata) of a table part (:func:`gyrocal.io.tables.write_table`)."""
    data, label = _required_bytes(folder, key)
    return read_table_with_metadata(label, data=data)


def read_part_columns(folder, key: str):
    """(:class:`gyrocal.io.columns.Columns`, metadata) of a table part, without pandas."""
    data, label = _required_bytes(folder, key)
    return read_columns_with_metadata(label, data=data)


def read_part_doc(folder, key: str) -> dict[str, Any] | None:
    """A JSON part as it is, a failure record or a result (read and parsed once), None
    where it is missing."""
    from . import failure

    data = part_bytes(folder, key)
    if data is None:
        return None
    doc = failure.load_json(part_label(folder, key), data=data, refuse_records=False)
    if not isinstance(doc, dict):
        raise CorruptFileError("not a JSON object", source=part_label(folder, key))
    return doc


def read_part_json(folder, key: str) -> dict[str, Any]:
    """A JSON part; a failure record raises :class:`gyrocal.io.failure.UpstreamFailure`."""
    from . import failure

    data = part_bytes(folder, key)
    return failure.load_json(part_label(folder, key), data=data)


def part_failure(folder, key: str) -> FailureRecord | None:
    """The failure record a part holds, None where it holds a result or is missing. A
    Parquet part's record is in its footer: only that is read, loose or packed."""
    from . import failure

    loose = Path(folder) / UNIT_FILES[key]
    if loose.exists():
        return failure.read(loose)
    with _member(folder, key) as member:
        return None if member is None else failure.read(UNIT_FILES[key], data=member)


def part_metadata(folder, key: str) -> dict[bytes, bytes] | None:
    """The schema metadata of a Parquet part (its footer alone read), None where it is
    missing."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    loose = Path(folder) / UNIT_FILES[key]
    try:
        if loose.exists():
            return pq.read_schema(loose).metadata or {}
        with _member(folder, key) as member:
            return None if member is None else pq.read_schema(member).metadata or {}
    except (pa.ArrowInvalid, OSError) as exc:
        raise CorruptFileError(
            f"not a readable Parquet file ({exc})", source=part_label(folder, key)
        ) from None


@contextlib.contextmanager
def _member(folder, key: str):
    """A packed part as a seekable file (a stored member reads in place), or None."""
    container = Path(folder) / CONTAINER_OF.get(key, "")
    if key not in CONTAINER_OF or not container.is_file():
        yield None
        return
    try:
        archive = zipfile.ZipFile(container)
    except (zipfile.BadZipFile, OSError) as exc:
        raise CorruptFileError(f"not a readable archive ({exc})", source=container) from None
    with archive:
        try:
            member = archive.open(UNIT_FILES[key])
        except KeyError:
            yield None
            return
        with member:
            yield member


def pack(folder, owned=()) -> None:
    """Move the loose parts in ``folder`` into their archives: those of the parts in
    ``owned``, the parts the stage just wrote (all archives without it). One of them it did
    not write this time (a model with no free points) leaves its archive rather than stay
    from an earlier run, and so does the archive's job log, which tells of that run (the
    guard adds this job's, :func:`pack_log`)."""
    folder = Path(folder)
    for name, keys in CONTAINERS.items():
        if owned and not set(owned) & set(keys):
            continue  # another job's archive: not this stage's to rewrite
        loose = {k: folder / UNIT_FILES[k] for k in keys if (folder / UNIT_FILES[k]).exists()}
        container = folder / name
        dropped = {UNIT_FILES[k] for k in owned if k in keys and k not in loose}
        if not loose and not (dropped and container.exists()):
            continue
        members = (_members(container) or {}) if container.is_file() else {}
        for n in dropped | {LOG_OF[name]}:
            members.pop(n, None)
        members.update({UNIT_FILES[k]: p.read_bytes() for k, p in loose.items()})
        _write_archive(container, members)
        for p in loose.values():
            p.unlink()


def _members(container: Path) -> dict[str, bytes] | None:
    """An archive's members; None where it is not a readable archive."""
    try:
        with zipfile.ZipFile(container) as archive:
            return {n: archive.read(n) for n in archive.namelist()}
    except (zipfile.BadZipFile, OSError):
        return None  # a broken archive is rebuilt from what this run wrote (pack)


def _write_archive(container: Path, members: dict[str, bytes]) -> None:
    with atomic.replacing(container) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as archive:
        for n in sorted(members):
            info = zipfile.ZipInfo(n, date_time=_ZIP_DATE)
            info.external_attr = 0o644 << 16
            archive.writestr(info, members[n])


# A workflow job's log (what the stage printed, and the guard's record of a failure it
# caught: gyrocal/run/guard.py) is written as a file while the job runs and joins the
# job's archive when the job ends well.
LOG_PARTS = {"segment": ("segmentation.zip", "segment.log"), "analyse": ("analysis.zip", "analyse.log")}
LOG_OF = {container: name for container, name in LOG_PARTS.values()}


def pack_log(folder, stage: str, log: Path) -> bool:
    """Move the job log ``log`` of ``stage`` into the stage's archive in ``folder``; False
    (the log left where it is) where there is no readable archive to take it."""
    container, name = LOG_PARTS[stage]
    container = Path(folder) / container
    members = _members(container) if container.is_file() else None
    if members is None:
        return False
    members[name] = Path(log).read_bytes()
    _write_archive(container, members)
    Path(log).unlink()
    return True


def job_log(folder, stage: str) -> str | None:
    """The text of ``stage``'s job log in ``folder``: the one a job that ended badly left
    beside the archive where that is the newer, else the packed one."""
    container, name = LOG_PARTS[stage]
    loose, container = Path(folder) / name, Path(folder) / container
    if loose.exists() and (
        not container.exists() or loose.stat().st_mtime_ns >= container.stat().st_mtime_ns
    ):
        return loose.read_text(errors="replace")
    try:
        with zipfile.ZipFile(container) as archive:
            return archive.read(name).decode(errors="replace")
    except (KeyError, zipfile.BadZipFile, OSError):
        return None


# The parts each stage writes, which it owns in its archive (:func:`pack`).
STAGE_PARTS = {
    "segment": CONTAINERS["segmentation.zip"],
    "validate": ("validation", *VALIDATION_TABLES, "free_points"),
    "diagnose": DIAGNOSIS_FILES,
    "analyse": CONTAINERS["analysis.zip"],
}


def pack_stage(folder, stage: str, owned=None) -> None:
    """:func:`pack` after ``stage`` ran (or was recorded as failed) in ``folder``; ``owned``,
    the parts it wrote where not all of :data:`STAGE_PARTS` (a diagnosis written elsewhere)."""
    pack(folder, STAGE_PARTS.get(stage, ()) if owned is None else owned)


def clear_stage(folder, stage: str, owned=None) -> None:
    """Before ``stage`` runs in ``folder``: its own parts left loose by an earlier run that
    was stopped before packing go, so that :func:`pack` takes only what this run wrote."""
    for key in STAGE_PARTS.get(stage, ()) if owned is None else owned:
        (Path(folder) / UNIT_FILES[key]).unlink(missing_ok=True)
