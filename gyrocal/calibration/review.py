"""The calibration's review: is what the fit found physical, and does the log behind it hold up?

:func:`review` runs every check on one unit session: those on the log and its holds
(:mod:`gyrocal.io.plausibility`) and those on the calibration made from them. An error
(:class:`~gyrocal.io.plausibility.ImplausibleInputError`) where the log cannot be right: a
scale factor that is a unit conversion or a sign, axes that are permuted. A warning
otherwise, recorded in the calibration file's ``warnings``: a scale factor or cross-axis term
far from nominal, a calibration from one temperature point, a point left out or thin.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import AXES
from ..io.plausibility import (
    AXIS_SIGN_CAUSE,
    CODES,
    REFERENCE_SIGN,
    SCALE_TOLERANCE,
    UNIT_MATCH,
    Finding,
    ImplausibleInputError,
    finding,
    log_findings,
    observation_findings,
    rejection_findings,
    time_base,
    unit_meaning,
)

if TYPE_CHECKING:
    import pandas as pd

    from .file import Calibration

MISALIGNMENT_LIMIT = 0.2  # 11°: beyond the several degrees of a hand-mounted rig


def scale_findings(
    Ks: np.ndarray, identified: tuple[bool, ...], source=None, temperatures=None
) -> list[Finding]:
    """Errors for unit conversions, signs and permutations in K (the median over the
    calibration's temperature points, ``Ks`` (n, 3, 3)); warnings for a scale or cross-axis
    term far from nominal at any point (its worst). ``identified[i]``: whether axis i's scale
    was fitted (a sweep at rest fits none)."""
    out: list[Finding] = []
    Ks = np.asarray(Ks).reshape(-1, 3, 3)
    temperatures = np.full(len(Ks), np.nan) if temperatures is None else np.asarray(temperatures)
    if not _refuse_impossible_scales(np.median(Ks, axis=0), identified, source):
        return out

    def worst(i, j):  # the entry furthest from nominal over the points, and where
        dev = np.abs(Ks[:, i, j] - (1.0 if i == j else 0.0))
        k = int(np.argmax(dev))
        return float(Ks[k, i, j]), float(temperatures[k]), float(dev[k])

    def at(temp):
        return f" at {temp:.1f} °C" if np.isfinite(temp) else ""

    far = [(AXES[i], *worst(i, i)) for i in range(3) if identified[i]]
    far = [f for f in far if f[3] > SCALE_TOLERANCE]
    if far:
        out.append(
            finding(
                "scale_far_from_one",
                "scale factor "
                + ", ".join(f"K[{a},{a}] = {v:.4g}{at(T)}" for a, v, T, _ in far)
                + f": more than {SCALE_TOLERANCE:.0%} from 1, beyond any MEMS gyro's sensitivity "
                "tolerance; check the units and the reference",
                scale={a: {"value": v, "temperature": T} for a, v, T, _ in far},
            )
        )
    cross = [(AXES[i], AXES[j], *worst(i, j)) for i in range(3) for j in range(3) if i != j and identified[i]]
    cross = [c for c in cross if c[4] > MISALIGNMENT_LIMIT]
    if cross:
        out.append(
            finding(
                "misalignment_large",
                "cross-axis term "
                + ", ".join(f"K[{a},{b}] = {v:.3g}{at(T)}" for a, b, v, T, _ in cross)
                + f": over {MISALIGNMENT_LIMIT:g} ({math.degrees(MISALIGNMENT_LIMIT):.0f}°); mount "
                "labels or axes may be wrong",
                terms={f"{a}.{b}": {"value": v, "temperature": T} for a, b, v, T, _ in cross},
            )
        )
    return out


def _refuse_impossible_scales(K: np.ndarray, identified: tuple[bool, ...], source) -> bool:
    """Raise where the median K (3, 3) cannot be a gyro's: permuted axes, a unit conversion,
    a sign. False when no axis's scale was fitted (nothing to judge)."""
    diag = np.diag(K)
    # Permuted axes: an output follows another axis' rate, not its own.
    for i, a in enumerate(AXES):
        j = int(np.argmax(np.abs(K[i])))
        if identified[i] and j != i and abs(abs(K[i, j]) - 1) < UNIT_MATCH and abs(diag[i]) < 0.5:
            raise ImplausibleInputError(
                f"gyro_{a} follows the rig's {AXES[j]} rate (K[{a},{AXES[j]}] = {K[i, j]:.3g}, "
                f"K[{a},{a}] = {diag[i]:.3g}): the gyro columns are permuted, or the mount labels name "
                "the wrong axes",
                source=source,
            )
    seen = [(i, d) for i, d in enumerate(diag) if identified[i]]
    if not seen:
        return False
    values = np.array([d for _, d in seen])
    meaning = unit_meaning(values)
    if meaning is not None:
        raise ImplausibleInputError(
            f"scale factors {', '.join(f'{v:.4g}' for v in values)} against the reference: {meaning}",
            source=source,
        )
    if np.all(np.abs(values + 1) < SCALE_TOLERANCE):
        raise ImplausibleInputError(
            f"scale factors {', '.join(f'{v:.4g}' for v in values)}: every axis reads against the "
            f"reference; {REFERENCE_SIGN}",
            source=source,
        )
    flipped = [AXES[i] for i, d in seen if abs(d + 1) < SCALE_TOLERANCE]
    if flipped:
        raise ImplausibleInputError(
            f"gyro_{', gyro_'.join(flipped)} read{'s' if len(flipped) == 1 else ''} against the "
            f"reference (scale {', '.join(f'{diag[AXES.index(a)]:.4g}' for a in flipped)}) while the "
            f"other axes agree: {AXIS_SIGN_CAUSE}",
            source=source,
        )
    return True


def fit_findings(cal: Calibration, one_temperature: bool = False) -> list[Finding]:
    """Warnings from the fit: one temperature point only, points left out or thin."""
    out: list[Finding] = []
    # a continuous fit's points are bins; a servo's or a hand session's one temperature is
    # its design (``one_temperature``)
    if cal.kind != "temperature_grid" or one_temperature:
        return out
    points = cal.extra.get("points") or []
    used = [p for p in points if p["used"]]
    if len(used) == 1:
        out.append(
            finding(
                "single_temperature",
                f"calibrated at one temperature ({used[0]['temperature']:.1f} °C): nothing is known "
                "of the unit's temperature dependence, and the calibration applies as it is at every "
                "temperature",
                temperature=used[0]["temperature"],
            )
        )
    if len(points) > 1:
        typical = float(np.median([p["holds"] for p in points]))
        thin = [p for p in points if p["used"] and p["holds"] < 0.5 * typical]
        if thin:
            out.append(
                finding(
                    "point_few_holds",
                    "temperature point "
                    + ", ".join(f"{p['temperature']:.1f} °C ({p['holds']} holds)" for p in thin)
                    + f" has under half the typical {typical:.0f} holds: its calibration rests on less",
                    points=[{"temperature": p["temperature"], "holds": p["holds"]} for p in thin],
                    typical=typical,
                )
            )
    excluded = [p for p in points if not p["used"]]
    if excluded:
        out.append(
            finding(
                "point_excluded",
                "temperature point "
                + ", ".join(f"{p['temperature']:.1f} °C ({p.get('excluded_because')})" for p in excluded)
                + " is left out of the calibration: the interpolation spans it from its neighbours",
                points=[
                    {"temperature": p["temperature"], "reason": p.get("excluded_because")} for p in excluded
                ],
            )
        )
    return out


def review(
    obs: pd.DataFrame,
    info: Mapping[str, Any] | None,
    cal: Calibration,
    *,
    timed_holds: bool,
    axis_mounts: bool,
    one_temperature: bool,
    source=None,
) -> list[Finding]:
    """Every check on one unit session: its log's statistics and segmentation's ``info``, its
    holds ``obs`` and its calibration ``cal``. What it needs of the session's protocol
    (:class:`gyrocal.protocols.registry.Protocol`): whether its holds last as long as the
    rig held them (``timed_holds``: their typical length tells the time base's unit),
    whether it mounts one axis on the rig axis at a time (``axis_mounts``), and whether one
    temperature is its design (``one_temperature``). Raises :class:`ImplausibleInputError`
    where the log cannot be right, returns the warnings otherwise (the order of
    :data:`CODES`)."""
    info = info or {}
    error, warning = time_base(info.get("input_stats"), info.get("typical_hold_s") if timed_holds else None)
    if error is not None:
        raise ImplausibleInputError(error, source=source)
    found = log_findings(info.get("input_stats"), source) + ([warning] if warning else [])
    if info.get("stamps"):  # the windows' reading of bursty stamps says more than a median
        found = [f for f in found if f["code"] not in ("sample_jitter", "dropped_samples")]
        found.append(finding("sample_jitter", info["stamps"], rate_hz=info.get("sample_rate")))
    Ks = cal.matrices()[0]
    names = set(cal.model.names)
    identified = tuple(f"scale.{a}" in names for a in AXES)
    reads_accel = any(n.startswith("accel_") for n in cal.model.inputs)
    seen = observation_findings(obs, axis_mounts, source, model_reads_accel=reads_accel)
    try:
        found += scale_findings(Ks, identified, source, cal.grid.temperatures)
    except ImplausibleInputError as exc:
        mounts = [f for f in seen if f["code"] == "mount_contradicts_gravity"]
        if not mounts:
            raise
        joined = ImplausibleInputError(f"{exc}; and {mounts[0]['message']}")  # exc names the file
        joined.source = exc.source
        raise joined from None
    found += seen + rejection_findings(info)
    for note in info.get("segmentation_warnings") or ():
        found.append(finding("phases_doubtful", note))
    if "temp" in (info.get("filled_columns") or ()):
        found.append(
            finding(
                "temperature_not_logged",
                f"the log has no temp column: the calibration holds at the session's unknown "
                f"temperature and is given at {float(cal.grid.temperatures[0]):.1f} °C, the reference "
                "temperature",
                filled="temp",
            )
        )
    found += fit_findings(cal, one_temperature)
    order = list(CODES)
    return sorted(found, key=lambda f: order.index(f["code"]))
