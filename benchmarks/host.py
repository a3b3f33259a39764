"""What the benchmarks share: the machine they ran on (recorded beside the figures), the job logs they read."""

from __future__ import annotations

import os
import re
from pathlib import Path


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo, or "unknown CPU" where there is none."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def cores() -> str:
    return f"{os.cpu_count()} cores"


def job_files(source: Path) -> list[Path]:
    """A file, or a folder's files in the order their jobs ran: SLURM names a job's log by
    its id, so numbers sort as numbers (a retry's log after its first attempt's)."""
    if not source.is_dir():
        return [source]

    def key(p):
        return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", str(p))]

    return sorted((p for p in source.rglob("*") if p.is_file()), key=key)
