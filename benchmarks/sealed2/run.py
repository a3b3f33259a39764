"""Run the second sealed benchmark: write every unit's three sessions, judge each unit twice
(two-session diagnosis, then one-log diagnosis) and print aggregate scores only.

    /work/main/.venv/bin/python benchmarks/sealed2/run.py [--jobs 2] [--quick] [--max-units N]
                                                         [--seed S] [--keep DIR]

Nothing per unit is printed or written (no family names, no parameters, no per-unit rows);
the logs live in a temporary folder that is removed at the end unless --keep is given.
"""
from __future__ import annotations

import os

# One BLAS thread per worker: on a 2-core machine a pool of numpy processes that each spin a
# BLAS thread pool runs several times slower. Set before numpy is first imported.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generator as gen  # noqa: E402

CHECKOUT = os.path.dirname(os.path.dirname(HERE))   # the checkout this runner lies in
JUDGE_DIR = os.path.join(CHECKOUT, "benchmarks")
MODES = (("two-session", False), ("one-log", True))
DEFAULT_SEED = 20260514

# The judge's vocabulary (judge.py's interface docstring).
REASONS = ("mounting", "lab", "unit changed", "between points", "slow noise", "too small",
           "direction of approach", "unexplained")
READS = ("rate", "accel", "temperature", "thermal", "time", "mount")
ACTS = ("bias", "scale", "cross-axis")
SPOIL_TOL = 1.02     # a fix "spoils" a unit when session 2 ends more than 2 % worse than default


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
    sys.path.insert(0, CHECKOUT)
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
    """Every word in the generator's truth must be one the judge can say."""
    bad = set()
    for F in gen.FAMILIES.values():
        bad |= set(F["reasons"]) - set(REASONS)
        bad |= set(F["reads"]) - set(READS)
        bad |= set(F["acts"]) - set(ACTS)
    if bad:
        raise SystemExit(f"generator truth uses words outside the judge's vocabulary: {sorted(bad)}")


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if x == x else None


def score(truth, r):
    """One unit's result against the generator's truth -> dict of booleans."""
    v = r.get("verdict")
    out = dict(success=False, fixed=False, right=False, wrong=False, spoiled=False,
               missed=False, false_alarm=False, peer_fixed=False, error=False)
    if v not in ("quiet", "fix", "no_sensor_term"):
        out["error"] = True
        return out
    before = _num(r.get("next_before_rms"))
    after = _num(r.get("next_after_rms"))
    out["spoiled"] = (v == "fix" and before is not None and after is not None
                      and after > SPOIL_TOL * before)
    if truth["complete"]:
        out["false_alarm"] = v != "quiet"
        out["success"] = v == "quiet"
        return out
    thr = truth["threshold"]
    peer = _num(r.get("peer_next_after_rms"))
    reads = set(r.get("reads") or [])
    acts = r.get("acts_on")
    acts = set(acts) if isinstance(acts, (list, tuple, set)) else {acts}
    reason = r.get("reason")
    if v == "fix":
        out["fixed"] = after is not None and after <= thr
        out["right"] = bool(reads & truth["reads"]) and bool(acts & truth["acts"])
        out["wrong"] = not out["right"]
    elif v == "no_sensor_term":
        out["right"] = reason in REASONS and reason in truth["reasons"]
        out["wrong"] = not out["right"]
    else:
        out["missed"] = True
    out["peer_fixed"] = peer is not None and peer <= thr
    out["success"] = ((out["fixed"] and out["right"])
                      or (v == "no_sensor_term" and out["right"] and truth["reason_ok"]))
    return out


KEYS = ("success", "fixed", "right", "wrong", "spoiled", "missed", "false_alarm",
        "peer_fixed", "error")


def aggregate(truths, results):
    tot = dict.fromkeys(KEYS, 0)
    for uid, t in truths.items():
        s = score(t, results.get(uid, {"verdict": "error"}))
        for k in KEYS:
            tot[k] += bool(s[k])
    return tot


# ---------------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description="second sealed gyro-calibration diagnosis benchmark")
    ap.add_argument("--jobs", type=int, default=2, help="process pool size (default 2)")
    ap.add_argument("--units-per-family", type=int, default=2, help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="4 units, for wiring checks")
    ap.add_argument("--max-units", type=int, default=None, help="judge only the first N units")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED,
                    help=f"master seed (default {DEFAULT_SEED})")
    ap.add_argument("--keep", default=None, help="write the logs here and keep them")
    ap.add_argument("--judge-dir", default=JUDGE_DIR, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    check_vocabulary()

    specs = gen.plan(args.units_per_family, args.seed, quick=args.quick)
    if args.max_units:
        specs = specs[:args.max_units]
    root = args.keep or tempfile.mkdtemp(prefix="sealed2_bench_")
    os.makedirs(root, exist_ok=True)
    t_start = time.time()
    try:
        with ProcessPoolExecutor(max_workers=args.jobs) as ex:
            gen_out = list(ex.map(_generate, [(s, root) for s in specs]))
        truths = {uid: tr for uid, _, tr in gen_out}
        paths = {uid: p for uid, p, _ in gen_out}
        n = len(truths)
        n_comp = sum(t["complete"] for t in truths.values())
        n_eff = n - n_comp
        print(f"sealed2 benchmark: {n} units ({n_eff} with an effect, {n_comp} complete), "
              f"3 sessions each, seed {args.seed}; generation {time.time() - t_start:.0f} s",
              flush=True)
        print(f"{'mode':<12} {'units':>5} {'success':>8} {'fixed':>6} {'right':>6} {'wrong':>6} "
              f"{'spoiled':>7} {'missed':>6} {'f.alarm':>8} {'peer':>5} {'errors':>6} {'wall':>7}",
              flush=True)
        for name, one in MODES:
            t0 = time.time()
            # the larger (six-mount) units first, so that no long unit is left alone at the end
            order = sorted(paths, key=lambda u: (not truths[u]["six"], u))
            tasks = [(uid, paths[uid], one, args.judge_dir) for uid in order]
            with ProcessPoolExecutor(max_workers=args.jobs, initializer=_silence) as ex:
                res = {uid: r for uid, _, r, _ in ex.map(_judge, tasks)}
            wall = time.time() - t0
            tot = aggregate(truths, res)
            print(f"{name:<12} {n:>5} {100.0 * tot['success'] / max(n, 1):>7.0f}% "
                  f"{tot['fixed']:>6} {tot['right']:>6} {tot['wrong']:>6} {tot['spoiled']:>7} "
                  f"{tot['missed']:>6} {tot['false_alarm']:>4}/{n_comp:<3} {tot['peer_fixed']:>5} "
                  f"{tot['error']:>6} {wall:>6.0f}s", flush=True)
        print(f"total wall time {time.time() - t_start:.0f} s; fixed/right/wrong/missed/peer count "
              f"the {n_eff} effect units, f.alarm the {n_comp} complete ones, spoiled and errors "
              f"all units; success % is over all units", flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
