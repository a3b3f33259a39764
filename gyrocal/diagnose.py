"""Where the model fails and which physical effect is missing.

Three questions, answered from the observations alone:

1. **Does the model explain the data?** The in-sample residuals of every fit, divided by
   each observation's noise floor, should scatter like unit normals: χ² against its
   degrees of freedom, overall and per output axis. When the session's noise model has bias
   instability or rate random walk, χ² and the F-tests below come from the generalised
   least-squares fits that account for the holds' shared wander (:func:`gyrocal.model.fit`).
2. **Where does the excess live?** For every covariate the log offers (temperature, its
   rate, the reference rate, its magnitude and direction, the mount, the accelerometer,
   time, hold length), the share of the excess χ² that the covariate's bins account for,
   beyond what bins explain by chance. Ranked, plus heat maps (mount × rate, temperature ×
   rate).
3. **Which effect is missing?** Every candidate term (the library's, those the user names,
   those of the user's term files) is added to the model in turn; the extended model is
   refitted and validated the same way. Candidates are ranked by the validation RMS they
   reach; each gets a nested-model F-test against the base model and the fitted size of the
   effect in physical units. The significance level is family-wise: half goes to the χ²
   test of question 1, half is shared (Bonferroni) by the candidates, so on data the model
   explains the diagnosis raises a false alarm at most that often.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import special

from .config import Settings
from .floor import with_upper_floor
from .errors import GyrocalError, MissingInputError
from .model import columns_of
from .signals import SERIES_INPUTS
from .terms import AXES, TERMS, make_term
from .terms.effects import CANDIDATES
from .thermal import fit_model, in_sample
from .validate import validate

COVARIATES = {
    "temperature": "temp", "temperature rate": "temp_rate", "reference rate": "ref_rate",
    "|rate|": "abs_rate", "direction": "direction", "mount": "mount",
    "accel_x": "accel_x", "accel_y": "accel_y", "accel_z": "accel_z",
    "time": "time", "hold duration": "duration",
}


# The χ² and F tails the tests below use, from scipy.special as scipy.stats computes them
# (chi2.sf is chdtrc, chi2.ppf 2·gammaincinv(df/2, q), f.sf fdtrc; 1 below the support):
# the same numbers without importing scipy.stats, which takes longer than a diagnosis.
def chi2_sf(x, df) -> float:
    return float(special.chdtrc(df, 0.0 if x < 0 else x))


def chi2_ppf(q, df) -> float:
    return float(2.0 * special.gammaincinv(df / 2.0, q))


def f_sf(x, df_num, df_den) -> float:
    return float(special.fdtrc(df_num, df_den, 0.0 if x < 0 else x))


def fisher_combined(*p_values) -> float:
    """Fisher's combination of independent p-values (each floored at 1e-300)."""
    p = np.maximum(np.asarray(p_values, dtype=float), 1e-300)
    return chi2_sf(-2.0 * np.sum(np.log(p)), 2 * p.size)


@dataclass
class Evaluation:
    """A model fitted and validated: what the diagnosis compares."""

    name: str
    terms: list[str]
    kind: str
    fitted: object
    summary: dict
    chi2: float
    dof: int


@dataclass
class Candidate:
    term: str
    status: str                              # ranked | not identifiable | missing inputs
    validation_rms_with: float | None = None
    p_value: float | None = None
    f_statistic: float | None = None
    df: tuple[int, int] | None = None
    gain_pct: float | None = None
    significant: bool = False
    size: list[dict] = field(default_factory=list)
    peak_effect: float | None = None         # deg/s over the observations
    reason: str = ""
    expected_with: float | None = None       # what a correct model would leave, deg/s
    explains_excess: bool = False            # validation RMS within chance of that
    tied_with: list[str] = field(default_factory=list)   # fits this protocol cannot tell apart
    together: list[str] = field(default_factory=list)    # also missing: named with this one
    alone_rms: float | None = None                       # validation RMS with this one alone
    leftover: dict | None = None             # the covariate its residuals still follow most
    next_session: dict | None = None         # how the extended model carries over
    chi2: float | None = None                # of the extended fit, for ties

    def to_dict(self) -> dict:
        out = {"term": self.term, "status": self.status,
               "validation_rms_with": self.validation_rms_with, "p_value": self.p_value}
        if self.status == "ranked":
            out.update(f_statistic=self.f_statistic, df=list(self.df), gain_pct=self.gain_pct,
                       significant=self.significant, size=self.size, peak_effect=self.peak_effect,
                       expected_rms_with=self.expected_with, explains_excess=self.explains_excess,
                       tied_with=self.tied_with, together=self.together, alone_rms=self.alone_rms,
                       leftover=self.leftover, next_session=self.next_session)
        else:
            out["reason"] = self.reason
        return out


@dataclass
class Diagnosis:
    base: Evaluation
    significance: float
    chi2_red: dict[str, float]               # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float
    explains: bool
    covariates: list[dict]
    candidates: list[Candidate]
    best: Candidate | None
    partial: list[Candidate]
    verdict: str
    heatmaps: dict
    residuals: pd.DataFrame                   # observations + resid_, floor_, z_ per axis
    config_line: str = ""                     # the model: lines that add the best candidate
    ladder: list[dict] = field(default_factory=list)
    within_noise: dict | None = None          # the χ² test with the slow noise at its upper bound
    next_session: dict | None = None          # the configured model on another session
    advice: list[str] = field(default_factory=list)
    time_drift: dict | None = None            # TIME_DRIFT's fit: the rival no term can beat

    def to_dict(self) -> dict:
        s = self.base.summary
        return {
            "format": "gyrocal.diagnosis/1",
            "model": {"terms": self.base.terms, "kind": self.base.kind},
            "validation_rms": s["validation_rms"], "noise_floor": s["noise_floor"],
            "excess": s["excess"], "expected_rms": s["expected_rms"],
            "excess_over_expected": s["excess_over_expected"], "held_out": s["held_out"],
            "significance": self.significance,
            "chi2_red": self.chi2_red, "rms_over_floor": self.rms_over_floor,
            "excess_p_value": self.excess_p_value, "explains_the_data": self.explains,
            "verdict": self.verdict,
            "within_noise_uncertainty": self.within_noise,
            "next_session": self.next_session,
            "advice": self.advice,
            "time_drift": self.time_drift,
            "best": None if self.best is None else {
                **self.best.to_dict(), "config_line": self.config_line,
                "option": " ".join(add_term_option(t) for t in (self.best.term, *self.best.together))},
            "partial": [{"term": c.term, "validation_rms_with": c.validation_rms_with,
                         "expected_rms_with": c.expected_with, "gain_pct": c.gain_pct,
                         "remaining_excess": c.validation_rms_with / c.expected_with
                         if c.expected_with else None} for c in self.partial],
            "candidates": [c.to_dict() for c in self.candidates],
            "covariates": self.covariates,
            "ladder": self.ladder,
        }


