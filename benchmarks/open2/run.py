"""Run the open2 units through the checkout's judge and score the answers against the truth.

The checkout judged is the one this file sits in (two folders up); its
``benchmarks/judge.py`` is called as ``judge_unit([s0, s1, s2], protocol="turntable",
one_session=...)`` in both modes for every unit.

    python benchmarks/open2/run.py [--jobs 2] [--quick] [--max-units N] [--seed S]
                                   [--keep DIR] [--family NAME] [--rows FILE]

Reference floor per unit: the larger of (a) the true hold-mean noise floor on session 2 (RMS of
the hold means of the simulated white noise and bias instability) and (b) what a complete
model leaves: the RMS hold-mean error on session 2 of this generator's own standard
per-temperature 12-parameter calibration of session 0, on the same unit simulated without
its effect. Effect magnitudes are multiples of that floor.
"""
from __future__ import annotations

import os

for _v in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS', 'NUMEXPR_NUM_THREADS'):
    os.environ.setdefault(_v, '1')

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHECKOUT = HERE.parents[1]
for _p in (str(HERE), str(CHECKOUT / 'benchmarks'), str(CHECKOUT)):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import generator as gen  # noqa: E402

TOL_FIXED = 1.2      # fixed: session 2 after the fix within 1.2 x the reference floor
TOL_SPOIL = 1.02     # spoiled: a fix leaves session 2 more than 2 % worse than the default


def _judge(paths, one):
    from judge import judge_unit
    t = time.time()
    try:
        r = judge_unit([str(p) for p in paths], protocol='turntable', one_session=one)
    except Exception as e:  # the judge should not raise; count it as an error verdict
        r = dict(verdict='error', reads=[], acts_on=None, reason=None,
                 detail=f'{type(e).__name__}: {e}')
    r = dict(r)
    r['seconds'] = round(time.time() - t, 2)
    return r


def work(job):
    unit, base, keep = job
    d = Path(base) / unit['name']
    t = time.time()
    paths, truth, _ = gen.generate_unit(unit, str(d))
    tgen = time.time() - t
    res = {'two': _judge(paths, False), 'one': _judge(paths, True)}
    if not keep:
        shutil.rmtree(d, ignore_errors=True)
    return unit, truth, res, tgen


def _ratio(x, f):
    return None if x is None else float(x) / f


def score(truth, r, mode):
    """Score one judge answer against the truth (see README.md, 'Scoring')."""
    F = truth['floor_ref']
    verdict = r.get('verdict')
    reads = sorted(r.get('reads') or [])
    acts = r.get('acts_on')
    reason = r.get('reason')
    before = _ratio(r.get('next_before_rms'), F)
    after = _ratio(r.get('next_after_rms'), F)
    peer = _ratio(r.get('peer_next_after_rms'), F)
    if verdict != 'fix' or after is None:
        after = before
    complete = truth['category'] == 'complete'
    too_small = before is not None and before <= TOL_FIXED
    fixed = after is not None and after <= TOL_FIXED
    right = None
    if verdict == 'fix' and not complete:
        rs = set(reads)
        right = bool(truth['fix_ok'] and rs & set(truth['reads_right'])
                     and rs <= set(truth['reads_right']) | set(truth['reads_ok'])
                     and acts in truth['acts_on'])
    elif verdict == 'no_sensor_term' and not complete:
        right = reason in truth['reasons']
    wrong = right is False
    spoiled = bool(verdict == 'fix' and before is not None and after is not None
                   and after > before * TOL_SPOIL)
    false_alarm = bool(complete and verdict != 'quiet')
    visible = truth['one_log_visible'] or mode == 'two'
    if complete:
        success = verdict == 'quiet'
    elif not visible:
        # a single log cannot reveal it: success is not to claim a wrong fix
        success = (verdict in ('quiet', 'no_sensor_term')
                   or (verdict == 'fix' and fixed and bool(right)))
    elif verdict == 'fix':
        success = bool(fixed and right)
    elif verdict == 'no_sensor_term':
        success = bool(right) or (too_small and reason == 'too small')
    elif verdict == 'quiet':
        success = too_small
    else:
        success = False
    return dict(verdict=verdict, reads=reads, acts_on=acts, reason=reason,
                before=before, after=after, peer=peer,
                judge_floor=_ratio(r.get('floor'), F), too_small=too_small,
                fixed=fixed, right=right, wrong=wrong, spoiled=spoiled,
                false_alarm=false_alarm, success=bool(success), visible=visible,
                detail=r.get('detail'), seconds=r.get('seconds'))


def _med(xs):
    xs = [x for x in xs if x is not None]
    return f'{statistics.median(xs):6.2f}' if xs else '     -'


