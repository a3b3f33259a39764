"""Benchmark: the fleet summary's page at production sizes.

Renders the summary of N synthetic unit sessions (as ``gyrocal fleet`` would after reading
them: one row each, a failed one in 97) in batches of 1,000, through
``gyrocal.fleet.summary.write_fleet_report`` in this process, and prints the render time,
the index page's bytes and the largest batch page's bytes. Reading N results folders is not
timed here (docs/cluster.md: about 5 ms a unit).

    python benchmarks/fleet_summary.py [--units 1000 10000 100000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    from gyrocal.fleet import summary as fleet
    from tests.fleet.test_summary_pages import rows

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, nargs="+", default=[1000, 10000, 100000])
    args = parser.parse_args()
    print(f"{'units':>8} {'render s':>9} {'index KiB':>10} {'batch pages':>12} {'largest page KiB':>17}")
    for n in args.units:
        table = rows({f"B{b:04d}": min(1000, n - b * 1000) for b in range((n + 999) // 1000)})
        ok = [r for r in table if r["status"] == "ok"]
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "reports" / "index.html"
            t0 = time.perf_counter()
            fleet.write_fleet_report({"rows": table, "ok": ok, "fleet": None, "servo_vs_turntable": []}, path)
            took = time.perf_counter() - t0
            pages = list((path.parent / "batches").glob("*.html"))
            largest = max((p.stat().st_size for p in pages), default=0)
            print(
                f"{n:>8} {took:>9.1f} {path.stat().st_size / 1024:>10.0f} {len(pages):>12} {largest / 1024:>17.0f}"
            )


if __name__ == "__main__":
    main()
