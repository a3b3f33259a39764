"""The simulation study of seed 001, Section III: estimation errors of k and b over many
simulated units and runs (Figs 2 and 5), and their mean squared error against the servo
speed (Fig. 4, Eq 9).

Each run is one six-observation calibration (Fig. 1). An observation is the mean raw output
over one revolution (Eq 8), generated directly in distribution: per-sample white noise of
standard deviation σ averaged over N samples is N(0, σ²/N) per axis, so no sample is
drawn. The true rate is the servo speed about the sensor axis tilted by the hand-mounting
misalignment (its sine ~ U(0, 10 %), Section III-A 2), in a random azimuth); raw output
``m = g / k - b`` (seed 001's convention, see :mod:`gyrocal.protocols.servo.fit`).

Speed ripple (Section III-A 4, 5 % of the speed): ``ripple_mode="periodic"`` (default) is the
servo of Section II-B, whose ripple is periodic in the revolution and cancels in the
revolution mean; ``"white"`` takes assumption 4 literally, independent per-sample speed
errors, whose revolution mean is N(0, (0.05 ω)² / N) common to the three axes and enters
against the commanded speed. The paper's spreads (scale errors ~5.7x smaller than at σ = 0.2
with σ = 0.035, the same ratio for biases) fit the periodic ripple; white ripple would
dominate the scale error at σ = 0.035.

Speed and sample count: the paper does not state them for Section III-A. Three of its
figures agree with 3 rad/s and one revolution at 200 Hz (N = 419): the first-iteration
offsets of Table I, the ratio of scale to bias error in Fig. 2 (≈ k²/ω ≈ 0.31) and the
bias spread (σ/√(2N) per side). Those are the defaults of :func:`study`. For Fig. 4 the
paper says the bias MSE does not change with speed, which holds only for a fixed sample
count per observation: :func:`speed_sweep` keeps N fixed (419) unless told otherwise.

Algorithm 1 runs batched over all runs (:func:`gyrocal.protocols.servo.fit.algorithm1`, stacked 6x6
solves). The LM reference is scipy's ``least_squares(method="lm")`` called per run (about
0.5 ms each); ``lm_runs`` limits it to the first runs of every set.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import matplotlib
import numpy as np
import pandas as pd

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402

from ...io import atomic
from ...io.errors import ConfigError  # noqa: E402
from ...report import plots  # noqa: E402
from ...simulate.servo import DIRECTIONS, direction_axis, draw_parameters, tilted_axes  # noqa: E402
from .fit import (
    PARAMETERS,
    ServoFit,
    ServoFitError,
    algorithm1,
    fit_iterative,
    initial_guess,
    lm_solve,
    parameters_from_beta,
)

CONDITIONS = {"normal": (1, False), "extreme": (2, True)}  # name -> (seed code, extreme ranges)
PAPER_SPEED = 3.0  # rad/s, see the module docstring
PAPER_RATE = 200.0  # Hz, Section III-A 3)
PAPER_SAMPLES = int(round(PAPER_RATE * 2 * math.pi / PAPER_SPEED))  # one revolution: 419
FIG4_SPEEDS = tuple(np.round(np.arange(0.3, 3.0 + 1e-9, 0.1), 1))  # Section III-B
# Seed 001's figures keep the frame and the hash salt they were first drawn with, so that
# their files (and the papers' page that inlines them) stay the same bytes.
_STYLE = {"svg.hashsalt": "gyrocal-servo", "axes.spines.top": True, "axes.spines.right": True}


def _rng(*key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(k) for k in key]))


def _noise_code(noise: float) -> int:
    return int(round(noise * 1e6))


def simulate_observations(
    k: np.ndarray,
    b: np.ndarray,
    n_runs: int,
    rng: np.random.Generator,
    *,
    speed: float,
    noise: float,
    samples: int,
    ripple: float = 0.05,
    ripple_mode: str = "periodic",
    misalignment: float = 0.1,
    directions=DIRECTIONS,
) -> np.ndarray:
    """Six-observation runs for parameter sets k, b (S, 3): mean raw outputs (S, n_runs, 6, 3)
    in rad/s. The same draws serve every ``speed``, ``noise`` and ``ripple_mode``, so runs
    differing only in those are paired."""
    if ripple_mode not in ("periodic", "white"):
        raise ConfigError(f"ripple_mode must be 'periodic' or 'white'; got {ripple_mode!r}")
    k = np.asarray(k, dtype=float)[:, None, None, :]
    b = np.asarray(b, dtype=float)[:, None, None, :]
    S, n_obs = k.shape[0], len(directions)
    axis, sign = (np.array(x) for x in zip(*(direction_axis(d) for d in directions), strict=False))
    tilt = np.arcsin(rng.uniform(0.0, misalignment, (S, n_runs, n_obs)))
    azimuth = rng.uniform(0.0, 2 * math.pi, (S, n_runs, n_obs))
    z_noise = rng.standard_normal((S, n_runs, n_obs, 3))
    z_ripple = rng.standard_normal((S, n_runs, n_obs))
    a = sign[:, None] * tilted_axes(axis, tilt, azimuth)
    factor = 1.0 + (ripple / math.sqrt(samples) * z_ripple if ripple_mode == "white" else 0.0)
    g = speed * np.asarray(factor)[..., None] * a
    return g / k - b + noise / math.sqrt(samples) * z_noise


class BatchFit(NamedTuple):
    """Seed 001's parameters fitted on R runs."""

    k: np.ndarray  # (R, 3)
    b: np.ndarray  # (R, 3)
    iterations: np.ndarray  # (R,): Algorithm 1's β0 updates, or LM's function evaluations
    converged: np.ndarray  # (R,): False where the run gave no estimate


