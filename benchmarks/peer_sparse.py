"""Benchmark: a generic sparse-regression peer of the missing-effect diagnosis (issue 52).

The baseline a data scientist would try: regress the default calibration's hold-mean
residuals on a library of candidate functions of the inputs the log has, keep a sparse
subset, fit it on ONE session and apply it to another session of the same unit. The
diagnosis has to fix more units than this does.

* Residual: each hold's error after the default calibration's interpolated compensation,
  compensated minus true rate, exactly as :func:`gyrocal.fleet.drift.revalidate` scores it
  (:func:`gyrocal.fleet.drift.hold_errors`), on the holds revalidate scores (within 1 °C
  of the calibrated span), on the fit session too; the peer's "before" figure on the unseen
  session is checked against revalidate's own RMS.
* Library (per output axis): own rate, the other axes' rates, |own rate|, its sign,
  specific force where logged, temperature, its rate, time since power-on, time within the
  temperature point's visit, the previous hold's own rate and the mount one-hot (the
  continuous inputs z-scored on the fit session); every monomial of them up to degree 2, and up to degree 3
  in own rate, |own rate|, temperature and time; columns z-scored on the fit session,
  constant and duplicate columns dropped, plus a constant.
* STLSQ: sequentially thresholded least squares with ridge, as pysindy's ``STLSQ``
  defines it (ridge on the kept columns, drop |coef| < threshold, repeat until the support
  stops changing, then an unregularised least-squares refit on the support: pysindy's
  ``unbias``). Written here rather than imported: pysindy brings a stack for a dozen lines,
  and the cross-validation reuses each fold's Gram matrix. Threshold and ridge strength are
  chosen by cross-validation on the fit session: leave one temperature point out (five
  interleaved folds of holds where there are fewer than three points); an infinite
  threshold, no correction, is one of the choices.
* Lasso: scikit-learn's ``LassoCV`` (50 penalties on its default path) over the same folds, when scikit-learn is installed
  (the optional ``bench`` extra: ``pip install -c requirements.lock -e '.[bench]'``).

``next_after_rms`` is the best peer's figure on the unseen session, chosen on that session:
generous to the peer, which is what a baseline to beat should be.

    python benchmarks/peer_sparse.py [--units 2] [--jobs 2] [--cases all|history] [--out FILE]

Prints per case the unseen session's (session 2's) hold-mean RMS ÷ floor before and after
each peer's fix fitted on session 0, and how many units each peer fixes (≤ 1.2 × the floor,
under coloured noise ÷ what the default leaves on the complete unit, as diagnosis.py counts).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import tempfile
import time
import warnings
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from itertools import combinations_with_replacement
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

AXES = ("x", "y", "z")
FIXED = 1.2  # diagnosis.py's criterion: the unseen session within 1.2x the floor
SPAN_MARGIN = 1.0  # revalidate's default: holds farther beyond the calibrated span are not scored
MAX_ITER = 20  # pysindy STLSQ's default
RIDGE = (1e-4, 1e-2, 1.0)  # ridge strengths tried, × the number of holds (columns are z-scored)
THRESHOLDS = 20  # thresholds tried per ridge strength, log-spaced over the ridge fit's |coef|
CUBIC = ("own", "|own|", "temp", "t")  # the bases whose degree-3 monomials the library holds


def has_sklearn() -> bool:
    try:
        import sklearn  # noqa: F401
    except ImportError:
        return False
    return True


# --------------------------------------------------------------------------- the library


def hold_inputs(obs) -> dict[str, np.ndarray]:
    """The hold-level inputs the library is built from, shared by the output axes: rates,
    specific force (where logged), temperature and its rate, time since power-on, time
    within the visit of the temperature point, each axis' previous hold's rate, and the
    mount (its label per hold)."""
    t_start = obs["t_start"].to_numpy(float)
    t_mid = 0.5 * (t_start + obs["t_end"].to_numpy(float))
    order = np.argsort(t_start, kind="stable")
    out = {f"rate_{a}": obs[f"rate_{a}"].to_numpy(float) for a in AXES}
    for a in AXES:
        if f"accel_{a}" in obs and np.isfinite(obs[f"accel_{a}"].to_numpy(float)).all():
            out[f"accel_{a}"] = obs[f"accel_{a}"].to_numpy(float)
    out["temp"] = obs["temp"].to_numpy(float)
    out["temp_rate"] = obs["temp_rate"].to_numpy(float)
    out["t"] = t_mid
    # A visit: a run of holds of one temperature point in time order (a point revisited
    # later starts a new visit, its clock at zero again).
    point = obs["point"].to_numpy()[order]
    new_visit = np.r_[True, point[1:] != point[:-1]]
    visit = np.cumsum(new_visit) - 1
    visit_start = t_start[order][new_visit][visit]
    t_point = np.empty_like(t_mid)
    t_point[order] = t_mid[order] - visit_start
    out["t_point"] = t_point
    for a in AXES:
        prev = np.empty_like(t_mid)
        prev[order] = np.r_[0.0, out[f"rate_{a}"][order][:-1]]
        out[f"prev_rate_{a}"] = prev
    out["mount"] = obs["mount"].astype(str).to_numpy()
    return out


def _bases(inputs: dict, axis: str, mounts: list[str]) -> dict[str, np.ndarray]:
    """The library's inputs for one output axis, under names a reader knows (own rate's
    monomials are named by its axis)."""
    own = inputs[f"rate_{axis}"]
    b = {"own": own}
    b.update({f"rate_{a}": inputs[f"rate_{a}"] for a in AXES if a != axis})
    b["|own|"] = np.abs(own)
    b["sign(own)"] = np.sign(own)
    b.update({k: inputs[k] for k in ("accel_x", "accel_y", "accel_z") if k in inputs})
    b.update({k: inputs[k] for k in ("temp", "temp_rate", "t", "t_point")})
    b["prev_own"] = inputs[f"prev_rate_{axis}"]
    b.update({f"mount[{m}]": (inputs["mount"] == m).astype(float) for m in mounts})
    return b


def _monomials(names: list[str]) -> list[tuple[int, ...]]:
    """Index tuples of the library's monomials: all of degree 1-2, and degree 3 among CUBIC."""
    idx = range(len(names))
    terms = [(i,) for i in idx] + list(combinations_with_replacement(idx, 2))
    cubic = [i for i, n in enumerate(names) if n in CUBIC]
    return terms + list(combinations_with_replacement(cubic, 3))


