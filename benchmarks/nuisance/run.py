"""Run the open nuisance benchmark: complete units only, every rig/chamber/operator/logger
nuisance drawn wide; judge each unit in both modes and compare the tool's default
calibration with the standard calibration computed here.

    PYTHONPATH=<checkout> /work/main/.venv/bin/python benchmarks/nuisance/run.py
        [--units 60] [--jobs 2] [--seed 20250611] [--keep DIR] [--rows FILE] [--first K]

Per unit (open benchmark, printed and written to --rows): both verdicts and reasons,
next_before_rms, the reference floor (larger of the white hold-mean floor and the standard
calibration's session-2 error), the tool/floor ratio and the standard/floor ratio, and every
nuisance parameter drawn.  The checkout judged is the one this file lies in (two folders up).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_v, "1")   # one core per worker: the pool size is the load

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generator as gen  # noqa: E402

CHECKOUT = os.path.dirname(os.path.dirname(HERE))
JUDGE_DIR = os.path.join(CHECKOUT, "benchmarks")
MODES = (("two-session", False), ("one-log", True))
DEFAULT_SEED = 20250611

# pass criteria (fixed before any run of the tool on this set)
PASS_MEDIAN = 1.05
PASS_P95 = 1.2
PASS_FA = 0.05

# nuisance parameters the aggregate is split by: name -> "cont" (terciles) or "cat"
SPLITS = {
    "hold_drift_max": "cont", "hold_drift_frac": "cont", "hold_drift_frac_log": "cont",
    "door_dip": "cont", "tau_door": "cont", "offpoint_dT": "cont", "offpoint_eff": "cont",
    "k_bi": "cont", "bi_kind": "cat", "bi_tau_max": "cont", "k_rep": "cont",
    "tau_case": "cont", "two_stage": "cat", "self_heat": "cont", "sh_unsettled": "cont",
    "conv": "cont", "sensor_mode": "cat", "sensor_track": "cont", "sensor_track_eff": "cont",
    "temp_lsb": "cat", "temp_noise": "cont",
    "seat_eff": "cont", "power_cycle": "cat", "handle_s": "cont", "tremor": "cont",
    "hand_mix": "cont",
    "n_mounts": "cat", "n_rates": "cat", "rmax": "cat", "hold_s": "cont", "fs": "cat",
    "n_points0": "cat", "rate_kind0": "cat", "rate_kind2": "cat", "temp_kind0": "cat",
    "shift2": "cat", "revisit0": "cat", "pauses0": "cat", "power_on0": "cat",
    "soak_log": "cat", "accel_cols": "cat", "rad_units": "cat", "time_kind": "cat",
    "mount_col": "cat", "ref_noise": "cat", "interp_eff": "cont", "arw": "cont",
    "std_over_white": "cont",
}


# ---------------------------------------------------------------------------- worker
def _silence():
    """Pool initializer: whatever the judged code prints stays out of the output."""
    fd = os.open(os.devnull, os.O_WRONLY)
    os.dup2(fd, 1)
    os.dup2(fd, 2)


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _unit(args):
    seed, index, root, keep = args
    row = {"index": index}
    t0 = time.time()
    P = gen.draw_unit(seed, index)
    uid = P["uid"]
    row["uid"] = uid
    built = gen.build_unit(P)
    folder = os.path.join(root, uid)
    paths = gen.write_unit(built, folder)
    row["gen_s"] = time.time() - t0
    row["contract"] = sum((gen.validate_log(p) for p in paths), [])
    ref = gen.reference_floor(built)
    row.update({"white_floor": ref["white"], "standard_rms": ref["standard"],
                "ref_floor": ref["floor"], "std_ratio": ref["standard"] / ref["floor"]})
    tr = dict(built["trace"])
    tr["std_over_white"] = ref["standard"] / ref["white"]
    row["trace"] = tr
    del built
    sys.path.insert(0, CHECKOUT)
    sys.path.insert(0, JUDGE_DIR)
    for name, one in MODES:
        t1 = time.time()
        try:
            from judge import judge_unit
            r = judge_unit(list(paths), protocol="turntable", one_session=one)
            r = dict(r) if isinstance(r, dict) else {"verdict": "error"}
        except BaseException as exc:  # noqa: BLE001 - a crash is recorded as an error
            r = {"verdict": "error", "exception": f"{type(exc).__name__}: {exc}"[:300]}
        det = r.pop("detail", None)
        r = {k: (v if isinstance(v, (str, int, float, bool, type(None), list)) else str(v))
             for k, v in r.items()}
        if det is not None:
            r["detail"] = str(det)[:400]
        nb = _num(r.get("next_before_rms"))
        r["ratio"] = nb / ref["floor"] if nb is not None else None
        r["judge_s"] = time.time() - t1
        row[name] = r
    if not keep:
        shutil.rmtree(folder, ignore_errors=True)
    return row


# ---------------------------------------------------------------------------- aggregate
def _pct(x, q):
    return float(np.percentile(x, q)) if len(x) else float("nan")


def _dist(x):
    x = [v for v in x if v is not None]
    if not x:
        return "   n/a"
    return (f"{np.median(x):6.3f} {_pct(x, 90):6.3f} {_pct(x, 95):6.3f} {max(x):6.3f}")


def _fa(r):
    return r.get("verdict") not in ("quiet", "error")


def _err(r):
    return r.get("verdict") == "error"


def _bins(rows, key, kind):
    vals = [r["trace"].get(key) for r in rows]
    if kind == "cat":
        labels = [str(v) for v in vals]
        return labels, sorted(set(labels), key=lambda s: (len(s), s))
    v = np.array([float(x) for x in vals])
    q1, q2 = np.percentile(v, [100 / 3, 200 / 3])
    labels = []
    for x in v:
        labels.append(f"<={q1:.3g}" if x <= q1 else (f"({q1:.3g},{q2:.3g}]" if x <= q2 else f">{q2:.3g}"))
    order = [f"<={q1:.3g}", f"({q1:.3g},{q2:.3g}]", f">{q2:.3g}"]
    return labels, [o for o in order if o in labels]


def aggregate(rows, out=print):
    rows = sorted(rows, key=lambda r: r["index"])
    n = len(rows)
    out("")
    out(f"=== nuisance benchmark: {n} complete units ===")
    bad = [r["uid"] for r in rows if r.get("contract")]
    out(f"contract problems in logs: {len(bad)} units {bad[:10]}")
    out("")
    out(f"{'mode':<12} {'units':>5} {'f.alarm':>8} {'rate':>6} {'errors':>6}  by reason")
    summary = {}
    for name, _ in MODES:
        rs = [r[name] for r in rows]
        fa = sum(_fa(r) for r in rs)
        er = sum(_err(r) for r in rs)
        reasons = {}
        for r in rs:
            if _fa(r):
                k = r.get("verdict") + (f":{r.get('reason')}" if r.get("reason") else "")
                reasons[k] = reasons.get(k, 0) + 1
        rtxt = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
        out(f"{name:<12} {n:>5} {fa:>8} {100.0 * fa / max(n, 1):>5.1f}% {er:>6}  {rtxt}")
        summary[name] = {"fa": fa, "fa_rate": fa / max(n, 1), "errors": er, "reasons": reasons}
    out("")
    out("default calibration of session 0 on session 2, over the reference floor")
    out(f"{'':<34} {'median':>6} {'p90':>6} {'p95':>6} {'max':>6}")
    tool = [r["two-session"].get("ratio") for r in rows]
    tool1 = [r["one-log"].get("ratio") for r in rows]
    std = [r["std_ratio"] for r in rows]
    out(f"{'tool next_before / floor (2-sess)':<34} {_dist(tool)}")
    out(f"{'tool next_before / floor (1-log)':<34} {_dist(tool1)}")
    out(f"{'standard (own) / floor':<34} {_dist(std)}")
    out(f"{'standard / white floor':<34} {_dist([r['trace']['std_over_white'] for r in rows])}")
    gf = [(_num(r['two-session'].get('floor')) or float('nan')) / r['white_floor'] for r in rows]
    out(f"{'judge floor / white floor':<34} {_dist([x for x in gf if x == x])}")
    tv = [x for x in tool if x is not None]
    med, p95 = (np.median(tv), _pct(tv, 95)) if tv else (float("nan"),) * 2
    ok_ratio = bool(tv) and med <= PASS_MEDIAN and p95 <= PASS_P95
    ok_fa = all(summary[m]["fa_rate"] <= PASS_FA for m, _ in MODES)
    out("")
    out(f"PASS criteria: median <= {PASS_MEDIAN} ({med:.3f}: {'ok' if med <= PASS_MEDIAN else 'FAIL'}), "
        f"p95 <= {PASS_P95} ({p95:.3f}: {'ok' if p95 <= PASS_P95 else 'FAIL'}), "
        f"false alarms <= {100 * PASS_FA:.0f}% per mode ("
        + ", ".join(f"{m} {100 * summary[m]['fa_rate']:.1f}%" for m, _ in MODES)
        + f": {'ok' if ok_fa else 'FAIL'}) -> {'PASS' if ok_ratio and ok_fa else 'FAIL'}")

    # splits (buffered: the association summary is printed first)
    final_out = out
    buf = []
    out = buf.append
    out("")
    out("split by nuisance parameter: n | f.alarm 2-sess, 1-log | tool ratio median p90 p95 max")
    assoc = []
    for key, kind in SPLITS.items():
        if key not in rows[0]["trace"]:
            continue
        labels, order = _bins(rows, key, kind)
        if len(order) < 2:
            continue
        out(f"  {key}")
        fa_rates = []
        meds = []
        tails = []
        for b in order:
            sel = [r for r, l in zip(rows, labels) if l == b]
            f2 = sum(_fa(r["two-session"]) for r in sel)
            f1 = sum(_fa(r["one-log"]) for r in sel)
            rat = [r["two-session"].get("ratio") for r in sel]
            out(f"    {b:<22} {len(sel):>3} | {f2:>3} {f1:>3} | {_dist(rat)}")
            if len(sel) >= 3:
                fa_rates.append((f2 + f1) / (2 * len(sel)))
                rv = [x for x in rat if x is not None]
                if rv:
                    meds.append(_pct(rv, 90))
                    tails.append((sum(x > PASS_P95 for x in rv) / len(rv), b))
        rho = None
        if kind == "cont":
            from scipy.stats import spearmanr
            pairs = [(float(r["trace"][key]), r["two-session"].get("ratio")) for r in rows
                     if r["two-session"].get("ratio") is not None]
            if len(pairs) > 4:
                rho = float(spearmanr([p[0] for p in pairs], [p[1] for p in pairs]).correlation)
        auc = None
        if kind == "cont":
            x = np.array([float(r["trace"][key]) for r in rows])
            y = np.array([_fa(r["two-session"]) or _fa(r["one-log"]) for r in rows])
            if 0 < y.sum() < len(y):
                from scipy.stats import rankdata
                rk = rankdata(x)
                n1 = y.sum()
                auc = float((rk[y].sum() - n1 * (n1 + 1) / 2) / (n1 * (len(y) - n1)))
        assoc.append({"key": key, "rho": rho, "auc": auc,
                      "fa_spread": (max(fa_rates) - min(fa_rates)) if len(fa_rates) > 1 else 0.0,
                      "p90_spread": (max(meds) - min(meds)) if len(meds) > 1 else 0.0,
                      "tail": (max(tails)[0] - min(tails)[0]) if len(tails) > 1 else 0.0,
                      "tail_bins": (min(tails), max(tails)) if len(tails) > 1 else None})
    out = final_out
    out("")
    out("most associated with the worst ratios (|Spearman rho| of tool ratio; p90 spread across bins):")
    for a in sorted([a for a in assoc if a["rho"] is not None], key=lambda a: -abs(a["rho"]))[:6]:
        out(f"  {a['key']:<18} rho {a['rho']:+.2f}   p90 spread {a['p90_spread']:.3f}")
    out(f"most associated with the tail (share of units with ratio > {PASS_P95}: best bin -> worst bin):")
    for a in sorted(assoc, key=lambda a: -a["tail"])[:8]:
        (lo, blo), (hi, bhi) = a["tail_bins"] or ((0, "-"), (0, "-"))
        out(f"  {a['key']:<18} {100 * lo:4.0f}% ({blo}) -> {100 * hi:4.0f}% ({bhi})")
    out("most associated with false alarms (spread of the false-alarm rate across bins, bins >= 3 units;"
        " AUC: P(param of a false-alarm unit > that of a quiet unit), continuous only):")
    for a in sorted(assoc, key=lambda a: -a["fa_spread"])[:8]:
        auc = f"AUC {a['auc']:.2f}" if a["auc"] is not None else ""
        out(f"  {a['key']:<18} FA-rate spread {a['fa_spread']:.2f}  {auc}")
    out("continuous parameters farthest from AUC 0.5 for false alarms:")
    for a in sorted([a for a in assoc if a["auc"] is not None], key=lambda a: -abs(a["auc"] - 0.5))[:6]:
        out(f"  {a['key']:<18} AUC {a['auc']:.2f}  FA-rate spread {a['fa_spread']:.2f}")
    for line in buf:
        out(line)
    return summary


# ---------------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description="open nuisance benchmark (complete units)")
    ap.add_argument("--units", type=int, default=60)
    ap.add_argument("--first", type=int, default=0, help="index of the first unit (default 0)")
    ap.add_argument("--jobs", type=int, default=2, help="process pool size (default 2)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--keep", default=None, help="write the logs here and keep them")
    ap.add_argument("--rows", default=None, help="write per-unit JSON rows here")
    ap.add_argument("--aggregate-only", default=None, metavar="ROWS",
                    help="print the aggregate of a rows file and exit")
    args = ap.parse_args(argv)
    if args.aggregate_only:
        with open(args.aggregate_only) as fh:
            aggregate(json.load(fh))
        return 0
    jobs = max(1, min(args.jobs, 2))
    root = args.keep or tempfile.mkdtemp(prefix="nuisance_bench_")
    os.makedirs(root, exist_ok=True)
    rows = []
    t0 = time.time()
    try:
        tasks = [(args.seed, i, root, bool(args.keep))
                 for i in range(args.first, args.first + args.units)]
        with ProcessPoolExecutor(max_workers=jobs, initializer=_silence) as ex:
            futs = [ex.submit(_unit, t) for t in tasks]
            for f in as_completed(futs):
                r = f.result()
                rows.append(r)
                a, b = r["two-session"], r["one-log"]
                ra = f"{a['ratio']:.3f}" if a.get("ratio") is not None else "n/a"
                print(f"{r['uid']} gen {r['gen_s']:.1f}s judge {a['judge_s']:.0f}+{b['judge_s']:.0f}s "
                      f"2s={a.get('verdict')}:{a.get('reason')} 1l={b.get('verdict')}:{b.get('reason')} "
                      f"tool/floor {ra} std/floor {r['std_ratio']:.3f} "
                      f"floor {r['ref_floor']:.4g} (white {r['white_floor']:.4g})"
                      + (f" CONTRACT {r['contract']}" if r["contract"] else ""), flush=True)
                if args.rows:
                    with open(args.rows, "w") as fh:
                        json.dump(sorted(rows, key=lambda r: r["index"]), fh, indent=1,
                                  default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    aggregate(rows)
    print(f"\nwall {time.time() - t0:.0f}s for {len(rows)} units, {jobs} jobs", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