def fit_batch(m: np.ndarray, speed: float, *, tol: float = 1e-6, max_iter: int = 50) -> BatchFit:
    """Algorithm 1 on runs m (R, 6, 3)."""
    out = algorithm1(m, np.full(m.shape[:-1], speed), tol=tol, max_iter=max_iter)
    ok = out.converged & out.positive
    with np.errstate(invalid="ignore", divide="ignore"):
        k, b = parameters_from_beta(np.where(ok[:, None], out.beta, 1.0))
    return BatchFit(k, b, out.iterations, ok)


def convergence_run(
    k,
    b,
    rng: np.random.Generator,
    *,
    speed: float = PAPER_SPEED,
    noise: float = 0.035,
    samples: int = PAPER_SAMPLES,
    tol: float = 1e-6,
) -> ServoFit:
    """One simulated six-observation calibration of the unit (k, b), fitted by Algorithm 1
    with its trace: the iteration-by-iteration estimates of Table I."""
    m = simulate_observations(
        np.asarray(k, dtype=float)[None],
        np.asarray(b, dtype=float)[None],
        1,
        rng,
        speed=speed,
        noise=noise,
        samples=samples,
    )[0, 0]
    return fit_iterative(m, np.full(6, speed), tol=tol)


def lm_batch(m: np.ndarray, speed: float) -> BatchFit:
    """scipy LM per run on m (R, 6, 3), started at Algorithm 1's first step."""
    R = m.shape[0]
    k, b = np.ones((R, 3)), np.zeros((R, 3))
    nfev = np.zeros(R, dtype=int)
    ok = np.zeros(R, dtype=bool)
    omega = np.full(m.shape[1], speed)
    for r in range(R):
        try:
            x0 = initial_guess(m[r], omega)
        except (ServoFitError, np.linalg.LinAlgError):  # no start: a failed run, counted
            continue
        res = lm_solve(m[r], omega, x0)
        if res.success and np.isfinite(res.x).all():
            k[r], b[r], nfev[r], ok[r] = np.abs(res.x[:3]), res.x[3:], res.nfev, True
    return BatchFit(k, b, nfev, ok)


def _frame(condition, noise, method, k_true, b_true, fit: BatchFit) -> pd.DataFrame:
    S, R = k_true.shape[0], fit.k.shape[0] // k_true.shape[0]
    ok = fit.converged
    cols = {
        "condition": condition,
        "noise": noise,
        "method": method,
        "set": np.repeat(np.arange(S), R),
        "run": np.tile(np.arange(R), S),
        "converged": ok,
        "iterations": fit.iterations,
    }
    true = np.repeat(np.hstack([k_true, b_true]), R, axis=0)
    est = np.hstack([fit.k, fit.b])
    for j, p in enumerate(PARAMETERS):
        cols[f"{p}_true"] = true[:, j]
        cols[f"{p}_err"] = np.where(ok, est[:, j] - true[:, j], np.nan)  # NaN: no estimate
    return pd.DataFrame(cols)