class Library:
    """One output axis' candidate columns, with the z-scoring of the fit session (bases, then
    monomials) kept to build the same columns on another session."""

    def __init__(self, inputs: dict, axis: str):
        self.axis = axis
        self.mounts = sorted(set(inputs["mount"]))
        bases = _bases(inputs, axis, self.mounts)
        names = list(bases)
        raw = np.column_stack([bases[n] for n in names])
        self.base_mean, self.base_std = raw.mean(0), raw.std(0)
        live = self.base_std > 1e-12 * np.maximum(1.0, np.abs(self.base_mean))
        # Indicators stay 0/±1 (one mount times another is then 0 and dropped, a one-hot
        # squared itself); the other inputs are z-scored before their products are taken.
        categorical = np.array([n.startswith(("mount[", "sign(")) for n in names])
        self.base_mean[categorical], self.base_std[categorical] = 0.0, 1.0
        self.base_names = [n for n, k in zip(names, live, strict=True) if k]
        self.base_mean, self.base_std = self.base_mean[live], self.base_std[live]
        self.terms = _monomials(self.base_names)
        cols = self._raw_columns(raw[:, live])
        mean, std = cols.mean(0), cols.std(0)
        keep = std > 1e-9 * np.maximum(1.0, np.abs(mean))
        z = (cols[:, keep] - mean[keep]) / std[keep]
        # Columns the same on every hold as an earlier one (a one-hot squared, |r|²=r²).
        _, first = np.unique(np.round(z, 9), axis=1, return_index=True)
        chosen = np.flatnonzero(keep)[np.sort(first)]
        self.terms = [self.terms[i] for i in chosen]
        self.mean, self.std = mean[chosen], std[chosen]
        self.names = ["1"] + [self._name(t) for t in self.terms]

    def _raw_columns(self, raw: np.ndarray) -> np.ndarray:
        z = (raw - self.base_mean) / self.base_std
        return np.column_stack([np.prod(z[:, list(t)], axis=1) for t in self.terms])

    def _name(self, term: tuple[int, ...]) -> str:
        counts = Counter(term)
        parts = []
        for i in sorted(counts):
            n = self.base_names[i].replace("own", f"rate_{self.axis}")
            parts.append(n if counts[i] == 1 else f"{n}^{counts[i]}")
        return "*".join(parts)

    def columns(self, inputs: dict) -> np.ndarray:
        """The library on a session's holds (n, 1 + terms): a constant, then the z-scored
        monomials (z-scored with the fit session's means and spreads)."""
        bases = _bases(inputs, self.axis, self.mounts)
        raw = np.column_stack([bases[n] for n in self.base_names])
        z = (self._raw_columns(raw) - self.mean) / self.std
        return np.column_stack([np.ones(len(raw)), z])


