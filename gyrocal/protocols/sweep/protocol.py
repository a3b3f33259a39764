"""The temperature-sweep protocol (seed 003) as a registered
:class:`gyrocal.protocols.registry.Protocol`: windows along a slow ramp as observations, fitted by the
common model as a continuous function of temperature, and the paper's drift models (poly and
RBF, ΔT and ΔT², Eq 16) with bias stability (Eq 30–32) as the report's own section."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict

import numpy as np

from ...fit.floor import merge_intervals
from ...terms import AXES
from ..registry import OwnAnalysis, Protocol, SettingsView, checked_options, register
from .defaults import DEFAULTS

# The report reads this module for its sections and figure: what segmentation, the fits
# and their tables import (pandas, the log reader) is imported where they run.
if TYPE_CHECKING:
    import pandas as pd

    from ...io.holds import Segmentation
    from ...io.log import RigLog
    from .models import DriftModel


POINT_SPANS = (10.0, 5.0, 2.0, 1.0, 0.5)  # °C: the widest that gives POINTS_WANTED points
POINTS_WANTED = 8


def auto_point_span(temps) -> float:
    """The temperature points' width for a sweep whose span is unknown in advance: 10 °C
    over a wide sweep (−40…85 °C: 13 points), narrower over a chamber test's few degrees,
    so that leaving points out still leaves several to interpolate from."""
    span = float(np.ptp(temps)) if len(temps) else 0.0
    return next((w for w in POINT_SPANS if span / w >= POINTS_WANTED), POINT_SPANS[-1])


def segment_sweep(log: RigLog, options: dict, *, name: str = "sweep") -> Segmentation:
    """Seed 003 windows (:func:`gyrocal.protocols.sweep.sweep_windows`) as observations; each window's
    temperature point is its ``point_span`` °C bin (``"auto"``: :func:`auto_point_span`), so leaving a point out leaves out a
    stretch of the sweep (leave-temperature-out on a continuous ramp)."""
    from ...io.holds import (
        Segmentation,
        hold_table,
        no_stable_periods,
        segments_of_holds,
        temperature_points,
        timeline,
    )
    from ...io.log import MOUNTS
    from . import sweep_windows

    opts = checked_options(name, options)
    span = opts.pop("point_span")
    win = sweep_windows(log, protocol=name, **opts)
    span = auto_point_span(win["temp"].to_numpy()) if span == "auto" else float(span)
    point, point_temp = temperature_points(win["temp"].to_numpy(), span=span)
    mount = win["mount"].to_numpy(dtype=object)
    if not all(isinstance(m, str) and m in MOUNTS for m in mount):
        # At rig rate 0 the mount is immaterial to the model; +z keeps the schema.
        mount = np.full(len(win), "+z", dtype=object)
    obs = hold_table(
        t_start=win["t_start"].to_numpy(),
        t_end=win["t_end"].to_numpy(),
        n=win["n"].to_numpy(),
        mount=mount,
        mount_source=win.attrs.get("mount_source") or "none",
        ref_rate=win["ref_rate"].to_numpy(),
        gyro=win[[f"gyro_{a}" for a in AXES]].to_numpy(),
        std=win[[f"std_{a}" for a in AXES]].to_numpy(),
        temp=win["temp"].to_numpy(),
        temp_rate=win["temp_rate"].to_numpy(),
        point=point,
        point_temp=point_temp,
    )
    obs["window"] = win["window"].to_numpy()
    window_s = float(win.attrs["window_s"])
    segments = segments_of_holds(obs, "window")
    dropped = {k: int(v) for k, v in win.attrs["dropped"].items()}
    info = {
        "protocol": name,
        "path": str(log.path),
        "rows_read": log.rows_read,
        "rows_dropped": log.rows_dropped,
        "rows_used": int(win["n"].sum()),
        "sample_rate": float(win.attrs["sample_rate"]),
        "typical_hold_s": window_s,
        "holds_accepted": int(len(obs)),
        "windows_total": int(win.attrs["windows_total"]),
        "windows_dropped": dropped,
        "t_ref": float(win.attrs["t_ref"]),
        "rig_rate": float(win.attrs["rig_rate"]),
        "mount": win.attrs.get("mount", ""),
        "point_span": span,
        "window_s": window_s,
        "runs": int(win.attrs["runs"]),
        "bursts": int(win.attrs["bursts"]),
        "longest_stall_s": float(win.attrs["longest_stall_s"]),
    }
    if win.attrs.get("stamps"):
        info["stamps"] = win.attrs["stamps"]
    return Segmentation(obs, segments, no_stable_periods(), timeline(log), info)


def windows_from_observations(obs: pd.DataFrame) -> pd.DataFrame:
    """Sweep observations back to :func:`gyrocal.protocols.sweep.sweep_windows` columns; the error of a
    window is its mean output minus the rig rate along the mount axis."""
    import pandas as pd

    t_ref = float(obs.attrs.get("t_ref", obs["temp"].iloc[0]))
    out = pd.DataFrame(
        {
            "window": obs["window"] if "window" in obs else obs["hold"],
            "t_start": obs["t_start"],
            "t_end": obs["t_end"],
            "n": obs["n"],
            "temp": obs["temp"],
            "temp_rate": obs["temp_rate"],
            "ref_rate": obs["ref_rate"],
            **{f"gyro_{a}": obs[f"gyro_{a}"] for a in AXES},
            **{f"std_{a}": obs[f"std_{a}"] for a in AXES},
            **{f"err_{a}": obs[f"gyro_{a}"] - obs[f"rate_{a}"] for a in AXES},
            "mount": obs["mount"].astype(str),
        }
    )
    out["dT"] = out["temp"] - t_ref
    out["dT2"] = out["dT"] ** 2
    out.attrs["t_ref"] = t_ref
    return out.reset_index(drop=True)


SWEEP_MODELS = {  # seed 003: conventional f(ΔT) and modified f(ΔT, ΔT²) (Eq 16), two ways each
    "poly(ΔT)": ("poly", "dT"),
    "poly(ΔT, ΔT²)": ("poly", "dT,dT2"),
    "RBF(ΔT)": ("rbf", "dT"),
    "RBF(ΔT, ΔT²)": ("rbf", "dT,dT2"),
}


class SweepFit(NamedTuple):
    """The four drift models fitted on the training sweep (:data:`SWEEP_MODELS`)."""

    train: pd.DataFrame  # the first monotone sweep's windows
    verify: pd.DataFrame  # the next sweep's, or the training windows again
    sweeps: int  # how many monotone sweeps the log holds
    models: dict[str, DriftModel]


def sweep_fit(obs: pd.DataFrame) -> SweepFit:
    from . import fit_drift, split_sweeps

    sweeps = split_sweeps(windows_from_observations(obs))
    train = sweeps[0]
    verify = sweeps[1] if len(sweeps) > 1 else sweeps[0]
    models = {
        name: fit_drift(train, kind=kind, inputs=inputs) for name, (kind, inputs) in SWEEP_MODELS.items()
    }
    return SweepFit(train, verify, len(sweeps), models)


class SweepPart(TypedDict):
    windows: int
    t_start: float
    t_end: float
    temp_from: float
    temp_to: float
    t_ref: float


class SweepAnalysis(TypedDict):
    """Seed 003's drift models and bias stability on a sweep (JSON-plain, for the report)."""

    protocol: str
    sweeps: int
    train: SweepPart
    verify: SweepPart
    verified_on_training: bool
    models: dict[str, dict[str, Any]]  # per model: kind, inputs, residual_rms, parameters
    stability: dict[str, dict[str, Any]]  # per pair of models: conventional, modified, rows