def study(
    n_sets: int = 30,
    n_runs: int = 500,
    noise=(0.035, 0.2),
    conditions=("normal", "extreme"),
    seed: int = 0,
    method=("iterative", "lm"),
    *,
    speed: float = PAPER_SPEED,
    samples: int | None = None,
    sample_rate: float = PAPER_RATE,
    ripple: float = 0.05,
    ripple_mode: str = "periodic",
    misalignment: float = 0.1,
    lm_runs: int | None = None,
) -> pd.DataFrame:
    """Estimation errors (estimate − truth) of k and b, one row per condition, noise level,
    parameter set, run and method (Section III-A and III-C).

    ``n_sets`` units are drawn per condition (shared by the noise levels); each is
    calibrated ``n_runs`` times. ``samples`` per observation defaults to one revolution at
    ``speed`` and ``sample_rate``. Columns: condition, noise (rad/s), method, set, run,
    converged, iterations (β0 updates; LM: function evaluations), ``<p>_true``, ``<p>_err``
    for p in kx..bz (b in rad/s); errors are NaN only where a run gave no estimate.
    """
    methods = (method,) if isinstance(method, str) else tuple(method)
    noises = (noise,) if np.isscalar(noise) else tuple(noise)
    conds = (conditions,) if isinstance(conditions, str) else tuple(conditions)
    bad = [c for c in conds if c not in CONDITIONS] + [x for x in methods if x not in ("iterative", "lm")]
    if bad:
        raise ConfigError(
            f"unknown condition or method {', '.join(map(repr, bad))}; conditions: "
            f"{', '.join(CONDITIONS)}; methods: iterative, lm"
        )
    n = samples or int(round(sample_rate * 2 * math.pi / speed))
    frames = []
    for cond in conds:
        code, extreme = CONDITIONS[cond]
        k, b = draw_parameters(_rng(seed, code), n_sets, extreme=extreme)
        for sigma in noises:
            m = simulate_observations(
                k,
                b,
                n_runs,
                _rng(seed, code, _noise_code(sigma), 1),
                speed=speed,
                noise=sigma,
                samples=n,
                ripple=ripple,
                ripple_mode=ripple_mode,
                misalignment=misalignment,
            )
            flat = m.reshape(-1, 6, 3)
            for meth in methods:
                if meth == "iterative":
                    fit = fit_batch(flat, speed)
                    frames.append(_frame(cond, sigma, meth, k, b, fit))
                else:
                    sub = m if lm_runs is None else m[:, :lm_runs]
                    fit = lm_batch(sub.reshape(-1, 6, 3), speed)
                    frames.append(_frame(cond, sigma, meth, k, b, fit))
    return pd.concat(frames, ignore_index=True)


def box_stats(df: pd.DataFrame, by=("condition", "noise", "method")) -> pd.DataFrame:
    """Box-plot statistics of the errors per group and parameter, plus ``k`` and ``b``
    pooled over the axes and ``all`` six pooled: count, min, q1, median, q3, max, the
    whiskers (furthest errors within 1.5 IQR of the box) and the number beyond them."""
    by = list(by)
    long = df.melt(
        id_vars=by, value_vars=[f"{p}_err" for p in PARAMETERS], var_name="parameter", value_name="error"
    ).dropna(subset=["error"])
    long["parameter"] = long["parameter"].str.removesuffix("_err")
    pooled = long.assign(parameter=long["parameter"].str[0])
    everything = long.assign(parameter="all")
    long = pd.concat([long, pooled, everything], ignore_index=True)
    keys = by + ["parameter"]
    g = long.groupby(keys, sort=True)["error"]
    out = pd.DataFrame(
        {
            "count": g.size(),
            "min": g.min(),
            "q1": g.quantile(0.25),
            "median": g.median(),
            "q3": g.quantile(0.75),
            "max": g.max(),
        }
    )
    iqr = out["q3"] - out["q1"]
    lo_fence = (out["q1"] - 1.5 * iqr).rename("lo_fence")
    hi_fence = (out["q3"] + 1.5 * iqr).rename("hi_fence")
    merged = long.join(lo_fence, on=keys).join(hi_fence, on=keys)
    inside = merged[(merged["error"] >= merged["lo_fence"]) & (merged["error"] <= merged["hi_fence"])]
    gi = inside.groupby(keys, sort=True)["error"]
    out["whisker_lo"] = gi.min()
    out["whisker_hi"] = gi.max()
    out["outliers"] = out["count"] - gi.size().reindex(out.index, fill_value=0)
    return out.reset_index()