# --------------------------------------------------------------------------- the peers


def stlsq(X: np.ndarray, y: np.ndarray, threshold: float, alpha: float, gram=None) -> np.ndarray:
    """pysindy's STLSQ: ridge on the kept columns, columns with |coef| < threshold dropped,
    until the support stops changing (at most MAX_ITER passes), then least squares on the
    support (``unbias``). ``gram`` (X'X, X'y) spares recomputing them."""
    G, b = gram if gram is not None else (X.T @ X, X.T @ y)
    p = X.shape[1]
    keep = np.ones(p, dtype=bool)
    coef = np.zeros(p)
    for _ in range(MAX_ITER):
        if not keep.any():
            break
        k = np.flatnonzero(keep)
        coef = np.zeros(p)
        coef[k] = np.linalg.solve(G[np.ix_(k, k)] + alpha * np.eye(k.size), b[k])
        big = np.abs(coef) >= threshold
        done = big.sum() == keep.sum()
        keep = big
        if done:
            break
    coef = np.zeros(p)
    if keep.any():
        coef[keep] = np.linalg.lstsq(X[:, keep], y, rcond=None)[0]
    return coef


def folds(point: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Leave one temperature point out; five interleaved folds of holds where the session
    has fewer than three points."""
    idx = np.arange(len(point))
    groups = point if np.unique(point).size >= 3 else idx % 5
    return [(idx[groups != g], idx[groups == g]) for g in np.unique(groups)]


def fit_stlsq(X: np.ndarray, y: np.ndarray, splits) -> tuple[np.ndarray, dict]:
    """STLSQ with the threshold and ridge strength of least cross-validated error; an
    infinite threshold (no correction) is among the choices."""
    n = len(y)
    grams = [(X[tr], y[tr], (X[tr].T @ X[tr], X[tr].T @ y[tr])) for tr, _ in splits]
    best = (float(np.sum([np.sum(y[te] ** 2) for _, te in splits])), np.inf, RIDGE[0] * n)
    G, b = X.T @ X, X.T @ y
    for r in RIDGE:
        alpha = r * n
        top = np.abs(np.linalg.solve(G + alpha * np.eye(len(b)), b)).max()
        for threshold in np.geomspace(1e-3 * top, top, THRESHOLDS):
            sse = 0.0
            for (Xt, yt, gram), (_, te) in zip(grams, splits, strict=True):
                sse += float(np.sum((y[te] - X[te] @ stlsq(Xt, yt, threshold, alpha, gram)) ** 2))
                if sse >= best[0]:
                    break
            if sse < best[0]:
                best = (sse, float(threshold), alpha)
    coef = stlsq(X, y, best[1], best[2], (G, b)) if np.isfinite(best[1]) else np.zeros(X.shape[1])
    return coef, {"threshold": best[1], "ridge": best[2], "cv_rms": float(np.sqrt(best[0] / n))}


def fit_lasso(X: np.ndarray, y: np.ndarray, splits) -> tuple[np.ndarray, dict]:
    """scikit-learn's LassoCV on the z-scored columns (its own intercept in place of the
    constant column), over the same folds."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import LassoCV

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model = LassoCV(alphas=50, cv=splits, max_iter=2000, precompute=True).fit(X[:, 1:], y)
    coef = np.r_[model.intercept_, model.coef_]
    return coef, {"alpha": float(model.alpha_)}


