"""A day's manifest run as shards: each shard a workflow run of its own, the day's view their
union.

Snakemake plans a workflow in about 3 ms a unit session (docs/cluster.md), so a day of
100,000 would wait five minutes for its plan and hold one lock over all of it. ``gyrocal
shard --run`` splits the manifest (:func:`gyrocal.fleet.manifest.write_shards`), runs the
workflow on each shard in a working directory of its own (``OUT/shard-0001/``; runs do
not share ``.snakemake`` or lock each other), a few at a time, and then writes the day's
view beside them: ``OUT/fleet.parquet``, the shards' fleet tables as one with a ``shard``
column, and ``OUT/index.html``, a row per shard linking to its fleet summary.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

from ..io import atomic
from ..io.errors import ConfigError

POLL_S = 0.5  # s between looks at the running shards: a shard's run takes minutes to hours
STOP_S = 60  # s a stopped shard's Snakemake has to cancel its jobs and release its lock
CONFIG_FLAGS = ("--config", "-C")
# Options that say how many jobs run (or a profile that may): without any, --cores all.
CORES_FLAGS = ("--cores", "-c", "--jobs", "-j", "--profile", "--workflow-profile")


@dataclass
class ShardRun:
    """One shard's workflow run: its manifest, working directory, exit status (None while
    it runs) and wall time."""

    manifest: Path
    folder: Path
    status: int | None = None
    seconds: float = 0.0

    @property
    def name(self) -> str:
        return self.manifest.stem

    @property
    def log(self) -> Path:
        return self.folder / "snakemake.log"


def workflow_command(
    shard: ShardRun, snakefile: Path, configfile: Path | None, snakemake_args: list[str]
) -> list[str]:
    """The Snakemake command of one shard: the repository's workflow in the shard's folder,
    the user's options, and one ``--config`` with the user's items and the shard's manifest
    as ``devices`` (Snakemake keeps only the last ``--config`` it is given)."""
    rest, items = _config_items(snakemake_args)
    command = [
        sys.executable,
        "-m",
        "snakemake",
        "--snakefile",
        str(snakefile),
        "--directory",
        str(shard.folder),
    ]
    if configfile is not None and not _given(rest, ("--configfile", "--configfiles")):
        command += ["--configfile", str(configfile)]
    if not _given(rest, CORES_FLAGS) and not os.environ.get("SNAKEMAKE_PROFILE"):
        command += ["--cores", "all"]
    items = [item for item in items if not item.startswith("devices=")]
    if not any(item.startswith("registry=") for item in items) and not _configures_registry(
        configfile, rest
    ):  # the day's shards index their runs in one registry beside them
        items.append(f"registry={(shard.folder.parent / 'registry.sqlite').resolve()}")
    return [*command, *rest, "--config", *items, f"devices={shard.manifest}"]


def _configures_registry(configfile: Path | None, rest: list[str]) -> bool:
    """Whether a config file the shards run with names a registry of its own: the one
    given, those the options name (``--configfile A``, ``--configfile=A``, ``--configfiles A
    B``), and the workflow's own ``config/config.yaml`` that the Snakefile reads first."""
    files = [Path("config") / "config.yaml"]
    files += [configfile] if configfile is not None else []
    taking = False
    for arg in rest:
        if arg.startswith(("--configfile=", "--configfiles=")):
            files.append(Path(arg.split("=", 1)[1]))
            taking = False
        elif arg in ("--configfile", "--configfiles"):
            taking = True
        elif taking and not arg.startswith("-"):
            files.append(Path(arg))
        else:
            taking = False
    import yaml

    for path in files:
        try:
            values = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError):
            continue  # the workflow says what is wrong with it
        if isinstance(values, dict) and "registry" in values:
            return True
    return False


def _given(args: list[str], flags: tuple[str, ...]) -> bool:
    """Whether one of ``flags`` is among ``args``: ``--flag V``, ``--flag=V`` or ``-cV``."""
    short = tuple(f for f in flags if len(f) == 2)
    return any(
        a in flags or a.split("=", 1)[0] in flags or (a.startswith(short) and not a.startswith("--"))
        for a in args
    )


def _config_items(args: list[str]) -> tuple[list[str], list[str]]:
    """(the options without their ``--config``, the ``KEY=VALUE`` items of every one)."""
    rest, items, i = [], [], 0
    while i < len(args):
        if args[i] in CONFIG_FLAGS:
            i += 1
            while i < len(args) and not args[i].startswith("-"):
                items.append(args[i])
                i += 1
            continue
        if args[i].startswith("--config="):
            items.append(args[i].split("=", 1)[1])
        else:
            rest.append(args[i])
        i += 1
    return rest, items


