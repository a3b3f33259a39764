"""Benchmark: how long Snakemake takes to plan a large fleet (``snakemake -n``).

Writes a synthetic manifest of N unit sessions (turntable, 100 units per batch) and a small
config into a temporary folder and times a dry run of the repository's workflow on it, each
in a fresh process, on the cores of this machine. No log needs any content:

* ``demo`` (default) — the paths lie under the demo folder, so each unit also gets the
  ``simulate`` job that would make its log: 3 jobs per unit (simulate, segment, analyse,
  which reports too);
* ``fleet`` — the paths lie elsewhere, in empty files (planning looks only at a log's
  existence and time stamp): 2 jobs per unit (segment, analyse), the shape of a
  production fleet whose logs exist.

The dry run is ``snakemake -n --quiet``: the plan alone. Without ``--quiet`` Snakemake also
prints every job (about 6 MB for 1,000 units), which doubles the time; ``--listing`` times
that too. Prints the jobs planned, wall and CPU seconds, peak memory and the cost per unit,
each with the machine's load when it ended (``uptime``: a shared machine's load moves a
wall time by a quarter either way). ``--cprofile FILE`` runs the largest N under cProfile
and prints where the time goes. ``--one`` also times planning one unit's report in each
fleet: what every job a cluster runs pays as it starts, since it reads the whole manifest.

    python benchmarks/dag.py [--units 1000 10000] [--layout demo|fleet] [--repeat 1]
                             [--listing] [--cprofile dag.prof] [--keep DIR]
    python benchmarks/dag.py --units 10000 50000 --layout fleet --one   # docs/cluster.md's plan
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from host import cores, cpu_name

REPO = Path(__file__).resolve().parents[1]
CONFIG = """devices: devices.tsv
demo:
  folder: demo/logs
  preset: quick
  temperatures: [0, 20, 40]
  rates: [10, 100, 400]
model: {terms: [bias, scale, misalignment]}
"""


def write_fleet(folder: Path, n: int, layout: str) -> None:
    """A manifest of ``n`` unit sessions and the config naming it (same bytes every time);
    for the fleet layout, an empty file at each log's path."""
    root = "demo/logs" if layout == "demo" else "rig"
    lines = ["device\tbatch\tsession\tprotocol\tpath"]
    for i in range(n):
        batch, device, session = f"B{i // 100:04d}", f"U{i:05d}", "2026-01-01"
        path = f"{root}/{batch}/{device}/{session}.parquet"
        lines.append(f"{device}\t{batch}\t{session}\tturntable\t{path}")
        if layout == "fleet":
            (folder / path).parent.mkdir(parents=True, exist_ok=True)
            (folder / path).touch()
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "devices.tsv").write_text("\n".join(lines) + "\n")
    (folder / "config.yaml").write_text(CONFIG)


def dry_run(
    folder: Path, cprofile: Path | None = None, listing: bool = False, targets: tuple[str, ...] = ()
) -> dict:
    """One ``snakemake -n`` in a fresh process: wall and CPU seconds, peak RSS. The usage
    is that one child's (``wait4``): the high-water mark of all children
    (``RUSAGE_CHILDREN``) would carry a larger earlier run's over."""
    prefix = [sys.executable] + (["-m", "cProfile", "-o", str(cprofile)] if cprofile else [])
    command = prefix + [
        "-m",
        "snakemake",
        "--dry-run",
        "--snakefile",
        str(REPO / "Snakefile"),
        "--directory",
        str(folder),
        "--configfile",
        str(folder / "config.yaml"),
        "--cores",
        str(os.cpu_count() or 1),
        *targets,
    ]
    command += [] if listing else ["--quiet"]  # last: it takes an optional value
    with tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            sys.exit(f"snakemake -n failed in {folder}:\n{err.read()[-3000:]}")
    return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "peak_mib": usage.ru_maxrss / 1024}


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def machine() -> str:
    import snakemake

    return f"{cpu_name()}, {cores()}, Python {platform.python_version()}, Snakemake {snakemake.__version__}"


def print_profile(path: Path, limit: int = 25) -> None:
    import pstats

    stats = pstats.Stats(str(path))
    stats.sort_stats("cumulative").print_stats(r"snakemake/(dag|jobs|rules|workflow)\.py|common\.smk", limit)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, nargs="+", default=[1000, 10000])
    parser.add_argument("--layout", choices=["demo", "fleet"], default="demo")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--listing", action="store_true", help="also time -n without --quiet")
    parser.add_argument("--cprofile", type=Path, help="profile the largest N into this file")
    parser.add_argument("--keep", type=Path, help="write the fleets here instead of a temporary folder")
    parser.add_argument(
        "--one",
        action="store_true",
        help="also time planning one unit's report in each fleet: what every "
        "cluster job pays as it starts (it parses the whole manifest)",
    )
    args = parser.parse_args()

    print(machine())
    # Per unit: segment, analyse (+ simulate); then fleet and all.
    per_unit = 3 if args.layout == "demo" else 2
    print(
        f"{'units':>7} {'jobs':>7} {'output':>8} {'wall s':>8} {'CPU s':>8} {'peak MiB':>9} "
        f"{'ms/unit':>8}  load (1, 5, 15 min)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        base = args.keep or Path(tmp)
        for n in args.units:
            folder = base / f"{args.layout}{n}"
            write_fleet(folder, n, args.layout)
            for _ in range(args.repeat):
                for listing in [False, True] if args.listing else [False]:
                    r = dry_run(folder, listing=listing)
                    print(
                        f"{n:>7} {per_unit * n + 2:>7} {'listing' if listing else 'quiet':>8} "
                        f"{r['wall']:>8.1f} {r['cpu']:>8.1f} {r['peak_mib']:>9.0f} "
                        f"{1000 * r['wall'] / n:>8.1f}  {load()}",
                        flush=True,
                    )
                if args.one:
                    r = dry_run(folder, targets=("reports/B0000/U00000/2026-01-01.html",))
                    print(
                        f"{n:>7} {per_unit:>7} {'one unit':>8} {r['wall']:>8.1f} "
                        f"{r['cpu']:>8.1f} {r['peak_mib']:>9.0f} {'':>8}  {load()}",
                        flush=True,
                    )
        if args.cprofile:
            n = max(args.units)
            dry_run(base / f"{args.layout}{n}", cprofile=args.cprofile)
            print(f"\ncProfile of N = {n} ({args.cprofile}), cumulative:")
            print_profile(args.cprofile)


if __name__ == "__main__":
    main()
