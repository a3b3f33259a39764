"""Checks of the fifth sealed generator on its own (the judged software is never run here).

    /work/main/.venv/bin/python benchmarks/sealed5/selfcheck.py [--units N] [--clean K]

1. Nuisances off (no bias instability or turn-on repeatability, no door, no self-heating, sensor
   on the die, no re-seating, no curvature of K(T), B(T), no output quantisation): the standard
   calibration of session 0 must reach about the white hold-mean floor on session 2.
2. Every log of the first N units of the plan is written and checked against the contract.
3. Each effect unit's achieved ratio (standard calibration on session 2 / reference floor) is
   its drawn target, within the magnitude range.

Prints aggregate figures only (no family names, no per-unit rows).
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generator as gen  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--units", type=int, default=None, help="first N units of the plan (default all)")
    ap.add_argument("--clean", type=int, default=6, help="units for the nuisance-off check")
    args = ap.parse_args(argv)
    specs = gen.plan()
    ratios = []
    for sp in specs[:args.clean]:
        b = gen.build_unit(sp, clean=True, with_tables=False)
        ratios.append(b["truth"]["standard_no_effect"] / b["truth"]["white_floor"])
    print(f"nuisances off: standard / white floor  mean {np.mean(ratios):.3f}  "
          f"range {min(ratios):.3f}-{max(ratios):.3f}  ({len(ratios)} units)")
    root = tempfile.mkdtemp(prefix="sealed5_check_")
    n_logs = n_bad = 0
    rows, gen_s, std_w, hit = [], [], [], []
    try:
        for sp in specs[:args.units]:
            t0 = time.time()
            b = gen.build_unit(sp)
            paths = gen.write_unit(b, os.path.join(root, sp["uid"]))
            gen_s.append(time.time() - t0)
            for p in paths:
                n_logs += 1
                n_bad += bool(gen.validate_log(p))
            rows += [t.num_rows for t in b["tables"]]
            tr = b["truth"]
            std_w.append(tr["standard_no_effect"] / tr["white_floor"])
            if not tr["complete"]:
                lo, hi = gen.MAG_BINS[sp["mag_bin"]]
                hit.append(abs(tr["achieved_ratio"] / tr["target_ratio"] - 1) < 1e-3
                           and lo <= tr["target_ratio"] <= hi)
            shutil.rmtree(os.path.join(root, sp["uid"]), ignore_errors=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"contract: {n_logs - n_bad}/{n_logs} logs valid")
    print(f"rows per session: min {min(rows)}  median {int(np.median(rows))}  max {max(rows)}")
    print(f"standard / white floor with nuisances (effect removed): median {np.median(std_w):.2f}  "
          f"range {min(std_w):.2f}-{max(std_w):.2f}")
    print(f"effect units on their target ratio: {sum(hit)}/{len(hit)}")
    print(f"generation: {np.mean(gen_s):.1f} s per unit on average")
    return 0 if n_bad == 0 and all(hit) else 1


if __name__ == "__main__":
    raise SystemExit(main())
