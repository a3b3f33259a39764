"""Benchmark: what the user waits for. Whole processes, imports included, side by side.

For the full seed-000 turntable protocol (seed 7) at each sample rate asked (25, 100 and
1000 Hz by default; a log is simulated once, batch by batch, into a cache outside the
repository: ``$GYROCAL_BENCH_CACHE``, else ``~/.cache/gyrocal/benchmarks``), each run
starts, one after the other:

* read       — a Python process that only reads the columns gyrocal reads
               (``pyarrow.parquet.read_table``);
* readwrite  — with ``apply``: a Python process that reads every column batch by batch
               (262,144 rows, as apply) and writes them back with apply's Parquet settings
               (``gyrocal.calibration.apply.writer_options``): the least an apply can do;
* calibrate  — ``python -m gyrocal calibrate LOG -o CAL.json``;
* diagnose   — ``python -m gyrocal diagnose LOG -o DIAG.json``;
* apply      — ``python -m gyrocal apply CAL.json LOG -o OUT.parquet``.

Runs are interleaved; printed per rate are the median and quartiles of each process's wall
time, of its paired ratio to the read-only process, and its peak resident memory (its own
``ru_maxrss``, from ``wait4``) in MiB and per million rows, its best run against the read's
best (each process when the machine was kindest), with the machine, the date and
the load average; then ``diagnose`` against ``calibrate`` and ``apply`` against
``readwrite``, paired.

    python benchmarks/process.py [--rates 25,100,1000] [--repeat 5] [--only calibrate,apply]
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
from dataclasses import replace
from pathlib import Path

from host import cores, cpu_name

ROOT = Path(__file__).resolve().parents[1]
CACHE = Path(os.environ.get("GYROCAL_BENCH_CACHE", Path.home() / ".cache" / "gyrocal" / "benchmarks"))
PROCESSES = ("read", "readwrite", "calibrate", "diagnose", "apply")
# apply's batches and Parquet settings (gyrocal.calibration.apply: BATCH_ROWS, writer_options), without
# importing gyrocal: the imports are part of what apply costs beyond reading and writing.
READ_WRITE = """
import sys, pyarrow as pa, pyarrow.parquet as pq
reader = pq.ParquetFile(sys.argv[1], pre_buffer=False, buffer_size=1 << 20)
schema = reader.schema_arrow
dictionary = [name for name in schema.names if name not in ("gyro_x", "gyro_y", "gyro_z")]
with pq.ParquetWriter(sys.argv[2], schema, use_dictionary=dictionary) as writer:
    for batch in reader.iter_batches(batch_size=1 << 18, use_threads=True):
        writer.write_table(pa.Table.from_batches([batch], schema=schema))
"""


def log_at(rate: float) -> Path:
    """The full seed-000 protocol log at ``rate`` Hz, simulated once (the simulator writes
    it chunk by chunk, so a 1 kHz log needs no more memory than a 100 Hz one)."""
    path = CACHE / f"seed_protocol_{rate:g}hz" / "U001.parquet"
    if not path.exists():
        sys.path.insert(0, str(ROOT))
        from gyrocal.simulate import rig_for, simulate

        rig = replace(rig_for("turntable", "seed", {}), sample_rate=float(rate))
        print(f"# simulating {path} (once)", flush=True)
        simulate(path.parent, units=1, seed=7, rig=rig)
    return path


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
    if len(values) < 2:
        return values[0], values[0], values[0]
    q1, q2, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, q2, q3


def commands(log: Path, scratch: Path) -> dict[str, list[str]]:
    import pyarrow.parquet as pq

    sys.path.insert(0, str(ROOT))
    from gyrocal.io.log import REQUIRED
    from gyrocal.protocols.turntable.segment import LOG_COLUMNS

    names = pq.read_schema(log).names
    columns = list(REQUIRED) + [c for c in LOG_COLUMNS if c in names]
    gyrocal = [sys.executable, "-m", "gyrocal"]
    return {
        "read": [
            sys.executable,
            "-c",
            f"import sys, pyarrow.parquet as pq; pq.read_table(sys.argv[1], columns={columns!r})",
            str(log),
        ],
        "readwrite": [sys.executable, "-c", READ_WRITE, str(log), str(scratch / "rewritten.parquet")],
        "calibrate": [*gyrocal, "calibrate", str(log), "-o", str(scratch / "cal.json")],
        "diagnose": [*gyrocal, "diagnose", str(log), "-o", str(scratch / "diag.json")],
        "apply": [
            *gyrocal,
            "apply",
            str(scratch / "cal.json"),
            str(log),
            "-o",
            str(scratch / "applied.parquet"),
        ],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="25,100,1000", help="sample rates, Hz")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument(
        "--only", default=",".join(PROCESSES[2:]), help="gyrocal processes to time beside the read-only one"
    )
    args = parser.parse_args()
    import pyarrow.parquet as pq

    only = args.only.split(",")
    wanted = ["read"] + [p for p in PROCESSES[1:] if p in only or (p == "readwrite" and "apply" in only)]
    load = os.getloadavg()
    print(
        f"# {dt.datetime.now():%Y-%m-%d %H:%M}, {cpu_name()}, {cores()}, Python "
        f"{sys.version.split()[0]}; load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; "
        f"{args.repeat} interleaved runs per process"
    )
    print(
        f"{'rate':>6} {'rows':>12} {'process':<10} {'wall s: median':>15} {'(quartiles)':>14} "
        f"{'÷ read':>7} {'(quartiles)':>14} {'best s':>7} {'÷ best read':>11} {'peak MiB':>9} {'MiB/Mrow':>9}"
    )
    for rate in (float(r) for r in args.rates.split(",")):
        log = log_at(rate)
        rows = pq.read_metadata(log).num_rows
        with tempfile.TemporaryDirectory() as scratch:
            argv = commands(log, Path(scratch))
            run(argv["calibrate"])  # apply reads the calibration; also warms the page cache
            results = {name: [] for name in wanted}
            for _ in range(args.repeat):
                for name in wanted:
                    results[name].append(run(argv[name]))
        for name, values in results.items():
            q1, q2, q3 = quartiles([w for w, _ in values])
            r1, r2, r3 = quartiles([w / r[0] for (w, _), r in zip(values, results["read"], strict=False)])
            peak = max(m for _, m in values)
            # best of the runs, against the read's best: each process when the machine was kindest
            best, best_read = min(w for w, _ in values), min(w for w, _ in results["read"])
            print(
                f"{rate:>6g} {rows:>12,} {name:<10} {q2:>15.2f} {f'({q1:.2f}–{q3:.2f})':>14} "
                f"{r2:>6.2f}× {f'({r1:.2f}–{r3:.2f})':>14} {best:>7.2f} {best / best_read:>10.2f}× "
                f"{peak:>9.0f} {peak / rows * 1e6:>9.1f}",
                flush=True,
            )
        for num, den in (("diagnose", "calibrate"), ("apply", "readwrite")):
            if num in results and den in results:
                d1, d2, d3 = quartiles(
                    [d / c for (d, _), (c, _) in zip(results[num], results[den], strict=False)]
                )
                print(f"{rate:>6g} {'':>12} {num} ÷ {den}, paired: {d2:.2f}× ({d1:.2f}–{d3:.2f})", flush=True)


if __name__ == "__main__":
    main()
