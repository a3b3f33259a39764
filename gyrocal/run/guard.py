"""A unit's workflow job under limits of memory and time (config ``job_limits``).

``python -m gyrocal.run.guard [--memory-mb N] [--timeout-s S] [--job-memory-mb M] [--job-log FILE] STAGE ARGS...``
runs ``python -m gyrocal STAGE ARGS...`` (``segment``, ``analyse`` or ``report``) and
watches it. When the stage's resident memory passes the limit, or it runs past its time,
the guard kills it and writes the stage's failure records in place of every output it
promised ("ran out of memory (limit N MiB)", "timed out after S s"), then exits 0: the
workflow goes on and the fleet summary lists the unit as failed with the reason.

The guard measures memory itself (the resident set, as a scheduler or a cgroup counts it)
rather than setting ``RLIMIT_AS`` in the stage: under an address-space limit, imports
fail to map libraries, OpenBLAS aborts, Arrow cannot start a thread and a stage can even
hang, each with its own misleading error; killed by the guard, the reason is known.

In a SLURM job, the job's own time limit is a limit too, on the job's last attempt. The
profiles retry a job the scheduler ended, once, with twice the runtime: before the last
attempt the scheduler ends a stage that runs too long and the retry gets more time; on
the last, nothing would follow, and a unit the scheduler ended would have no record and
hold back the fleet summary. There the guard stops its stage when the job has only
:data:`KEEP_S` seconds left (time for the unit's steps after it to pass the record on)
and records "would outrun its SLURM job's time limit (...)". Memory likewise: on the last
attempt the stage may hold :data:`MEMORY_SHARE` of what its job asked for
(``--job-memory-mb``, the rule's mem_mb), where that is below the configured limit. The
workflow gives the job's attempt (``--attempt``) and the number of attempts
(``GYROCAL_ATTEMPTS`` in the environment: workflow/rules/common.smk); without them an
attempt is the last.

A stage killed by anyone else (the scheduler, the user, a SIGKILL) gets no record: the
guard exits with the stage's status, Snakemake removes the job's outputs, and a rerun
runs it again. Writes are atomic (:mod:`gyrocal.io.atomic`), so the killed stage left no
partial file; the guard removes the temporary files it left.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from ..io.atomic import PAUSE_ENV, leftovers

STAGES = ("segment", "analyse", "report")
POLL_S = 0.05  # how often the stage's memory and time are checked
# Seconds of a SLURM job's time left to the unit's steps after this one when the guard
# stops a stage on the job's last attempt: each later step passes a failure record on in
# a few seconds (a process start, a small read and write), Snakemake's job ends after.
KEEP_S = {"segment": 30.0, "analyse": 20.0, "report": 10.0}
ATTEMPTS_ENV = "GYROCAL_ATTEMPTS"
# Set by the workflow when its jobs run through the SLURM executor (workflow/rules/common.smk),
# whose --mem the scheduler enforces: not by a local run inside an allocation.
SLURM_MEMORY_ENV = "GYROCAL_SLURM_MEMORY"
# The share of a SLURM job's memory a stage may hold on the job's last attempt: the job's
# cgroup also holds the guard, and file pages the kernel may not reclaim in time.
MEMORY_SHARE = 0.8


# The guard's record of what a stage cost, one line on the job's stderr (:func:`_run`).
# Not anchored at a line's start: Snakemake writes a message and its line end in two
# writes, so a job's line may land between them, after a message of Snakemake's.
COST_LINE = re.compile(
    r"gyrocal\.run\.guard: (\w+) of (\S+) took ([\d.]+) s, ([\d.]+) s CPU, "
    r"(\d+) MiB peak$",
    re.M,
)


def costs(text: str) -> list[tuple[str, str, float, float, float]]:
    """(stage, unit folder, wall s, CPU s, peak MiB) of each cost line in ``text`` (a
    workflow run's output, a SLURM job's log)."""
    return [
        (stage, where, float(wall), float(cpu), float(peak))
        for stage, where, wall, cpu, peak in COST_LINE.findall(text)
    ]


def stage_outputs(args) -> list[Path]:
    """Every file the stage's failure records go to: those ``gyrocal STAGE
    --record-failures`` writes when it fails (gyrocal/run/cli.py, gyrocal/run/stages.py)."""
    from ..io.unit_folder import DIAGNOSIS_FILES, STAGE_PARTS, UNIT_FILES, VALIDATION_TABLES

    if args.command == "report":
        return [Path(args.output)]
    if args.command == "segment":
        folder, keys = Path(args.out), STAGE_PARTS["segment"]
    else:
        folder, keys = Path(args.unit), ("calibration", "validation", *VALIDATION_TABLES, *DIAGNOSIS_FILES)
    report = [Path(args.report)] if getattr(args, "report", None) else []  # analyse --report
    return [folder / UNIT_FILES[k] for k in keys] + report


def kept_outputs(args, outputs: list[Path], since_ns: int) -> list[Path]:
    """The outputs a stopped ``analyse`` keeps: those its steps finished in this run (each
    written whole, atomically, after the job started: a calibration, a validation, their
    failure records) stay; the rest (the step it was stopped in, the ones after, the
    report) get the record. A stopped segmentation keeps nothing: its files go together."""
    if args.command != "analyse":
        return []
    kept = []
    for out in outputs:
        try:
            if out.suffix != ".html" and out.stat().st_mtime_ns >= since_ns:
                kept.append(out)
        except FileNotFoundError:
            pass
    return kept


def stage_archives(args) -> list[Path]:
    """The archives the stage packs its parts into (their temporary files are leftovers too)."""
    from ..io.unit_folder import CONTAINER_OF, STAGE_PARTS

    if args.command not in ("segment", "analyse"):
        return []
    folder = Path(unit_folder(args))
    return [folder / name for name in sorted({CONTAINER_OF[k] for k in STAGE_PARTS[args.command]})]


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


def last_attempt(attempt: int | None) -> tuple[bool, str]:
    """Whether ``attempt`` is its job's last, of the ``GYROCAL_ATTEMPTS`` the workflow
    allows, and which it is ("attempt 2 of 2"); without either, the last."""
    try:
        attempts = int(os.environ.get(ATTEMPTS_ENV, ""))
    except ValueError:
        attempts = None
    if attempt is None or attempts is None:
        return True, ""
    return attempt >= attempts, f"attempt {attempt} of {attempts}"


def _seconds(text: str) -> float | None:
    """SLURM's ``[days-][hours:]minutes:seconds`` in seconds; None for UNLIMITED and the
    like."""
    match = re.fullmatch(r"(?:(\d+)-)?(?:(\d+):)?(\d+):(\d+)", text.strip())
    if not match:
        return None
    days, hours, minutes, seconds = (int(g or 0) for g in match.groups())
    return ((days * 24 + hours) * 60 + minutes) * 60 + seconds


def slurm_time_left() -> tuple[float, str] | None:
    """(Seconds the SLURM job this runs in has left, its time limit as SLURM writes it),
    or None outside SLURM, without a limit, or when squeue cannot tell."""
    job = os.environ.get("SLURM_JOB_ID")
    squeue = shutil.which("squeue")
    if not job or not squeue:
        return None
    try:
        out = subprocess.run(
            [squeue, "--noheader", f"--jobs={job}", "--format=%L|%l"],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    left, _, limit = out.stdout.strip().partition("|")
    seconds = _seconds(left) if out.returncode == 0 else None
    return None if seconds is None else (seconds, limit)


def scheduler_limit(stage: str, attempt: int | None) -> tuple[float, str] | None:
    """(Seconds from now, reason) at which the guard stops ``stage`` so that its SLURM job
    ends with the unit's failure recorded rather than at its time limit, on the job's last
    attempt; None otherwise."""
    last, which = last_attempt(attempt)
    found = slurm_time_left() if last else None
    if found is None:
        return None
    left, limit = found
    where = ", ".join(filter(None, [limit, which]))
    return (max(left - KEEP_S[stage], 0.0), f"would outrun its SLURM job's time limit ({where})")


def scheduler_memory(memory_mb, job_memory_mb, attempt) -> tuple[float | None, str | None]:
    """(The stage's memory limit, MiB, and the failure it records there) for a stage whose
    SLURM job asked for ``job_memory_mb`` (the rule's mem_mb, which the SLURM executor
    passes as ``--mem``, MiB to SLURM): on the job's last attempt under the workflow's SLURM
    executor (:data:`SLURM_MEMORY_ENV`), :data:`MEMORY_SHARE` of it where that is below
    ``memory_mb`` (config job_limits), so that the unit is recorded as out of memory where
    the scheduler would kill the job with no record; otherwise ``memory_mb``."""
    own = (None, None) if memory_mb is None else (memory_mb, f"ran out of memory (limit {memory_mb:g} MiB)")
    last, which = last_attempt(attempt)
    if not (last and job_memory_mb and os.environ.get(SLURM_MEMORY_ENV)):
        return own
    share = math.floor(MEMORY_SHARE * job_memory_mb)
    if memory_mb is not None and memory_mb <= share:
        return own
    where = ", ".join(filter(None, [f"{job_memory_mb:g} MiB", which]))
    return share, f"ran out of memory (limit {share:g} MiB: its SLURM job's memory, {where})"


def watch(
    child: subprocess.Popen,
    memory: tuple[float | None, str | None],
    timeout_s,
    deadline: tuple[float, str] | None = None,
) -> tuple[int, str | None]:
    """Wait for ``child``; kill it at a limit (``memory``: MiB and the reason,
    :func:`scheduler_memory`), or at ``deadline`` (seconds from now, reason). Returns (its
    wait status, the reason it was killed or None, its resource usage)."""
    start = time.monotonic()
    reason = None
    memory_mb, out_of_memory = memory
    while True:
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            child.returncode = os.waitstatus_to_exitcode(status)
            # Ended on its own with more than the limit at some instant between two
            # polls: its abnormal end is the memory's (the kernel's OOM killer, a
            # MemoryError outside any stage).
            if (
                reason is None
                and child.returncode != 0
                and memory_mb is not None
                and usage.ru_maxrss / 1024 > memory_mb
            ):
                reason = out_of_memory
            return child.returncode, reason, usage
        if reason is None:
            if timeout_s is not None and time.monotonic() - start > timeout_s:
                reason = f"timed out after {timeout_s:g} s"
            elif deadline is not None and time.monotonic() - start > deadline[0]:
                reason = deadline[1]
            elif memory_mb is not None and (_rss_mb(child.pid) or 0) > memory_mb:
                reason = out_of_memory
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


def run(
    command: list[str], memory_mb=None, timeout_s=None, attempt=None, log=None, job_memory_mb=None
) -> int:
    """Run the stage; with ``log``, what the stage prints and the guard's record of a failure
    go to that file, which joins the stage's archive when the job ends well
    (:func:`gyrocal.io.unit_folder.pack_log`) and stays where it is, its end echoed to
    stderr, when it does not. The guard's cost line goes to stderr either way."""
    if not command or command[0] not in STAGES:
        raise SystemExit(f"gyrocal.run.guard: give one of {', '.join(STAGES)} and its arguments")
    memory = scheduler_memory(memory_mb, job_memory_mb, attempt)
    if log is None:
        return _run(command, memory, timeout_s, attempt, None)[0]
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    # A log left here is an earlier attempt's that ended badly (the scheduler killed it):
    # its end goes to this job's stderr, and this attempt's log starts afresh, so that a
    # retried unit's archive is the same bytes as one run once.
    if log.exists() and log.stat().st_size:
        _echo_end(log, "an earlier attempt's log")
    with open(log, "w") as out:
        status, args = _run(command, memory, timeout_s, attempt, out)
    from ..io.unit_folder import LOG_PARTS, pack_log

    if args is not None and args.command not in LOG_PARTS:
        return status  # a report's log stays the file it was asked to be
    if status != 0 or args is None or not pack_log(unit_folder(args), args.command, log):
        _echo_end(log, str(log))
    return status


def _echo_end(log: Path, what: str) -> None:
    tail = log.read_text(errors="replace").splitlines()[-20:]
    # One write, line end included, so that no other job's line lands inside it.
    sys.stderr.write("\n".join([f"gyrocal.run.guard: the end of {what}:", *tail, ""]))
    sys.stderr.flush()


def unit_folder(args) -> str:
    """The results folder of a segment or analyse stage's arguments."""
    return args.out if args.command == "segment" else args.unit


def _run(command, memory, timeout_s, attempt, out) -> tuple[int, argparse.Namespace | None]:
    started = time.monotonic()
    started_ns = time.time_ns()  # outputs written after this are this run's (kept_outputs)
    child = subprocess.Popen(
        [sys.executable, "-m", "gyrocal", *command], stdout=out, stderr=out, preexec_fn=_die_with(os.getpid())
    )
    os.environ.pop(PAUSE_ENV, None)  # the test's pause is the stage's, not the records'
    out = out or sys.stderr  # the guard's own lines: where the stage's go
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
    status, reason, usage = watch(child, memory, timeout_s, scheduler_limit(command[0], attempt))
    # The stage's own cost: what sizes the rules' resources, and what a workflow run adds
    # to its units' processes (benchmarks/requests.py, throughput.py). On the job's stderr
    # (Snakemake's output; a SLURM job's log), not in its log, which is a part of the unit's
    # archive and the same on every run.
    where = None if args is None else unit_folder(args) if args.command != "report" else args.output
    print(
        f"gyrocal.run.guard: {command[0]}{f' of {where}' if where else ''} took "
        f"{time.monotonic() - started:.2f} s, {usage.ru_utime + usage.ru_stime:.2f} s CPU, "
        f"{usage.ru_maxrss / 1024:.0f} MiB peak",
        file=sys.stderr,
        flush=True,
    )
    if args is None:
        return _exit_status(status), None
    outputs = stage_outputs(args)
    _remove_leftovers(outputs + stage_archives(args))  # this run's, and those of a run killed before it
    if reason is None:
        return _exit_status(status), args
    if not args.record_failures:  # the stage's own failures stop the run: so does this
        print(f"gyrocal: error: {args.command} {reason}", file=out, flush=True)
        return 1, args
    from ..io import failure
    from ..report.pages import write_failure

    meta = {k: getattr(args, k, None) for k in ("device", "batch", "session", "protocol")}
    kept = kept_outputs(args, outputs, started_ns)
    write_failure([o for o in outputs if o not in kept], failure.record(args.command, reason, meta))
    if args.command in ("segment", "analyse"):  # the records join the unit's archive
        from ..io.unit_folder import pack_stage

        pack_stage(unit_folder(args), args.command)
    print(f"gyrocal: {args.command} failed (recorded): {reason}", file=out, flush=True)
    return 0, args


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gyrocal.run.guard",
        description="Run a unit's stage under limits; record the unit as failed at a limit.",
    )
    parser.add_argument("--memory-mb", type=float, help="resident memory, MiB")
    parser.add_argument("--timeout-s", type=float, help="wall time, s")
    parser.add_argument(
        "--attempt", type=int, help="the job's attempt, of the GYROCAL_ATTEMPTS in the environment"
    )
    parser.add_argument(
        "--job-memory-mb", type=float, help="the memory the job asked of SLURM, MiB (the rule's mem_mb)"
    )
    parser.add_argument(
        "--job-log",
        help="the job's log: written while it runs, then packed "
        "into the stage's archive (gyrocal/io/unit_folder.py)",
    )
    parser.add_argument("command", nargs=argparse.REMAINDER, help="STAGE ARGS... of gyrocal")
    args = parser.parse_args(argv)
    return run(args.command, args.memory_mb, args.timeout_s, args.attempt, args.job_log, args.job_memory_mb)


if __name__ == "__main__":
    sys.exit(main())
