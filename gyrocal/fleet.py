"""Fleet operations over a manifest's results: end-of-line verdicts and yield, outliers
against the batch, and drift audits of devices calibrated more than once.

The settings come from the workflow config's ``spec``, ``outliers`` and ``drift`` sections
(:class:`FleetSettings`); the numbers from :mod:`gyrocal.eol` and :mod:`gyrocal.drift`. The
output is JSON-plain, written to the fleet's ``eol.json`` for production systems and
rendered in the fleet summary and one drift page per audited device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import ConfigError, GyrocalError

PROTOCOLS = ("turntable", "servo", "sweep")


@dataclass(frozen=True)
class FleetSettings:
    spec: dict = field(default_factory=dict)          # protocol -> SpecLimits
    outlier_threshold: float = 3.5
    drift_tolerance: dict = field(default_factory=dict)
    drift_temperature: float | None = None
    drift_max_excess: float | None = None

    @classmethod
    def from_dict(cls, values: dict | None) -> FleetSettings:
        from .eol import SpecLimits
        values = dict(values or {})
        spec = values.get("spec") or {}
        if not isinstance(spec, dict):
            raise ConfigError("spec must map protocols to limits")
        limits = {}
        for protocol, section in spec.items():
            if protocol not in PROTOCOLS:
                raise ConfigError(f"unknown protocol spec.{protocol}; known: {', '.join(PROTOCOLS)}")
            limits[protocol] = SpecLimits.from_dict(section, key=f"spec.{protocol}")
        outliers = values.get("outliers") or {}
        threshold = outliers.get("threshold", 3.5) if isinstance(outliers, dict) else None
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) \
                or not math.isfinite(threshold) or threshold <= 0:
            raise ConfigError(f"outliers.threshold must be a positive number, got {threshold!r}")
        drift = values.get("drift") or {}
        if not isinstance(drift, dict) or set(drift) - {"tolerance", "temperature", "max_excess"}:
            raise ConfigError("drift takes tolerance, temperature and max_excess")
        tolerance = drift.get("tolerance") or {}
        if not isinstance(tolerance, dict):
            raise ConfigError("drift.tolerance must map parameter patterns to changes")
        return cls(limits, float(threshold), dict(tolerance), drift.get("temperature"),
                   drift.get("max_excess"))


def _finite(value):
    """inf and NaN have no place in a file: they become None (printed as –)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _records(frame: pd.DataFrame) -> list[dict]:
    return [{k: _finite(v.item() if hasattr(v, "item") else v) for k, v in row.items()}
            for row in frame.to_dict("records")]


def end_of_line(units: list[dict], settings: FleetSettings) -> dict:
    """Verdict per unit (``unit["row"]`` manifest row, ``unit["folder"]`` results), yield per
    batch. Units of a protocol without limits are not judged."""
    from .eol import batch_yield, judge_folder
    verdicts = {}
    for unit in units:
        row = unit["row"]
        limits = settings.spec.get(row["protocol"])
        if limits is None:
            continue
        verdict = judge_folder(unit["folder"], limits)
        verdicts[(row["batch"], row["device"], row["session"])] = verdict
    yields = batch_yield(list(verdicts.values())) if verdicts else pd.DataFrame()
    return {"verdicts": verdicts, "yield": _records(yields) if len(yields) else []}


def outliers(calibrated: list[dict], settings: FleetSettings) -> tuple[list[dict], list[str], str]:
    """Turntable units against their batch: (flagged rows, notes, distributions figure)."""
    from .eol import fleet_outliers, parameter_table, plot_parameter_distributions
    rows = [u for u in calibrated if u["protocol"] == "turntable"]
    if not rows:
        return [], [], ""
    table = parameter_table([u["calibration"] for u in rows])
    table["session"] = [u["session"] for u in rows]
    flagged = fleet_outliers(table, threshold=settings.outlier_threshold)
    figure = plot_parameter_distributions(table, flagged)
    return _records(flagged), list(flagged.attrs.get("notes", [])), figure


