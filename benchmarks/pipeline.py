"""Benchmark: the full seed-000 protocol at 100 Hz, gyrocal's chain against a bare read.

Prints, for the same Parquet log and the same columns:

* bare   — ``pyarrow.parquet.read_table`` of the columns segmentation reads;
* chain  — ingest + segment + fit + validate (``gyrocal.pipeline.chain`` without hashing/writing);
* full   — ``gyrocal calibrate`` as a user runs it (adds the input SHA-256 and the file).

Each is timed in a fresh process (imports excluded), repeated and interleaved; medians and
minima are printed with peak resident memory above the process's baseline. The log is
simulated once into ``benchmarks/.cache`` (about 8 M rows, 180 MB).

    python benchmarks/pipeline.py [--repeat 5] [--fresh]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from host import cores, cpu_name

CACHE = Path(__file__).resolve().parent / ".cache"
LOG = CACHE / "seed_protocol" / "U001.parquet"


def child(mode: str) -> None:
    import pyarrow.parquet as pq

    from gyrocal.io.log import REQUIRED
    from gyrocal.pipeline.chain import run
    from gyrocal.pipeline.config import Settings
    from gyrocal.protocols.turntable.segment import LOG_COLUMNS

    columns = list(REQUIRED) + [c for c in LOG_COLUMNS if c in pq.read_schema(LOG).names]
    usage = resource.getrusage(resource.RUSAGE_SELF)
    base, cpu0 = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
    t0 = time.perf_counter()
    if mode == "bare":
        table = pq.read_table(LOG, columns=columns)
        nbytes = table.nbytes
    elif mode == "chain":
        from gyrocal.fit.thermal import fit_grid
        from gyrocal.fit.validate import validate
        from gyrocal.io.log import read_log
        from gyrocal.protocols.turntable.segment import segment

        settings = Settings()
        log = read_log(LOG, optional=LOG_COLUMNS)
        seg = segment(log, settings.segmentation)
        model = settings.model.build()
        grid_fit = fit_grid(model, seg.observations)
        validate(model, seg.observations, grid_fit)
        nbytes = 0
    else:
        from gyrocal.calibration.file import save_calibration

        save_calibration(run(LOG).calibration, CACHE / "bench.calibration.json")
        nbytes = 0
    wall = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(
        json.dumps(
            {
                "wall": wall,
                "cpu": usage.ru_utime + usage.ru_stime - cpu0,
                "peak_mb": (usage.ru_maxrss - base) / 1024,
                "nbytes": nbytes,
            }
        )
    )


def measure(mode: str) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", mode], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def machine() -> str:
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    import numpy
    import pyarrow

    return (
        f"{cpu_name()}, {cores()}, {mem:.0f} GiB; Python {platform.python_version()}, "
        f"numpy {numpy.__version__}, pyarrow {pyarrow.__version__}"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--child")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--fresh", action="store_true")
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    if args.fresh or not LOG.exists():
        from gyrocal.simulate import simulate

        t0 = time.perf_counter()
        simulate(LOG.parent, units=1, seed=7)
        print(f"simulated the seed-000 protocol in {time.perf_counter() - t0:.1f} s")
    import pyarrow.parquet as pq

    meta = pq.read_metadata(LOG)
    print(f"log: {meta.num_rows:,} rows, {LOG.stat().st_size / 2**20:.0f} MiB on disk")
    print(f"machine: {machine()}")
    print(f"date: {time.strftime('%Y-%m-%d')}")
    results = {m: [] for m in ("bare", "chain", "full")}
    for _ in range(args.repeat):
        for mode in results:
            results[mode].append(measure(mode))
    bare = [r["wall"] for r in results["bare"]]
    bare_cpu = statistics.median(r["cpu"] for r in results["bare"])
    table_mb = results["bare"][0]["nbytes"] / 2**20
    print(
        f"{'':6s} {'median s':>9s} {'min s':>7s} {'paired x bare (median, quartiles)':>34s} "
        f"{'CPU s':>6s} {'x bare':>6s} {'peak MiB':>9s}"
    )
    for mode, rs in results.items():
        walls = [r["wall"] for r in rs]
        # each run against the bare read just before it: drift of the machine cancels
        ratios = sorted(w / b for w, b in zip(walls, bare, strict=False))
        q1, _, q3 = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else ratios * 3
        cpu = statistics.median(r["cpu"] for r in rs)
        peak = max(r["peak_mb"] for r in rs)
        print(
            f"{mode:6s} {statistics.median(walls):9.3f} {min(walls):7.3f} "
            f"{statistics.median(ratios):15.2f} ({q1:.2f} to {q3:.2f}) "
            f"{cpu:6.2f} {cpu / bare_cpu:6.2f} {peak:9.0f}"
        )
    print(f"columns read: {table_mb:.0f} MiB in memory")


if __name__ == "__main__":
    main()
