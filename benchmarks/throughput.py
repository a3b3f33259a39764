"""Benchmark: what the workflow costs per unit session, locally and on a one-node SLURM.

Simulates turntable logs, demo-sized (the quick preset: a log of minutes, as ``make demo``
makes) and full-protocol (the seed-000 protocol at 100 Hz: 8.3 M rows, 175 MB), into a
fleet shaped as a production line's (the logs exist, outside the demo folder: per unit a
segment and an analyse job, which reports too, then the fleet summary), and runs the workflow on
each fleet in a fresh process:

* ``local -c1`` - ``snakemake --cores 1``: one job at a time, so that what the run adds to
  its units' processes is its wall time minus theirs;
* ``local -c2`` - ``snakemake --cores 2``, what a user of two cores waits for;
* ``slurm u=1`` and ``slurm u=5`` - ``--profile profiles/slurm`` on a one-node cluster
  started for the benchmark (tests/workflow/slurm.py: root and Debian's slurm-wlm and munge), with
  ``--group-components unit=1`` and with the profile's own ``unit=5``; job states from
  squeue (no accounting database here), the profile's status checks as shipped (first
  after 20 s). Each job asks for the node's two CPUs, so the node runs one at a time.

Per run it prints Snakemake's jobs and the scheduler's submissions per unit, the run's
wall time per unit, the unit's own processes (its segment and analyse stages, as
gyrocal.run.guard measures them on the job's stderr: wall and CPU seconds), and what the workflow
adds per unit: the run's wall time beyond its stages and the fleet job. On SLURM it splits
that into the time inside the jobs (SLURM's elapsed time beyond the stages: Snakemake
starting in the job, twice, and srun) and outside (submission, queueing, status checks),
and gives the core-seconds SLURM allocated per unit. Then the files and bytes one unit
leaves behind. Every line carries the machine's load (``uptime``); figures taken while
other work loads the machine are noisy.

    python benchmarks/throughput.py [--quick 8] [--full 2] [--no-slurm] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from host import cores, cpu_name, job_files

REPO = Path(__file__).resolve().parents[1]
CACHE = Path(__file__).resolve().parent / ".cache" / "throughput"
CONFIG = "devices: devices.tsv\nmodel: {terms: [bias, scale, misalignment]}\n"
STAGES = ("segment", "analyse")  # the analyse job writes the report too
SESSION = "2026-01-01"


def load() -> str:
    return "load " + " ".join(Path("/proc/loadavg").read_text().split()[:3])


def simulate(preset: str, n: int) -> list[Path]:
    """``n`` logs of ``preset``, simulated once into benchmarks/.cache."""
    folder = CACHE / preset
    folder.mkdir(parents=True, exist_ok=True)
    logs = []
    for i in range(1, n + 1):
        log = folder / f"U{i:03d}.parquet"
        if not log.exists():
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "gyrocal",
                    "simulate",
                    "--log",
                    str(log),
                    "--device",
                    log.stem,
                    "--batch",
                    "B1",
                    "--session",
                    SESSION,
                    "--preset",
                    preset,
                ],
                check=True,
                stdout=subprocess.DEVNULL,
            )
        logs.append(log)
    return logs


def fleet(folder: Path, logs: list[Path]) -> Path:
    folder.mkdir(parents=True)
    rows = [f"{log.stem}\tB1\t{SESSION}\tturntable\t{log}" for log in logs]
    (folder / "devices.tsv").write_text("device\tbatch\tsession\tprotocol\tpath\n" + "\n".join(rows) + "\n")
    (folder / "config.yaml").write_text(CONFIG)
    return folder


def workflow(folder: Path, args: list[str], env: dict | None = None) -> tuple[float, str]:
    """One workflow run in a fresh process: its wall time and output (kept beside the run as
    snakemake.txt, where benchmarks/requests.py reads the jobs' costs)."""
    command = [
        sys.executable,
        "-m",
        "snakemake",
        "--snakefile",
        str(REPO / "Snakefile"),
        "--directory",
        str(folder),
        "--configfile",
        str(folder / "config.yaml"),
        *args,
    ]
    t0 = time.perf_counter()
    out = subprocess.run(command, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    (folder / "snakemake.txt").write_text(out.stdout + out.stderr)
    if out.returncode != 0:
        sys.exit(f"the run in {folder} failed:\n{(out.stdout + out.stderr)[-3000:]}")
    return wall, out.stdout + out.stderr


def stage_seconds(text: str, devices: list[str]) -> tuple[float, float]:
    """The units' stages, summed: wall and CPU seconds, from the guard's line of each job
    (in the run's output; on SLURM, in the jobs' logs)."""
    from gyrocal.run.guard import costs

    last = {(stage, where): (w, c) for stage, where, w, c, _ in costs(text)}  # a retry's last
    wall = cpu = 0.0
    for device in devices:
        for stage in STAGES:
            w, c = last[(stage, f"results/B1/{device}/{SESSION}")]
            wall, cpu = wall + w, cpu + c
    return wall, cpu


def slurm_logs(folder: Path) -> str:
    """The SLURM jobs' logs of a run (the profile's slurm-logdir, kept for this)."""
    return "".join(p.read_text(errors="replace") for p in job_files(folder / "logs" / "slurm"))


def fleet_seconds(folder: Path) -> float:
    """The fleet job's wall time (Snakemake's benchmark file of the rule)."""
    lines = (folder / "results" / "benchmark" / "fleet.tsv").read_text().splitlines()
    return float(lines[-1].split("\t")[0])


def leaves(folder: Path, devices: list[str]) -> dict[str, tuple[float, float]]:
    """Files and bytes per unit, by where they lie."""
    groups = {
        "results": [
            p
            for d in devices
            for p in (folder / "results" / "B1" / d / SESSION).iterdir()
            if p.suffix != ".log"
        ],
        "report": [folder / "reports" / "B1" / d / f"{SESSION}.html" for d in devices],
        # a job's log is a part of its archive; one left loose is a job that ended badly
        "job logs": [p for d in devices for p in (folder / "results" / "B1" / d / SESSION).glob("*.log")],
        "benchmark files": [
            p for d in devices for p in (folder / "results" / "benchmark").glob(f"*/B1/{d}/{SESSION}.tsv")
        ],
        # Snakemake's record of each output it made (one file per output; the fleet's too)
        ".snakemake/metadata": list((folder / ".snakemake" / "metadata").iterdir()),
    }
    return {
        k: (len(v) / len(devices), sum(p.stat().st_size for p in v) / len(devices)) for k, v in groups.items()
    }


def seconds(text: str) -> int:
    days, _, clock = text.rpartition("-")
    parts = [int(p) for p in clock.split(":")]
    parts = [0] * (3 - len(parts)) + parts
    return ((int(days or 0) * 24 + parts[0]) * 60 + parts[1]) * 60 + parts[2]


def report(
    mode: str,
    preset: str,
    n: int,
    wall: float,
    stages: tuple[float, float],
    fleet_s: float,
    submissions: int | None = None,
    inside: float | None = None,
    core_s: float | None = None,
) -> None:
    """One run's line. What the workflow adds is its wall time beyond the stages and the
    fleet job, meaningful where jobs run one at a time (not with two local cores)."""
    added = (wall - stages[0] - fleet_s) / n
    line = (
        f"{mode:<10} {preset:<6} {n:>3} {len(STAGES):>4} "
        f"{'-' if submissions is None else f'{submissions / n:.2f}':>6} {wall:>7.1f} "
        f"{wall / n:>6.1f} {stages[0] / n:>6.1f} {stages[1] / n:>6.1f} "
        f"{'-' if mode == 'local -c2' else f'{added:.1f}':>6}"
    )
    if inside is not None:
        line += f" {inside / n:>6.1f} {added - inside / n:>7.1f} {core_s / n:>7.1f}"
    print(f"{line}   [{load()}]", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", type=int, default=8, help="demo-sized units")
    parser.add_argument("--full", type=int, default=2, help="full-protocol units")
    parser.add_argument("--no-slurm", action="store_true")
    parser.add_argument("--keep", type=Path, help="run the fleets here, and keep them")
    args = parser.parse_args()

    import snakemake

    print(f"{cpu_name()}, {cores()}, Python {sys.version.split()[0]}, Snakemake {snakemake.__version__}")
    cluster = None
    if not args.no_slurm:
        sys.path.insert(0, str(REPO))
        from tests.workflow import slurm

        missing = [name for name, ok in slurm.found().items() if not ok]
        if missing:
            print(f"no SLURM runs: missing {', '.join(missing)}")
        else:
            cluster = slurm.Cluster().start()
            print(f"SLURM: {cluster.version}, one node of {os.cpu_count()} CPUs")
    print(
        "per unit: Snakemake jobs (+ fleet and all per run), sbatch submissions, wall s, "
        "the unit's stages (wall s, CPU s), the workflow's own wall s"
        + ("; on SLURM: of those, inside the jobs and outside, and core-s allocated" if cluster else "")
    )
    print(
        f"{'mode':<10} {'log':<6} {'n':>3} {'jobs':>4} {'sbatch':>6} {'wall s':>7} "
        f"{'s/unit':>6} {'stage':>6} {'CPU':>6} {'added':>6}"
        + (f" {'inside':>6} {'outside':>6} {'core-s':>7}" if cluster else "")
    )
    left = {}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            base = args.keep or Path(tmp)
            for preset, n in (("quick", args.quick), ("seed", args.full)):
                if n <= 0:
                    continue
                logs = simulate(preset, n)
                devices = [log.stem for log in logs]
                for mode, extra in (("local -c1", ["--cores", "1"]), ("local -c2", ["--cores", "2"])):
                    folder = fleet(base / f"{preset}-{mode.replace(' ', '')}", logs)
                    wall, text = workflow(folder, extra)
                    report(mode, preset, n, wall, stage_seconds(text, devices), fleet_seconds(folder))
                left[preset] = leaves(folder, devices)
                if cluster is None:
                    continue
                for mode, extra in (("slurm u=1", ["--group-components", "unit=1"]), ("slurm u=5", [])):
                    folder = fleet(base / f"{preset}-{mode.replace(' ', '').replace('=', '')}", logs)
                    wall, text = workflow(
                        folder,
                        [
                            "--profile",
                            str(REPO / "profiles" / "slurm"),
                            "--cores",
                            "2",
                            "--slurm-status-command",
                            "squeue",
                            "--slurm-keep-successful-logs",
                            *extra,
                        ],
                        env=cluster.env,
                    )
                    name = re.search(r"SLURM run ID: (\S+)", text).group(1)
                    jobs = [j for j in cluster.jobs() if j["name"] == name]
                    stages, fleet_s = stage_seconds(slurm_logs(folder), devices), fleet_seconds(folder)
                    elapsed = sum(seconds(j["elapsed"]) for j in jobs)
                    core_s = sum(seconds(j["elapsed"]) * int(j["cpus"]) for j in jobs)
                    units = sorted(j["submitted"] for j in jobs if j["comment"] != "rule_fleet")
                    report(
                        mode,
                        preset,
                        n,
                        wall,
                        stages,
                        fleet_s,
                        len(jobs),
                        elapsed - stages[0] - fleet_s,
                        core_s,
                    )
                    print(
                        f"{'':<10} the {len(units)} unit jobs were submitted from {units[0][11:]} "
                        f"to {units[-1][11:]} (squeue's submit times, to the second)"
                    )
    finally:
        if cluster is not None:
            cluster.stop()
    for preset, per_unit in left.items():
        print(f"\nwhat one unit leaves, {preset} log (files, bytes; the log itself aside):")
        for where, (files, size) in per_unit.items():
            print(f"  {where:<22} {files:>5.1f} {size / 1024:>8.1f} KiB")
        print(
            f"  {'total':<22} {sum(f for f, _ in per_unit.values()):>5.1f} "
            f"{sum(b for _, b in per_unit.values()) / 1024:>8.1f} KiB"
        )


if __name__ == "__main__":
    main()
