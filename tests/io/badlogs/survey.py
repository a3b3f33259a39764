"""Run gyrocal as a black box on the good log and every bad kind; print one row per kind.

    python tests/io/badlogs/survey.py [--out DIR] [--seed S] [--jobs N]

Each file goes through `python -m gyrocal calibrate FILE --protocol turntable -o FILE.json`
in a subprocess (cwd outside the repo, PYTHONPATH=/work/main), so only the command line,
stderr, exit status and the written JSON are observed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
sys.path.insert(0, str(HERE))
import generator  # noqa: E402  (standalone: numpy + pyarrow only)


def run_one(name: str, log: Path, cwd: str) -> dict:
    out = log.with_suffix(".json")
    out.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    try:
        p = subprocess.run(
            [
                sys.executable,
                "-m",
                "gyrocal",
                "calibrate",
                str(log),
                "--protocol",
                "turntable",
                "-o",
                str(out),
            ],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        rc, err = p.returncode, p.stderr
    except subprocess.TimeoutExpired:
        rc, err = "timeout", ""
    row = {
        "kind": name,
        "rc": rc,
        "stderr": (err.strip().splitlines() or [""])[0],
        "written": out.exists(),
        "diagK": "",
        "warnings": "",
        "nan": "",
    }
    if out.exists():
        bad = []  # json's parse_constant sees NaN / Infinity / -Infinity tokens
        try:
            cal = json.loads(out.read_text(), parse_constant=lambda c: bad.append(c) or float(c))
        except ValueError as e:
            row["diagK"] = f"unparsable JSON: {e}"
            return row
        row["nan"] = "NaN!" if bad else "no"
        grid = cal.get("grid") or {}
        temps, ks = grid.get("temperature") or [], grid.get("K") or []
        if temps and ks:
            i = min(range(len(temps)), key=lambda j: abs(temps[j] - 25.0))
            row["diagK"] = f"@{temps[i]:.0f}C " + " ".join(f"{ks[i][a][a]:.4g}" for a in range(3))
        row["warnings"] = ",".join(str(w.get("code")) for w in cal.get("warnings") or []) or "-"
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="folder for the logs and calibration files (default: a temp folder)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    folder = Path(a.out or tempfile.mkdtemp(prefix="badlogs_")).resolve()
    files = generator.write_all(folder, seed=a.seed)
    cwd = tempfile.mkdtemp(prefix="badlogs_cwd_")  # never run inside the repo
    with ThreadPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(lambda kv: run_one(kv[0], kv[1], cwd), files.items()))

    print(f"logs in {folder}")
    head = ("kind", "cat", "expect", "rc", "cal", "diag K", "warnings", "NaN", "stderr (first line)")
    table = []
    for r in rows:
        cat, exp = (
            ("good", "accept")
            if r["kind"] == "good"
            else (generator.KINDS[r["kind"]][1], generator.EXPECT[r["kind"]][0])
        )
        table.append(
            (
                r["kind"],
                cat,
                exp,
                str(r["rc"]),
                "yes" if r["written"] else "no",
                r["diagK"],
                r["warnings"],
                r["nan"],
                r["stderr"][:110],
            )
        )
    w = [max(len(x[i]) for x in table + [head]) for i in range(len(head) - 1)]
    for x in [head] + table:
        print("  ".join(c.ljust(w[i]) for i, c in enumerate(x[:-1])) + "  " + x[-1])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
