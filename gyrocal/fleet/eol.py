"""End of line: does each calibrated unit meet its spec, and how many of a batch do.

* :func:`judge` — one unit's :class:`Verdict` against its :class:`~gyrocal.fleet.limits.SpecLimits`,
  every failed limit listed with its value, limit and unit; a unit whose calibration failed
  fails with that failure as its reason.
* :func:`batch_yield` — units, passed, failed and yield per batch.

The limits come from :mod:`gyrocal.fleet.limits` and the parameters judged from
:mod:`gyrocal.calibration.parameters`; :mod:`gyrocal.fleet.outliers` finds the units far from their batch.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..calibration.file import Calibration
from ..calibration.parameters import parameters_at, temperature_coefficients
from ..io.errors import GyrocalError
from .limits import NOISE_LIMITS, SpecLimits, match_pattern


@dataclass(frozen=True)
class Verdict:
    """Pass or fail of one unit, every failed limit as one line, and every value checked
    (name -> value, limit, unit, passed; JSON-plain)."""

    passed: bool
    reasons: tuple[str, ...]
    checked: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)  # device, batch, session, protocol
    calibrated: bool = True  # False: no calibration to judge

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.meta,
            "passed": self.passed,
            "calibrated": self.calibrated,
            "reasons": list(self.reasons),
            "checked": self.checked,
        }


def _failure_text(what: str, failed) -> str:
    if isinstance(failed, Mapping):
        return f"{what} failed: the {failed.get('stage')} stage failed: {failed.get('error')}"
    return f"{what} failed: {' '.join(str(failed).split())}"


def _is_failure(x) -> bool:
    from ..io.failure import FORMAT

    return isinstance(x, BaseException) or (isinstance(x, Mapping) and x.get("format") == FORMAT)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def judge(calibration, summary: Mapping | None, seg_info: Mapping | None, limits: SpecLimits) -> Verdict:
    """Judge one unit against ``limits``.

    ``calibration`` is a :class:`Calibration`, or the failure record (``gyrocal.failure/1``)
    or exception that stands for one that failed: the unit then fails with that failure as
    its reason. ``summary`` is the validation summary (``validation.json``'s ``summary``),
    ``seg_info`` the segmentation info (the observations' metadata ``info``); either may be
    None or a failure record. A configured limit whose value cannot be had (no validation
    summary, a single-temperature calibration for a temperature coefficient, no rejection
    counts for a hold share) fails the unit, saying so: end of line passes only what it
    has checked.
    """
    if _is_failure(calibration) or calibration is None:
        return _uncalibrated_verdict(calibration)
    cal: Calibration = calibration
    checks = _Checks()
    if limits.parameters:
        _check_parameters(checks, cal, limits)
    if limits.temperature_coefficients:
        _check_temperature_coefficients(checks, cal, limits)
    _check_validation(checks, summary, limits)
    _check_noise(checks, cal, limits)
    if limits.temperature_span is not None:
        _check_temperature_span(checks, cal, limits)
    _check_segmentation(checks, cal, seg_info, limits)
    if limits.fail_on_warnings:
        _check_warnings(checks, cal, limits)
    meta = {k: cal.meta.get(k) for k in ("device", "batch", "session", "protocol")}
    return Verdict(not checks.reasons, tuple(checks.reasons), checks.checked, meta)


def _uncalibrated_verdict(calibration) -> Verdict:
    """The failed verdict of a unit without a calibration: its failure (record or exception)
    or None is the reason."""
    meta = dict(calibration) if isinstance(calibration, Mapping) else {}
    reason = (
        _failure_text("calibration", calibration)
        if calibration is not None
        else "calibration failed: no calibration"
    )
    return Verdict(
        False, (reason,), {}, {k: meta.get(k) for k in ("device", "batch", "session", "protocol")}, False
    )


@dataclass
class _Checks:
    """What a verdict has checked so far: each value by name (value, limit, unit, passed),
    and a line for each that failed, in the order checked."""

    checked: dict = field(default_factory=dict)
    reasons: list[str] = field(default_factory=list)

    def record(self, name, value, limit, unit, ok, reason=None) -> None:
        self.checked[name] = {"value": value, "limit": limit, "unit": unit, "passed": bool(ok)}
        if not ok:
            self.reasons.append(reason)

    def unavailable(self, name, what, why) -> None:
        """A configured limit whose value cannot be had: it fails, saying why."""
        self.checked[name] = {"value": None, "limit": None, "unit": None, "passed": False, "note": why}
        self.reasons.append(f"{what} not available: {why}")


def _check_parameters(checks: _Checks, cal: Calibration, limits: SpecLimits) -> None:
    """Each parameter a limit's pattern matches, at the spec's temperature, within its range."""
    p = parameters_at(cal, limits.temperature)
    patterns = [pat for pat, _ in limits.parameters]
    ranges = dict(limits.parameters)
    T = float(p["temperature"].iloc[0])
    for name, value, unit, clamped in p[["parameter", "value", "unit", "clamped"]].itertuples(index=False):
        pat = match_pattern(patterns, name)
        if pat is None:
            continue
        lo, hi = ranges[pat]
        symmetric = lo == -hi
        limit_text = f"±{hi:g} {unit}" if symmetric else f"[{lo:g}, {hi:g}] {unit}"
        verb = "exceeds" if symmetric else "outside"
        where = f" at {T:g} °C" + (" (clamped to the calibrated span)" if clamped else "")
        checks.record(
            name,
            float(value),
            [lo, hi],
            unit,
            lo <= value <= hi,
            f"{name} = {_fmt(value)} {unit} {verb} {limit_text}{where}",
        )


def _check_temperature_coefficients(checks: _Checks, cal: Calibration, limits: SpecLimits) -> None:
    """Each parameter's temperature coefficient a limit's pattern matches, within its limit;
    a single-temperature calibration has none."""
    tc = temperature_coefficients(cal)
    patterns = [pat for pat, _ in limits.temperature_coefficients]
    limit_of = dict(limits.temperature_coefficients)
    if tc is None:
        for pat in patterns:
            checks.unavailable(
                f"d({pat})/dT",
                f"d({pat})/dT",
                f"calibrated at a single temperature ({cal.grid.span[0]:.1f} °C)",
            )
        return
    lo, hi = cal.grid.span
    for name, value, unit in tc.itertuples(index=False):
        pat = match_pattern(patterns, name)
        if pat is None:
            continue
        lim = limit_of[pat]
        checks.record(
            f"d({name})/dT",
            value,
            lim,
            unit,
            value <= lim,
            f"d({name})/dT = {_fmt(value)} {unit} exceeds ±{lim:g} {unit} over {lo:.1f} to {hi:.1f} °C",
        )


def _check_validation(checks: _Checks, summary: Mapping | None, limits: SpecLimits) -> None:
    """The validation RMS and the excess over the noise floor, each within its limit."""
    for key, what, unit in (
        ("validation_rms", "validation RMS", "deg/s"),
        ("excess", "excess over the noise floor", "×"),
    ):
        lim = getattr(limits, key)
        if lim is None:
            continue
        if _is_failure(summary):
            checks.unavailable(
                key, what, _failure_text("validation", summary).removeprefix("validation failed: ")
            )
            continue
        value = None if summary is None else summary.get(key)
        if value is None or not math.isfinite(value):
            checks.unavailable(
                key, what, "no validation summary" if summary is None else f"the summary has no {key}"
            )
            continue
        text = (
            f"{_fmt(value)} deg/s exceeds {lim:g} deg/s"
            if unit == "deg/s"
            else f"{value:.3g}× exceeds {lim:g}×"
        )
        checks.record(key, float(value), lim, unit, value <= lim, f"{what} = {text}")


def _check_noise(checks: _Checks, cal: Calibration, limits: SpecLimits) -> None:
    """Each limited noise term of the calibration's session, its largest axis within the limit."""
    noise = cal.extra.get("noise") or {}
    for term, lim in limits.noise:
        what, unit = NOISE_LIMITS[term]
        if "session" not in noise:
            checks.unavailable(
                f"noise.{term}", what, noise.get("reason", "the calibration has no noise characterisation")
            )
            continue
        value = float(np.max(noise["session"][term]))
        checks.record(
            f"noise.{term}",
            value,
            lim,
            unit,
            value <= lim,
            f"{what} = {value:.3g} {unit} exceeds {lim:g} {unit} (largest axis)",
        )


def _check_temperature_span(checks: _Checks, cal: Calibration, limits: SpecLimits) -> None:
    """The calibrated span reaches both ends of the spec's span, within its tolerance."""
    want_lo, want_hi = limits.temperature_span
    tol = limits.temperature_span_tolerance
    lo, hi = cal.grid.span
    ok_lo, ok_hi = lo <= want_lo + tol, hi >= want_hi - tol
    checks.checked["temperature_span"] = {
        "value": [lo, hi],
        "limit": [want_lo, want_hi],
        "unit": "°C",
        "tolerance": tol,
        "passed": bool(ok_lo and ok_hi),
    }
    within = f" (tolerance {tol:g} °C)" if tol else ""
    for ok, end in ((ok_lo, want_lo), (ok_hi, want_hi)):
        if not ok:
            checks.reasons.append(
                f"calibrated span {lo:.1f} to {hi:.1f} °C does not reach {end:g} °C{within}"
            )


def _check_segmentation(checks: _Checks, cal: Calibration, seg_info, limits: SpecLimits) -> None:
    """The accepted holds, their share of the candidates, and the temperature points, each
    at least its minimum."""
    seg_failed = _is_failure(seg_info)
    info = {} if seg_info is None or seg_failed else seg_info
    why_no_info = (
        _failure_text("segmentation", seg_info).removeprefix("segmentation failed: ")
        if seg_failed
        else "no segmentation info"
    )
    if limits.min_holds is not None:
        n = info.get("holds_accepted")
        if n is None:
            checks.unavailable("min_holds", "accepted holds", why_no_info)
        else:
            checks.record(
                "min_holds",
                int(n),
                limits.min_holds,
                "holds",
                n >= limits.min_holds,
                f"accepted holds = {int(n)} below the minimum {limits.min_holds}",
            )
    if limits.min_hold_share is not None:
        share, why = hold_share(info) if info else (None, why_no_info)
        if share is None:
            checks.unavailable("min_hold_share", "accepted hold share", why)
        else:
            checks.record(
                "min_hold_share",
                share,
                limits.min_hold_share,
                "1",
                share >= limits.min_hold_share,
                f"accepted hold share = {100 * share:.1f} % below the minimum "
                f"{100 * limits.min_hold_share:g} %",
            )
    if limits.min_temperature_points is not None:
        n = info.get("temperature_points")
        if n is None and not seg_failed:
            n = len(cal.grid.temperatures)  # servo, sweep: the calibration's own points
        if n is None:
            checks.unavailable("min_temperature_points", "temperature points", why_no_info)
        else:
            checks.record(
                "min_temperature_points",
                int(n),
                limits.min_temperature_points,
                "points",
                n >= limits.min_temperature_points,
                f"temperature points = {int(n)} below the minimum {limits.min_temperature_points}",
            )


def _check_warnings(checks: _Checks, cal: Calibration, limits: SpecLimits) -> None:
    """No plausibility warning the spec fails on (all of them, or the codes it names)."""
    warned = [
        w
        for w in cal.extra.get("warnings", [])
        if limits.fail_on_warnings is True or w["code"] in limits.fail_on_warnings
    ]
    checks.checked["warnings"] = {
        "value": [w["code"] for w in warned],
        "limit": limits.fail_on_warnings
        if limits.fail_on_warnings is True
        else list(limits.fail_on_warnings),
        "unit": None,
        "passed": not warned,
    }
    checks.reasons.extend(f"plausibility warning {w['code']}: {w['message']}" for w in warned)


def hold_share(info: Mapping) -> tuple[float | None, str]:
    """Accepted holds over candidate holds, and why not when it cannot be had.

    Turntable: candidates are the accepted holds plus those rejected by a hold check;
    ``handling_motion`` is the re-mounting between mounts, not a hold, and is not counted.
    Sweep: accepted windows over all windows. Servo sessions report no rejections."""
    accepted = info.get("holds_accepted")
    if accepted is None:
        return None, "the segmentation info has no holds_accepted"
    if "rejected_by_reason" in info:
        rejected = sum(int(v) for k, v in info["rejected_by_reason"].items() if k != "handling_motion")
        total = int(accepted) + rejected
    elif "windows_total" in info:
        total = int(info["windows_total"])
    else:
        return None, "the segmentation reports no rejected holds for this protocol"
    return (float(accepted) / total if total else None), "no candidate holds"


def read_unit(folder) -> tuple:
    """(calibration, validation summary, segmentation info) from a unit's results folder
    (``results/{batch}/{device}/{session}``), each part read once (the observations' footer
    alone): each a result, a failure record, or None where the part is missing. What the
    fleet summary's row and :func:`judge` both take."""
    from ..io import failure
    from ..io.tables import OBS_META_KEY
    from ..io.unit_folder import part_metadata, read_part_doc

    cal = read_part_doc(folder, "calibration")
    if cal is not None and cal.get("format") != failure.FORMAT:
        cal = Calibration.from_dict(cal, source=Path(folder) / "calibration.json")
    summary = read_part_doc(folder, "validation")
    if summary is not None and summary.get("format") != failure.FORMAT:
        summary = summary.get("summary")
    info = None
    meta = part_metadata(folder, "observations")  # the footer alone
    if meta is not None and meta.get(failure.META_KEY):
        info = json.loads(meta[failure.META_KEY])  # the segmentation's failure record
    elif meta is not None and meta.get(OBS_META_KEY):
        info = json.loads(meta[OBS_META_KEY]).get("info")
    return cal, summary, info


def unit_inputs(folder) -> tuple:
    """:func:`read_unit` for :func:`judge`: a missing calibration is an error naming it."""
    from ..io.errors import CorruptFileError

    cal, summary, info = read_unit(folder)
    if cal is None:
        raise CorruptFileError("no such file", source=Path(folder) / "calibration.json")
    return cal, summary, info


def judge_folder(folder, limits: SpecLimits) -> Verdict:
    """:func:`judge` on a unit's results folder; a folder without a readable calibration
    gives a failed verdict naming the problem."""
    try:
        cal, summary, info = unit_inputs(folder)
    except GyrocalError as exc:
        return judge(exc, None, None, limits)
    return judge(cal, summary, info, limits)


def batch_yield(verdicts_by_unit) -> pd.DataFrame:
    """Per batch (from each verdict's ``meta``): units, passed, failed (of which
    ``no_calibration``), yield in percent; one row per batch, sorted by batch name.
    Accepts a mapping unit -> :class:`Verdict` or an iterable of verdicts."""
    verdicts = list(verdicts_by_unit.values() if isinstance(verdicts_by_unit, Mapping) else verdicts_by_unit)
    frame = pd.DataFrame(
        {
            "batch": [str(v.meta.get("batch")) if v.meta.get("batch") is not None else "" for v in verdicts],
            "passed": [bool(v.passed) for v in verdicts],
            "no_calibration": [not v.calibrated for v in verdicts],
        }
    )
    if frame.empty:
        return pd.DataFrame(
            {
                "batch": pd.Series([], dtype=str),
                "units": pd.Series([], dtype=int),
                "passed": pd.Series([], dtype=int),
                "failed": pd.Series([], dtype=int),
                "no_calibration": pd.Series([], dtype=int),
                "yield_pct": pd.Series([], dtype=float),
            }
        )
    g = frame.groupby("batch", sort=True)
    out = pd.DataFrame(
        {
            "units": g.size(),
            "passed": g["passed"].sum().astype(int),
            "no_calibration": g["no_calibration"].sum().astype(int),
        }
    ).reset_index()
    out["failed"] = out["units"] - out["passed"]
    out["yield_pct"] = 100.0 * out["passed"] / out["units"]
    return out[["batch", "units", "passed", "failed", "no_calibration", "yield_pct"]]
