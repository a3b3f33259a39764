"""Benchmark: what a unit report costs, as the user waits for it (whole processes).

For a demo-sized turntable unit (the quick preset) and a full-protocol one (the seed-000
protocol at 100 Hz, 8.3 M rows), simulated once into ``benchmarks/.cache/report``, the unit
is segmented and analysed once; then ``gyrocal report UNIT -o R.html`` runs ``--repeat``
times in fresh processes (imports included), beside one ``gyrocal calibrate`` of the same
log for scale; then what the report costs the workflow's analyse job, which writes it in
the process that analysed the unit: in a fresh process that has imported what the analyse
stage imports, the CPU time of the report stage (its own imports included), median of the runs. Printed per unit: the report's wall and
CPU seconds (median, min), its peak resident memory, its bytes and those of its figures, the
calibrate process's wall and CPU seconds, and the report's CPU seconds inside the analyse job.

Run it with the package's bytecode written (``PYTHONDONTWRITEBYTECODE`` unset), as an
installed package has it: compiling gyrocal's modules on every start adds about 0.3 s.

    python benchmarks/report.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from host import cores, cpu_name

CACHE = Path(__file__).resolve().parent / ".cache" / "report"
GYROCAL = [sys.executable, "-m", "gyrocal"]


def timed(command: list[str]) -> tuple[float, float, float]:
    """Wall s, CPU s and peak RSS MiB of one process (its own, from wait4)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"{' '.join(command)} failed:\n{err[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


IN_JOB = """
import resource, sys
import gyrocal.diagnosis, gyrocal.pipeline.chain, gyrocal.run.cli, gyrocal.run.stages as stages
before = resource.getrusage(resource.RUSAGE_SELF)
stages.report_stage(sys.argv[1], sys.argv[2])
after = resource.getrusage(resource.RUSAGE_SELF)
print(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
"""


def in_job(results: Path, html: Path) -> float:
    """CPU s of the report stage in a process that already holds the analyse stage's imports."""
    out = subprocess.run(
        [sys.executable, "-c", IN_JOB, str(results), str(html)], check=True, capture_output=True, text=True
    )
    return float(out.stdout.split()[-1])


def unit(preset: str) -> tuple[Path, Path]:
    """(log, results folder) of the preset's unit, made once."""
    folder = CACHE / preset
    log, results = folder / "U001.parquet", folder / "U001"
    folder.mkdir(parents=True, exist_ok=True)
    if not log.exists():
        subprocess.run(
            [*GYROCAL, "simulate", "--log", str(log), "--device", "U001", "--seed", "7", "--preset", preset],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    if not (results / "analysis.zip").exists():
        subprocess.run(
            [*GYROCAL, "segment", str(log), "--out", str(results)], check=True, stdout=subprocess.DEVNULL
        )
        subprocess.run([*GYROCAL, "analyse", str(results)], check=True, stdout=subprocess.DEVNULL)
    return log, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(
        f"{cpu_name()}, {cores()}, Python {sys.version.split()[0]}, "
        f"load {' '.join(Path('/proc/loadavg').read_text().split()[:3])}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    print(
        f"{'log':<6} {'report wall s':>16} {'CPU s':>12} {'peak MiB':>9} {'bytes':>9} {'figures':>9}"
        f"   {'calibrate wall s, CPU s':>24}   {'in the analyse job, CPU s':>26}"
    )
    for preset in ("quick", "seed"):
        log, results = unit(preset)
        html = CACHE / preset / "U001.html"
        runs = [timed([*GYROCAL, "report", str(results), "-o", str(html)]) for _ in range(args.repeat)]
        walls, cpus, peaks = zip(*runs, strict=False)
        text = html.read_text()
        figures = sum(len(s) for s in re.findall(r"<svg.*?</svg>", text, flags=re.S))
        cal_wall, cal_cpu, _ = timed(
            [*GYROCAL, "calibrate", str(log), "-o", str(CACHE / preset / "cal.json")]
        )
        extra = [in_job(results, html) for _ in range(args.repeat)]
        print(
            f"{preset:<6} {statistics.median(walls):>7.2f} ({min(walls):.2f}) "
            f"{statistics.median(cpus):>6.2f} ({min(cpus):.2f}) {max(peaks):>9.0f} "
            f"{len(text.encode()):>9,} {figures:>9,}   {cal_wall:>12.2f}, {cal_cpu:.2f}"
            f"   {statistics.median(extra):>26.2f}"
        )


if __name__ == "__main__":
    main()