def speed_sweep(
    speeds=FIG4_SPEEDS,
    *,
    n_sets: int = 30,
    n_runs: int = 500,
    noise=(0.035, 0.2),
    condition: str = "normal",
    seed: int = 0,
    samples: int | None = PAPER_SAMPLES,
    sample_rate: float = PAPER_RATE,
    ripple: float = 0.05,
    ripple_mode: str = "periodic",
    misalignment: float = 0.1,
) -> pd.DataFrame:
    """Mean squared error (Eq 9) of each parameter against the servo speed (Fig. 4), with
    Algorithm 1. The same units and draws serve every speed. ``samples=None``: one
    revolution per observation at each speed (N falls as the speed rises). Columns: speed
    (rad/s), noise, runs, failed (no convergence), ``mse_<p>``, ``mse_k``, ``mse_b`` (means
    over the axes; b in (rad/s)²)."""
    code, extreme = CONDITIONS[condition]
    k, b = draw_parameters(_rng(seed, code), n_sets, extreme=extreme)
    rows = []
    for sigma in (noise,) if np.isscalar(noise) else tuple(noise):
        for w in speeds:
            n = samples or int(round(sample_rate * 2 * math.pi / w))
            m = simulate_observations(
                k,
                b,
                n_runs,
                _rng(seed, code, _noise_code(sigma), 2),
                speed=float(w),
                noise=sigma,
                samples=n,
                ripple=ripple,
                ripple_mode=ripple_mode,
                misalignment=misalignment,
            )
            fit = fit_batch(m.reshape(-1, 6, 3), float(w))
            ok = fit.converged
            err = np.hstack([fit.k, fit.b])[ok] - np.repeat(np.hstack([k, b]), n_runs, axis=0)[ok]
            mse = np.mean(err**2, axis=0)
            row = {
                "speed": float(w),
                "noise": sigma,
                "samples": n,
                "runs": int(ok.size),
                "failed": int((~ok).sum()),
            }
            row.update({f"mse_{p}": float(v) for p, v in zip(PARAMETERS, mse, strict=False)})
            row["mse_k"], row["mse_b"] = float(mse[:3].mean()), float(mse[3:].mean())
            rows.append(row)
    return pd.DataFrame(rows)


def _save(fig: Figure, path) -> Path:
    path = Path(path)
    with plots.figure_style(_STYLE), atomic.replacing(path) as tmp:
        fig.savefig(tmp, format="svg", metadata=plots.SVG_METADATA)
    return path


def plot_error_boxes(df: pd.DataFrame, path, *, title: str | None = None) -> Path:
    """Box plots of the errors (Figs 2 and 5): a row per (condition, noise), a column per
    method, a box per parameter (whiskers at 1.5 IQR). Deterministic SVG."""
    groups = sorted(df.groupby(["condition", "noise"]).groups)
    methods = [m for m in ("lm", "iterative") if m in set(df["method"])]
    names = {"lm": "Levenberg-Marquardt", "iterative": "Algorithm 1"}
    with plots.figure_style(_STYLE):
        fig = Figure(figsize=(4.2 * len(methods), 2.8 * len(groups)), layout="constrained")
        axes = fig.subplots(len(groups), len(methods), squeeze=False)
        for i, (cond, sigma) in enumerate(groups):
            for j, meth in enumerate(methods):
                ax = axes[i, j]
                sub = df[(df["condition"] == cond) & (df["noise"] == sigma) & (df["method"] == meth)]
                data = [sub[f"{p}_err"].dropna().to_numpy() for p in PARAMETERS]
                parts = ax.boxplot(data, whis=1.5, flierprops={"markersize": 2, "alpha": 0.4})
                for flier in parts["fliers"]:  # thousands of points: an image layer
                    flier.set_rasterized(True)
                ax.set_xticks(range(1, 7), [f"{p[0]}{p[1]}" for p in PARAMETERS])
                ax.axhline(0.0, color="#888", lw=0.6)
                ax.set_title(f"{cond}, σ = {sigma:g} rad/s, {names[meth]}", fontsize=9)
                ax.set_ylabel("estimate − truth (1; b: rad/s)")
        if title:
            fig.suptitle(title)
    return _save(fig, path)