def evaluate(settings: Settings, obs: pd.DataFrame, name: str = "model") -> Evaluation:
    """``settings.model`` fitted to ``obs`` and validated leaving temperature points out."""
    m = settings.model
    fitted = fit_model(m.build(), obs, kind=m.kind, method=m.interpolation, degree=m.degree)
    summary = validate(fitted.model, obs, fitted, reference_temperature=m.reference_temperature).summary
    return evaluation_of(settings, fitted, summary, name)


def evaluation_of(settings: Settings, fitted, summary: dict, name: str = "model") -> Evaluation:
    """A fit of ``settings.model`` and its validation summary, made elsewhere (the analyse
    job's fit and validate stages), as the diagnosis reads them."""
    chi2 = sum(sum(f.chi2.values()) for f in fitted.fits)
    dof = sum(sum(f.dof.values()) for f in fitted.fits)
    return Evaluation(name, [t.spec_string() for t in fitted.model.terms], settings.model.kind,
                      fitted, summary, chi2, dof)


def extended(settings: Settings, spec, kind: str | None = None) -> Settings:
    """The settings with ``spec`` added to the model (replacing a term of the same
    identity, so ``bias_temp_poly(degree=3)`` supersedes ``bias_temp_poly(degree=2)``)."""
    model = settings.model.with_terms((spec,))
    return replace(settings, model=replace(model, kind=kind or model.kind))


def candidate_terms(settings: Settings) -> list[str]:
    """The library's candidates and every term of the model's term files whose effect the
    model lacks, plus the candidates the user names (these may also supersede a term of
    the model, e.g. a higher degree); temperature-only terms only for continuous models."""
    model = settings.model.build()
    have = {t.spec_string() for t in model.terms}
    have_keys = {t.identity for t in model.terms}
    files = {str(Path(f).resolve()) for f in settings.model.term_files}
    user_file_terms = [n for n, cls in TERMS.items() if getattr(cls, "source_file", None) in files]
    requested = {make_term(spec).spec_string() for spec in settings.diagnosis.candidates}
    out = []
    for spec in [*CANDIDATES, *settings.diagnosis.candidates, *user_file_terms]:
        term = make_term(spec)
        label = term.spec_string()
        if label in have or label in out or (term.identity in have_keys and label not in requested):
            continue
        if settings.model.kind == "grid" and term.varies_with_temperature:
            continue
        out.append(label)
    return out


def _pooled(fits, name: str) -> tuple[float, float]:
    """Inverse-variance mean of one coefficient over the fits (one per temperature point,
    or the single continuous fit) and its standard error."""
    # A joint grid fit holds a point-scope coefficient as ``<name>.@<point>``, one per point.
    pairs = [(f.values[j], f.stderr[j]) for f in fits for j, n in enumerate(f.names)
             if n == name or n.split(".@")[0] == name]
    v = np.array([p[0] for p in pairs])
    w = 1.0 / np.maximum(np.array([p[1] for p in pairs]), 1e-300) ** 2
    return float(np.sum(w * v) / np.sum(w)), float(np.sqrt(1.0 / np.sum(w)))


def _effect_size(evaluation: Evaluation, spec: str, added: list[str], obs_data: dict
                 ) -> tuple[list[dict], float]:
    """Each added coefficient pooled over the fits, and the largest contribution of the
    added term to any observation (deg/s)."""
    fits = evaluation.fitted.fits
    unit = make_term(spec).unit
    size = [dict(zip(("coefficient", "value", "stderr", "unit"), (name, *_pooled(fits, name), unit)))
            for name in added]
    model = fits[0].model
    peak = 0.0
    for result, rows in zip(fits, evaluation.fitted.rows):
        design = model.design({k: v[rows] for k, v in obs_data.items()})
        for a in AXES:
            contribution = sum(result.coef(n) * np.asarray(design[n]) for n in result.names
                               if n.split(".@")[0] in added and n.split(".")[1] == a)
            if np.ndim(contribution):
                peak = max(peak, float(np.max(np.abs(contribution))))
    return size, peak


LEFTOVER_FRACTION = 0.02  # of the configured model's excess χ²/dof: see _Judge.explains
NEGLIGIBLE_OVER_FLOOR = 1.2  # structure left within this many times the floor is negligible
SOAKED_SPREAD = 5.0  # °C: a temperature point's spread below which it is one soak

TIME_LIKE = ("time", "time within a temperature point", "hold duration")

# The grouping each covariate is measured against: rate effects show on the axis that
# turns, so they are judged within the rotating axis; drift within a temperature point is
# judged within the point (what changes there is time, not the temperature).
BASELINE = {"|rate|": "rotating axis", "direction": "rotating axis",
            "reference rate": "rotating axis", "time within a temperature point": "point"}


def _partition(values: np.ndarray) -> np.ndarray:
    return np.unique(values.astype(str), return_inverse=True)[1]


def _between(z: np.ndarray, labels: np.ndarray) -> tuple[float, int]:
    """Σ over groups and axes of n · mean(z)², and the number of groups."""
    counts = np.bincount(labels)
    sums = np.stack([np.bincount(labels, weights=z[:, i]) for i in range(z.shape[1])], axis=1)
    used = counts > 0
    return float(np.sum(sums[used] ** 2 / counts[used, None])), int(used.sum())