def table(rows, mode):
    rs = [r for r in rows if r['mode'] == mode]
    lines = [f'mode: {"two-session (s0 diagnosed, s1 the other session)" if mode == "two" else "one-log (s0 only)"}',
             f'{"family":24s} {"cat":10s} {"n":>3s} {"succ":>5s} {"fixed":>5s} {"right":>5s} '
             f'{"wrong":>5s} {"spoil":>5s} {"quiet":>5s} {"f.a.":>4s} {"before":>6s} {"after":>6s} '
             f'{"peer":>6s}  verdicts']
    groups = {}
    for r in rs:
        groups.setdefault(r['family'], []).append(r)

    def line(name, cat, g):
        vs = {}
        for r in g:
            key = r['verdict'] if r['verdict'] != 'no_sensor_term' else f'nst:{r["reason"]}'
            vs[key] = vs.get(key, 0) + 1
        return (f'{name:24s} {cat:10s} {len(g):3d} {sum(r["success"] for r in g):5d} '
                f'{sum(r["fixed"] for r in g):5d} {sum(bool(r["right"]) for r in g):5d} '
                f'{sum(r["wrong"] for r in g):5d} {sum(r["spoiled"] for r in g):5d} '
                f'{sum(r["verdict"] == "quiet" for r in g):5d} '
                f'{sum(r["false_alarm"] for r in g):4d} {_med([r["before"] for r in g])} '
                f'{_med([r["after"] for r in g])} {_med([r["peer"] for r in g])}  '
                + ', '.join(f'{k} {v}' for k, v in sorted(vs.items())))
    order = list(gen.FAMILIES) + [gen.COMPLETE]
    for fam in order:
        if fam in groups:
            lines.append(line(fam, groups[fam][0]['category'], groups[fam]))
    lines.append('-' * 120)
    for cat in ('sensor', 'confusable', 'no_term', 'complete'):
        g = [r for r in rs if r['category'] == cat]
        if g:
            lines.append(line(f'[{cat}]', '', g))
    inv = [r for r in rs if not r['visible']]
    if inv:
        lines.append(line('[not in one log]', '', inv))
    lines.append(line('[all]', '', rs))
    return '\n'.join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--jobs', type=int, default=2)
    ap.add_argument('--quick', action='store_true',
                    help='one unit per family (the middle stratum) and two complete units')
    ap.add_argument('--max-units', type=int)
    ap.add_argument('--seed', type=int, default=20250611)
    ap.add_argument('--keep', metavar='DIR', help='keep the logs and truth files in DIR')
    ap.add_argument('--family', help='only this family (or "complete")')
    ap.add_argument('--rows', metavar='FILE', help='write the per-unit rows (JSON) here')
    a = ap.parse_args(argv)

    units = gen.make_units(a.seed, families=[a.family] if a.family else None)
    if a.quick:
        units = ([u for u in units if u['family'] != gen.COMPLETE and u['name'].endswith('_1')]
                 + [u for u in units if u['family'] == gen.COMPLETE][:2])
    if a.max_units:
        units = units[:a.max_units]
    if not units:
        ap.error('no units selected')
    base = a.keep or tempfile.mkdtemp(prefix='open2-')
    os.makedirs(base, exist_ok=True)
    jobs = [(u, base, bool(a.keep)) for u in units]
    t0 = time.time()
    print(f'open2: {len(units)} units, checkout {CHECKOUT}, jobs {a.jobs}, seed {a.seed}',
          flush=True)
    results = []
    if a.jobs <= 1:
        it = map(work, jobs)
    else:
        import multiprocessing as mp
        pool = mp.get_context('fork').Pool(a.jobs, maxtasksperchild=8)
        it = pool.imap_unordered(work, jobs)
    for unit, truth, res, tgen in it:
        results.append((unit, truth, res, tgen))
        s2 = score(truth, res['two'], 'two')
        s1 = score(truth, res['one'], 'one')
        print(f'{time.time() - t0:7.1f}s {unit["name"]:28s} mag {unit["magnitude"]:6.2f} '
              f'| two: {s2["verdict"]}/{s2["reason"] or ",".join(s2["reads"])}/{s2["acts_on"]} '
              f'{"OK" if s2["success"] else "--"} | one: {s1["verdict"]}/'
              f'{s1["reason"] or ",".join(s1["reads"])}/{s1["acts_on"]} '
              f'{"OK" if s1["success"] else "--"}', flush=True)
    if a.jobs > 1:
        pool.close(); pool.join()
    wall = time.time() - t0

    rows = []
    for unit, truth, res, tgen in sorted(results, key=lambda x: x[0]['name']):
        for mode in ('two', 'one'):
            s = score(truth, res[mode], mode)
            rows.append(dict(
                unit=unit['name'], family=truth['family'], category=truth['category'],
                variant=truth['variant'], magnitude=truth['magnitude'], mode=mode,
                one_log_visible=truth['one_log_visible'], floor_ref=truth['floor_ref'],
                noise_floor=truth['noise_floor'], complete_left=truth['complete_left'],
                my_before=truth['my_before'] / truth['floor_ref'],
                truth=dict(expected=truth['expected'], fix_ok=truth['fix_ok'],
                           reads_right=truth['reads_right'], reads_ok=truth['reads_ok'],
                           acts_on=truth['acts_on'], reasons=truth['reasons']),
                gen_seconds=round(tgen, 1), **s))
    print()
    out = []
    for mode in ('two', 'one'):
        out.append(table(rows, mode))
        out.append('')
    out.append(f'before/after/peer: median of session-2 hold-mean RMS over the reference floor '
               f'(max of true noise floor and complete-model residual); fixed <= {TOL_FIXED}; '
               f'spoiled: after > {TOL_SPOIL} x before.')
    out.append(f'units {len(units)}, wall {wall:.0f} s, jobs {a.jobs}')
    text = '\n'.join(out)
    print(text)
    if a.rows:
        with open(a.rows, 'w') as fh:
            json.dump(dict(seed=a.seed, wall_seconds=round(wall, 1), jobs=a.jobs,
                           checkout=str(CHECKOUT), rows=rows), fh, indent=1, default=float)
    if not a.keep:
        shutil.rmtree(base, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
