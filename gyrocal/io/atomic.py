"""Atomic writes: every file gyrocal writes appears whole or not at all.

A writer fills a temporary file beside its target (same folder, so the same file system)
and renames it onto the target only once the file is complete and flushed to disk; on an
error the temporary file is removed. A process killed mid-write (SIGKILL, out of memory,
a scheduler's time limit) leaves at most a temporary file ``.NAME.PID.XXXXXX.tmp``, never
a partial ``NAME`` that a rerun, Snakemake or a reader would take as a result.

Nothing here imports gyrocal: every module may use it.
"""

from __future__ import annotations

import os
import secrets
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# Test-only seam (tests/workflow/test_faults.py): a target whose path ends with this value sleeps
# between its complete temporary file and the rename, for a test to kill the writer there
# or to hold a job past its time limit. "SUFFIX" or "SUFFIX:SECONDS" (default 600 s).
PAUSE_ENV = "GYROCAL_TEST_PAUSE_BEFORE_RENAME"


def temporary_name(path) -> Path:
    """A fresh temporary path beside ``path``: hidden, naming the writing process."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(3)}.tmp")


def leftovers(path) -> list[Path]:
    """Temporary files and folders a killed writer of ``path`` left behind (this module's,
    and the ``NAME.tmp`` of writers that use a fixed name)."""
    path = Path(path)
    name = _glob_escape(path.name)
    found = [*path.parent.glob(f".{name}.*.tmp"), *path.parent.glob(f".{name}.*.old")]
    fixed = path.with_name(path.name + ".tmp")
    return found + ([fixed] if fixed.exists() else [])


def _glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


def sync(path) -> None:
    """Flush ``path``'s data to disk, so that after a crash of the machine the renamed file
    is not empty or partial (a rename reaches the disk on its own schedule)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _pause(path: Path) -> None:
    value = os.environ.get(PAUSE_ENV)
    if not value:
        return
    suffix, _, seconds = value.partition(":")
    if suffix and str(path).endswith(suffix):
        time.sleep(float(seconds or 600))


@contextmanager
def replacing(path) -> Iterator[Path]:
    """The temporary path to write ``path``'s content to, renamed onto ``path`` when the
    block ends; removed, leaving ``path`` as it was, when the block raises."""
    path = Path(path)
    tmp = temporary_name(path)
    try:
        yield tmp
        sync(tmp)
        _pause(path)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(path, text: str, *, encoding: str = "utf-8", newline: str | None = None) -> None:
    with replacing(path) as tmp, open(tmp, "w", encoding=encoding, newline=newline) as fh:
        fh.write(text)


@contextmanager
def replacing_folder(path) -> Iterator[Path]:
    """A temporary folder to fill, put in ``path``'s place when the block ends (the old
    folder is moved aside, then deleted); removed when the block raises. Readers see the
    old folder or the new one, complete; between the two renames, none."""
    path = Path(path)
    tmp = temporary_name(path)
    tmp.mkdir(parents=True)
    try:
        yield tmp
        _pause(path)
        old = None
        if path.exists():
            old = temporary_name(path).with_suffix(".old")
            os.replace(path, old)
        os.replace(tmp, path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