PEERS = {"stlsq": fit_stlsq, "lasso": fit_lasso}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def _scored(cal, temp: np.ndarray) -> np.ndarray:
    """The holds revalidate scores: those within SPAN_MARGIN °C of the calibrated span
    (all, where none is)."""
    lo, hi = cal.grid.span
    use = np.maximum(lo - temp, temp - hi) <= SPAN_MARGIN
    return use if use.any() else np.ones(len(temp), dtype=bool)


def peer_next(log_fit, log_unseen, protocol: str, peers=None) -> dict:
    """The sparse-regression peers fitted on ``log_fit``'s residuals after the protocol's
    default calibration, applied with that calibration to ``log_unseen``'s holds.

    ``protocol`` is gyrocal's ("turntable", "sweep"; a zoo name "turntable3" is read as
    "turntable"); ``peers`` a subset of PEERS (default: STLSQ, and the Lasso where
    scikit-learn is installed). Returns ``next_before_rms`` and ``floor`` (revalidate's
    validation RMS and noise floor on the unseen session, deg/s), ``next_after_rms`` (the
    best peer's), ``next_after_by_peer``, ``fit_before_rms``/``fit_after_by_peer`` (the fit
    session, in sample), ``selected`` (each peer's kept terms per output axis) and ``fits``
    (each peer's chosen settings per axis).
    """
    from gyrocal.fleet.drift import hold_errors, revalidate
    from gyrocal.pipeline.chain import run, segment_log
    from gyrocal.pipeline.config import Settings

    protocol = "turntable" if protocol.startswith("turntable") else protocol
    if peers is None:
        peers = [p for p in PEERS if p != "lasso" or has_sklearn()]
    settings = Settings().for_protocol(protocol)
    cal = run(log_fit, settings, protocol=protocol).calibration
    obs_fit = segment_log(log_fit, settings, protocol).observations.reset_index(drop=True)
    obs_new = segment_log(log_unseen, settings, protocol).observations.reset_index(drop=True)
    check = revalidate(cal, obs_new)
    err_fit, _ = hold_errors(cal, obs_fit)
    err_new, _ = hold_errors(cal, obs_new)
    use_fit = _scored(cal, obs_fit["temp"].to_numpy(float))
    use_new = _scored(cal, obs_new["temp"].to_numpy(float))
    before = _rms(err_new[use_new])
    if not np.isclose(before, check["validation_rms"], rtol=1e-9, atol=0.0):
        raise AssertionError(f"the peer's residual {before} is not revalidate's {check['validation_rms']}")
    # Fitted on the holds revalidate would score on the fit session: beyond the calibrated
    # span the calibration says nothing, and its error there is no residual to learn from.
    in_fit = {k: v[use_fit] for k, v in hold_inputs(obs_fit).items()}
    in_new = hold_inputs(obs_new)
    y_fit = err_fit[use_fit]
    splits = folds(obs_fit["point"].to_numpy()[use_fit])
    fixed_fit = {p: y_fit.copy() for p in peers}
    fixed_new = {p: err_new.copy() for p in peers}
    selected: dict = {p: {} for p in peers}
    fits: dict = {p: {} for p in peers}
    for i, axis in enumerate(AXES):
        lib = Library(in_fit, axis)
        X, X_new = lib.columns(in_fit), lib.columns(in_new)
        for p in peers:
            coef, info = PEERS[p](X, y_fit[:, i], splits)
            fixed_fit[p][:, i] -= X @ coef
            fixed_new[p][:, i] -= X_new @ coef
            selected[p][axis] = [lib.names[j] for j in np.flatnonzero(coef)]
            fits[p][axis] = {**info, "columns": len(lib.names)}
    by_peer = {p: _rms(fixed_new[p][use_new]) for p in peers}
    return {
        "next_before_rms": before,
        "next_after_rms": min(by_peer.values()) if by_peer else before,
        "next_after_by_peer": by_peer,
        "floor": float(check["noise_floor"]),
        "fit_before_rms": _rms(err_fit[use_fit]),
        "fit_after_by_peer": {p: _rms(fixed_fit[p]) for p in peers},
        "holds_fit": int(use_fit.sum()),
        "holds_unseen": int(use_new.sum()),
        "selected": selected,
        "fits": fits,
    }