def plot_speed_sweep(sweep: pd.DataFrame, path) -> Path:
    """MSE of each parameter against the servo speed (Fig. 4): a panel per noise level."""
    levels = sorted(sweep["noise"].unique())
    with plots.figure_style(_STYLE):
        fig = Figure(figsize=(4.5 * len(levels), 3.4), layout="constrained")
        axes = fig.subplots(1, len(levels), squeeze=False)[0]
        for ax, sigma in zip(axes, levels, strict=False):
            sub = sweep[sweep["noise"] == sigma].sort_values("speed")
            for p in PARAMETERS:
                ax.plot(
                    sub["speed"],
                    sub[f"mse_{p}"],
                    marker="o",
                    ms=2.5,
                    lw=1,
                    ls="-" if p[0] == "k" else "--",
                    label=p,
                )
            ax.set_yscale("log")
            ax.set_xlabel("servo speed, rad/s")
            ax.set_ylabel("MSE (Eq 9)")
            ax.set_title(f"σ = {sigma:g} rad/s")
            ax.legend(ncol=2, fontsize=7)
    return _save(fig, path)


# ---------------------------------------------------------------------------------------
# What the cross-axis terms cost and gain (beyond Section III). The unit now has cross-axis
# sensitivity: raw output m = K g + B with K = diag(1/k) + M, M off-diagonal ~ U(±cross);
# seed 001's k and b as in Section III-A. Each run calibrates on one session's rotations and
# is judged on the next session's (the same design, new mounts): what its user meets.

CROSS_DESIGNS = {
    # Fig. 1: one rotation each way about each sensor axis
    "three axes": tuple((d, None) for d in DIRECTIONS),
    # Fig. 1 twice, the unit re-mounted in between: twelve hand-placed axes near three
    "three axes twice": tuple((d, None) for d in DIRECTIONS * 2),
    # Fig. 1 and each way about the three face diagonals (the unit on a 45° wedge)
    "six axes": tuple((d, None) for d in DIRECTIONS)
    + tuple(
        (
            f"{s}{a}{b}",
            np.array([1.0 if c in (a, b) else 0.0 for c in "xyz"]) * (1 if s == "+" else -1) / math.sqrt(2),
        )
        for a, b in (("x", "y"), ("x", "z"), ("y", "z"))
        for s in "+-"
    ),
}
CROSS_MOUNTINGS = {"hand": 0.1, "fixture": 0.0}  # sine of the largest tilt (Section III-A 2)


def _design_axes(design: str, mounting: str, shape: tuple, rng: np.random.Generator):
    """Rotation axes (*shape, n, 3) of ``design`` as mounted: each nominal axis tilted by a
    tilt whose sine is U(0, CROSS_MOUNTINGS[mounting]) toward a random azimuth, new for every
    rotation (as Section III's simulation mounts each of its six), and the nominal rate
    directions (n, 3)."""
    spec = CROSS_DESIGNS[design]
    nominal = np.array(
        [np.eye(3)[direction_axis(d)[0]] * direction_axis(d)[1] if v is None else v for d, v in spec]
    )
    n = len(nominal)
    tilt = np.arcsin(rng.uniform(0.0, CROSS_MOUNTINGS[mounting], (*shape, n)))
    azimuth = rng.uniform(0.0, 2 * math.pi, (*shape, n))
    # two unit vectors perpendicular to each nominal axis
    helper = np.where(np.abs(nominal[:, :1]) < 0.9, np.eye(3)[0], np.eye(3)[1])
    e1 = np.cross(nominal, helper)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(nominal, e1)
    axes = (
        np.cos(tilt)[..., None] * nominal
        + (np.sin(tilt) * np.cos(azimuth))[..., None] * e1
        + (np.sin(tilt) * np.sin(azimuth))[..., None] * e2
    )
    return axes, nominal