def drift_audits(calibrated: list[dict], folders: dict, settings: FleetSettings) -> list[dict]:
    """Devices with two or more turntable sessions: parameter changes with their
    significance, and the previous session's calibration re-validated on the newest
    session's holds."""
    from .drift import parameter_changes, plot_drift, revalidate
    by_device: dict[str, list[dict]] = {}
    for unit in calibrated:
        if unit["protocol"] == "turntable":
            by_device.setdefault(unit["device"], []).append(unit)
    audits = []
    for device, sessions in sorted(by_device.items()):
        if len(sessions) < 2:
            continue
        sessions = sorted(sessions, key=lambda u: u["session"])
        audit = {"device": device, "sessions": [u["session"] for u in sessions],
                 "batch": sessions[-1]["batch"]}
        try:
            changes = parameter_changes([u["calibration"] for u in sessions],
                                        temperature=settings.drift_temperature,
                                        tolerance=settings.drift_tolerance)
            audit["changes"] = _records(changes)
            audit["flagged"] = _records(changes[changes["flagged"]])
            audit["figure"] = plot_drift(changes)
            previous, newest = sessions[-2], sessions[-1]
            reval = revalidate(previous["calibration"],
                               folders[(newest["batch"], device, newest["session"])] / "observations.parquet",
                               max_excess=settings.drift_max_excess)
            audit["revalidation"] = {**{k: _finite(v) for k, v in reval.items() if k != "table"},
                                     "table": _records(reval["table"]),
                                     "calibration_session": previous["session"],
                                     "log_session": newest["session"]}
        except GyrocalError as exc:
            audit["error"] = str(exc)
        audits.append(audit)
    return audits


def audit(units: list[dict], calibrated: list[dict], settings: FleetSettings) -> dict:
    folders = {(u["row"]["batch"], u["row"]["device"], u["row"]["session"]): Path(u["folder"])
               for u in units}
    eol = end_of_line(units, settings)
    flagged, notes, figure = outliers(calibrated, settings)
    return {"eol": eol, "outliers": flagged, "outlier_notes": notes, "outlier_figure": figure,
            "drift": drift_audits(calibrated, folders, settings)}


def eol_document(result: dict, settings: FleetSettings) -> dict:
    """The machine-readable end-of-line record: every judged unit and the batch yields."""
    verdicts = [{**v.to_dict(), "batch": key[0], "device": key[1], "session": key[2]}
                for key, v in sorted(result["eol"]["verdicts"].items())]
    return {"format": "gyrocal.eol/1",
            "spec": {p: limits.to_dict() for p, limits in sorted(settings.spec.items())},
            "yield": result["eol"]["yield"], "units": verdicts,
            "outliers": result["outliers"],
            "drift": [{k: v for k, v in a.items() if k != "figure"} for a in result["drift"]]}


def drift_page_name(device: str) -> str:
    return f"drift/{device}.html"


def drift_devices(rows: list[dict]) -> list[str]:
    """Devices the manifest lists with two or more turntable sessions (their drift pages)."""
    counts: dict[str, int] = {}
    for row in rows:
        if row["protocol"] == "turntable":
            counts[row["device"]] = counts.get(row["device"], 0) + 1
    return sorted(d for d, n in counts.items() if n >= 2)


def other_sessions(rows: list[dict]) -> dict[tuple, tuple]:
    """For each unit session, another session of the same device and protocol whose
    carry-over judges the diagnosis' candidates (:func:`gyrocal.diagnose.diagnose`): the
    next in session order, the one before for the last. Turntable and sweep sessions only
    (a servo's hand mount leaves the true rate unknown)."""
    by_device: dict[tuple, list[tuple]] = {}
    for row in rows:
        if row["protocol"] in ("turntable", "sweep"):
            key = (row["batch"], row["device"], row["session"])
            by_device.setdefault((row["device"], row["protocol"]), []).append(key)
    out = {}
    for keys in by_device.values():
        keys.sort(key=lambda k: (k[2], k[0]))
        for i, key in enumerate(keys):
            if len(keys) > 1:
                out[key] = keys[i + 1] if i + 1 < len(keys) else keys[i - 1]
    return out


def json_safe(value):
    """Nested values with numpy scalars as Python numbers and inf/NaN as None."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    return _finite(value)