# --------------------------------------------------------------------------- the zoo


def write_sessions(case, unit_seed: int, folder: str, sessions=(0, 2)) -> list[Path]:
    """The zoo sessions of ``case`` that diagnosis.run_case writes, written the same way
    (the same unit, seeds, rates, ramps, overrides and file names)."""
    from benchmarks.diagnosis import RATE_HZ
    from benchmarks.zoo.generator import make_unit, write_session

    effect, protocol, noise = case[:3]
    overrides = case[4] if len(case) > 4 else {}
    session_overrides = case[5] if len(case) > 5 else {}
    unit = make_unit(effect=effect, protocol=protocol, noise=noise, seed=unit_seed, **overrides)
    by_session = bool(session_overrides) and all(isinstance(k, int) for k in session_overrides)
    per_session = {s: session_overrides.get(s, {}) if by_session else session_overrides for s in (0, 1, 2)}
    tag = "".join(f"-{k}{v:g}" for k, v in {**overrides, **({} if by_session else session_overrides)}.items())
    tag += "".join(f"-s{s}{k}{v}" for s, o in per_session.items() if by_session for k, v in o.items())
    paths = []
    for s in sessions:
        path = Path(folder) / f"{effect}-{protocol}{tag}-{noise}-{unit_seed}-s{s}.parquet"
        ramp = {"ramp_c_per_h": (30.0, 60.0, 45.0)[s]} if protocol == "sweep" else {}
        write_session(
            unit,
            path,
            session=s,
            seed=1000 * unit_seed + s,
            rate_hz=RATE_HZ.get(protocol, 25.0),
            **ramp,
            **per_session[s],
        )
        paths.append(path)
    return paths


def run_case(case, unit_seed: int, folder: str) -> dict:
    """One zoo unit: the peers fitted on session 0, judged on session 2."""
    from benchmarks.diagnosis import label
    from gyrocal.io.errors import GyrocalError

    effect, protocol, noise, expected = case[:4]
    row = {"effect": effect, "protocol": label(case), "noise": noise, "unit": unit_seed, "expected": expected}
    if protocol == "servo":  # revalidate needs a known true rate; diagnosis.py skips it too
        row["skipped"] = "servo: no known rate on the unseen session"
        return row
    started = time.perf_counter()
    fit, unseen = write_sessions(case, unit_seed, folder)
    try:
        r = peer_next(fit, unseen, protocol)
    except GyrocalError as exc:
        row["error"] = str(exc)
        return row
    row["seconds"] = round(time.perf_counter() - started, 1)
    row.update(r)
    row["before"] = r["next_before_rms"] / r["floor"]
    row["after"] = {
        p: v / r["floor"] for p, v in {"best": r["next_after_rms"], **r["next_after_by_peer"]}.items()
    }
    return row


def judged(rows: list[dict]) -> None:
    """Each row's before/after ratios judged as diagnosis.py judges a fix: ÷ the floor, and
    under coloured noise ÷ what the default leaves on the complete unit (effect "none") of
    the same protocol and seed, where the floor from static data leaves the wander out."""
    complete = {
        (r["protocol"], r["noise"], r["unit"]): r.get("before") for r in rows if r["effect"] == "none"
    }
    for r in rows:
        if "before" not in r:
            continue
        ref = complete.get((r["protocol"], r["noise"], r["unit"])) if r["noise"] != "white" else None
        ref = ref if isinstance(ref, float) and ref > 0 else 1.0
        r["judged_before"] = r["before"] / ref
        r["judged_after"] = {p: v / ref for p, v in r["after"].items()}