STABILITY_PAIRS = {  # (conventional, modified) of SWEEP_MODELS, as the report's tables pair them
    "polynomial": ("poly(ΔT)", "poly(ΔT, ΔT²)"),
    "RBF network": ("RBF(ΔT)", "RBF(ΔT, ΔT²)"),
    "paper (Tables 3–7)": ("poly(ΔT)", "RBF(ΔT, ΔT²)"),
}


def sweep_analysis(obs: pd.DataFrame, fitted: SweepFit | None = None) -> SweepAnalysis:
    """Seed 003 Section 3.2 on a sweep's windows: the drift models fitted on the first
    monotone sweep and verified on the next (step 1), with bias stability BS1/BS2/BS3 and
    improvements P1/P2/P3 (Eq 30–32, the shape of Tables 3–7). A log with a single sweep is
    verified on its own training windows, and says so."""
    from . import stability_table

    train, verify, n_sweeps, models = fitted or sweep_fit(obs)
    tables = {}
    for label, (conv, mod) in STABILITY_PAIRS.items():
        table = stability_table(verify, {"conventional": models[conv], "modified": models[mod]})
        tables[label] = {
            "conventional": conv,
            "modified": mod,
            "rows": [
                {"axis": axis, **{k: float(v) for k, v in row.items()}} for axis, row in table.iterrows()
            ],
        }
    return {
        "protocol": "sweep",
        "sweeps": n_sweeps,
        "train": _describe(train),
        "verify": _describe(verify),
        "verified_on_training": n_sweeps < 2,
        "models": {
            name: {
                "kind": m.kind,
                "inputs": m.inputs,
                "residual_rms": [float(v) for v in m.residual_rms],
                "parameters": len(m.parameter_names()),
            }
            for name, m in models.items()
        },
        "stability": tables,
    }


