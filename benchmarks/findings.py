"""Benchmark: the diagnosis' two findings no term holds, on every turntable case of the zoo.

"Fixed in the lab" (``gyrocal.diagnosis.lab``) and "between the temperature points"
(``gyrocal.diagnosis.between``) are tests of their own, each made under its own gate. Here
both are made on every unit, ungated, so that what they would say where they are not asked
shows too: for each turntable case of ``benchmarks/diagnosis.py`` (units from
``benchmarks/zoo``, the simulator written without gyrocal's code), each unit and sessions 0
and 1, the configured model is fitted and validated and each test's verdict counted. The
lab test is counted only where the fit's χ² test fails (where the diagnosis makes it).

    python benchmarks/findings.py [--units 3] [--jobs 2]

Prints per case how many sessions each test flags, of how many it was made on.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

ALPHA = 0.01  # the diagnosis' default significance


def run_unit(case, unit_seed: int) -> dict:
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.diagnosis import evaluate
    from gyrocal.diagnosis.between import between_points
    from gyrocal.diagnosis.lab import lab_fixed
    from gyrocal.diagnosis.where import fit_quality
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings

    effect, protocol, noise = case[:3]
    unit = make_unit(
        effect=effect, protocol=protocol, noise=noise, seed=unit_seed, **(case[4] if len(case) > 4 else {})
    )
    settings = Settings().for_protocol("turntable")
    out = {"lab": [0, 0], "between": [0, 0]}  # [flagged, made]
    with tempfile.TemporaryDirectory() as folder:
        for session in (0, 1):
            log = Path(folder) / f"s{session}.parquet"
            write_session(
                unit,
                log,
                session=session,
                seed=1000 * unit_seed + session,
                rate_hz=25.0,
                **(case[5] if len(case) > 5 else {}),
            )
            obs = segment_log(log, settings, "turntable").observations
            base = evaluate(settings, obs, "configured model")
            quality = fit_quality(base, len(obs))
            if quality.excess_p_value < ALPHA / 2:
                lab = lab_fixed(obs, quality, base.dof, ALPHA)
                if lab is not None:
                    out["lab"][0] += lab.explains
                    out["lab"][1] += 1
            between = between_points(base.fitted, ALPHA)
            if between is not None:
                out["between"][0] += between.fails
                out["between"][1] += 1
    return out


def main() -> None:
    from diagnosis import CASES, label
    from host import cores, cpu_name

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    cases = [c for c in CASES if c[1].startswith("turntable")]
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        jobs = {
            (label(c), c[0], c[2], c[3]): [pool.submit(run_unit, c, s) for s in range(1, args.units + 1)]
            for c in cases
        }
        results = {k: [j.result() for j in v] for k, v in jobs.items()}
    print(
        f"# {time.strftime('%Y-%m-%d %H:%M')}, {cpu_name()}, {cores()}, "
        f"{args.units} units x 2 sessions per case, {time.perf_counter() - started:.0f} s"
    )
    print(
        "| effect | protocol | noise | expected | fixed in the lab (flagged / made) | "
        "between points (flagged / made) |"
    )
    print("|---|---|---|---|---|---|")
    for (protocol, effect, noise, expected), units in results.items():
        cells = []
        for test in ("lab", "between"):
            flagged, made = (sum(u[test][i] for u in units) for i in (0, 1))
            cells.append(f"{flagged} / {made}")
        print(f"| {effect} | {protocol} | {noise} | {expected} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