def run_shards(
    manifests: list[Path],
    out: Path,
    snakemake_args: list[str],
    *,
    at_once: int = 1,
    snakefile: Path,
    configfile: Path | None,
    command=workflow_command,
    echo=print,
) -> list[ShardRun]:
    """Run the workflow on every shard, ``at_once`` at a time, each one's output in its
    ``snakemake.log``; ``echo`` says when each starts and ends."""
    if not Path(snakefile).is_file():
        raise ConfigError(
            "no workflow here: run gyrocal shard --run from the repository's folder, or give --snakefile",
            source=snakefile,
        )
    runs = [ShardRun(Path(m).resolve(), Path(out).resolve() / Path(m).stem) for m in manifests]
    waiting, running = list(runs), []
    with _terminate_as_interrupt():
        try:
            while waiting or running:
                while waiting and len(running) < max(at_once, 1):
                    shard = waiting.pop(0)
                    shard.folder.mkdir(parents=True, exist_ok=True)
                    with open(shard.log, "w") as log:
                        process = subprocess.Popen(
                            command(shard, Path(snakefile).resolve(), configfile, snakemake_args),
                            stdout=log,
                            stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL,
                            preexec_fn=_interruptible,
                        )
                    running.append((shard, process, time.monotonic()))
                    echo(f"{shard.name}: started ({shard.folder})")
                time.sleep(POLL_S)
                for item in [r for r in running if r[1].poll() is not None]:
                    running.remove(item)
                    shard, process, started = item
                    shard.status, shard.seconds = process.returncode, time.monotonic() - started
                    echo(
                        f"{shard.name}: "
                        + (
                            "done"
                            if shard.status == 0
                            else f"failed (exit status {shard.status}; see {shard.log})"
                        )
                        + f" in {shard.seconds:.0f} s"
                    )
        finally:
            _stop([process for _, process, _ in running])
    return runs


def _interruptible() -> None:
    """In a shard's process before it runs: Ctrl-C back to its default. A run started in the
    background by a script (or under a test runner's worker) ignores SIGINT, and a child
    inherits that: its Snakemake would not hear the stop and be killed STOP_S later."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stop(processes: list[subprocess.Popen]) -> None:
    """Stop the shards still running as Ctrl-C would (Snakemake cancels its jobs and
    releases its lock), killed if they have not ended within ``STOP_S``."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + STOP_S
    for process in processes:
        try:
            process.wait(max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class _terminate_as_interrupt:
    """While the shards run, SIGTERM (a scheduler's or a user's kill) stops them as Ctrl-C
    does, so that none is left running with its lock held."""

    def __enter__(self):
        self.before = None
        # not the main thread: signals are not this function's to take
        with contextlib.suppress(ValueError):
            self.before = signal.signal(signal.SIGTERM, self._raise)
        return self

    def __exit__(self, *exc):
        if self.before is not None:
            signal.signal(signal.SIGTERM, self.before)

    @staticmethod
    def _raise(signum, frame):
        raise KeyboardInterrupt


@dataclass(frozen=True)
class DayCounts:
    """The day's unit sessions over every shard whose workflow finished (:func:`day_view`)."""

    units: int
    ok: int
    failed: int
    eol_passed: int
    eol_failed: int


def day_view(runs: list[ShardRun], out: Path) -> DayCounts:
    """``OUT/fleet.parquet`` (the fleet table of every shard whose workflow finished,
    ``shard`` first; a column one shard's models lack is null there) and ``OUT/index.html``;
    returns the day's counts."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..report.pages import render_page

    tables, rows = [], []
    for shard in runs:
        path = shard.folder / "results" / "fleet.parquet"
        summary = shard.folder / "reports" / "index.html"
        row = {
            "name": shard.name,
            "status": shard.status,
            "log": f"{shard.name}/snakemake.log",
            "summary": f"{shard.name}/reports/index.html" if summary.is_file() else None,
            "units": None,
            "ok": None,
            "failed": None,
            "eol_passed": None,
            "eol_failed": None,
        }
        if shard.status == 0 and path.is_file():  # a stopped run's table may be an earlier run's
            table = pq.read_table(path)
            status = table.column("status").to_pylist()
            verdicts = table.column("eol_passed").to_pylist() if "eol_passed" in table.column_names else []
            row.update(
                units=table.num_rows,
                ok=status.count("ok"),
                failed=status.count("failed"),
                eol_passed=verdicts.count(True),
                eol_failed=verdicts.count(False),
            )
            tables.append(table.add_column(0, "shard", pa.array([shard.name] * table.num_rows, pa.string())))
        rows.append(row)
    if tables:
        day = pa.concat_tables(tables, promote_options="permissive")
        day = day.replace_schema_metadata({b"gyrocal.format": b"gyrocal.fleet/1"})
        with atomic.replacing(out / "fleet.parquet") as tmp:
            pq.write_table(day, tmp)
    totals = DayCounts(**{f.name: sum(r[f.name] or 0 for r in rows) for f in fields(DayCounts)})
    atomic.write_text(out / "index.html", render_page("day_index.html.j2", shards=rows, totals=totals))
    return totals