def _cross_fits(m: np.ndarray, speed: float, nominal: np.ndarray, sem: float) -> dict:
    """K (R, 3, 3) and B (R, 3) of each model on runs m (R, n, 3) (rad/s; revolution means'
    noise ``sem``), NaN where a run gives no estimate: the symmetric model where the
    rotations do not determine its cross terms (:func:`gyrocal.protocols.servo.fit.fit_model`'s rule)
    or it does not converge; ``auto`` as :func:`gyrocal.protocols.servo.fit.fit_model` chooses."""
    from scipy.special import chdtrc

    from .fit import (
        CROSS_ALPHA,
        CROSS_PAIRS,
        MAX_CROSS_STDERR,
        algorithm1_symmetric,
        cross_chi2,
        cross_stderr,
        symmetric_covariance,
        symmetric_parameters,
    )

    R = m.shape[0]
    out = {}
    s = fit_batch(m, speed)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["seed001"] = (
            np.where(s.converged[:, None, None], np.eye(3) / s.k[:, None, :], np.nan),
            -s.b,
        )
    X = np.column_stack([nominal * speed, np.ones(len(nominal))])
    coef = np.linalg.pinv(X) @ m  # (R, 4, 3): one design for every run
    out["fixture"] = (np.swapaxes(coef[:, :3], 1, 2), coef[:, 3])
    nan = (np.full((R, 3, 3), np.nan), np.full((R, 3), np.nan))
    out["symmetric"], use = nan, np.zeros(R, dtype=bool)
    if m.shape[1] >= 9:
        m_sem = np.full(m.shape, sem)
        start_k = np.where(s.converged[:, None], s.k, 1.0)
        identified = s.converged & (
            cross_stderr(
                symmetric_covariance(
                    start_k[:, :, None] * np.eye(3), -np.where(s.converged[:, None], s.b, 0.0), m, m_sem
                )
            )
            <= MAX_CROSS_STDERR
        )
        a = algorithm1_symmetric(m, np.full(m.shape[:-1], speed))
        ok = identified & a.converged & a.positive
        C, B = symmetric_parameters(np.where(ok[:, None], a.beta, np.r_[1, 1, 1, 0, 0, 0, 0, 0, 0]))
        K = np.linalg.inv(C)
        out["symmetric"] = (np.where(ok[:, None, None], K, np.nan), np.where(ok[:, None], B, np.nan))
        chi2 = cross_chi2(K, symmetric_covariance(C, B, m, m_sem))
        use = ok & (chdtrc(len(CROSS_PAIRS), np.nan_to_num(chi2, nan=0.0)) < CROSS_ALPHA)
    out["auto"] = (
        np.where(use[:, None, None], out["symmetric"][0], out["seed001"][0]),
        np.where(use[:, None], out["symmetric"][1], out["seed001"][1]),
    )
    return out


def cross_axis_study(
    n_sets: int = 30,
    n_runs: int = 200,
    noise=(0.035,),
    *,
    cross: float = 0.01,
    designs=tuple(CROSS_DESIGNS),
    mountings=tuple(CROSS_MOUNTINGS),
    seed: int = 0,
    speed: float = PAPER_SPEED,
    samples: int = PAPER_SAMPLES,
) -> pd.DataFrame:
    """Next-session errors of seed 001's model, the symmetric and the fixture model, one
    row per mounting, design, noise, model, set and run.

    Each run draws a calibration session and a next session of the same unit (new mounts,
    new noise; a fixture holds the commanded axes), fits each model on the first and
    compensates the second. Columns: ``magnitude`` (RMS of |ŵ| − ω: what a servo can judge
    on a hand mount), ``nominal`` (RMS length of ŵ minus the commanded rate vector: what it
    can judge with a fixture), ``true`` (RMS length of ŵ minus the true rate vector, which
    only a simulation knows), the same three for the raw output (``raw_*``), ``floor`` (the
    revolution mean's noise, σ/√N) and ``estimated`` (False where the model gave no
    estimate); rad/s."""
    code = 3
    rows = []
    k, b = draw_parameters(_rng(seed, code), n_sets)
    M = _rng(seed, code, 1).uniform(-cross, cross, (n_sets, 3, 3)) * (1 - np.eye(3))
    K = np.eye(3) / k[:, None, :] + M  # (S, 3, 3): w = K g + B
    B = -b
    for mounting in mountings:
        for design in designs:
            for sigma in (noise,) if np.isscalar(noise) else tuple(noise):
                rng = _rng(
                    seed,
                    code,
                    _noise_code(sigma),
                    2,
                    list(CROSS_MOUNTINGS).index(mounting),
                    list(CROSS_DESIGNS).index(design),
                )
                floor = sigma / math.sqrt(samples)
                first = _servo_session(K, B, design, mounting, (n_sets, n_runs), floor, speed, rng)
                second = _servo_session(K, B, design, mounting, (n_sets, n_runs), floor, speed, rng)
                fits = _cross_fits(first.m.reshape(-1, *first.m.shape[2:]), speed, first.nominal, floor)
                errors = _next_session_errors(fits, second, speed)
                for model, (ok, (mag, nom, true)) in errors.models.items():
                    rows.append(
                        pd.DataFrame(
                            {
                                "mounting": mounting,
                                "design": design,
                                "noise": sigma,
                                "model": model,
                                "set": np.repeat(np.arange(n_sets), n_runs),
                                "run": np.tile(np.arange(n_runs), n_sets),
                                "estimated": ok,
                                "magnitude": np.where(ok, mag, np.nan),
                                "nominal": np.where(ok, nom, np.nan),
                                "true": np.where(ok, true, np.nan),
                                "raw_magnitude": errors.raw.magnitude,
                                "raw_nominal": errors.raw.nominal,
                                "raw_true": errors.raw.true,
                                "floor": floor,
                            }
                        )
                    )
    return pd.concat(rows, ignore_index=True)


