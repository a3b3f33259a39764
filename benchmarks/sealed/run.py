"""Run the sealed benchmark: write every unit's three sessions, judge each unit twice
(two-session diagnosis, then one-log diagnosis) and print aggregate scores only.

    /work/main/.venv/bin/python benchmarks/sealed/run.py [--jobs 2] [--units-per-family 2]
                                                        [--quick] [--seed S] [--keep DIR]

Nothing per unit is printed or written (no family names, no parameters, no per-unit rows);
the logs live in a temporary folder that is removed at the end unless --keep is given.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generator as gen  # noqa: E402

MAIN = os.path.dirname(os.path.dirname(HERE))  # the checkout this runner lies in
JUDGE_DIR = os.path.join(MAIN, "benchmarks")
MODES = (("two-session", False), ("one-log", True))

# The judge's vocabulary of no_sensor_term reasons (judge.py's interface docstring). A reason is
# a right story for a unit exactly when the generator's truth for its family lists it
# (generator.FAMILIES "reasons"); any other reason, in this list or not, is a wrong story.
REASONS = ("mounting", "lab", "unit changed", "between points", "slow noise", "too small",
           "direction of approach", "unexplained")


# ---------------------------------------------------------------------------- workers
def _silence():
    """Pool initializer: whatever the judged code prints stays out of the aggregate output."""
    fd = os.open(os.devnull, os.O_WRONLY)
    os.dup2(fd, 1)
    os.dup2(fd, 2)


def _generate(args):
    spec, root = args
    built = gen.build_unit(spec)
    paths = gen.write_unit(built, os.path.join(root, spec["uid"]))
    return spec["uid"], paths, built["truth"]


def _judge(args):
    uid, paths, one_session, judge_dir = args
    sys.path.insert(0, MAIN)
    sys.path.insert(0, judge_dir)
    t0 = time.time()
    try:
        from judge import judge_unit
        r = judge_unit(list(paths), protocol="turntable", one_session=one_session)
        r = dict(r) if isinstance(r, dict) else {"verdict": "error"}
    except BaseException as exc:  # noqa: BLE001 - a crash is scored as an error
        r = {"verdict": "error", "exception": type(exc).__name__}
    r.pop("detail", None)         # never kept, never printed
    return uid, one_session, r, time.time() - t0


# ---------------------------------------------------------------------------- scoring
def check_vocabulary():
    """Every right reason in the generator's truth must be a word the judge can say."""
    unknown = sorted({r for F in gen.FAMILIES.values() for r in F["reasons"]} - set(REASONS))
    if unknown:
        raise SystemExit(f"generator truth names reasons outside the judge's vocabulary: {unknown}")


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if x == x else None


def score(truth, r):
    """One unit's result against the generator's truth -> dict of booleans."""
    v = r.get("verdict")
    out = dict(success=False, fixed=False, right=False, wrong=False, missed=False,
               false_alarm=False, peer_fixed=False, error=False)
    if v not in ("quiet", "fix", "no_sensor_term"):
        out["error"] = True
        return out
    if truth["complete"]:
        out["false_alarm"] = v != "quiet"
        out["success"] = v == "quiet"
        return out
    thr = truth["threshold"]
    after = _num(r.get("next_after_rms"))
    peer = _num(r.get("peer_next_after_rms"))
    reads = set(r.get("reads") or [])
    reason = r.get("reason")
    out["fixed"] = v == "fix" and after is not None and after <= thr
    said_why = v == "no_sensor_term" and reason in REASONS and reason in truth["reasons"]
    if v == "fix":
        out["right"] = bool(reads & truth["reads"])
        out["wrong"] = not out["right"]
    elif v == "no_sensor_term":
        out["right"] = said_why
        out["wrong"] = not said_why
    else:
        out["missed"] = True
    out["peer_fixed"] = peer is not None and peer <= thr
    out["success"] = out["fixed"] or (said_why and not truth["carried"])
    return out


def aggregate(truths, results):
    n = len(truths)
    n_eff = sum(not t["complete"] for t in truths.values())
    n_comp = n - n_eff
    tot = dict(success=0, fixed=0, right=0, wrong=0, missed=0, false_alarm=0, peer_fixed=0, error=0)
    for uid, t in truths.items():
        s = score(t, results.get(uid, {"verdict": "error"}))
        for k in tot:
            tot[k] += bool(s[k])
    return n, n_eff, n_comp, tot


# ---------------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description="sealed gyro-calibration diagnosis benchmark")
    ap.add_argument("--jobs", type=int, default=2, help="process pool size (default 2)")
    ap.add_argument("--units-per-family", type=int, default=2, help="units per effect family (default 2)")
    ap.add_argument("--quick", action="store_true", help="a small subset, for wiring checks")
    ap.add_argument("--max-units", type=int, default=None, help="judge only the first N units")
    ap.add_argument("--seed", type=int, default=20250611, help="master seed (default 20250611)")
    ap.add_argument("--keep", default=None, help="write the logs here and keep them")
    ap.add_argument("--judge-dir", default=JUDGE_DIR, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    check_vocabulary()

    specs = gen.plan(args.units_per_family, args.seed, quick=args.quick)
    if args.max_units:
        specs = specs[:args.max_units]
    root = args.keep or tempfile.mkdtemp(prefix="sealed_bench_")
    os.makedirs(root, exist_ok=True)
    t_start = time.time()
    try:
        with ProcessPoolExecutor(max_workers=args.jobs) as ex:
            gen_out = list(ex.map(_generate, [(s, root) for s in specs]))
        truths = {uid: tr for uid, _, tr in gen_out}
        paths = {uid: p for uid, p, _ in gen_out}
        t_gen = time.time() - t_start
        n_eff = sum(not t["complete"] for t in truths.values())
        print(f"sealed benchmark: {len(specs)} units ({n_eff} with an effect from "
              f"{len({t['family'] for t in truths.values() if not t['complete']})} families, "
              f"{len(specs) - n_eff} complete), 3 sessions each, seed {args.seed}; "
              f"generation {t_gen:.0f} s", flush=True)
        print(f"{'mode':<12} {'units':>5} {'success':>8} {'fixed':>6} {'right':>6} {'wrong':>6} "
              f"{'missed':>6} {'f.alarm':>8} {'peer':>6} {'errors':>6} {'wall':>7}", flush=True)
        for name, one in MODES:
            t0 = time.time()
            tasks = [(uid, paths[uid], one, args.judge_dir) for uid in sorted(paths)]
            with ProcessPoolExecutor(max_workers=args.jobs, initializer=_silence) as ex:
                res = {uid: r for uid, _, r, _ in ex.map(_judge, tasks)}
            wall = time.time() - t0
            n, ne, nc, tot = aggregate(truths, res)
            print(f"{name:<12} {n:>5} {100.0 * tot['success'] / max(n, 1):>7.0f}% "
                  f"{tot['fixed']:>6} {tot['right']:>6} {tot['wrong']:>6} {tot['missed']:>6} "
                  f"{tot['false_alarm']:>4}/{nc:<3} {tot['peer_fixed']:>6} {tot['error']:>6} "
                  f"{wall:>6.0f}s", flush=True)
        print(f"total wall time {time.time() - t_start:.0f} s; fixed/right/wrong/missed/peer count "
              f"the {n_eff} effect units, f.alarm the complete ones; success counts all units",
              flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
