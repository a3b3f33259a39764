"""Run the twelfth sealed benchmark: write every unit's three sessions, judge each unit twice
(two-session diagnosis, then one-log diagnosis) and print an aggregate table only.

    /work/main/.venv/bin/python benchmarks/sealed12/run.py [--jobs 2] [--quick] [--max-units N]
                                                         [--seed S] [--keep DIR]
                                                         [--units-per-family K] [--private DIR]

Nothing per unit is printed (no family names, no parameters, no per-unit rows); every log is
validated against the contract; the per-unit breakdown goes to --private DIR only (default
/tmp/keeper12, outside the repository); the logs live in a temporary folder that is removed at
the end unless --keep is given.  The checkout judged is the one this file lies in (two folders up).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core per worker: the pool size is the load

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generator as gen  # noqa: E402

CHECKOUT = os.path.dirname(os.path.dirname(HERE))  # the checkout this runner lies in
JUDGE_DIR = os.path.join(CHECKOUT, "benchmarks")
MODES = (("two-session", False), ("one-log", True))

# judge.py's vocabulary (its interface docstring)
REASONS = (
    "mounting",
    "lab",
    "unit changed",
    "between points",
    "slow noise",
    "too small",
    "direction of approach",
    "unexplained",
)
READS = ("rate", "accel", "temperature", "thermal", "time", "mount")
ACTS = ("bias", "scale", "cross-axis")
SPOIL = 1.05  # a fix is "spoiled" when the unseen session is >5% worse than the default
KEYS = (
    "success",
    "fixed",
    "right",
    "wrong",
    "spoiled",
    "missed",
    "false_alarm",
    "peer_fixed",
    "peer_seen",
    "error",
)


# ---------------------------------------------------------------------------- workers
def _silence():
    """Pool initializer: whatever the judged code prints stays out of the table."""
    fd = os.open(os.devnull, os.O_WRONLY)
    os.dup2(fd, 1)
    os.dup2(fd, 2)


def _generate(args):
    spec, root = args
    built = gen.build_unit(spec)
    paths = gen.write_unit(built, os.path.join(root, spec["uid"]))
    probs = [f"{os.path.basename(p)}: {m}" for p in paths for m in gen.validate_log(p)]
    truth = dict(built["truth"], rows=[int(ss["t"].size) for ss in built["sessions"]], problems=probs)
    return spec["uid"], paths, truth


def _judge(args):
    uid, paths, one_session = args
    sys.path.insert(0, CHECKOUT)
    sys.path.insert(0, JUDGE_DIR)
    try:
        from judge import judge_unit

        r = judge_unit(list(paths), protocol="turntable", one_session=one_session)
        r = dict(r) if isinstance(r, dict) else {"verdict": "error"}
    except BaseException as exc:  # noqa: BLE001 - a crash is scored as an error
        r = {"verdict": "error", "exception": type(exc).__name__}
    r.pop("detail", None)  # never kept, never printed
    return uid, r


# ---------------------------------------------------------------------------- scoring
def check_vocabulary():
    """The generator's truth may only name words the judge can say."""
    bad = set()
    for F in gen.FAMILIES.values():
        bad |= set(F["reasons"]) - set(REASONS)
        bad |= set(F["reads"]) - set(READS)
        bad |= set(F["acts"] or ()) - set(ACTS)
    if bad:
        raise SystemExit(f"generator truth uses words outside the judge's vocabulary: {sorted(bad)}")


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if x == x else None


def _words(x):
    if x is None:
        return set()
    if isinstance(x, str):
        return {x}
    try:
        return {str(w) for w in x}
    except TypeError:
        return {str(x)}


def score(truth, r):
    """One unit's answer against the generator's truth -> dict of booleans."""
    v = r.get("verdict")
    out = dict.fromkeys(KEYS, False)
    if v not in ("quiet", "fix", "no_sensor_term"):
        out["error"] = True
        return out
    before = _num(r.get("next_before_rms"))
    after = _num(r.get("next_after_rms"))
    peer = _num(r.get("peer_next_after_rms"))
    if v == "fix" and after is not None and before is not None:
        out["spoiled"] = after > SPOIL * before
    if truth["complete"]:
        out["false_alarm"] = v != "quiet"
        out["success"] = v == "quiet"
        return out
    thr = truth["threshold"]
    out["fixed"] = v == "fix" and after is not None and after <= thr
    if v == "fix":
        story = bool(_words(r.get("reads")) & truth["reads"]) and bool(
            _words(r.get("acts_on")) & truth["acts"]
        )
        out["right"], out["wrong"] = story, not story
    elif v == "no_sensor_term":
        said = r.get("reason") in truth["reasons"]
        out["right"], out["wrong"] = said, not said
    else:
        out["missed"] = True
    out["peer_seen"] = peer is not None
    out["peer_fixed"] = peer is not None and peer <= thr
    out["success"] = (out["fixed"] and out["right"]) or (
        v == "no_sensor_term" and out["right"] and not truth["carried"]
    )
    return out


