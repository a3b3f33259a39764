"""Benchmark: what the user waits for. Whole processes, imports included, side by side.

For the full seed-000 protocol log of ``benchmarks/pipeline.py`` (100 Hz, simulated once
into ``benchmarks/.cache``), each run starts, one after the other:

* read       — a Python process that only reads the columns gyrocal reads
               (``pyarrow.parquet.read_table``);
* calibrate  — ``python -m gyrocal calibrate LOG -o CAL.json``.

Runs are interleaved; printed are the median and quartiles of each process's wall time,
of the paired ratio calibrate ÷ read, and each process's peak resident memory (its own
``ru_maxrss``, from ``wait4``), with the machine and the date.

    python benchmarks/process.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from host import cores, cpu_name
from pipeline import LOG

ROOT = Path(__file__).resolve().parents[1]


def run(argv: list[str]) -> tuple[float, float]:
    """(wall seconds, peak RSS MiB) of one process."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.read().decode()[-500:]}")
    return wall, usage.ru_maxrss / 1024


def quartiles(values: list[float]) -> tuple[float, float, float]:
    q1, q2, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, q2, q3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    if not LOG.exists():  # the same log as benchmarks/pipeline.py
        from gyrocal.simulate import simulate
        simulate(LOG.parent, units=1, seed=7)
    import pyarrow.parquet as pq

    from gyrocal.io import REQUIRED
    from gyrocal.turntable.segment import LOG_COLUMNS
    columns = list(REQUIRED) + [c for c in LOG_COLUMNS if c in pq.read_schema(LOG).names]
    rows = pq.read_metadata(LOG).num_rows
    with tempfile.TemporaryDirectory() as scratch:
        commands = {
            "read": [sys.executable, "-c", "import sys, pyarrow.parquet as pq; "
                     f"pq.read_table(sys.argv[1], columns={columns!r})", str(LOG)],
            "calibrate": [sys.executable, "-m", "gyrocal", "calibrate", str(LOG), "-o",
                          str(Path(scratch) / "cal.json")],
        }
        results = {name: [] for name in commands}
        for _ in range(args.repeat):
            for name, argv in commands.items():
                results[name].append(run(argv))
    print(f"# {dt.date.today()}, {cpu_name()}, {cores()}, Python "
          f"{sys.version.split()[0]}; {rows:,} rows at 100 Hz, {args.repeat} interleaved runs")
    print(f"{'process':<10} {'wall s: median':>15} {'(quartiles)':>16} {'peak RSS MiB':>13} "
          f"{'bytes/row':>10}")
    for name, values in results.items():
        q1, q2, q3 = quartiles([w for w, _ in values])
        peak = max(m for _, m in values)
        print(f"{name:<10} {q2:>15.2f} {f'({q1:.2f}–{q3:.2f})':>16} {peak:>13.0f} "
              f"{peak * 2 ** 20 / rows:>10.0f}")
    ratio = [c[0] / r[0] for c, r in zip(results["calibrate"], results["read"])]
    q1, q2, q3 = quartiles(ratio)
    print(f"calibrate ÷ read, paired: median {q2:.2f}× (quartiles {q1:.2f}–{q3:.2f})")


if __name__ == "__main__":
    main()