def _describe(part: pd.DataFrame) -> SweepPart:
    return {
        "windows": int(len(part)),
        "t_start": float(part["t_start"].iloc[0]),
        "t_end": float(part["t_end"].iloc[-1]),
        "temp_from": float(part["temp"].iloc[0]),
        "temp_to": float(part["temp"].iloc[-1]),
        "t_ref": float(part.attrs["t_ref"]),
    }


def analysis(obs: pd.DataFrame) -> OwnAnalysis:
    """:func:`sweep_analysis` and the drift models' figure."""
    from ...report import plots

    fitted = sweep_fit(obs)
    return OwnAnalysis(
        sweep_analysis(obs, fitted), [plots.sweep_drift(fitted.train, fitted.verify, fitted.models)]
    )


def static_windows(seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Runs of adjacent windows whose temperature rate is under ``max_temp_rate`` °C/min:
    the soak before the first ramp, the dwells at the targets. Windows either side of a
    stall of arrival-stamped samples join too: the stall held no missing sample."""
    obs = seg.observations
    steady = np.abs(obs["temp_rate"].to_numpy(float)) <= max_temp_rate
    rate = float(seg.info.get("sample_rate", 1.0))
    return merge_intervals(
        obs.loc[steady, "t_start"].to_numpy(float),
        obs.loc[steady, "t_end"].to_numpy(float),
        2.0 / rate + float(seg.info.get("longest_stall_s") or 0.0),
    )


class Sweep(Protocol):
    """Seed 003's conventional drift model (linear in ΔT, fitted jointly over the sweep) as
    the model, its modified model (Eq 16, + ΔT²) as the diagnosis' candidate and the
    ladder's step."""

    name = "sweep"
    description = "temperature sweep: windows along slow ramps at a constant rig rate (seed 003)"
    report_section = "protocols/sweep_section.html.j2"
    defaults = DEFAULTS
    timed_holds = False

    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        return segment_sweep(log, settings.protocol_options("sweep"))

    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        return static_windows(seg, max_temp_rate)

    def analysis(self, obs: pd.DataFrame) -> OwnAnalysis:
        return analysis(obs)


SWEEP = register(Sweep())
