"""Benchmark: the plausibility checks' false alarms on good logs gyrocal's authors did not write.

Every unit of the diagnosis zoo (``benchmarks/zoo``: a simulator written from the contract
and the physics without gyrocal's source) is a correctly recorded log of a real sensor,
whatever physical effect it carries: none should be refused, and a warning on one is a false
alarm unless the effect is what the warning names. For each case of
``benchmarks/diagnosis.py`` and each unit seed, session 0 is calibrated with the protocol's
default settings and its warnings (or its error) are counted.

    python benchmarks/plausibility.py [--units 2] [--jobs 2]

Prints a row per unit (case, warnings or error) and the totals.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from diagnosis import CASES, RATE_HZ  # noqa: E402
from host import cores, cpu_name  # noqa: E402


def run_case(case, unit_seed: int, folder: str) -> dict:
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.chain import run
    from gyrocal.pipeline.config import Settings

    effect, protocol, noise, _ = case
    gyrocal_protocol = "turntable" if protocol.startswith("turntable") else protocol
    unit = make_unit(effect=effect, protocol=protocol, noise=noise, seed=unit_seed)
    path = Path(folder) / f"{effect}-{protocol}-{noise}-{unit_seed}.parquet"
    write_session(unit, path, session=0, seed=1000 * unit_seed, rate_hz=RATE_HZ.get(protocol, 25.0))
    row = {"effect": effect, "protocol": protocol, "noise": noise, "unit": unit_seed}
    try:
        cal = run(path, Settings(), protocol=gyrocal_protocol).calibration
    except GyrocalError as exc:
        row["error"] = str(exc).replace(str(path) + ": ", "")
        return row
    row["warnings"] = [w["code"] for w in cal.extra.get("warnings", [])]
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=2, help="unit seeds per case")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print(f"# {dt.date.today()}, {cpu_name()}, {cores()}; {len(CASES)} cases x {args.units} units")
    rows = []
    with tempfile.TemporaryDirectory() as folder, ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(run_case, case, seed, folder) for case in CASES for seed in range(args.units)]
        for f in futures:
            row = f.result()
            rows.append(row)
            said = f"error: {row['error']}" if "error" in row else (", ".join(row["warnings"]) or "-")
            print(
                f"{row['effect']:<24} {row['protocol']:<11} {row['noise']:<9} {row['unit']:>2}  {said}",
                flush=True,
            )
    errors = sum("error" in r for r in rows)
    warned = [r for r in rows if r.get("warnings")]
    codes: dict[str, int] = {}
    for r in warned:
        for c in r["warnings"]:
            codes[c] = codes.get(c, 0) + 1
    print(
        f"\n{len(rows)} units: {errors} refused, {len(warned)} with warnings "
        f"({', '.join(f'{c} {n}' for c, n in sorted(codes.items())) or 'none'}), "
        f"{len(rows) - errors - len(warned)} without; {time.perf_counter() - started:.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