class ServoSession(NamedTuple):
    """Simulated revolution means of a session: the true rates and the output (rad/s)."""

    g: np.ndarray  # (S, R, n, 3) true rate vectors
    m: np.ndarray  # (S, R, n, 3) revolution means
    nominal: np.ndarray  # (n, 3) the commanded axes


def _servo_session(
    K, B, design: str, mounting: str, shape: tuple, floor: float, speed: float, rng
) -> ServoSession:
    """A session of every set and run: new mounts and new noise (``floor``: a revolution
    mean's)."""
    axes, nominal = _design_axes(design, mounting, shape, rng)
    g = speed * axes
    m = np.einsum("sij,srnj->srni", K, g) + B[:, None, None, :] + floor * rng.standard_normal(g.shape)
    return ServoSession(g, m, nominal)


class RunErrors(NamedTuple):
    """RMS errors (rad/s) of each run's next session: against the servo speed (what a servo
    can judge on a hand mount), the commanded rate vector (with a fixture) and the true one
    (which only a simulation knows)."""

    magnitude: np.ndarray
    nominal: np.ndarray
    true: np.ndarray


class NextSession(NamedTuple):
    raw: RunErrors  # the raw output's
    models: dict[str, tuple[np.ndarray, RunErrors]]  # per model: where it gave an estimate, its errors


def _next_session_errors(fits: dict, session: ServoSession, speed: float) -> NextSession:
    """How far each model's compensation of the next session lies from the servo speed,
    the commanded rate vector and the true one."""
    g1f, m1f = session.g.reshape(-1, *session.g.shape[2:]), session.m.reshape(-1, *session.m.shape[2:])
    commanded = speed * session.nominal

    def rms_errors(w) -> RunErrors:
        return RunErrors(
            np.sqrt(np.mean((np.linalg.norm(w, axis=-1) - speed) ** 2, axis=-1)),
            np.sqrt(np.mean(np.sum((w - commanded) ** 2, axis=-1), axis=-1)),
            np.sqrt(np.mean(np.sum((w - g1f) ** 2, axis=-1), axis=-1)),
        )

    models = {}
    for model, (Kf, Bf) in fits.items():
        ok = np.isfinite(Kf).all(axis=(1, 2)) & np.isfinite(Bf).all(axis=1)
        safe_K = np.where(ok[:, None, None], Kf, np.eye(3))
        offset = m1f - np.where(ok[:, None], Bf, 0.0)[:, None, :]
        models[model] = (ok, rms_errors(np.linalg.solve(safe_K[:, None], offset[..., None])[..., 0]))
    return NextSession(rms_errors(m1f), models)


def cross_axis_summary(df: pd.DataFrame) -> pd.DataFrame:
    """Per mounting, design, noise and model: the share of runs with an estimate and, by
    each judge, the median next-session error over the floor (``<judge>_floor``) and the
    median improvement over the raw output (``gain_<judge>``, raw ÷ compensated)."""
    keys = [df[k] for k in ("mounting", "design", "noise", "model")]
    g = df.groupby(keys, sort=False)
    out = g.agg(runs=("run", "size"), estimated=("estimated", "mean"))
    for judge in ("magnitude", "nominal", "true"):
        out[f"{judge}_floor"] = (df[judge] / df["floor"]).groupby(keys, sort=False).median()
        out[f"gain_{judge}"] = (df[f"raw_{judge}"] / df[judge]).groupby(keys, sort=False).median()
    return out.reset_index()
