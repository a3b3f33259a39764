"""Benchmark: the README's learning loop on the demo fleet, as a user takes it.

In a fresh copy of the repository (the files git tracks) the workflow runs on the demo
fleet; the fix the diagnosis offers for U004 is appended to the config as the report prints
it (the lines under ``models:``), and the workflow runs again. Printed: the jobs of the
second run, which calibration files changed (every unit but U004 must be byte for byte as
it was), and U004's figures before and after, in the session and on its other session, as
its report, its record of runs and the fleet table give them.

    python benchmarks/learning_loop.py [--cores 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import html
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UNIT = ("B1", "U004", "2026-01-07")


def copy_repository(target: Path) -> None:
    files = subprocess.run(
        ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    for name in files:
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, target / name)


def workflow(folder: Path, cores: int) -> tuple[float, str]:
    started = time.perf_counter()
    out = subprocess.run(
        [str(Path(sys.executable).parent / "snakemake"), "--cores", str(cores)],
        cwd=folder,
        capture_output=True,
        text=True,
    )
    if out.returncode:
        sys.exit(f"the workflow failed:\n{out.stderr[-3000:]}")
    return time.perf_counter() - started, out.stderr


def digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted((folder / "results").glob("*/*/*/calibration.json"))
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--keep", help="run in this folder and leave it (default: a temporary one)")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from gyrocal.io.unit_folder import read_part_json

    folder = Path(args.keep or tempfile.mkdtemp(prefix="learning-loop-"))
    folder.mkdir(parents=True, exist_ok=True)
    copy_repository(folder)
    first, _ = workflow(folder, args.cores)
    unit = folder / "results" / Path(*UNIT)
    before = read_part_json(unit, "diagnosis")
    lines = before["best"]["unit_config_line"]
    hashes = digests(folder)
    config = folder / "config" / "config.yaml"
    config.write_text(config.read_text() + "\n" + lines + "\n")
    second, log = workflow(folder, args.cores)
    jobs = dict(re.findall(r"^(\w+)\s+(\d+)$", log[log.index("Job stats") :].split("\n\n")[0], re.M))
    changed = [name for name, digest in digests(folder).items() if hashes.get(name) != digest]
    runs = json.loads((unit / "runs.json").read_text())["runs"]
    last, now = runs[-2], runs[-1]
    page = (folder / "reports" / UNIT[0] / UNIT[1] / f"{UNIT[2]}.html").read_text()
    since = re.search(r'<p class="verdict" id="since-last">(.*?)</p>', page, re.S)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, the demo fleet in {folder}")
    print(f"first run {first:.0f} s; the fix for {UNIT[1]} appended:\n{lines}")
    print(f"second run {second:.0f} s, jobs: {jobs}")
    print(f"calibration files changed: {len(changed)} of {len(hashes)}: {', '.join(changed)}")
    print(
        f"{UNIT[1]} {UNIT[2]}: {last['excess']:.3g} -> {now['excess']:.3g} times the floor in session; "
        f"on {now['next_session']['session']}: {last['next_session']['excess']:.3g} -> "
        f"{now['next_session']['excess']:.3g}; the fix was expected to reach {last['fix']['excess']:.3g} "
        f"and {last['fix']['next_excess']:.3g}"
    )
    print(
        "report: " + " ".join(html.unescape(re.sub(r"<[^>]+>", "", since.group(1))).split())
        if since
        else "report: no 'since the last model' paragraph"
    )
    others = [c for c in changed if f"/{UNIT[1]}/" not in c]
    if not args.keep:
        shutil.rmtree(folder)
    return 1 if others else 0


if __name__ == "__main__":
    sys.exit(main())