def _covariate_table(obs: pd.DataFrame, data: dict, z: np.ndarray, fitted_rows: np.ndarray,
                     dof: int, excess_significant: bool) -> tuple[list[dict], dict]:
    """Share of the excess χ² each covariate accounts for, ranked; heat maps.

    A covariate's share is what grouping the holds by it adds to the grouping it is judged
    against (:data:`BASELINE`; none for most), beyond chance: for unit-normal residuals the
    gain is χ² with 3 degrees of freedom per extra group, whose expectation is subtracted
    and whose p-value is reported. Covariates that group the holds identically (on three
    mounts: the mount, the rotating axis and the accelerometer) are one row, since the
    protocol cannot tell them apart. Without a significant excess there is nothing to share
    out: the shares are None."""
    frame = pd.DataFrame({k: v for k, v in data.items() if np.ndim(v) == 1})
    frame["mount"] = obs["mount"].astype(str).to_numpy()
    frame["rotating axis"] = obs["axis"].astype(str).to_numpy()
    frame["abs_rate"] = np.abs(data["ref_rate"])
    frame["direction"] = np.sign(data["ref_rate"])
    frame["time"] = (data["t_start"] - data["t_start"].min()) / 3600.0
    frame = frame[fitted_rows].reset_index(drop=True)
    zz = z[fitted_rows]
    total = float(np.sum(zz ** 2))
    excess = max(total - dof, 1e-9)
    labels: dict[str, np.ndarray] = {}
    for label, column in {**COVARIATES, "rotating axis": "rotating axis"}.items():
        if column not in frame:
            continue
        values = frame[column]
        if column not in ("mount", "rotating axis") and not np.isfinite(values.to_numpy(dtype=float)).all():
            continue
        if column in ("mount", "rotating axis") or values.nunique() <= 8:
            labels[label] = _partition(values.to_numpy())
        else:
            labels[label] = pd.qcut(values.rank(method="first"), 8, labels=False).to_numpy()
    if "point" in frame and frame["point"].nunique() > 1:
        point = _partition(frame["point"].to_numpy())
        within = np.zeros(len(frame), dtype=np.int64)
        for p in np.unique(point):  # time quartiles inside each point
            rows = np.flatnonzero(point == p)
            within[rows] = pd.qcut(frame["time"].iloc[rows].rank(method="first"),
                                   min(4, len(rows)), labels=False).to_numpy()
        labels["time within a temperature point"] = point * 4 + within
        labels["point"] = point
    # Covariates that group the holds the same way are one: the protocol confounds them.
    groups: list[list[str]] = []
    for label in labels:
        if label == "point":
            continue
        for g in groups:
            if _same_partition(labels[g[0]], labels[label]):
                g.append(label)
                break
        else:
            groups.append([label])
    rows = []
    for names in groups:
        lead = names[0]
        base_name = BASELINE.get(lead)
        base = labels.get(base_name) if base_name else None
        base = np.zeros(len(frame), dtype=np.int64) if base is None else base
        joint = _partition(np.char.add(np.char.add(base.astype(str), "|"), labels[lead].astype(str)))
        ss_joint, k_joint = _between(zz, joint)
        ss_base, k_base = _between(zz, base)
        df = 3 * (k_joint - k_base)
        gain = ss_joint - ss_base
        p = float(chi2_sf(gain, df)) if df > 0 else 1.0
        share = min(max(gain - df, 0.0) / excess, 1.0) if excess_significant else None
        row = {"covariate": " = ".join(names) if len(names) > 1 else lead, "bins": int(k_joint),
               "share_of_excess": share, "p_value": p, "within": base_name,
               "chi2_beyond_chance": max(gain - df, 0.0)}
        if len(names) > 1:
            row["confounded"] = names
            row["reason"] = "these group the holds identically in this protocol: it cannot tell them apart"
        rows.append(row)
    rows.sort(key=lambda r: -(r["share_of_excess"] or 0.0))
    rms = lambda g: float(np.sqrt(np.mean(zz[g.to_numpy()] ** 2)))  # noqa: E731
    idx = pd.Series(np.arange(len(frame)))
    rate_bins = frame["ref_rate"].round(3).to_numpy()
    temp_bins = frame["temp"].round(0).to_numpy()
    heat = {
        "mount_by_rate": {f"{m}|{r}": rms(g) for (m, r), g in idx.groupby([frame["mount"].to_numpy(), rate_bins])},
        "temperature_by_rate": {f"{t}|{r}": rms(g) for (t, r), g in idx.groupby([temp_bins, rate_bins])},
    }
    return rows, heat


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two labellings split the holds into the same groups."""
    # Labels are small non-negative integers (_partition, qcut): count distinct pairs as
    # distinct integers, a hash rather than the sort of a row-wise unique.
    a, b = a.astype(np.int64), b.astype(np.int64)
    pairs = a * (int(b.max()) + 1) + b
    return len(np.unique(pairs)) == len(np.unique(a)) == len(np.unique(b))


def diagnose(settings: Settings, obs: pd.DataFrame, other: pd.DataFrame | None = None, *,
             base: Evaluation | None = None) -> Diagnosis:
    """Diagnose ``settings.model`` on the observations; see the module docstring.

    ``other``, the observations of another session of the same unit, is what the user's
    calibration will meet: each model is then also judged by how it carries over to it
    (:func:`carry_over`), and an excess whose pattern does not repeat there is noise.
    ``base``, the configured model already fitted and validated on ``obs``
    (:func:`evaluation_of`), is used rather than fitting again."""
    alpha = settings.diagnosis.significance
    if base is None:
        base = evaluate(settings, obs, "configured model")
    data = columns_of(obs)
    n = len(obs)
    resid, floor, fitted_rows = in_sample(base.fitted, n)
    z = resid / floor
    dof_axis = {a: sum(f.dof[a] for f in base.fitted.fits) for a in AXES}
    chi2_axis = {a: sum(f.chi2[a] for f in base.fitted.fits) for a in AXES}
    chi2_red = {"all": base.chi2 / base.dof, **{a: chi2_axis[a] / dof_axis[a] for a in AXES}}
    rms_over_floor = {"all": float(np.sqrt(np.nanmean(z ** 2))),
                      **{a: float(np.sqrt(np.nanmean(z[:, i] ** 2))) for i, a in enumerate(AXES)}}
    excess_p = float(chi2_sf(base.chi2, base.dof))
    explains = excess_p >= alpha / 2
    judge = _Judge(settings, obs, data, other, alpha, max(base.chi2 / base.dof - 1.0, 0.0))
    base_next = judge.carry(base)
    if base_next is not None and "error" in base_next:
        judge.other = None    # the other session cannot be used: judged on this one alone
    unrepeated = False
    if not explains and usable(base_next) and base_next["unrepeated_p_value"] is not None:
        # An excess that does not come back in the other session, whose residuals differ
        # from this one's by more than the floor, is slow noise, not an effect.
        unrepeated = explains = (base_next["repeat_p_value"] >= alpha / 2
                                 and base_next["unrepeated_p_value"] < alpha / 2)
    within_noise = None
    if not explains and not usable(base_next):
        # Slow wander the static data could not rule out may be all the excess is.
        upper = with_upper_floor(obs)
        if upper is not None:
            wide = evaluate(settings, upper, "configured model, slow noise at its upper bound")
            within_noise = {"excess_p_value": float(chi2_sf(wide.chi2, wide.dof)),
                            "chi2_red": wide.chi2 / wide.dof,
                            "static_seconds": float(obs.attrs.get("static_seconds") or 0.0)}
            within_noise["explains"] = within_noise["excess_p_value"] >= alpha / 2
    covariates, heat = _covariate_table(obs, data, np.nan_to_num(z), fitted_rows, base.dof,
                                        not explains)

    names = candidate_terms(settings)
    tolerance = explained_tolerance(obs, base.summary["holds_scored"], alpha)
    candidates: list[Candidate] = []
    tested = []
    for spec in names:
        term = make_term(spec)
        series = "series" in data
        missing = sorted(c for c in term.needs if c not in data and not c.startswith("rate_")
                         and not (series and c in SERIES_INPUTS))
        if missing:
            candidates.append(Candidate(spec, "missing inputs", reason=f"needs {', '.join(missing)}"))
            continue
        try:
            ext = evaluate(extended(settings, spec), obs, spec)
        except MissingInputError as exc:
            candidates.append(Candidate(spec, "missing inputs", reason=_reason(exc)))
            continue
        except GyrocalError as exc:
            candidates.append(Candidate(spec, "not identifiable", reason=_reason(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: report it
            candidates.append(Candidate(spec, "failed", reason=f"{type(exc).__name__}: {exc}"))
            continue
        added = [c for c in ext.fitted.names if c not in base.fitted.names]
        df_num, df_den = base.dof - ext.dof, ext.dof
        problem = ("it leaves fewer temperature points"
                   if len(ext.fitted.used_points()) != len(base.fitted.used_points())
                   else "it adds no coefficient to the model" if df_num <= 0
                   else "it leaves no degree of freedom" if df_den <= 0 else None)
        if problem:
            candidates.append(Candidate(spec, "not identifiable", reason=problem))
            continue
        f_stat = ((base.chi2 - ext.chi2) / df_num) / (ext.chi2 / df_den)
        p = float(f_sf(f_stat, df_num, df_den))
        size, peak = _effect_size(ext, spec, added, data)
        v0, v1 = base.summary["validation_rms"], ext.summary["validation_rms"]
        candidate = Candidate(spec, "ranked", v1, p, float(f_stat), (df_num, df_den),
                              100.0 * (1 - v1 / v0), False, size, peak,
                              expected_with=ext.summary["expected_rms"])
        candidate.chi2 = ext.chi2
        candidate.explains_excess = judge.explains(ext, candidate, base_next, tolerance)
        candidates.append(candidate)
        tested.append(candidate)
    for c in tested:  # Bonferroni over the candidates actually tested
        c.significant = c.p_value < alpha / 2 / max(len(tested), 1)
    _mark_ties(tested)
    ranked = sorted(tested, key=lambda c: c.validation_rms_with)
    candidates = ranked + [c for c in candidates if c.status != "ranked"]
    v0, expected = base.summary["validation_rms"], base.summary["expected_rms"]
    useful = [c for c in ranked if c.significant and not explains and c.validation_rms_with < v0]
    if usable(base_next):  # what the user will meet: the other session first
        useful.sort(key=lambda c: c.next_session["validation_rms"] if usable(c.next_session) else np.inf)
    # Named only when it explains the excess: what is left is what a correct model leaves.
    best = next((c for c in useful if c.explains_excess), None)
    drift = _time_drift(judge, settings, obs, base, base_next, tolerance) if not explains else None
    if best is not None and drift is not None and drift["explains"] and "time" not in _kinds(best.term):
        # Within a soak the mounts follow each other in time: a term that is constant per
        # mount (a g-sensitivity) and a bias drifting in time can fit the same steps. When
        # the drift explains the excess too, the protocol cannot name either.
        drift["rival_of"] = best.term
        best = None
    # Two effects at once are looked for only when the held-out error is above what a
    # correct model leaves by more than that figure's uncertainty: among the tens of pairs,
    # some fit a small excess by chance, and passing the checks of what is left is weak
    # evidence when there is little left to test.
    resolvable = v0 > expected * tolerance
    if best is None and useful and resolvable and _practical_gain(base, useful[0]):
        # Two effects missing at once: the most useful term, then each other one on top.
        best = _second_step(judge, useful[0], ranked, base.summary["validation_rms"], tolerance)
    # Otherwise, terms that take away a real part of it are reported as partial.
    timed = best is None and drift is not None and drift["explains"]
    # A drift in time that explains the excess is the finding: terms that fit a part of it
    # are not reported as partial explanations.
    partial = [] if best or timed else [c for c in useful if _practical_gain(base, c)][:3]
    verdict = _verdict(base, best, explains, rms_over_floor, covariates, "floor_x" in obs, partial,
                       within_noise, unrepeated, base_next if usable(base_next) else None,
                       None if timed else tolerance)
    if timed:
        verdict += " " + _drift_sentence(base, drift)
    residuals = obs.reset_index(drop=True).assign(
        **{f"{q}_{a}": v[:, i] for q, v in (("resid", resid), ("floor", floor), ("z", z))
           for i, a in enumerate(AXES)})
    diag = Diagnosis(base, alpha, chi2_red, rms_over_floor, excess_p, explains, covariates,
                     candidates, best, partial, verdict, heat, residuals,
                     config_line=config_line(_extended_all(settings, best).model) if best else "")
    diag.ladder = ladder(settings, obs, base)
    diag.within_noise = within_noise
    diag.next_session = base_next
    diag.advice = advice(best, partial, candidates, covariates, explains, usable(base_next), drift)
    diag.time_drift = drift
    return diag


# A bias drifting linearly in time, fitted per temperature point on a grid: not an effect of
# the library but the rival every soaked protocol must rule out (a warm-up, a ramp).
TIME_DRIFT = {"name": "expression", "formula": "t"}


def _time_drift(judge: "_Judge", settings, obs, base: Evaluation, base_next, tolerance) -> dict | None:
    """How far a bias drifting in time within each temperature point takes the held-out
    error, and whether it explains the excess as a named term would have to; None where time
    within a point is not separable from temperature (a sweep) or the fit cannot be made."""
    if not judge.soaked or "t_start" not in obs:
        return None
    try:
        ev = evaluate(extended(settings, TIME_DRIFT), obs, "bias drifting in time")
    except GyrocalError:
        return None
    probe = Candidate("expression(formula='t')", "ranked")
    explains = judge.explains(ev, probe, base_next, tolerance)
    return {"validation_rms": ev.summary["validation_rms"], "expected_rms": ev.summary["expected_rms"],
            "explains": bool(explains and ev.summary["validation_rms"] < base.summary["validation_rms"]),
            "leftover": probe.leftover, "next_session": probe.next_session, "rival_of": None}


def _drift_sentence(base: Evaluation, drift: dict) -> str:
    rival = (f" {drift['rival_of']} fits it as well, and neither can be named: the mounts follow "
             "each other in time, so this protocol cannot tell an effect constant per mount from "
             "a drift."
             if drift["rival_of"] else "")
    return (f"A bias drifting linearly in time within each temperature point explains the excess "
            f"(validation RMS {base.summary['validation_rms']:.3g} → {drift['validation_rms']:.3g} deg/s, "
            f"what a correct model would leave: {drift['expected_rms']:.3g}): the missing effect "
            f"is a drift in time, such as a warm-up or a ramp, not a library term.{rival}")


class _Judge:
    """Whether a model leaves only what a correct one would, from one session or two.

    One session: its in-sample χ² is within chance or its validation RMS within chance of
    what a correct model leaves, *and* its residuals follow no covariate beyond chance (a
    term that soaks up most of an effect it is not, as a g-sensitivity on a linear time
    drift whose holds run in order of speed, leaves the rest lined up with time or rate).
    Two sessions: what its residuals still hold does not repeat in the other session, and
    it does not carry over worse than the configured model."""

    def __init__(self, settings, obs, data, other, alpha, base_excess: float):
        self.settings, self.obs, self.data, self.other, self.alpha = settings, obs, data, other, alpha
        self.base_excess = base_excess   # the configured model's χ²/dof − 1
        if other is not None and ("revolution" in obs or "revolution" in other):
            self.other = None  # a servo session's hand mount leaves the true rate unknown
        # Time is not temperature only where each point soaks at one temperature (not a sweep).
        self.soaked = bool("point" in obs and float(
            obs.groupby("point")["temp"].agg(lambda t: t.max() - t.min()).max()) < SOAKED_SPREAD)
        # The session's noise model has slow terms (bias instability, rate random walk):
        # holds close in time share their wander, which groups them by time.
        self.slow_known = any(float(np.nanmax(obs[f"{k}_{a}"])) > 0 for k in ("flicker", "rrw")
                              for a in AXES if f"{k}_{a}" in obs)

    def carry(self, ev: Evaluation) -> dict | None:
        """:func:`carry_over` to the other session; None without one, ``{"error": ...}``
        when this model cannot be applied there (a term reading an input it lacks)."""
        if self.other is None:
            return None
        try:
            return carry_over(self.settings, ev, self.obs, self.other)
        except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: note it
            return {"error": _reason(exc) if isinstance(exc, GyrocalError) else f"{type(exc).__name__}: {exc}"}

    def leftover(self, ev: Evaluation) -> dict:
        resid, floor, rows = in_sample(ev.fitted, len(self.obs))
        table, _ = _covariate_table(self.obs, self.data, np.nan_to_num(resid / floor), rows,
                                    ev.dof, True)
        worst = min(table, key=lambda r: r["p_value"])
        return {"covariate": worst["covariate"],
                "p_value": min(1.0, worst["p_value"] * len(table)),  # Bonferroni
                "chi2_red_share": worst["chi2_beyond_chance"] / max(ev.dof, 1)}

    def explains(self, ext: Evaluation, candidate: Candidate, base_next, tolerance) -> bool:
        half = self.alpha / 2
        candidate.leftover = left = self.leftover(ext)
        candidate.next_session = nxt = self.carry(ext) if usable(base_next) else None
        # Structure left over counts when it is real and not negligible. The right effect
        # fitted in a shape some per cent off leaves real but tiny structure; negligible is
        # small beside the effect (2 % of the excess, a shape about 15 % off in amplitude)
        # and beside the floor (within 1.2 times it). A wrong term that merely correlates
        # with the effect leaves more.
        sizeable = left["chi2_red_share"] > min(LEFTOVER_FRACTION * self.base_excess,
                                                NEGLIGIBLE_OVER_FLOOR ** 2 - 1.0)
        structure = sizeable and left["p_value"] < half
        in_chance = (float(chi2_sf(ext.chi2, ext.dof)) >= half
                     or ext.summary["validation_rms"] <= ext.summary["expected_rms"] * tolerance)
        # Slow noise lines residuals up with time and nothing else: structure in rate, mount
        # or temperature is an effect, and structure in time is one too unless slow noise is
        # known, from the static data's noise model or from two sessions that differ by more
        # than the floor (unrepeated_p_value).
        slow_noise = self.slow_known or (usable(nxt) and nxt["unrepeated_p_value"] is not None
                                         and nxt["unrepeated_p_value"] < half)
        exempt = self.soaked and slow_noise and left["covariate"] in TIME_LIKE
        if not usable(nxt):
            return in_chance and (not structure or exempt)
        # Two independent looks at what is left, combined (Fisher): its structure in this
        # session and its repetition in the other. What is left is within chance, or known
        # to be slow noise; and the other session is no worse than with the configured model.
        combined = nxt["repeat_p_value"]
        if sizeable and not exempt:
            combined = fisher_combined(left["p_value"], combined)
        nxt["left_p_value"] = combined
        return (combined >= half and (in_chance or slow_noise)
                and nxt["validation_rms"] <= base_next["validation_rms"])


def usable(nxt) -> bool:
    """A carry-over to another session that could be made and tested."""
    return nxt is not None and "error" not in nxt and nxt.get("repeat_p_value") is not None


def carry_over(settings: Settings, ev: Evaluation, obs: pd.DataFrame, other: pd.DataFrame) -> dict:
    """``ev``'s calibration (the fit of ``settings`` extended by the candidate; its
    reference temperature is ``settings``') applied to another session of the unit
    (:func:`gyrocal.drift.revalidate`) and whether the pattern of its residuals repeats there
    (:func:`repeat_p_value`) or the sessions differ by slow noise (:func:`unrepeated_p_value`)."""
    from .drift import hold_errors, revalidate
    from .pipeline import calibrate_observations
    cal, _ = calibrate_observations(obs, settings, meta={}, fitted=ev.fitted, checks=False)
    r = revalidate(cal, other)
    errors, floor1 = hold_errors(cal, other)
    resid, floor0, rows = in_sample(ev.fitted, len(obs))
    z0, z1 = (resid / floor0)[rows], errors / floor1
    out = {"validation_rms": r["validation_rms"], "noise_floor": r["noise_floor"],
           "excess": r["excess"], "expected_rms": r["expected_rms"], "holds": r["holds"],
           "repeat_p_value": repeat_p_value(obs.iloc[rows], z0, other, z1),
           "unrepeated_p_value": unrepeated_p_value(obs.iloc[rows], z0, other, z1)}
    if not all(np.isfinite(v) for v in out.values() if isinstance(v, float)):
        raise GyrocalError("the other session's errors are not finite")
    return out


REPEAT_DRAWS = 9999
POINT_MATCH = 3.0   # °C: soaked points of two sessions closer than this are the same point


def _cells(obs: pd.DataFrame, soaked_spread: float = SOAKED_SPREAD) -> pd.DataFrame:
    """Each hold's cell, the key two sessions of one protocol share (temperature, mount,
    rate and, along a sweep, the direction the temperature moves), and its block of
    neighbouring cells (10 °C × mount) whose errors a slow wander shares."""
    temp = obs["temp"].to_numpy(float)
    point_temp = obs["point_temp"].to_numpy(float) if "point_temp" in obs else temp
    if "point" in obs:
        spread = obs.groupby(obs["point"].to_numpy())["temp"].transform(lambda t: t.max() - t.min())
        soaked = spread.to_numpy() < soaked_spread
    else:
        soaked = np.zeros(len(obs), dtype=bool)
    # Holds of one soaked point share its temperature; along a sweep, 2 °C bins and the
    # direction of the ramp (on a soak the temperature rate is noise: no direction).
    tbin = np.where(soaked, point_temp, 2.0 * np.round(temp / 2.0))
    rate = obs["temp_rate"].to_numpy(float) if "temp_rate" in obs else np.zeros(len(obs))
    rising = np.where(soaked, 0.0, np.sign(np.round(np.nan_to_num(rate), 1)))
    return pd.DataFrame({"temp": tbin, "soaked": soaked, "mount": obs["mount"].astype(str).to_numpy(),
                         "rate": np.round(obs["ref_rate"].to_numpy(float), 1), "rising": rising})


def _snap(cells1: pd.DataFrame, cells0: pd.DataFrame) -> pd.DataFrame:
    """Session 1's soaked point temperatures moved to session 0's nearest, when within
    :data:`POINT_MATCH` (set points drift a little between sessions)."""
    points0 = np.unique(cells0.loc[cells0["soaked"], "temp"])
    if points0.size == 0:
        return cells1
    t = cells1["temp"].to_numpy(float)
    nearest = points0[np.abs(t[:, None] - points0[None, :]).argmin(axis=1)]
    snap = cells1["soaked"].to_numpy() & (np.abs(nearest - t) <= POINT_MATCH)
    return cells1.assign(temp=np.where(snap, nearest, t))


KEY = ["temp", "mount", "rate", "rising"]


def _shared_cells(obs0, z0, obs1, z1):
    """Per cell both sessions have: the mean residual of each (n, 3), the number of holds
    averaged in each, and the cell's block; session 1's offset per axis removed. None when
    fewer than 6 blocks are shared."""
    c0 = _cells(obs0)
    c1 = _snap(_cells(obs1), c0)

    def means(cells, z):
        frame = pd.concat([cells[KEY].reset_index(drop=True),
                           pd.DataFrame(np.nan_to_num(np.asarray(z, float)), columns=list(AXES))], axis=1)
        grouped = frame.groupby(KEY, sort=True)
        return grouped[list(AXES)].mean(), grouped.size()

    m0, k0 = means(c0, z0)
    m1, k1 = means(c1, z1)
    m1 = m1 - m1.mean()
    shared = m0.index.intersection(m1.index)
    if shared.empty:
        return None
    block = (np.floor(shared.get_level_values("temp").to_numpy(float) / 10.0).astype(int).astype(str)
             + "|" + shared.get_level_values("mount").to_numpy().astype(str))
    if np.unique(block).size < 6:
        return None
    return (m0.loc[shared].to_numpy(), m1.loc[shared].to_numpy(), k0.loc[shared].to_numpy(float),
            k1.loc[shared].to_numpy(float), block)


def repeat_p_value(obs0: pd.DataFrame, z0: np.ndarray, obs1: pd.DataFrame, z1: np.ndarray,
                   draws: int = REPEAT_DRAWS) -> float | None:
    """How likely, were the two sessions' residuals independent, a pattern that repeats as
    much as this one. Two-sided: a model wrong in a way that depends on the session's
    conditions (a lag at another ramp rate) can leave the pattern reversed.

    The residuals ``z`` (hold error ÷ floor, per axis) are averaged per cell shared by the
    sessions, and each block's mean per axis is removed from both: what is compared is the
    pattern within blocks (over rate, direction, time within a point), which a wander across
    blocks (bias instability, a random walk over the session) leaves alone. The statistic is
    |Σ z0·z1| over cells and axes. Its null distribution flips the sign of session 1's cells
    a whole block and axis at a time: wander within a block correlates its holds within a
    session, not across sessions, so flipping blocks keeps that correlation. Draws from a
    fixed seed: the same data give the same p. None when fewer than 6 blocks are shared."""
    shared = _shared_cells(obs0, z0, obs1, z1)
    if shared is None:
        return None
    a, b, _, _, block = shared
    labels, codes = np.unique(block, return_inverse=True)

    def within(m):
        sums = np.stack([np.bincount(codes, weights=m[:, i], minlength=labels.size) for i in range(3)], axis=1)
        return m - (sums / np.bincount(codes, minlength=labels.size)[:, None])[codes]

    products = within(a) * within(b)                                       # (cells, 3)
    per_block = np.stack([np.bincount(codes, weights=products[:, i], minlength=labels.size)
                          for i in range(products.shape[1])], axis=1).ravel()
    observed = per_block.sum()
    signs = np.random.default_rng(0).choice((-1.0, 1.0), size=(draws, per_block.size))
    null = signs @ per_block
    return float((1 + np.count_nonzero(np.abs(null) >= abs(observed) * (1 - 1e-12))) / (draws + 1))


def unrepeated_p_value(obs0, z0, obs1, z1) -> float | None:
    """Whether the sessions differ by more than white noise. Per shared cell, the
    difference of the two sessions' mean residuals over its standard deviation for white
    noise at the floor, ``sqrt(1/k0 + 1/k1)`` for cells of k0 and k1 holds, is a unit normal
    when what is left repeats; a χ² excess is noise between holds that the floor leaves out:
    slow wander. (Session 0's in-sample residuals scatter a little less than unit normals, by
    the fit's leverage: the test errs towards finding no wander.)"""
    shared = _shared_cells(obs0, z0, obs1, z1)
    if shared is None:
        return None
    a, b, k0, k1, _ = shared
    d = ((a - a.mean(axis=0)) - b) / np.sqrt(1.0 / k0 + 1.0 / k1)[:, None]
    return float(chi2_sf(float(np.sum(d ** 2)), d.size - 3))


def _extended_all(settings: Settings, best: Candidate) -> Settings:
    for spec in (best.term, *best.together):
        settings = extended(settings, spec)
    return settings


def _second_step(judge: _Judge, first: Candidate, ranked: list[Candidate], base_rms: float,
                 tolerance: float) -> Candidate | None:
    """``first`` with one more term that, added on top, explains the excess (F-test of the
    second addition, Bonferroni over the pairs tried); None when no pair does."""
    settings, obs, alpha = judge.settings, judge.obs, judge.alpha
    start = evaluate(extended(settings, first.term), obs, first.term)
    start_next = judge.carry(start) if judge.other is not None else None
    others = [c for c in ranked if c is not first and c.term not in first.tied_with]
    found = []
    for c in others:
        try:
            ext = evaluate(extended(extended(settings, first.term), c.term), obs, c.term)
        except Exception:  # noqa: BLE001 - as for single candidates: not a pair to name
            continue
        df_num, df_den = start.dof - ext.dof, ext.dof
        if df_num <= 0 or df_den <= 0 or len(ext.fitted.used_points()) != len(start.fitted.used_points()):
            continue
        f_stat = ((start.chi2 - ext.chi2) / df_num) / (ext.chi2 / df_den)
        p = float(f_sf(f_stat, df_num, df_den))
        if p >= alpha / 2 / max(len(others), 1):
            continue
        if ext.summary["validation_rms"] >= first.validation_rms_with:
            continue  # the second term must help on the holds left out too
        pair = replace(first, together=[c.term])
        if judge.explains(ext, pair, start_next, tolerance):
            found.append((ext.summary["validation_rms"], c.term, ext, pair))
    if not found:
        return None
    v, term, ext, pair = min(found, key=lambda f: f[0])
    return replace(pair, validation_rms_with=v, expected_with=ext.summary["expected_rms"],
                   explains_excess=True, alone_rms=first.validation_rms_with,
                   gain_pct=100.0 * (1 - v / base_rms))


def explained_tolerance(obs, holds: int, alpha: float) -> float:
    """How far above what a correct model would leave a validation RMS may lie and still
    count as explained: chance (:func:`chance_bound`) times twice the floor's own relative
    uncertainty. The floor comes from the session's static data, T seconds of it; the
    Allan deviation at a hold's length τ is then known to about ``sqrt(τ / 2T)``."""
    static = float(getattr(obs, "attrs", {}).get("static_seconds") or 0.0)
    hold = float(np.median(obs["duration"])) if "duration" in obs else 0.0
    floor_se = float(np.sqrt(hold / (2.0 * static))) if static > 0 and hold > 0 else 0.0
    return chance_bound(holds, alpha) * (1.0 + 2.0 * min(floor_se, 0.5))


def chance_bound(holds: int, alpha: float) -> float:
    """How far above the RMS a correct model should leave a validation RMS of ``holds``
    holds (three errors each) may lie by chance: ``sqrt(χ²_N(1 − α/2) / N)``."""
    n = 3 * max(int(holds), 1)
    return float(np.sqrt(chi2_ppf(1.0 - alpha / 2, n) / n))


def _practical_gain(base: Evaluation, c: Candidate) -> bool:
    """A term takes away a practical part of the excess: at least a quarter of the
    validation RMS above what a correct model leaves."""
    v0, expected = base.summary["validation_rms"], base.summary["expected_rms"]
    return v0 > expected and (v0 - c.validation_rms_with) >= 0.25 * (v0 - expected)


def _mark_ties(tested: list[Candidate]) -> None:
    """Candidates whose extended fits are the same to a part in 10⁶ (χ²) add the same
    columns in this protocol's span (a quadratic and an asymmetric scale at one speed)."""
    for c in tested:
        c.tied_with = [o.term for o in tested if o is not c and o.df == c.df
                       and abs(o.chi2 - c.chi2) <= 1e-6 * max(c.chi2, 1e-300)]


def _reason(exc: BaseException) -> str:
    text = str(exc)
    return text.split(": ", 1)[1] if text.startswith("/") and ": " in text else text


def _p(value: float) -> str:
    return "< 1e-16" if value < 1e-16 else f"= {value:.2g}"


def _verdict(base, best, explains, rms_over_floor, covariates, noise_model: bool = False,
             partial=(), within_noise=None, unrepeated: bool = False, base_next=None,
             tolerance=None) -> str:
    text = _session_verdict(base, best, explains, rms_over_floor, covariates, noise_model,
                            partial, within_noise, unrepeated, base_next, tolerance)
    if base_next is None or base_next["holds"] or best is not None:
        return text
    if unrepeated:
        return text + (f" On the other session the errors are {base_next['excess']:.3g} times the "
                       "floor from the same noise: holds minutes apart scatter more than the floor "
                       "from the static data says.")
    if explains:
        return text + (f" On the other session the calibration's errors are {base_next['excess']:.3g} "
                       "times the floor: it does not carry over, the unit changed between sessions "
                       "(run-to-run bias, drift; gyrocal revalidate and gyrocal drift say which "
                       "parameters).")
    return text + f" On the other session the errors are {base_next['excess']:.3g} times the floor."


def _session_verdict(base, best, explains, rms_over_floor, covariates, noise_model, partial,
                     within_noise, unrepeated, base_next, tolerance=None) -> str:
    factor = rms_over_floor["all"]
    s = base.summary
    small = ""
    if tolerance is not None and s["validation_rms"] <= s["expected_rms"] * tolerance:
        small = (f" On the holds left out its error is {s['validation_rms'] / s['expected_rms']:.2f} times "
                 f"what a correct model would leave, within that figure's uncertainty (up to "
                 f"{tolerance:.2f}): the excess is too small to attribute to an effect.")
    caveat = ""
    if within_noise is not None and within_noise.get("explains"):
        caveat = (f" Caution: with the slow wander (bias instability, rate random walk) that the "
                  f"{within_noise['static_seconds']:.0f} s of static data cannot rule out, the reduced "
                  f"χ² would be {within_noise['chi2_red']:.2f}: the excess may be noise; longer static "
                  "stretches (soaks, a still rig before and after) would tell.")
    if best is not None:
        sizes = sorted(best.size, key=lambda z: -abs(z["value"]) / max(z["stderr"], 1e-300))
        top = (f" (largest: {sizes[0]['coefficient']} = {sizes[0]['value']:.3g} ± "
               f"{sizes[0]['stderr']:.2g} {sizes[0]['unit']})") if sizes else ""
        tied = (f" This protocol cannot tell it from {', '.join(best.tied_with)}: they fit the "
                "data identically." if best.tied_with else "")
        carried = ""
        if base_next is not None and usable(best.next_session):
            carried = (f" On the other session the error falls from {base_next['excess']:.3g} to "
                       f"{best.next_session['excess']:.3g} times the floor.")
        if best.together:
            return (f"Missing effects: {best.term} and {', '.join(best.together)}. Adding both "
                    f"lowers the validation RMS from {base.summary['validation_rms']:.3g} to "
                    f"{best.validation_rms_with:.3g} deg/s, what a correct model would leave "
                    f"({best.expected_with:.3g}); {best.term} alone takes it to {best.alone_rms:.3g}."
                    + carried)
        return (f"Missing effect: {best.term}. Adding it lowers the validation RMS from "
                f"{base.summary['validation_rms']:.3g} to {best.validation_rms_with:.3g} deg/s "
                f"({best.gain_pct:.0f} % less; F-test p {_p(best.p_value)}), what a correct model "
                f"would leave ({best.expected_with:.3g}); its largest contribution to a hold is "
                f"{best.peak_effect:.3g} deg/s{top}.{tied}{carried}")
    if not explains:
        lead = covariates[0] if covariates and (covariates[0]["share_of_excess"] or 0) > 0 else None
        where = (f"; the excess lives mostly with {lead['covariate']} "
                 f"({100 * lead['share_of_excess']:.0f} % of it)" if lead else "")
        if partial:
            first = partial[0]
            return (f"The model does not explain the data: its in-sample residuals are {factor:.2f} "
                    f"times their noise floor. No library or listed term explains it; "
                    f"{first.term} explains part of it (validation RMS {base.summary['validation_rms']:.3g}"
                    f" → {first.validation_rms_with:.3g} deg/s, still {first.validation_rms_with / first.expected_with:.2g}"
                    f" times what a correct model would leave){where}. The missing effect is likely "
                    "outside the library: write it as a term (docs/effects.md)." + caveat)
        return (f"The model does not explain the data: its in-sample residuals are {factor:.2f} "
                "times their noise floor, and no candidate term accounts for it" + where + "." + small
                + caveat)
    if unrepeated:
        return (f"The model explains the data: its in-sample residuals are {factor:.2f} times their "
                f"noise floor, but their pattern does not come back in the other session (p = "
                f"{base_next['repeat_p_value']:.2g}): the excess is slow noise the static data did not "
                "resolve, not a missing effect.")
    return (f"The model explains the data: its in-sample residuals are {factor:.2f} times "
            "their noise floor, as " + ("the sensor's noise model" if noise_model else
                                         "white noise within the holds") + " would leave; nothing is missing.")


# What separates effects of each kind of input, for a protocol that cannot tell them apart.
SEPARATES = {
    "accel": "mounts that put gravity along each axis in both directions (the six-mount "
             "protocol) separate orientation effects from the bias",
    "rate": "holds at several speeds in both directions on every axis separate the even and "
            "odd shapes of the rate",
    "thermal": "two sweeps at different ramp rates separate the temperature's rate and lag "
               "from the temperature itself",
    "time": "revisiting the first temperature point at the end of the session separates "
            "drift in time from temperature; another session (--other-session) tells a "
            "drift that repeats from slow noise",
}


def _kinds(term: str) -> set[str]:
    t = make_term(term)
    inputs = set(t.inputs())
    kinds = set()
    if any(i.startswith("accel") for i in inputs):
        kinds.add("accel")
    if any(i.startswith("rate_") or i == "ref_rate" for i in inputs):
        kinds.add("rate")
    if inputs & {"temp_rate", "temp_lag"}:
        kinds.add("thermal")
    if "t" in inputs:
        kinds.add("time")
    return kinds


def advice(best, partial, candidates, covariates, explains: bool, has_other: bool,
           drift: dict | None = None) -> list[str]:
    """What to do next, in sentences: what would separate effects this protocol confounds
    (and that either one compensates what it sees), where an unexplained excess lives and
    how to write the effect, and when another session would decide."""
    out = []
    if best is None and drift is not None and drift["explains"]:
        out.append("Write the drift as a term of t: --add-term \"expression(formula='t')\" fits "
                   "a bias drifting linearly within each point, and a term file can give it the "
                   "shape of the drift (docs/effects.md, section 7)"
                   + ("; visiting the first mount again at the end of a point separates a drift "
                      f"from {drift['rival_of']}" if drift["rival_of"] else "") + ".")
    if best is not None and best.tied_with:
        kinds = set().union(*(_kinds(t) for t in (best.term, *best.tied_with)))
        out.append(f"{best.term} and {', '.join(best.tied_with)} fit this session identically: "
                   f"either compensates what this protocol sees (validation RMS "
                   f"{best.validation_rms_with:.3g} deg/s). To tell them apart: "
                   + "; ".join(SEPARATES[k] for k in sorted(kinds) if k in SEPARATES) + ".")
    if explains or best is not None:
        return out
    blocked = [c for c in candidates if c.status == "not identifiable"]
    for c in blocked:
        kinds = _kinds(c.term)
        if kinds:
            out.append(f"{c.term} cannot be fitted from this protocol ({c.reason}): "
                       + "; ".join(SEPARATES[k] for k in sorted(kinds)) + ".")
    for c in partial[:1]:
        if c.leftover is not None:
            out.append(f"With {c.term} the residuals still follow {c.leftover['covariate']} "
                       f"(p = {c.leftover['p_value']:.2g}): the effect is likely another shape "
                       "of that covariate; write it as a term (docs/effects.md).")
    lead = covariates[0]["covariate"] if covariates and (covariates[0]["share_of_excess"] or 0) > 0 else None
    if lead is not None and lead.startswith("time") and not (drift and drift["explains"]):
        out.append("The excess follows time: a warm-up or a drift. Write it as a term of t with "
                   "a global coefficient (docs/effects.md, section 7, works one through); "
                   + SEPARATES["time"] + ".")
    if not has_other:
        out.append("Diagnose with another session of the unit (--other-session) to judge the "
                   "candidates by how they carry over to it, as a calibration will be used.")
    return out


def ladder(settings: Settings, obs: pd.DataFrame, base: Evaluation) -> list[dict]:
    """The base model, then each configured step added to the one before."""
    rows = [_ladder_row(base, [])]
    current = settings
    for step in settings.diagnosis.ladder:
        for spec in step["add"]:
            current = extended(current, spec, step["kind"])
        if step["kind"] and not step["add"]:
            current = replace(current, model=replace(current.model, kind=step["kind"]))
        try:
            ev = evaluate(current, obs, step["name"])
        except GyrocalError as exc:
            rows.append({"name": step["name"], "error": _reason(exc)})
            continue
        except Exception as exc:  # noqa: BLE001 - a user's term may fail any way: report it
            rows.append({"name": step["name"], "error": f"{type(exc).__name__}: {exc}"})
            continue
        added = [c for c in ev.fitted.names if c not in base.fitted.names]
        rows.append(_ladder_row(ev, added))
    return rows


def _ladder_row(ev: Evaluation, added: list[str]) -> dict:
    params = [dict(zip(("coefficient", "value", "stderr"), (name, *_pooled(ev.fitted.fits, name))))
              for name in added]
    s = ev.summary
    return {"name": ev.name, "kind": ev.kind, "terms": ev.terms,
            "validation_rms": s["validation_rms"], "noise_floor": s["noise_floor"],
            "expected_rms": s["expected_rms"], "excess": s["excess"],
            "chi2_red": ev.chi2 / ev.dof, "parameters": params}


def config_line(model) -> str:
    """The ``model:`` lines of the config for ``model`` (a ModelSettings): ``terms: [...]``
    and, when it has any, ``expressions: {...}``. Specs other than plain names are quoted."""
    quote = lambda t: t if t.isidentifier() else json.dumps(t)  # noqa: E731
    terms = [make_term(t).spec_string() for t in model.terms]
    lines = ["terms: [" + ", ".join(quote(t) for t in terms) + "]"]
    if model.expressions:
        lines.append("expressions: {" + ", ".join(f"{k}: {json.dumps(v)}" for k, v in model.expressions)
                     + "}")
    return "\n".join(lines)


def add_term_option(term: str) -> str:
    return "--add-term " + shlex.quote(term)
