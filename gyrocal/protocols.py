"""Servo and sweep logs as observation tables the common model, validation and diagnosis read.

Each protocol finds its own observations in the data (seed 001: whole revolutions of six
rotations; seed 003: windows along a temperature sweep) and writes them in the turntable's
hold table schema (``hold, t_start, t_end, duration, n, mount, …, point, point_temp``). From
there on one code path fits, validates (leave-temperature-out, or leave-hold-out at a single
temperature), diagnoses and reports every protocol; the seed-specific methods (Algorithm 1
and Levenberg–Marquardt, the RBF drift network and bias stability) are computed beside it
from the same table.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .io import GYRO, MOUNTS, RigLog
from .model import observation_floor
from .segment import Segmentation

AXES = ("x", "y", "z")
TIMELINE_BUCKETS = 2000


def timeline(log: RigLog, buckets: int = TIMELINE_BUCKETS) -> pd.DataFrame:
    """The log in at most ``buckets`` consecutive buckets (the turntable timeline's columns)."""
    t = log.column("t")
    n = len(t)
    starts = np.arange(0, n, max(1, -(-n // buckets)))
    ends = np.r_[starts[1:], n] - 1
    ref = log.column("ref_rate")
    out = {"t_start": t[starts], "t_end": t[ends],
           "temp": np.add.reduceat(log.column("temp"), starts) / (ends - starts + 1),
           "ref_min": np.minimum.reduceat(ref, starts), "ref_max": np.maximum.reduceat(ref, starts)}
    for name in GYRO:
        g = log.column(name)
        out[f"{name}_min"] = np.minimum.reduceat(g, starts)
        out[f"{name}_max"] = np.maximum.reduceat(g, starts)
    return pd.DataFrame(out)


def temperature_points(temp: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    """Group observations into temperature points ``span`` °C wide (bins aligned to 0 °C),
    numbered in order of temperature; returns (point, the point's mean temperature)."""
    bins = np.floor(np.asarray(temp, float) / span).astype(np.int64)
    _, point = np.unique(bins, return_inverse=True)
    sums = np.bincount(point, weights=temp)
    counts = np.bincount(point)
    return point.astype(np.int64), (sums / counts)[point]


def hold_table(*, t_start, t_end, n, mount: np.ndarray, mount_source: str, ref_rate, gyro,
               std, temp, temp_rate, point, point_temp) -> pd.DataFrame:
    """Observations in the turntable's hold schema; ``gyro``/``std`` are (k, 3)."""
    mount = np.asarray(mount, dtype=object)
    axis = np.array([m[1] for m in mount], dtype=object)
    sign = np.where(np.array([m[0] for m in mount]) == "+", 1.0, -1.0)
    ref_rate = np.asarray(ref_rate, float)
    k = len(ref_rate)
    out = pd.DataFrame({
        "hold": np.arange(k, dtype=np.int64), "t_start": t_start, "t_end": t_end,
        "duration": np.asarray(t_end, float) - np.asarray(t_start, float),
        "n": np.asarray(n, np.int64),
        "mount": pd.Categorical(mount, categories=list(MOUNTS)),
        "axis": axis.astype(str), "sign": sign, "mount_source": mount_source,
        "ref_rate": ref_rate,
        **{f"rate_{a}": np.where(axis == a, sign * ref_rate, 0.0) for a in AXES},
        **{f"gyro_{a}": gyro[:, i] for i, a in enumerate(AXES)},
        **{f"std_{a}": std[:, i] for i, a in enumerate(AXES)},
        "temp": temp, "temp_rate": temp_rate,
        "point": point, "point_temp": point_temp,
    })
    return out


def segment_sweep(log: RigLog, options: dict) -> Segmentation:
    """Seed 003 windows (:func:`gyrocal.sweep.sweep_windows`) as observations; each window's
    temperature point is its ``point_span`` °C bin, so leaving a point out leaves out a
    stretch of the sweep (leave-temperature-out on a continuous ramp)."""
    from .sweep import sweep_windows
    opts = dict(options)
    span = float(opts.pop("point_span", 10.0))
    win = sweep_windows(log, **opts)
    point, point_temp = temperature_points(win["temp"].to_numpy(), span)
    mount = win["mount"].to_numpy(dtype=object)
    if not all(isinstance(m, str) and m in MOUNTS for m in mount):
        # At rig rate 0 the mount is immaterial to the model; +z keeps the schema.
        mount = np.full(len(win), "+z", dtype=object)
    obs = hold_table(
        t_start=win["t_start"].to_numpy(), t_end=win["t_end"].to_numpy(), n=win["n"].to_numpy(),
        mount=mount, mount_source=win.attrs.get("mount_source") or "none",
        ref_rate=win["ref_rate"].to_numpy(),
        gyro=win[[f"gyro_{a}" for a in AXES]].to_numpy(), std=win[[f"std_{a}" for a in AXES]].to_numpy(),
        temp=win["temp"].to_numpy(), temp_rate=win["temp_rate"].to_numpy(),
        point=point, point_temp=point_temp)
    obs["window"] = win["window"].to_numpy()
    window_s = float(win.attrs["window_s"])
    kept = pd.DataFrame({"kind": "hold", "reason": "", "detail": "window",
                         "t_start": obs["t_start"], "t_end": obs["t_end"],
                         "ref_rate": obs["ref_rate"], "hold": obs["hold"]})
    segments = kept.astype({"kind": "string", "reason": "string", "detail": "string"})
    dropped = {k: int(v) for k, v in win.attrs["dropped"].items()}
    info = {"protocol": "sweep", "path": str(log.path), "rows_read": log.rows_read,
            "rows_dropped": log.rows_dropped, "rows_used": int(win["n"].sum()),
            "sample_rate": float(win.attrs["sample_rate"]), "typical_hold_s": window_s,
            "holds_accepted": int(len(obs)), "windows_total": int(win.attrs["windows_total"]),
            "windows_dropped": dropped, "t_ref": float(win.attrs["t_ref"]),
            "rig_rate": float(win.attrs["rig_rate"]), "mount": win.attrs.get("mount", ""),
            "point_span": span, "window_s": window_s}
    stable = pd.DataFrame({"t_start": [], "t_end": [], "temp": []}, dtype=float)
    return Segmentation(obs, segments, stable, timeline(log), info)



def windows_from_observations(obs: pd.DataFrame) -> pd.DataFrame:
    """Sweep observations back to :func:`gyrocal.sweep.sweep_windows` columns; the error of a
    window is its mean output minus the rig rate along the mount axis."""
    t_ref = float(obs.attrs.get("t_ref", obs["temp"].iloc[0]))
    out = pd.DataFrame({
        "window": obs["window"] if "window" in obs else obs["hold"],
        "t_start": obs["t_start"], "t_end": obs["t_end"], "n": obs["n"], "temp": obs["temp"],
        "temp_rate": obs["temp_rate"], "ref_rate": obs["ref_rate"],
        **{f"gyro_{a}": obs[f"gyro_{a}"] for a in AXES},
        **{f"std_{a}": obs[f"std_{a}"] for a in AXES},
        **{f"err_{a}": obs[f"gyro_{a}"] - obs[f"rate_{a}"] for a in AXES},
        "mount": obs["mount"].astype(str)})
    out["dT"] = out["temp"] - t_ref
    out["dT2"] = out["dT"] ** 2
    out.attrs["t_ref"] = t_ref
    return out.reset_index(drop=True)


SWEEP_MODELS = {  # seed 003: conventional f(ΔT) and modified f(ΔT, ΔT²) (Eq 16), two ways each
    "poly(ΔT)": ("poly", "dT"), "poly(ΔT, ΔT²)": ("poly", "dT,dT2"),
    "RBF(ΔT)": ("rbf", "dT"), "RBF(ΔT, ΔT²)": ("rbf", "dT,dT2"),
}


def sweep_fit(obs: pd.DataFrame):
    """(training windows, verification windows, number of sweeps, the four drift models)."""
    from .sweep import fit_drift, split_sweeps
    sweeps = split_sweeps(windows_from_observations(obs))
    train = sweeps[0]
    verify = sweeps[1] if len(sweeps) > 1 else sweeps[0]
    models = {name: fit_drift(train, kind=kind, inputs=inputs)
              for name, (kind, inputs) in SWEEP_MODELS.items()}
    return train, verify, len(sweeps), models


def sweep_analysis(obs: pd.DataFrame, fitted=None) -> dict:
    """Seed 003 Section 3.2 on a sweep's windows: the drift models fitted on the first
    monotone sweep and verified on the next (step 1), with bias stability BS1/BS2/BS3 and
    improvements P1/P2/P3 (Eq 30–32, the shape of Tables 3–7). A log with a single sweep is
    verified on its own training windows, and says so. JSON-plain."""
    from .sweep import stability_table
    train, verify, n_sweeps, models = fitted or sweep_fit(obs)
    sweeps = range(n_sweeps)
    pairs = {"polynomial": ("poly(ΔT)", "poly(ΔT, ΔT²)"), "RBF network": ("RBF(ΔT)", "RBF(ΔT, ΔT²)"),
             "paper (Tables 3–7)": ("poly(ΔT)", "RBF(ΔT, ΔT²)")}
    tables = {}
    for label, (conv, mod) in pairs.items():
        table = stability_table(verify, {"conventional": models[conv], "modified": models[mod]})
        tables[label] = {"conventional": conv, "modified": mod,
                         "rows": [{"axis": axis, **{k: float(v) for k, v in row.items()}}
                                  for axis, row in table.iterrows()]}

    def describe(part):
        return {"windows": int(len(part)), "t_start": float(part["t_start"].iloc[0]),
                "t_end": float(part["t_end"].iloc[-1]), "temp_from": float(part["temp"].iloc[0]),
                "temp_to": float(part["temp"].iloc[-1]), "t_ref": float(part.attrs["t_ref"])}
    return {"protocol": "sweep", "sweeps": len(sweeps), "train": describe(train),
            "verify": describe(verify), "verified_on_training": len(sweeps) < 2,
            "models": {name: {"kind": m.kind, "inputs": m.inputs,
                              "residual_rms": [float(v) for v in m.residual_rms],
                              "parameters": len(m.parameter_names())}
                       for name, m in models.items()},
            "stability": tables}


def _temperature_slopes(log: RigLog, t_start: np.ndarray, t_end: np.ndarray) -> np.ndarray:
    """Least-squares temperature slope (°C/min) over each [t_start, t_end] sample range."""
    t, temp = log.column("t"), log.column("temp")
    lo = np.searchsorted(t, t_start, side="left")
    hi = np.searchsorted(t, t_end, side="right")
    tc = t - t[0]
    csum = np.vstack([np.zeros(4), np.cumsum(np.c_[tc, temp, tc * tc, tc * temp], axis=0)])
    s = csum[hi] - csum[lo]
    n = (hi - lo).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = s[:, 2] - s[:, 0] ** 2 / n
        slope = (s[:, 3] - s[:, 0] * s[:, 1] / n) / var
    return np.where(np.isfinite(slope) & (var > 0), 60.0 * slope, 0.0)


def segment_servo(log: RigLog, options: dict) -> Segmentation:
    """Seed 001 rotations cut into whole revolutions (:func:`gyrocal.servo.find_rotations`),
    one observation per revolution (Eq 8). The mount of a revolution is the rotation's
    direction as the data show it (``+x``: the gyro's x reads the servo speed positive),
    and its reference rate the servo speed, so the common model sees the rate vector
    ``±ω`` along that axis. The noise of a revolution mean is the white-noise level
    (successive differences) over √n: the servo's ripple cancels over a whole revolution
    and must not inflate the floor."""
    from .servo import find_rotations
    rot = find_rotations(log, **options)
    rev = rot.revolutions
    gyro = rev[[f"gyro_{a}" for a in AXES]].to_numpy()
    noise = rev[[f"gyro_{a}_noise" for a in AXES]].to_numpy()
    t_start, t_end = rev["t_start"].to_numpy(), rev["t_end"].to_numpy()
    temp = rev["temp"].to_numpy()
    obs = hold_table(
        t_start=t_start, t_end=t_end, n=rev["n"].to_numpy(), mount=rev["direction"].to_numpy(dtype=object),
        mount_source="data",
        ref_rate=rev["ref_rate"].to_numpy(), gyro=gyro, std=noise, temp=temp,
        temp_rate=_temperature_slopes(log, t_start, t_end),
        point=np.zeros(len(rev), np.int64), point_temp=np.full(len(rev), float(np.mean(temp))))
    obs["rotation"] = rev["rotation"].to_numpy()
    obs["revolution"] = rev["revolution"].to_numpy()
    for i, a in enumerate(AXES):
        obs[f"gyro_{a}_noise"] = noise[:, i]
    segments = pd.DataFrame({"kind": "hold", "reason": "", "detail": "revolution",
                             "t_start": t_start, "t_end": t_end, "ref_rate": obs["ref_rate"],
                             "hold": obs["hold"]}).astype(
        {"kind": "string", "reason": "string", "detail": "string"})
    info = {"protocol": "servo", "path": str(log.path), "rows_read": log.rows_read,
            "rows_dropped": log.rows_dropped, "rows_used": int(rev["n"].sum()),
            "sample_rate": float((len(log.column("t")) - 1) / max(np.ptp(log.column("t")), 1e-12)),
            "typical_hold_s": float(np.median(t_end - t_start)), "holds_accepted": int(len(obs)),
            "rotations": int(rev["rotation"].nunique()), "directions": list(rot.directions),
            "warnings": list(rot.warnings)}
    stable = pd.DataFrame({"t_start": [], "t_end": [], "temp": []}, dtype=float)
    return Segmentation(obs, segments, stable, timeline(log), info)


SEGMENTERS = {"sweep": segment_sweep, "servo": segment_servo}


def analysis(protocol: str | None, obs: pd.DataFrame) -> tuple[dict | None, list[str]]:
    """The protocol's own methods on its observations, for the report: (JSON-plain
    results, SVG figures); (None, []) for the turntable, whose methods are the common ones."""
    from . import plots
    if protocol == "servo":
        iterative, lm = servo_fits(obs)
        return {"protocol": "servo", "iterative": iterative.summary(), "lm": lm.summary(),
                "settled_at": int(iterative.settled_at()),
                "max_difference_lm": float(np.max(np.abs(np.r_[iterative.k, iterative.b]
                                                         - np.r_[lm.k, lm.b])))}, []
    if protocol == "sweep":
        fitted = sweep_fit(obs)
        train, verify, _, models = fitted
        return sweep_analysis(obs, fitted), [plots.sweep_drift(train, verify, models)]
    return None, []


# --- servo: the calibration file holds seed 001's six-parameter fit --------------------------

SERVO_TERMS = ("bias", "scale")


def _servo_input(obs: pd.DataFrame) -> pd.DataFrame:
    """Revolution means in the form :func:`gyrocal.servo.fit.fit_observations` reads: the
    servo speed as |ref_rate|, the white-noise level per axis and the sample count."""
    cols = ["gyro_x", "gyro_y", "gyro_z", "n", *[f"gyro_{a}_noise" for a in AXES]]
    missing = [c for c in cols if c not in obs]
    if missing:
        from .errors import InputError
        raise InputError(f"servo observations lack {', '.join(missing)}: segment the log with "
                         "protocol servo")
    out = obs[cols].copy()
    out["ref_rate"] = obs["ref_rate"].abs()
    return out


def servo_fits(obs: pd.DataFrame):
    """(Algorithm 1, Levenberg–Marquardt) on every whole revolution (seed 001 Eq 8 per
    revolution, Eq 4–7, Algorithm 1)."""
    from .servo.fit import fit_observations
    data = _servo_input(obs)
    return fit_observations(data, method="iterative"), fit_observations(data, method="lm")


def servo_calibration(obs: pd.DataFrame, *, reference_temperature: float, meta: dict,
                      provenance: dict):
    """The calibration file of a servo session: ``K = diag(1/k)``, ``B = −b`` of Algorithm 1
    (:mod:`gyrocal.servo.fit` gives the mapping) as the terms bias and scale at the session's
    mean temperature, with both fits and the convergence trace carried along."""
    from .calibration import Calibration
    from .model import Model
    from .thermal import TemperatureGrid
    iterative, lm = servo_fits(obs)
    model = Model.from_spec(SERVO_TERMS)
    values, errors = iterative.coefficients(), iterative.coefficient_errors()
    names = tuple(model.names)
    temp = float(np.mean(obs["temp"]))
    grid = TemperatureGrid(np.array([temp]), names, np.array([[values[n] for n in names]]),
                           np.array([[errors[n] for n in names]]))
    if not (np.isfinite(grid.values).all() and np.isfinite(grid.stderr).all()):
        from .errors import IdentifiabilityError
        raise IdentifiabilityError("the servo fit gave non-finite parameters or errors",
                                   parameters=names)
    both = np.r_[iterative.k, iterative.b], np.r_[lm.k, lm.b]
    servo = {"method": "seed 001 Algorithm 1 (iterative least squares); Levenberg–Marquardt beside it",
             "iterative": iterative.summary(), "lm": lm.summary(),
             "settled_at": int(iterative.settled_at()),
             "max_difference_lm": float(np.max(np.abs(both[0] - both[1]))),
             "revolutions": int(len(obs)), "rotations": int(obs["rotation"].nunique())
             if "rotation" in obs else None}
    points = [{"temperature": temp, "holds": int(len(obs)), "used": True}]
    return Calibration(model, grid, reference_temperature, meta, provenance=provenance,
                       extra={"points": points, "servo": servo})


def servo_validation(obs: pd.DataFrame, cal):
    """Each revolution compensated by Algorithm 1 fitted on the other revolutions (when every
    rotation has two or more; otherwise in-sample, and said so): the error of the
    compensated rate's magnitude against the servo speed (the quantity Eq 2 matches), per
    rotation direction, beside the uncompensated error and the noise floor of each
    revolution mean (the white-noise level over √n, projected on the rotation axis)."""
    from .servo.fit import fit_observations
    from .validate import Validation
    data = _servo_input(obs)
    m = data[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    omega = data["ref_rate"].to_numpy()
    coefficients = cal.coefficients(np.array([float(np.mean(obs["temp"]))]), warn=False)
    k = 1.0 / (1.0 + np.array([coefficients[f"scale.{a}"][0] for a in AXES]))
    bias = np.array([coefficients[f"bias.{a}"][0] for a in AXES])
    in_sample = (m - bias) * k
    rotation = obs["rotation"].to_numpy() if "rotation" in obs else np.arange(len(obs))
    # Leaving a revolution out keeps the fit identifiable while its direction has another.
    held_out = bool(obs["mount"].astype(str).value_counts().min() >= 2)
    compensated = in_sample.copy()
    if held_out:
        for r in range(len(obs)):  # one refit per revolution (a few dozen), not per sample
            keep = np.arange(len(obs)) != r
            fit = fit_observations(data.iloc[keep], method="iterative")
            compensated[r] = fit.compensate(m[r:r + 1])[0]
    # the session's noise model where segmentation made one; else the white-noise level
    # over sqrt(n) (segment_servo stores it as the revolutions' std)
    noise = observation_floor(obs)
    norm = np.linalg.norm(compensated, axis=1)
    direction = compensated / norm[:, None]
    floor = np.sqrt(((direction * k * noise) ** 2).sum(axis=1))
    errors = {"uncompensated": np.linalg.norm(m, axis=1) - omega,
              "in_sample": np.linalg.norm(in_sample, axis=1) - omega,
              "validated": norm - omega}
    holds = pd.DataFrame({"hold": obs["hold"].to_numpy(), "direction": obs["mount"].astype(str).to_numpy(),
                          "rotation": rotation, "omega": omega, "noise_floor": floor,
                          **{f"{name}_error": e for name, e in errors.items()}})
    rows = []
    for d, part in holds.groupby("direction", sort=False):
        row = {"direction": d, "revolutions": int(len(part)),
               "noise_floor": float(np.sqrt(np.mean(part["noise_floor"] ** 2)))}
        for name in errors:
            e = part[f"{name}_error"].to_numpy()
            row[f"{name}_mean"], row[f"{name}_rms"] = float(e.mean()), float(np.sqrt(np.mean(e ** 2)))
        rows.append(row)
    table = pd.DataFrame(rows)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    n, p = len(obs), 6
    noise_floor = rms(floor)
    # A correct six-parameter model leaves the floor ×√(1 + p/n) on held-out revolutions
    # (leverage p/n on average), ×√(1 − p/n) in-sample; six revolutions leave nothing.
    expected = noise_floor * np.sqrt(1 + p / n) if held_out else \
        (noise_floor * np.sqrt(1 - p / n) if n > p else None)
    validation = rms(errors["validated"])
    ratio = lambda a, b: a / b if b else None  # noqa: E731 - None, never inf, in the JSON
    summary = {"validation_rms": validation, "noise_floor": noise_floor,
               "excess": ratio(validation, noise_floor),
               "expected_rms": None if expected is None else float(expected),
               "excess_over_expected": ratio(validation, expected),
               "uncompensated_rms": rms(errors["uncompensated"]), "single_rms": None,
               "in_sample_rms": rms(errors["in_sample"]),
               "reference_temperature": float(np.mean(obs["temp"])),
               "held_out": "revolution" if held_out else
               "nothing (one revolution per direction: in-sample)",
               "scored": "all", "holds_scored": int(n), "temperature_points": 1,
               "model_kind": "servo", "quantity": "magnitude of the compensated rate minus the servo speed"}
    by_temperature = pd.DataFrame({"temp": [summary["reference_temperature"]], "holds": [n],
                                   "validated_rms": [validation], "noise_floor": [noise_floor]})
    return Validation(holds, table, table.iloc[0:0], by_temperature, summary)
