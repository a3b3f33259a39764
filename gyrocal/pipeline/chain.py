"""The whole chain for one log: ingest, segment, fit per temperature, validate, calibrate.

Each stage is also a function of its own (and a CLI command), so the workflow can run and
cache them separately; this module only strings them together and records provenance.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from .. import __version__
from ..calibration.file import Calibration
from ..calibration.review import review
from ..fit.floor import (
    NoiseSummary,
    StretchSampler,
    add_floor_columns,
    characterise,
    noise_record,
    static_stretches,
)
from ..fit.thermal import ContinuousFit, GridFit
from ..fit.validate import Validation, free_point_fits, validate
from ..io import plausibility
from ..io.blocks import BlockSink
from ..io.errors import IdentifiabilityError, SegmentationError
from ..io.holds import Segmentation
from ..io.log import HASH_ALGORITHM, REQUIRED, file_digest, read_log, with_constants
from ..protocols import registry
from ..terms.signals import RECORD_COLUMNS, TEMP_RATE_WINDOW_S, HistoryBins, Series
from .config import Settings

if TYPE_CHECKING:
    from .identify import AddedTerm, BiasInSession


@dataclass(frozen=True)
class Run:
    calibration: Calibration
    segmentation: Segmentation
    fitted: GridFit | ContinuousFit | None  # None for a servo session (seed 001's own fit)
    validation: Validation


def versions() -> dict[str, str]:
    out = {"gyrocal": __version__}
    for package in ("numpy", "scipy", "pandas", "pyarrow"):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            out[package] = importlib.metadata.version(package)
    return out


# The decoded columns of a log are kept in memory up to this size; a larger log is reduced
# to block statistics as it is read and read again, batch by batch, for what needs samples
# (noise, the temperature record), so that memory does not grow with the log.
KEEP_BYTES = 384 * 2**20


def segment_log(
    path, settings: Settings, protocol: str = registry.DEFAULT, *, keep_bytes: float | None = KEEP_BYTES
) -> Segmentation:
    """Read and segment a log into observations by its protocol's rules; its hash
    (:data:`gyrocal.io.log.HASH_ALGORITHM`) is computed on a second thread meanwhile. Then one
    more pass over its samples (from memory, or from the file) gives the noise of its
    static stretches and its temperature record."""
    rules = registry.get(protocol)
    sink = BlockSink(rules.reading_blocks(settings)) if rules.reading_blocks else None
    with ThreadPoolExecutor(1) as pool:
        digest = pool.submit(file_digest, path)
        log = read_log(
            path,
            optional=rules.optional_columns + rules.without,
            sink=sink,
            required=tuple(c for c in REQUIRED if c not in rules.without),
            keep_bytes=keep_bytes if sink is not None else None,
        )
        filled = [c for c in rules.without if c not in log]
        log = with_constants(log, {"ref_rate": 0.0, "temp": settings.model.reference_temperature})
        plausibility.log_errors(log.input_stats, path)
        try:
            seg = rules.segment(log, settings)
        except SegmentationError as exc:
            raise plausibility.explain_segmentation(exc, log.input_stats, path) from None
        seg = with_mountings(seg, float(log.time_span[0]))
        seg.info["source"] = {
            "name": Path(path).name,
            HASH_ALGORITHM: digest.result(),
            "rows": log.rows_read,
            "rows_dropped": log.rows_dropped,
        }
        if log.input_stats is not None:
            seg.info["input_stats"] = log.input_stats
        if filled:
            seg.info["filled_columns"] = filled
    # The temperature rate is a slope over a window as long as a typical hold, for the fit
    # and for apply (the calibration file records the window).
    obs = seg.observations
    window = float(np.median(obs["duration"])) if len(obs) else TEMP_RATE_WINDOW_S
    max_temp_rate = settings.segmentation.max_temp_rate
    rate = float(seg.info.get("sample_rate") or 0.0)
    stretches = (
        static_stretches(log, seg, registry.get(protocol).static, max_temp_rate=max_temp_rate)
        if len(obs) and rate > 0
        else None
    )
    sampler = (
        StretchSampler(stretches, rate, trim_settling=registry.get(protocol).static_after_turning)
        if stretches is not None
        else None
    )
    record = HistoryBins(*log.time_span, window_s=window)
    # The record keeps the gyro's output and the specific force beside the temperature, in
    # the same bins: inputs with a history (a lag of the rate) read them, in the fit and in
    # apply alike.
    kept = [c for c in RECORD_COLUMNS if c in log]
    held = HeldTemperatures(obs) if "temp" not in filled else None
    for batch in log.scan(tuple(dict.fromkeys((*StretchSampler.NAMES, *kept)))):
        record.push(batch["t"], batch["temp"], {c: batch[c] for c in kept})
        if sampler is not None:
            sampler.push(batch)
        if held is not None:
            held.push(batch["t"], batch["temp"])
    seg = with_noise_floor(
        log,
        seg,
        protocol,
        max_temp_rate=max_temp_rate,
        sampled=sampler.result() if sampler is not None else None,
    )
    if "temp" in filled:  # a constant stand-in: no temperature record for terms to read
        return seg
    if held is not None and (extremes := held.extremes()) is not None:
        seg.info["point_temp_range"] = extremes
    return with_series(seg, record.result())


class HeldTemperatures:
    """The temperatures read during each temperature point's holds, sample by sample: their
    lowest and highest, gathered batch by batch in the pass that makes the temperature
    record. A hold's mean hides the sensor's scatter, which a log of the same rig shows
    again: a calibration keeps each point's extremes so that apply can tell a row beyond its
    end points by that scatter from one beyond the calibrated range."""

    def __init__(self, obs: pd.DataFrame):
        self.ok = len(obs) > 0 and {"t_start", "t_end", "point"} <= set(obs.columns)
        if not self.ok:
            return
        order = np.argsort(obs["t_start"].to_numpy(float), kind="stable")
        self.starts = obs["t_start"].to_numpy(float)[order]
        self.ends = obs["t_end"].to_numpy(float)[order]
        self.point = obs["point"].to_numpy(np.int64)[order]
        points = int(self.point.max()) + 1
        self.lo, self.hi = np.full(points, np.inf), np.full(points, -np.inf)

    def push(self, t: np.ndarray, temp: np.ndarray) -> None:
        if not self.ok or not len(t):
            return
        hold = np.searchsorted(self.starts, t, side="right") - 1
        inside = (hold >= 0) & (t <= self.ends[np.maximum(hold, 0)]) & np.isfinite(temp)
        hold, temp = hold[inside], np.asarray(temp, float)[inside]
        if not len(hold):
            return
        runs = np.flatnonzero(np.r_[True, hold[1:] != hold[:-1]])  # a hold's samples are contiguous
        point = self.point[hold[runs]]
        np.minimum.at(self.lo, point, np.minimum.reduceat(temp, runs))
        np.maximum.at(self.hi, point, np.maximum.reduceat(temp, runs))

    def extremes(self) -> list[list[float] | None] | None:
        """Each point's lowest and highest temperature read in its holds (°C), by point
        number; None for a point no sample was read in, or when there are no holds."""
        if not self.ok:
            return None
        return [[float(lo), float(h)] if h >= lo else None for lo, h in zip(self.lo, self.hi, strict=True)]


def with_series(seg: Segmentation, series: Series) -> Segmentation:
    """``seg`` whose observations carry the session's record (terms read series signals
    from it: :mod:`gyrocal.terms.signals`)."""
    seg.observations.attrs["series"] = series
    return seg


HANDLING = "handling_motion"  # the segments a remount leaves (rejected: the unit in hand)


def with_mountings(seg: Segmentation, first_time: float) -> Segmentation:
    """``seg`` whose observations say when the unit was last mounted (``mounted_at``, s on
    the log's clock): the end of the last handling before each hold, the log's first sample
    where none is. Terms read it as ``t_mount`` (:class:`gyrocal.terms.signals.Inputs`): a
    clamp that relaxes after each mounting follows it, not time since power-on. And when the
    log last resumed (``resumed_at``): the end of the last gap in it before each hold, the
    log's first sample where none is; the unit may have been powered anew in any gap, which
    gives its bias a new turn-on value (:mod:`gyrocal.diagnosis.sessions`)."""
    obs, segments = seg.observations, seg.segments
    if obs.empty or "t_start" not in obs:
        return seg

    def last_before(rows) -> np.ndarray:
        ends = np.sort(segments.loc[rows, "t_end"].to_numpy(float))
        starts = np.r_[first_time, ends]  # the first before any: the log's start
        return starts[np.searchsorted(ends, obs["t_start"].to_numpy(float), side="right")]

    handled = segments["reason"] == HANDLING if "reason" in segments else np.zeros(len(segments), bool)
    gaps = segments["kind"] == "gap" if "kind" in segments else np.zeros(len(segments), bool)
    obs = obs.assign(mounted_at=last_before(handled), resumed_at=last_before(gaps))
    return replace(seg, observations=obs)


def with_noise_floor(
    log, seg: Segmentation, protocol: str, *, max_temp_rate: float, sampled=None
) -> Segmentation:
    """``seg`` with the session's noise characterisation in ``info["noise"]`` and every
    observation's noise floor from it (:mod:`gyrocal.fit.floor`; ``sampled``: the static
    stretches' sums, when already gathered)."""
    summary = characterise(
        log, seg, registry.get(protocol).static, max_temp_rate=max_temp_rate, sampled=sampled
    )
    obs = add_floor_columns(seg.observations, summary, float(seg.info.get("sample_rate") or 0.0))
    obs.attrs["static_seconds"] = float(summary.get("static_seconds") or 0.0)
    return replace(seg, observations=obs, info={**seg.info, "noise": summary})


def calibrate_observations(
    obs: pd.DataFrame,
    settings: Settings,
    *,
    meta: dict,
    source: dict | None = None,
    label=None,
    noise: NoiseSummary | None = None,
    fitted: GridFit | ContinuousFit | None = None,
    info: dict | None = None,
    checks: bool = True,
) -> tuple[Calibration, GridFit | ContinuousFit | None]:
    """The calibration of one unit's observations: the common model's fit, or the
    protocol's own (:attr:`gyrocal.protocols.registry.Protocol.calibrate`; a servo session's is seed
    001's six-parameter fit, and no common-model fit comes back: None). ``noise``,
    segmentation's noise characterisation, is kept in the file
    (:func:`gyrocal.fit.floor.noise_record`). ``fitted``, a fit of ``settings.model`` to ``obs``
    already made, is used rather than fitting again. ``info``, segmentation's, gives the
    read's statistics to the plausibility checks (:func:`gyrocal.calibration.review.review`),
    which raise where the log cannot be right and leave their warnings in the file's ``warnings``
    (``checks=False``: none, for the diagnosis' candidate models)."""
    provenance = {"input": source or {}, "versions": versions(), "config_sha256": settings.sha256()}
    protocol = registry.get(meta.get("protocol"))
    own = protocol.calibrate
    if own is not None:
        cal = own(obs, settings, meta, provenance)
        if noise:
            cal.extra["noise"] = noise_record(noise)
        fitted = None
    else:
        extremes = (info or {}).get("point_temp_range")
        cal, fitted = _common_calibration(obs, settings, meta, provenance, label, noise, fitted, extremes)
    if settings.model_entry:
        cal.extra["model_entry"] = settings.model_entry
    if checks:
        cal.extra["warnings"] = (
            review(
                obs,
                info,
                cal,
                timed_holds=protocol.timed_holds,
                axis_mounts=protocol.axis_mounts,
                one_temperature=protocol.one_temperature,
                source=label,
            )
            + [
                plausibility.finding("term_dropped", f"{a['term']} left out: {a['reason']}", term=a["term"])
                for a in cal.extra.get("added_terms", ())
                if not a["kept"]
            ]
            + [
                plausibility.finding(
                    "term_not_identified",
                    f"{a['term']} kept for the held-out error it takes "
                    f"away, though {a['not_identified']}: the bias is judged as the "
                    "session measured it (bias_in_session), not as the fit extrapolates "
                    "it",
                    term=a["term"],
                )
                for a in cal.extra.get("added_terms", ())
                if a.get("not_identified")
            ]
        )
    return cal, fitted


def _common_calibration(obs, settings, meta, provenance, label, noise, fitted, extremes=None):
    """The common model's calibration (and fit, unless ``fitted`` is given). Terms beyond
    the protocol's own model are kept only where this unit's data identify them
    (:func:`gyrocal.pipeline.identify.identify`; the file's ``added_terms`` says which and
    why, with the held-out figures with and without each). ``extremes``, segmentation's
    ``point_temp_range``, gives each point's ``temp_range``."""
    added: tuple[AddedTerm, ...] = ()
    if fitted is None:
        from .identify import identify

        found = identify(settings, obs, meta.get("protocol"), source=label)
        fitted, added = found.fitted, found.added
    points = fitted.points
    model = fitted.model  # with any profiled setting at its fitted value
    # Apply derives the temperature rate over the window the fit's record used.
    series = obs.attrs.get("series")
    window = series.temp_rate_window_s if series is not None else float(np.median(obs["duration"]))
    covariates = (
        {"temp_rate": {"unit": "degC/min", "window_s": window}} if "temp_rate" in model.inputs else {}
    )
    cal = Calibration(
        model,
        fitted.coefficients,
        settings.model.reference_temperature,
        meta,
        provenance=provenance,
        extra={
            "points": [
                {
                    "temperature": float(r.temp),
                    "holds": int(r.holds),
                    "used": bool(r.used),
                    **_range_entry(extremes, int(r.point)),
                    **({"excluded_because": r.reason} if not r.used else {}),
                }
                for r in points.itertuples()
            ],
            **({"profiled": list(fitted.profiled)} if fitted.profiled else {}),
            **({"added_terms": [a.to_dict() for a in added]} if added else {}),
            **({"bias_in_session": session} if (session := _bias_in_session(fitted, added)) else {}),
            **({"noise": noise_record(noise)} if noise else {}),
        },
        covariates=covariates,
    )
    return cal, fitted


def _range_entry(extremes: list | None, point: int) -> dict:
    """A point's ``temp_range`` for the file (:class:`HeldTemperatures`), where recorded."""
    if extremes is None or point >= len(extremes) or extremes[point] is None:
        return {}
    return {"temp_range": list(extremes[point])}


def _bias_in_session(fitted, added) -> BiasInSession | None:
    from .identify import bias_in_session

    return bias_in_session(fitted, [a.term for a in added if a.kept and a.weakly])


def settings_used(settings: Settings, cal: Calibration) -> Settings:
    """The settings a calibration was made with: ``settings`` without the terms its unit's
    data could not identify (the file's ``added_terms``)."""
    from .identify import without

    dropped = [a["term"] for a in cal.extra.get("added_terms", ()) if not a["kept"]]
    return without(settings, dropped) if dropped else settings


def run(
    path,
    settings: Settings | None = None,
    *,
    protocol: str = registry.DEFAULT,
    device: str | None = None,
    batch: str | None = None,
    session: str | None = None,
) -> Run:
    """Calibrate one log end to end."""
    settings = (settings or Settings()).for_protocol(protocol)
    seg = segment_log(path, settings, protocol)
    meta = {
        "device": device or Path(path).name.removesuffix(".parquet"),
        "batch": batch,
        "session": session,
        "protocol": protocol,
    }
    cal, fitted = calibrate_observations(
        seg.observations,
        settings,
        meta=meta,
        source=seg.info["source"],
        label=path,
        noise=seg.info.get("noise"),
        info=seg.info,
    )
    return Run(cal, seg, fitted, validation(seg.observations, cal, fitted, settings, source=path))


def validation(obs: pd.DataFrame, cal: Calibration, fitted, settings: Settings, *, source=None) -> Validation:
    """The calibration's validation: the protocol's own (a servo's leave-revolution-out), or
    the common model's leave-temperature-out from ``fitted``."""
    own = registry.get(cal.meta.get("protocol")).validate
    if own is not None:
        return own(obs, cal)
    try:
        val = validate(
            fitted.model,
            obs,
            fitted,
            reference_temperature=settings.model.reference_temperature,
            every_point=False,
        )
    except IdentifiabilityError as exc:  # named after the input it came from
        if exc.source is not None or source is None:
            raise
        raise IdentifiabilityError(str(exc), parameters=exc.parameters, source=source) from None
    return replace(val, free_points=free_point_fits(obs)) if cal.kind == "continuous" else val