def aggregate(truths, results):
    tot = dict.fromkeys(KEYS, 0)
    for uid, t in truths.items():
        s = score(t, results.get(uid, {"verdict": "error"}))
        for k in KEYS:
            tot[k] += bool(s[k])
    return tot


# ---------------------------------------------------------------------------- private rows
def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (set, tuple, list)):
        return [_jsonable(v) for v in (sorted(x) if isinstance(x, set) else x)]
    if isinstance(x, (bool, str)) or x is None:
        return x
    try:
        return float(x) if not isinstance(x, int) else x
    except (TypeError, ValueError):
        return str(x)


def _write_private(folder, private, args):
    """Per-unit breakdown for the keeper only: never stdout, never the repository."""
    folder = os.path.abspath(folder)
    if folder.startswith(CHECKOUT + os.sep):
        raise SystemExit("--private must lie outside the repository")
    os.makedirs(folder, exist_ok=True)
    tag = "quick" if args.quick else "full"
    with open(os.path.join(folder, f"sealed12_{tag}_seed{args.seed}.json"), "w") as fh:
        json.dump(private, fh, indent=1, sort_keys=True)


# ---------------------------------------------------------------------------- main
HEADER = (
    f"{'mode':<12} {'units':>5} {'success':>8} {'fixed':>6} {'right':>6} {'wrong':>6} "
    f"{'spoiled':>7} {'missed':>6} {'f.alarm':>8} {'peer':>6} {'errors':>6} {'wall':>7}"
)


def main(argv=None):
    ap = argparse.ArgumentParser(description="twelfth sealed gyro-calibration diagnosis benchmark")
    ap.add_argument("--jobs", type=int, default=2, help="process pool size (default 2)")
    ap.add_argument("--quick", action="store_true", help="4 units, a wiring check")
    ap.add_argument("--max-units", type=int, default=None, help="judge only the first N units")
    ap.add_argument(
        "--seed", type=int, default=gen.MASTER_SEED, help=f"master seed (default {gen.MASTER_SEED})"
    )
    ap.add_argument("--keep", default=None, help="write the logs here and keep them")
    ap.add_argument("--units-per-family", type=int, default=3, help="units per effect family (default 3)")
    ap.add_argument(
        "--private",
        default="/tmp/keeper12",
        help="folder for the private per-unit breakdown (default /tmp/keeper12)",
    )
    args = ap.parse_args(argv)
    if os.path.abspath(args.private).startswith(CHECKOUT + os.sep):
        raise SystemExit("--private must lie outside the repository")
    check_vocabulary()
    jobs = max(1, args.jobs)

    specs = gen.plan(args.units_per_family, args.seed, quick=args.quick)
    if args.max_units:
        specs = specs[: args.max_units]
    root = args.keep or tempfile.mkdtemp(prefix="sealed12_bench_")
    os.makedirs(root, exist_ok=True)
    try:
        t0 = time.time()
        with ProcessPoolExecutor(max_workers=jobs) as ex:
            gen_out = list(ex.map(_generate, [(s, root) for s in specs]))
        t_gen = time.time() - t0
        truths = {uid: tr for uid, _, tr in gen_out}
        paths = {uid: p for uid, p, _ in gen_out}
        n = len(truths)
        n_comp = sum(t["complete"] for t in truths.values())
        bad = sum(bool(t["problems"]) for t in truths.values())
        if bad:
            print(f"contract validation: {bad} unit(s) with problems (see the private breakdown)")
        print(HEADER, flush=True)
        private = {uid: dict(truth=_jsonable(truths[uid]), answers={}) for uid in truths}
        for name, one in MODES:
            t1 = time.time()
            tasks = [(uid, paths[uid], one) for uid in sorted(paths)]
            with ProcessPoolExecutor(max_workers=jobs, initializer=_silence) as ex:
                res = dict(ex.map(_judge, tasks))
            wall = time.time() - t1 + t_gen / len(MODES)
            tot = aggregate(truths, res)
            for uid in truths:
                r = res.get(uid, {"verdict": "error"})
                private[uid]["answers"][name] = dict(answer=_jsonable(r), score=score(truths[uid], r))
            peer = f"{tot['peer_fixed']}" if tot["peer_seen"] else "n/a"
            print(
                f"{name:<12} {n:>5} {100.0 * tot['success'] / max(n, 1):>7.0f}% "
                f"{tot['fixed']:>6} {tot['right']:>6} {tot['wrong']:>6} {tot['spoiled']:>7} "
                f"{tot['missed']:>6} {tot['false_alarm']:>4}/{n_comp:<3} {peer:>6} "
                f"{tot['error']:>6} {wall:>6.0f}s",
                flush=True,
            )
        _write_private(args.private, private, args)
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
