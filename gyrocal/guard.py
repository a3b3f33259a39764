"""A unit's workflow job under limits of memory and time (config ``job_limits``).

``python -m gyrocal.guard [--memory-mb N] [--timeout-s S] STAGE ARGS...``
runs ``python -m gyrocal STAGE ARGS...`` (``segment``, ``analyse`` or ``report``) and
watches it. When the stage's resident memory passes the limit, or it runs past its time,
the guard kills it and writes the stage's failure records in place of every output it
promised ("ran out of memory (limit N MiB)", "timed out after S s"), then exits 0: the
workflow goes on and the fleet summary lists the unit as failed with the reason.

The guard measures memory itself (the resident set, as a scheduler or a cgroup counts it)
rather than setting ``RLIMIT_AS`` in the stage: under an address-space limit, imports
fail to map libraries, OpenBLAS aborts, Arrow cannot start a thread and a stage can even
hang, each with its own misleading error; killed by the guard, the reason is known.

A stage killed by anyone else (the scheduler, the user, a SIGKILL) gets no record: the
guard exits with the stage's status, Snakemake removes the job's outputs, and a rerun
runs it again. Writes are atomic (:mod:`gyrocal.atomic`), so the killed stage left no
partial file; the guard removes the temporary files it left.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from .atomic import PAUSE_ENV, leftovers

STAGES = ("segment", "analyse", "report")
POLL_S = 0.05  # how often the stage's memory and time are checked


def stage_outputs(args) -> list[Path]:
    """Every file the stage's failure records go to: those ``gyrocal STAGE
    --record-failures`` writes when it fails (gyrocal/cli.py, gyrocal/stages.py)."""
    from .unit_folder import DIAGNOSIS_FILES, VALIDATION_TABLES, UNIT_FILES
    if args.command == "report":
        return [Path(args.output)]
    if args.command == "segment":
        folder, keys = Path(args.out), ("observations", "history", "segments", "timeline")
    else:
        folder, keys = Path(args.unit), ("calibration", "validation", *VALIDATION_TABLES,
                                         *DIAGNOSIS_FILES)
    return [folder / UNIT_FILES[k] for k in keys]


def _rss_mb(pid: int) -> float | None:
    """The process's resident memory, MiB (None where /proc cannot tell)."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, IndexError, ValueError):
        return None


def _die_with(parent: int):
    """In the stage's process: die with the guard (a kill of the guard alone must not
    leave the stage writing on, unseen by Snakemake)."""
    def setup():
        if sys.platform.startswith("linux"):
            import ctypes
            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
            if os.getppid() != parent:  # the guard died before prctl took effect
                os._exit(137)
    return setup


def watch(child: subprocess.Popen, memory_mb, timeout_s) -> tuple[int, str | None]:
    """Wait for ``child``; kill it at a limit. Returns (its wait status, the reason it was
    killed, or None)."""
    start = time.monotonic()
    reason = None
    while True:
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            child.returncode = os.waitstatus_to_exitcode(status)
            # Ended on its own with more than the limit at some instant between two
            # polls: its abnormal end is the memory's (the kernel's OOM killer, a
            # MemoryError outside any stage).
            if (reason is None and child.returncode != 0 and memory_mb is not None
                    and usage.ru_maxrss / 1024 > memory_mb):
                reason = f"ran out of memory (limit {memory_mb:g} MiB)"
            return child.returncode, reason
        if reason is None:
            if timeout_s is not None and time.monotonic() - start > timeout_s:
                reason = f"timed out after {timeout_s:g} s"
            elif memory_mb is not None and (_rss_mb(child.pid) or 0) > memory_mb:
                reason = f"ran out of memory (limit {memory_mb:g} MiB)"
            if reason is not None:
                child.kill()
        time.sleep(POLL_S)


def _remove_leftovers(outputs) -> None:
    for out in outputs:
        for tmp in leftovers(out):
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)


def _exit_status(status: int) -> int:
    """The stage's exit status as a shell gives it (128 + N: killed by signal N)."""
    return status if status >= 0 else 128 - status


def run(command: list[str], memory_mb=None, timeout_s=None) -> int:
    if not command or command[0] not in STAGES:
        raise SystemExit(f"gyrocal.guard: give one of {', '.join(STAGES)} and its arguments")
    child = subprocess.Popen([sys.executable, "-m", "gyrocal", *command],
                             preexec_fn=_die_with(os.getpid()))
    os.environ.pop(PAUSE_ENV, None)  # the test's pause is the stage's, not the records'
    # A signal meant for the job (Snakemake's, a Ctrl-C) ends the stage too; no record.
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, lambda signum, _: child.send_signal(signum))
    # The stage's arguments, read by its own parser while it starts (a quarter second
    # of imports the job need not wait for). Arguments it refuses, it refuses too.
    from .cli import build_parser
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            args = build_parser().parse_args(command)
    except SystemExit:
        args = None
    status, reason = watch(child, memory_mb, timeout_s)
    if args is None:
        return _exit_status(status)
    outputs = stage_outputs(args)
    _remove_leftovers(outputs)  # this run's, and those of a run killed before it
    if reason is None:
        return _exit_status(status)
    if not args.record_failures:  # the stage's own failures stop the run: so does this
        print(f"gyrocal: error: {args.command} {reason}", file=sys.stderr)
        return 1
    from . import failure
    meta = {k: getattr(args, k, None) for k in ("device", "batch", "session", "protocol")}
    failure.write(outputs, failure.record(args.command, reason, meta))
    print(f"gyrocal: {args.command} failed (recorded): {reason}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gyrocal.guard",
        description="Run a unit's stage under limits; record the unit as failed at a limit.")
    parser.add_argument("--memory-mb", type=float, help="resident memory, MiB")
    parser.add_argument("--timeout-s", type=float, help="wall time, s")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="STAGE ARGS... of gyrocal")
    args = parser.parse_args(argv)
    return run(args.command, args.memory_mb, args.timeout_s)


if __name__ == "__main__":
    sys.exit(main())