def totals(rows: list[dict]) -> list[str]:
    """The fixed counts per peer: units with an effect (expected not "none") brought within
    FIXED, of all and of those the default leaves beyond it; units the default holds within
    FIXED that a peer takes beyond it (and how many of them are complete)."""
    scored = [r for r in rows if "judged_after" in r]
    effect = [r for r in scored if r["expected"] != "none"]
    needing = [r for r in effect if r["judged_before"] > FIXED]
    complete = [r for r in scored if r["expected"] == "none"]
    peers = sorted({p for r in scored for p in r["judged_after"]}, key=lambda p: (p != "best", p))
    lines = [
        f"scored units: {len(scored)} ({len(rows) - len(scored)} not: servo or error); with an effect "
        f"{len(effect)}, of which the default leaves {len(needing)} beyond {FIXED}x; complete {len(complete)}",
        f"default alone within {FIXED}x: {sum(r['judged_before'] <= FIXED for r in effect)} of {len(effect)}",
    ]
    for p in peers:
        ok = [r for r in effect if r["judged_after"].get(p, np.inf) <= FIXED]
        fixed = [r for r in needing if r["judged_after"].get(p, np.inf) <= FIXED]
        spoilt = [r for r in scored if r["judged_before"] <= FIXED < r["judged_after"].get(p, np.inf)]
        worse = [r for r in spoilt if r["expected"] == "none"]
        lines.append(
            f"{p:>6}: within {FIXED}x {len(ok)} of {len(effect)} units with an effect; fixed {len(fixed)} "
            f"of {len(needing)} the default leaves beyond; taken beyond {FIXED}x where the default "
            f"held: {len(spoilt)} ({len(worse)} of {len(complete)} complete units)"
        )
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=2)
    parser.add_argument("--cases", choices=("all", "history"), default="all")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", help="write the rows as JSON here")
    args = parser.parse_args(argv)
    from diagnosis import CASES, HISTORY
    from host import cores, cpu_name

    cases = {"all": CASES, "history": HISTORY}[args.cases]
    started = time.perf_counter()
    # One BLAS thread per worker: the matrices are small, and threads of several workers
    # contending for two shared cores made a unit take 20 times as long. Spawned workers
    # import numpy afresh, under these variables.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    spawn = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory() as folder, ProcessPoolExecutor(args.jobs, mp_context=spawn) as pool:
        jobs = [pool.submit(run_case, c, seed, folder) for c in cases for seed in range(1, args.units + 1)]
        rows = [j.result() for j in jobs]
    judged(rows)
    print(
        f"# {time.strftime('%Y-%m-%d')}, {cpu_name()}, {cores()}, {len(rows)} units, "
        f"{time.perf_counter() - started:.0f} s; peers: stlsq"
        + (", lasso (scikit-learn)" if has_sklearn() else " (scikit-learn not installed: no lasso)")
    )
    print("next session (2) ÷ floor, before -> after each peer fitted on session 0; terms kept (x/y/z)")
    for r in rows:
        head = f"{r['effect']:>24} {r['protocol']:>10} {r['noise']:>8} u{r['unit']}"
        if "judged_after" not in r:
            print(f"{head}  {r.get('skipped') or 'error: ' + str(r.get('error'))}")
            continue
        after = "  ".join(f"{p} {v:.3g}" for p, v in r["judged_after"].items())
        kept = "  ".join(
            f"{p} {'/'.join(str(len(r['selected'][p][a])) for a in AXES)}" for p in r["selected"]
        )
        print(f"{head}  {r['judged_before']:.3g} -> {after}  [{kept}]  {r['seconds']:.0f} s")
    print()
    print("\n".join(totals(rows)))
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
