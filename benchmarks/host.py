"""What the benchmarks print about the machine they ran on (recorded beside the figures)."""

from __future__ import annotations

import os
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
