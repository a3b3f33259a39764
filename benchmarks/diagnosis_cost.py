"""What a diagnosis costs per unit, this checkout against another: whole `gyrocal diagnose`
processes, imports included, on the same logs, alternating the two so that a change in the
machine's load falls on both.

    python benchmarks/diagnosis_cost.py --base /path/to/other/checkout [--repeats 3]

The other checkout (a worktree at an earlier commit) runs under the same Python and
packages. The logs are zoo units (benchmarks/zoo, one per kind of effect the diagnosis
searches, and a complete one) and one demo log, diagnosed from one log and with the other
session. Prints the median wall time of each case for both and their ratio, and the sums.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

# (effect, zoo protocol): one unit of each kind the diagnosis meets
CASES = [
    ("none", "turntable3"),
    ("scale_quadratic", "turntable3"),
    ("cross_axis_quadratic", "turntable3"),
    ("scale_range_switch", "turntable3"),
    ("warmup", "turntable3"),
    ("slow_pole_strong", "turntable3"),
    ("rate_band_bias", "turntable3"),
    ("g_sensitivity_temp", "turntable6"),
]
DEMO = ROOT / "demo" / "logs" / "B1" / "U001"


def write_logs(folder: Path, demo_folder: Path = DEMO) -> list[tuple[str, Path, Path]]:
    from benchmarks.zoo.generator import make_unit, write_session

    logs = []
    for effect, protocol in CASES:
        unit = make_unit(effect=effect, protocol=protocol, noise="white", seed=1)
        pair = [folder / f"{effect}-{protocol}-s{s}.parquet" for s in (0, 1)]
        for s, path in enumerate(pair):
            write_session(unit, path, session=s, seed=1000 + s, rate_hz=10.0)
        logs.append((f"{effect} {protocol}", *pair))
    demo = sorted(demo_folder.glob("*.parquet"))
    if len(demo) >= 2:
        logs.append(("demo U001", demo[0], demo[1]))
    return logs


def timed(root: Path, log: Path, other: Path | None, out: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(root)}
    cmd = [sys.executable, "-m", "gyrocal", "diagnose", str(log), "-o", str(out)]
    if other is not None:
        cmd += ["--other-session", str(other)]
    started = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{root}: gyrocal diagnose {log.name} failed: {done.stderr.strip()[-300:]}")
    return seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="the other checkout")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--demo", type=Path, default=DEMO, help="a demo unit's folder of logs (make demo writes it)"
    )
    args = parser.parse_args(argv)
    from host import cores, cpu_name

    roots = {"base": args.base.resolve(), "this": ROOT}
    print(f"# {time.strftime('%Y-%m-%d')}, {cpu_name()}, {cores()}, base {roots['base']}")
    print(f"{'case':>34} {'mode':>8} {'base s':>8} {'this s':>8} {'ratio':>6}")
    sums = {"base": 0.0, "this": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for label, s0, s1 in write_logs(folder, args.demo):
            for mode, other in (("one log", None), ("two", s1)):
                runs: dict[str, list[float]] = {"base": [], "this": []}
                for r in range(args.repeats):
                    order = ("base", "this") if r % 2 == 0 else ("this", "base")
                    for name in order:
                        runs[name].append(timed(roots[name], s0, other, folder / f"{name}.json"))
                med = {k: statistics.median(v) for k, v in runs.items()}
                for k in sums:
                    sums[k] += med[k]
                print(
                    f"{label:>34} {mode:>8} {med['base']:8.2f} {med['this']:8.2f} {med['this'] / med['base']:6.2f}"
                )
    print(f"{'sum':>34} {'':>8} {sums['base']:8.1f} {sums['this']:8.1f} {sums['this'] / sums['base']:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
