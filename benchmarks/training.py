"""A sealed set after its one run: a training set, judged whole with its own runner's rules
and printed unit by unit (which a sealed run never prints).

    PYTHONPATH=. python benchmarks/training.py sealed10 [--jobs 2] [--units V01 V02 ...]
                                                      [--logs DIR] [--out ROWS.json]

Each unit is built from the set's own generator and master seed (``plan``, ``build_unit``,
``write_unit``; sealed8 onwards), written once to ``--logs`` (kept there and reused on the next
run; a temporary folder otherwise), judged in both modes by ``benchmarks/judge.py`` and scored
by the set's ``run.score`` against the generator's truth. Prints one row per unit and mode, the
success per mode and the counts the sealed table gives. Only for sets already run once: its
rows name families, so running it on an unrun set unseals it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core per worker: the pool size is the load

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

MODES = (("two-session", False), ("one-log", True))
COUNTS = ("fixed", "right", "wrong", "spoiled", "missed", "false_alarm", "peer_fixed", "error")


def _set(name: str):
    return importlib.import_module(f"{name}.generator"), importlib.import_module(f"{name}.run")


def _built(args) -> tuple[str, list[str], dict]:
    name, spec, folder = args
    gen, _ = _set(name)
    unit = Path(folder) / spec["uid"]
    paths = sorted(str(p) for p in unit.glob("*.parquet"))
    truth_file = unit / "truth.json"
    if len(paths) == 3 and truth_file.exists():
        return spec["uid"], paths, json.loads(truth_file.read_text())
    built = gen.build_unit(spec)
    paths = [str(p) for p in gen.write_unit(built, str(unit))]
    truth = {k: sorted(v) if isinstance(v, set | tuple) else v for k, v in built["truth"].items()}
    truth_file.write_text(json.dumps(truth, default=str))
    return spec["uid"], paths, truth


def _judged(args) -> tuple[str, str, dict]:
    uid, paths, one_session = args
    from judge import judge_unit

    try:
        answer = judge_unit(list(paths), protocol="turntable", one_session=one_session)
    except Exception as exc:  # noqa: BLE001 - a crash is scored as an error
        answer = {"verdict": "error", "exception": f"{type(exc).__name__}: {exc}"}
    answer.pop("detail", None)
    return uid, "one-log" if one_session else "two-session", answer


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name", help="the set's folder under benchmarks/ (sealed8 onwards)")
    ap.add_argument("--jobs", type=int, default=2, help="process pool size (default 2)")
    ap.add_argument("--units", nargs="*", default=None, help="these units only")
    ap.add_argument("--logs", default=None, help="keep the logs here (reused when present)")
    ap.add_argument("--out", default=None, help="write the answers and scores as JSON here")
    args = ap.parse_args(argv)
    gen, run = _set(args.name)
    specs = [s for s in gen.plan() if not args.units or s["uid"] in args.units]
    folder = args.logs or tempfile.mkdtemp(prefix=f"{args.name}_training_")
    with ProcessPoolExecutor(args.jobs) as pool:
        built = list(pool.map(_built, [(args.name, s, folder) for s in specs]))
        truths = {uid: truth for uid, _, truth in built}
        for t in truths.values():
            for k in ("reads", "acts", "reasons"):
                t[k] = set(t.get(k) or ())
        jobs = [(uid, paths, one) for uid, paths, _ in built for _, one in MODES]
        rows: dict[str, dict] = {}
        for uid, mode, answer in pool.map(_judged, jobs):
            score = run.score(truths[uid], answer)
            rows.setdefault(uid, {})[mode] = {"answer": answer, "score": score}
            t = truths[uid]
            print(
                f"{uid} {mode:11s} {str(t.get('family')):16s} {answer.get('verdict')}"
                f" {answer.get('reason') or ''} {','.join(answer.get('reads') or [])}"
                f" {'success' if score['success'] else '-'}",
                flush=True,
            )
    for mode, _ in MODES:
        total = {k: sum(bool(rows[u][mode]["score"][k]) for u in rows) for k in (*COUNTS, "success")}
        share = 100.0 * total.pop("success") / max(len(rows), 1)
        print(
            f"{mode}: success {share:.0f} % of {len(rows)}; "
            + ", ".join(f"{k} {v}" for k, v in total.items())
        )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
