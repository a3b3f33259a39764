"""The resource requests of the unit jobs, read from what a run's jobs used.

Every unit job prints the guard's record of its stage on its stderr (gyrocal/run/guard.py):
``gyrocal.run.guard: STAGE of FOLDER took W s, C s CPU, M MiB peak``, which lands in
Snakemake's output on a local run and in the job's log on SLURM (kept with
``--slurm-keep-successful-logs``). This script gathers those lines from the files given
(saved Snakemake outputs, SLURM job logs, folders of them) and prints, per stage, what the
jobs used (wall time, CPU time and the cores that makes, peak resident memory: median,
95th percentile, largest) and the requests that follow:

* threads: 2 where the stage keeps more than 1.5 cores busy on the median job, else 1;
* mem_mb: the largest peak times 1.5, rounded up to 100 MB (at least 500);
* runtime: the largest wall time times 3, in whole minutes (at least 1).

These are the figures the rules in workflow/rules ask for (docs/cluster.md, Resources).

    snakemake ... 2> run.txt; python benchmarks/requests.py run.txt [logs/slurm ...]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from host import job_files  # noqa: E402

from gyrocal.run.guard import costs  # noqa: E402


def records(sources: list[Path]) -> dict[str, np.ndarray]:
    """Per stage, one row (wall s, CPU s, peak MiB) per job: within each source (one run),
    the last line of each unit folder's stage (a retried job's last attempt)."""
    last = {}
    for source in sources:
        for path in job_files(source):
            for stage, where, wall, cpu, peak in costs(path.read_text(errors="replace")):
                last[(str(source), stage, where)] = (wall, cpu, peak)
    found: dict[str, list] = {}
    for (_, stage, _), row in sorted(last.items()):
        found.setdefault(stage, []).append(row)
    return {stage: np.array(rows) for stage, rows in sorted(found.items())}


def requests(rows: np.ndarray) -> dict[str, int]:
    wall, cpu, peak = rows.T
    cores = np.median(cpu / np.maximum(wall, 1e-3))
    return {
        "threads": 2 if cores > 1.5 else 1,
        "mem_mb": max(500, int(math.ceil(peak.max() * 1.5 / 100.0)) * 100),
        "runtime": max(1, int(math.ceil(wall.max() * 3 / 60.0))),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "sources", nargs="+", type=Path, help="a run's saved output, SLURM job logs, or folders of them"
    )
    args = parser.parse_args(argv)
    found = records(args.sources)
    if not found:
        print(
            "no line of the guard's (gyrocal.run.guard: STAGE of FOLDER took ...) in "
            + ", ".join(map(str, args.sources)),
            file=sys.stderr,
        )
        return 1
    print(
        f"{'stage':<8} {'jobs':>5}  {'wall s (median, 95 %, max)':<28} {'cores used (median)':>19}  "
        f"{'peak MiB (median, 95 %, max)':<30} requests"
    )
    for stage, rows in found.items():
        wall, cpu, peak = rows.T
        q = lambda v: f"{np.median(v):.1f}, {np.percentile(v, 95):.1f}, {v.max():.1f}"  # noqa: E731
        r = requests(rows)
        print(
            f"{stage:<8} {len(rows):>5}  {q(wall):<28} {np.median(cpu / np.maximum(wall, 1e-3)):>19.2f}  "
            f"{q(peak):<30} threads {r['threads']}, mem_mb {r['mem_mb']}, runtime {r['runtime']} min"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
