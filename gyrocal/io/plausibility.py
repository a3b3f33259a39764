"""Plausibility of the inputs: is this log what a rig should have recorded?

A log can satisfy the contract (columns, types, time order) and still be wrong: gyro columns
in rad/s or mdps while the log declares deg/s, a reference rate of the opposite sign, a
temperature sensor that drops out or sticks. Fitted as they are, such logs give a
calibration that validates on itself (K absorbs a unit factor, B a stuck temperature) and
that a production line would ship. Two outcomes:

* an **error** (:class:`ImplausibleInputError`, exit status 2, the unit quarantined in a
  fleet run) where the log cannot be right: a scale factor that is a unit conversion or a
  sign, axes that are permuted, a temperature in kelvin;
* a **warning** otherwise (a :class:`Finding`), recorded in the calibration file
  (``warnings``: ``code``, ``message``, ``evidence``), shown at the top of the unit report,
  counted in the fleet summary, and failing end of line where the spec says
  ``fail_on_warnings``.

Here: the read's statistics of the log (:class:`InputStats`, batch by batch) and the checks
on them (:func:`log_errors`, :func:`log_findings`, the time base), segmentation's check of
the gyro against the reference (:func:`rate_ratio_check`), and the checks on the holds
(:func:`observation_findings`, :func:`rejection_findings`). The calibration's review
(:func:`gyrocal.calibration.review.review`) runs them with its checks on the fit.

Thresholds come from what MEMS gyroscopes are: scale-factor errors within a few per cent
(datasheets: ±1–3 % initial sensitivity tolerance), misalignment within a degree or two
(several on a hand-mounted servo rig), operating temperature −55…125 °C. :data:`CODES`
lists every warning; docs/inputs.md gives the catalogue of bad inputs and their outcomes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple, TypedDict

import numpy as np

from . import AXES
from .errors import InputError
from .formats import json_safe

CODES = {
    "gyro_out_of_range": "gyro samples beyond ±10,000 deg/s",
    "scale_far_from_one": "a scale factor more than 10 % from 1 that is no unit conversion",
    "misalignment_large": "a cross-axis term above 0.2 (11°)",
    "temperature_dropout": "temperature missing (NaN) for over 1 % of the rows",
    "temperature_stuck": "a finely resolved temperature reading one value for a long stretch",
    "temperature_out_of_range": "temperatures outside −60…150 °C",
    "accel_units": "the accelerometer reads about 9.8 at rest: m/s², not g",
    "accel_scale": "the accelerometer's magnitude at rest is far from 1 g",
    "mount_contradicts_gravity": "mount labels that disagree with gravity on the accelerometer",
    "accel_from_mounts": "no accelerometer: terms of the specific force read each mount's; applying needs one",
    "time_base_implausible": "a sample interval, hold length or session length no rig records",
    "sample_jitter": "sample intervals scattered by more than 10 % of the nominal",
    "dropped_samples": "samples missing between regular ones",
    "holds_rejected": "holds rejected for saturation, disagreement with the reference or instability",
    "single_temperature": "a turntable calibration from one temperature point",
    "temperature_not_logged": "no temperature column: the calibration is given at the reference temperature",
    "phases_doubtful": "segmentation left out a move meant as a turn, or took one for several turns",
    "point_few_holds": "a temperature point with under half the typical number of holds",
    "point_excluded": "a temperature point left out of the calibration",
    "holds_disagree_with_reference": "holds off by over 20 noise floors where their rate is not at other points",
    "protocol_unbalanced": "a rotation direction or a mount missing on some axis",
    "term_dropped": "a term beyond the protocol's model left out: this unit's data cannot tell it from the model's own",
    "term_not_identified": "a term beyond the protocol's model kept for its gain, though the data cannot tell it from the model's own",
}

# Scale-factor bounds (see the module docstring).
SCALE_TOLERANCE = 0.10
UNIT_MATCH = 0.15  # a ratio within 15 % of a unit factor is taken for it
TEMP_RANGE = (-60.0, 150.0)  # °C, beyond every MEMS part's operating range
KELVIN_RANGE = (200.0, 400.0)
DROPOUT_SHARE = 0.01
STUCK_MIN_S = 120.0
STUCK_SHARE = 0.05
FINE_RESOLUTION = 0.1  # °C: a sensor resolving finer than this does not sit still for long
JITTER_TOLERANCE = 0.10
JITTER_SHARE = 0.05
DROPPED_SHARE = 0.001
GAP_INTERVALS = 10  # an interval over this many nominal ones is a logger pause
GROSS_RESIDUAL = 20.0  # noise floors
RUN_BREAK_S = 60.0  # a pause this long ends a run of one temperature value
GYRO_LIMIT = 1e4  # deg/s: beyond every MEMS gyro's range (±4000 deg/s at most)
GARBLED_LIMIT = 1e8  # no unit makes a gyro read this (4000 deg/s in mdps is 4e6)
GARBLED_SHARE = 0.01  # of the samples beyond it: the columns are corrupt, not spiked
# What rigs record (s): samples from 100 kHz (beyond any MEMS gyro's output rate) to 0.5 Hz
# (a slow thermal logger), holds (a constant rate, a revolution, a face) of 0.05 s to an
# hour, sessions of a second to a month. Beyond the second bounds nothing records at all.
TIME_PLAUSIBLE = {"sample interval": (1e-5, 2.0), "hold": (0.05, 3600.0), "session": (1.0, 30 * 86400.0)}
TIME_POSSIBLE = {"sample interval": (1e-6, 60.0), "hold": (0.005, 86400.0), "session": (0.1, 366 * 86400.0)}
# Units a time column is written in by mistake for seconds: factor to seconds, name, and
# the gyrocal.units entry that declares it (None: convert t to seconds).
TIME_MISTAKES = (
    (1e-3, "milliseconds", "ms"),
    (1e-6, "microseconds", "us"),
    (1e-9, "nanoseconds", "ns"),
    (60.0, "minutes", None),
    (3600.0, "hours", None),
)


class ImplausibleInputError(InputError):
    """A log that satisfies the contract but cannot be what the rig recorded."""


class Finding(TypedDict):
    """A warning, as the calibration file records it (``code``: a key of :data:`CODES`)."""

    code: str
    message: str
    evidence: dict[str, Any]


def finding(code: str, message: str, **evidence) -> Finding:
    return {"code": code, "message": " ".join(message.split()), "evidence": json_safe(evidence)}


class InputSummary(TypedDict):
    """What :class:`InputStats` saw of a log, JSON-plain (inf and NaN as None): segmentation
    writes it in its info (``input_stats``), and the calibration's review reads it back."""

    rows: int
    temp_nonfinite: int
    temp_nonfinite_span: list[float] | None  # first and last t of a non-finite temperature
    temp_range: list[float] | None  # lowest and highest temperature, °C
    temp_out_of_range: int
    temp_finest_step: float | None
    temp_longest_run_s: float  # the longest stretch of one temperature reading
    temp_longest_run_at: float | None
    temp_longest_run_value: float | None
    duration_s: float
    nominal_dt: float | None  # the first batch's median sample interval
    intervals: int
    jittered: int
    dropped_intervals: int
    missing_samples: int
    nonfinite: dict[str, int]  # by column
    gyro_range: dict[str, list[float]]  # by column: lowest and highest
    gyro_beyond: int
    gyro_garbled: int


class InputStats:
    """What the read sees of the log's timing and temperature, batch by batch (bounded
    memory, vectorised per batch): non-finite temperatures, the longest run of one value,
    the finest step, the range, and the sample intervals against the first batch's median."""

    def __init__(self):
        self.rows = 0
        self.temp_nonfinite_span = [math.inf, -math.inf]
        self.temp_min, self.temp_max = math.inf, -math.inf
        self.out_of_range = 0
        self.finest_step = math.inf
        self.run_value = self.run_start = self.run_stop = self.last_t = None
        self.carry, self.blocks_seen = None, 0
        self.buffer = np.empty(0)
        self.longest_run = (0.0, None, None)  # seconds, start t, value
        self.nominal_dt = None
        self.last_raw_t = None
        self.pending: list[np.ndarray] = []
        self.intervals = self.jittered = self.dropped_intervals = self.missing_samples = 0
        self.first_t = None
        self.nonfinite: dict[str, int] = {}
        self.gyro_range: dict[str, list[float]] = {}
        self.gyro_beyond = self.gyro_garbled = 0

    def push_raw(self, batch: dict, suspicious: bool) -> None:
        """Every row as read, before rows with non-finite values are dropped (``suspicious``:
        the batch has some, so each column's are counted). Sample intervals are judged here,
        so that rows dropped for a NaN elsewhere do not look like samples the logger lost."""
        t = batch["t"]
        self.rows += len(t)
        finite_t = None if np.isfinite(t.sum()) else np.isfinite(t)
        self._intervals(t if finite_t is None else t[finite_t])
        if not suspicious:
            return
        for name in ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate"):
            if name in batch:
                bad = ~np.isfinite(batch[name])
                n_bad = int(np.count_nonzero(bad))
                if n_bad:
                    self.nonfinite[name] = self.nonfinite.get(name, 0) + n_bad
                if n_bad and name == "temp":  # where the temperature sensor dropped out
                    tb = t[bad if finite_t is None else bad & finite_t]
                    if tb.size:
                        self.temp_nonfinite_span = [
                            min(self.temp_nonfinite_span[0], float(tb[0])),
                            max(self.temp_nonfinite_span[1], float(tb[-1])),
                        ]

    def push(self, batch: dict) -> None:
        """The rows kept (finite, time strictly increasing)."""
        t, temp = batch["t"], batch.get("temp")  # a log may have none (Protocol.without)
        if not len(t):
            return
        for name in ("gyro_x", "gyro_y", "gyro_z"):
            if name in batch:
                lo, hi = float(batch[name].min()), float(batch[name].max())
                old = self.gyro_range.get(name, [math.inf, -math.inf])
                self.gyro_range[name] = [min(old[0], lo), max(old[1], hi)]
                if max(-lo, hi) > GYRO_LIMIT:
                    size = np.abs(batch[name])
                    self.gyro_beyond += int(np.count_nonzero(size > GYRO_LIMIT))
                    self.gyro_garbled += int(np.count_nonzero(size > GARBLED_LIMIT))
        self.first_t = float(t[0]) if self.first_t is None else self.first_t
        self.last_t = float(t[-1])
        if temp is None:
            return
        self.temp_min = min(self.temp_min, float(temp.min()))
        self.temp_max = max(self.temp_max, float(temp.max()))
        if self.temp_min < TEMP_RANGE[0] or self.temp_max > TEMP_RANGE[1]:
            self.out_of_range += int(np.count_nonzero((temp < TEMP_RANGE[0]) | (temp > TEMP_RANGE[1])))
        self._runs(t, temp)
        self.last_t = float(t[-1])

    RUN_BLOCK = 64  # samples: runs of one temperature value are found block by block

    def _runs(self, t, temp):
        """Runs of one temperature value, found on blocks of RUN_BLOCK samples aligned on the
        log's rows (so the batches do not matter): a block whose samples all hold one value
        continues the run of the blocks before it with that value, unless the logger paused
        over RUN_BREAK_S; a run is timed from its first block's first sample to its last
        block's last. At most two blocks' worth shorter than the sample-exact run: a stuck
        sensor is judged over minutes. The sensor's resolution is the finest step seen."""
        if self.carry is not None:
            t, temp = np.concatenate((self.carry[0], t)), np.concatenate((self.carry[1], temp))
        whole = len(t) // self.RUN_BLOCK * self.RUN_BLOCK
        self.carry = (t[whole:], temp[whole:]) if whole < len(t) else None
        if not whole:
            return
        tb = t[:whole].reshape(-1, self.RUN_BLOCK)
        xb = temp[:whole].reshape(-1, self.RUN_BLOCK)
        first_t, last_t, value = tb[:, 0], tb[:, -1], xb[:, 0]
        # The resolution from every 64th block of the log (the same blocks however it is batched).
        sampled = xb[(self.blocks_seen + np.arange(len(xb))) % 64 == 0]
        self.blocks_seen += len(xb)
        steps = np.abs(np.diff(sampled, axis=1))
        moving = steps[steps > 0]
        if moving.size:
            self.finest_step = min(self.finest_step, float(moving.min()))
        constant = (xb.min(axis=1) == xb.max(axis=1)) & (last_t - first_t <= RUN_BREAK_S)
        # A run breaks before block i when either block is not constant, the value changes
        # or the log paused between them.
        joined = (
            constant[1:]
            & constant[:-1]
            & (value[1:] == value[:-1])
            & (first_t[1:] - last_t[:-1] <= RUN_BREAK_S)
        )
        starts = np.flatnonzero(constant & np.concatenate(([True], ~joined)))
        ends = np.flatnonzero(constant & np.concatenate((~joined, [True])))
        if not starts.size:
            self._end_open_run()
            return
        begin, stop, held = first_t[starts], last_t[ends], value[starts]
        if self.run_value is not None:  # the open run goes on into this batch's first block
            if starts[0] == 0 and held[0] == self.run_value and begin[0] - self.run_stop <= RUN_BREAK_S:
                begin[0] = self.run_start
            else:
                self._end_open_run()
            self.run_value = None
        open_end = ends[-1] == len(constant) - 1
        closed = slice(0, len(starts) - 1 if open_end else len(starts))
        lengths = stop[closed] - begin[closed]
        if lengths.size:
            k = int(np.argmax(lengths))
            self._close(lengths[k], begin[k], held[k])
        if open_end:
            self.run_value, self.run_start, self.run_stop = held[-1], begin[-1], stop[-1]

    def _end_open_run(self):
        if self.run_value is not None:
            self._close(self.run_stop - self.run_start, self.run_start, self.run_value)
            self.run_value = None

    def _close(self, seconds, start, value):
        if seconds > self.longest_run[0]:
            self.longest_run = (float(seconds), float(start), float(value))

    NOMINAL_INTERVALS = 4096  # the nominal interval is the median of the first ones

    def _intervals(self, t):
        if not len(t):
            return
        if self.buffer.size < len(t):
            self.buffer = np.empty(len(t))
        # the interval from the previous batch's last sample first, then this batch's
        dt = self.buffer[: len(t) if self.last_raw_t is not None else len(t) - 1]
        if self.last_raw_t is not None:
            dt[0] = t[0] - self.last_raw_t
        np.subtract(t[1:], t[:-1], out=dt[len(dt) - (len(t) - 1) :])
        self.last_raw_t = float(t[-1])
        if self.nominal_dt is None:
            if self.pending is None:
                return  # settled without a usable interval
            self.pending.append(dt.copy())  # the buffer is reused
            if sum(len(d) for d in self.pending) < self.NOMINAL_INTERVALS:
                return
            self._settle()
            return
        self._count(dt)

    def _settle(self):
        dt = np.concatenate(self.pending) if self.pending else np.zeros(0)
        self.pending = None
        nominal = float(np.median(dt[: self.NOMINAL_INTERVALS])) if dt.size else 0.0
        if nominal > 0:  # else time does not increase, which reading refuses anyway
            self.nominal_dt = nominal
            self._count(dt)

    def _count(self, dt):
        if not dt.size:
            return
        lo, hi = (1 - JITTER_TOLERANCE) * self.nominal_dt, (1 + JITTER_TOLERANCE) * self.nominal_dt
        if lo <= dt.min() and dt.max() <= hi:  # the common case: nothing to count
            self.intervals += dt.size
            return
        ratio = dt / self.nominal_dt
        self.intervals += dt.size
        regular = ratio < 1.75
        self.jittered += int(np.count_nonzero(regular & (np.abs(ratio - 1.0) > JITTER_TOLERANCE)))
        skipped = (ratio >= 1.75) & (ratio <= GAP_INTERVALS)
        self.dropped_intervals += int(np.count_nonzero(skipped))
        self.missing_samples += int(np.sum(np.rint(ratio[skipped]) - 1))

    def summary(self) -> InputSummary:
        if self.nominal_dt is None and self.pending is not None:
            self._settle()
        self._end_open_run()  # the last run ends with the log (a partial block left out)
        run_s, run_t, run_value = self.longest_run
        return json_safe(
            {
                "rows": self.rows,
                "temp_nonfinite": self.nonfinite.get("temp", 0),
                "temp_nonfinite_span": self.temp_nonfinite_span if "temp" in self.nonfinite else None,
                "temp_range": [self.temp_min, self.temp_max] if self.temp_min <= self.temp_max else None,
                "temp_out_of_range": self.out_of_range,
                "temp_finest_step": self.finest_step,
                "temp_longest_run_s": run_s,
                "temp_longest_run_at": run_t,
                "temp_longest_run_value": run_value,
                "duration_s": (self.last_t - self.first_t) if self.first_t is not None else 0.0,
                "nominal_dt": self.nominal_dt,
                "intervals": self.intervals,
                "jittered": self.jittered,
                "dropped_intervals": self.dropped_intervals,
                "missing_samples": self.missing_samples,
                "nonfinite": self.nonfinite,
                "gyro_range": self.gyro_range,
                "gyro_beyond": self.gyro_beyond,
                "gyro_garbled": self.gyro_garbled,
            }
        )


def duration_text(seconds: float) -> str:
    """A duration as a person reads it: 12 µs, 0.01 s, 5.6 h, 55 days."""
    for size, unit in (
        (86400.0 * 365.25, "years"),
        (86400.0, "days"),
        (3600.0, "h"),
        (60.0, "min"),
        (1.0, "s"),
        (1e-3, "ms"),
        (1e-6, "µs"),
    ):
        if seconds >= size or unit == "µs":
            value = seconds / size
            return f"{value:,.0f} {unit}" if value >= 1000 else f"{value:.3g} {unit}"
    return f"{seconds:.3g} s"


_TIME_WORDS = {"sample interval": "samples {} apart", "hold": "holds of {}", "session": "a session of {}"}


def _time_said(values: dict, names: list[str]) -> str:
    parts = [_TIME_WORDS[q].format(duration_text(values[q])) for q in names]
    return " and ".join(parts) if len(parts) < 3 else f"{parts[0]}, {parts[1]} and {parts[2]}"


def _time_off(values: dict, bounds: dict) -> list[str]:
    return [q for q, v in values.items() if not bounds[q][0] <= v <= bounds[q][1]]


class TimeBaseReview(NamedTuple):
    """A time base that rigs do not record (:func:`time_base_review`)."""

    odd: list[str]  # the quantities off: "sample interval", "hold", "session"
    measured: dict[str, float]  # every quantity measured, seconds as t counts them
    fix: tuple[float, str, str | None] | None  # factor, name, declared unit that set all right
    error: bool  # a fix exists and two quantities are off, or one that nothing records


def time_base_review(stats: InputSummary | None, hold_s: float | None = None) -> TimeBaseReview | None:
    """The time base against what rigs record: the nominal sample interval, the session's
    length and, where the protocol's holds last as long as the rig held them, their typical
    length. None when all are what rigs record; else what is off (``odd``), the values, and
    the first unit (t in ms, µs, ns, min, h) that brings all of them into what rigs record
    (``fix``: factor, name, declared unit; None when none does) and whether it is an error:
    two of them off, or one that nothing records, with a fix."""
    measured: dict[str, float] = {}
    if stats and stats.get("nominal_dt"):
        measured["sample interval"] = float(stats["nominal_dt"])
    if hold_s:
        measured["hold"] = float(hold_s)
    if stats and stats.get("duration_s"):
        measured["session"] = float(stats["duration_s"])
    odd = _time_off(measured, TIME_PLAUSIBLE)
    if not odd:
        return None
    fix = next(
        (
            (f, name, unit)
            for f, name, unit in TIME_MISTAKES
            if not _time_off({q: v * f for q, v in measured.items()}, TIME_PLAUSIBLE)
        ),
        None,
    )
    error = fix is not None and (len(odd) >= 2 or bool(_time_off(measured, TIME_POSSIBLE)))
    return TimeBaseReview(odd, measured, fix, error)


def _time_fix_text(review: TimeBaseReview) -> str:
    """'in milliseconds, samples 10 ms apart: declare it ...'"""
    factor, name, unit = review.fix
    scaled = {q: v * factor for q, v in review.measured.items()}
    how = (
        f'declare it in the log\'s metadata gyrocal.units as {{"t": "{unit}"}} (an import '
        f"map: time.unit {unit})"
        if unit
        else "convert t to seconds"
    )
    return f"in {name}, {_time_said(scaled, review.odd)}: {how}"


def time_base(stats: InputSummary | None, hold_s: float | None = None) -> tuple[str | None, Finding | None]:
    """(an error's message, a warning) of :func:`time_base_review`. Rates are per second of
    the sensor's own clock, so a wrong time unit leaves K and B alone but not the noise
    figures (ARW, Allan deviation), the noise floor's time terms or time-read terms."""
    review = time_base_review(stats, hold_s)
    if review is None:
        return None, None
    odd, measured = review.odd, review.measured
    said = _time_said(measured, odd)
    if review.error:
        return f"t does not count seconds: {said}, which no rig records; {_time_fix_text(review)}", None
    evidence = {q.replace(" ", "_") + "_s": v for q, v in measured.items()}
    consequence = "the noise figures (ARW, Allan deviation) and time-read terms take t as seconds"
    if review.fix is None:
        return None, finding(
            "time_base_implausible",
            f"{said}, which rigs do not record: {consequence}; check the time column",
            odd=odd,
            **evidence,
        )
    return None, finding(
        "time_base_implausible",
        f"{said}, which rigs do not record; {_time_fix_text(review)}, if t counts "
        f"{review.fix[1]}; {consequence}",
        unit_factor=review.fix[0],
        odd=odd,
        **evidence,
    )


def explain_segmentation(exc: InputError, stats: InputSummary | None, source=None) -> InputError:
    """A segmentation's failure on a log whose time base is off where a unit factor would
    set it right: the time base is the likelier cause, so the error says it as well."""
    review = time_base_review(stats)
    if review is None or review.fix is None:
        return exc
    reason = str(exc).removeprefix(f"{exc.source}: ") if exc.source else str(exc)
    return ImplausibleInputError(
        f"{reason}; t may not count seconds: {_time_said(review.measured, review.odd)}, "
        f"which rigs do not record; {_time_fix_text(review)}",
        source=source,
    )


def log_errors(stats: InputSummary | None, source=None) -> None:
    """Raise where the read's :class:`InputStats` show the log cannot be right: a
    temperature in kelvin, a gyro axis that never changes, a time base in another unit
    than seconds (the sample interval and the session's length; holds are judged after
    segmentation, in :func:`review`)."""
    if not stats or not stats.get("rows"):
        return
    error, _ = time_base(stats)
    if error is not None:
        raise ImplausibleInputError(error, source=source)
    lo_hi = stats.get("temp_range")
    if lo_hi is not None and KELVIN_RANGE[0] <= lo_hi[0] and lo_hi[1] <= KELVIN_RANGE[1]:
        raise ImplausibleInputError(
            f"column temp reads {lo_hi[0]:.1f} to {lo_hi[1]:.1f}: kelvin, not °C? (declare "
            'it in the metadata gyrocal.units as {"temp": "K"})',
            source=source,
        )
    if (stats.get("gyro_garbled") or 0) > GARBLED_SHARE * stats["rows"]:
        raise ImplausibleInputError(
            f"{stats['gyro_garbled']} of {stats['rows']} gyro samples exceed ±{GARBLED_LIMIT:g}, "
            "which no gyro reads in any unit: the gyro columns are corrupted",
            source=source,
        )
    for name, (lo, hi) in (stats.get("gyro_range") or {}).items():
        if lo == hi:
            raise ImplausibleInputError(
                f"column {name} reads {lo:g} in every row: a stuck or disconnected axis", source=source
            )


def log_findings(stats: InputSummary | None, source=None) -> list[Finding]:
    """Warnings from the read's :class:`InputStats` summary."""
    if not stats or not stats.get("rows"):
        return []
    out = _temperature_findings(stats)
    if stats.get("gyro_beyond"):
        out.append(
            finding(
                "gyro_out_of_range",
                f"{stats['gyro_beyond']} gyro samples exceed ±{GYRO_LIMIT:g} deg/s, beyond any MEMS "
                "gyro's range: corrupted values; the holds around them are split or rejected",
                samples=stats["gyro_beyond"],
                ranges=stats.get("gyro_range"),
            )
        )
    return out + _timing_findings(stats)


def _temperature_findings(stats: InputSummary) -> list[Finding]:
    """The temperature out of range, missing for a share of the rows, or stuck."""
    out = []
    rows = stats["rows"]
    lo_hi = stats.get("temp_range")
    if lo_hi is not None:
        median_guess = 0.5 * (lo_hi[0] + lo_hi[1])
        if stats["temp_out_of_range"]:
            out.append(
                finding(
                    "temperature_out_of_range",
                    f"{stats['temp_out_of_range']} samples of temp lie outside {TEMP_RANGE[0]:g} to "
                    f"{TEMP_RANGE[1]:g} °C (from {lo_hi[0]:.4g} to {lo_hi[1]:.4g}): a sensor error "
                    "code or a wrong unit; those samples enter the holds' temperatures",
                    samples=stats["temp_out_of_range"],
                    temp_min=lo_hi[0],
                    temp_max=lo_hi[1],
                    midpoint=median_guess,
                )
            )
    if stats["temp_nonfinite"] > DROPOUT_SHARE * rows:
        first, last = stats["temp_nonfinite_span"] or (None, None)
        out.append(
            finding(
                "temperature_dropout",
                f"temp is missing (NaN) in {stats['temp_nonfinite']} of {rows} rows "
                f"({stats['temp_nonfinite'] / rows:.1%}), between t = {first:.0f} and {last:.0f} s: "
                "those rows are dropped with their gyro samples, and the temperature record has a hole",
                rows=stats["temp_nonfinite"],
                share=stats["temp_nonfinite"] / rows,
                first_t=first,
                last_t=last,
            )
        )
    duration = stats.get("duration_s") or 0.0
    run = stats.get("temp_longest_run_s") or 0.0
    if (
        run >= max(STUCK_MIN_S, STUCK_SHARE * duration)
        and (stats.get("temp_finest_step") or math.inf) < FINE_RESOLUTION
    ):
        out.append(
            finding(
                "temperature_stuck",
                f"temp reads exactly {stats['temp_longest_run_value']:.6g} °C for {run:.0f} s from "
                f"t = {stats['temp_longest_run_at']:.0f} s, although it resolves steps of "
                f"{stats['temp_finest_step']:.3g} °C elsewhere: a stuck sensor; holds in that stretch "
                "are calibrated at a temperature the unit may not have had",
                seconds=run,
                from_t=stats["temp_longest_run_at"],
                value=stats["temp_longest_run_value"],
                finest_step=stats["temp_finest_step"],
            )
        )
    return out


def _timing_findings(stats: InputSummary) -> list[Finding]:
    """Sample intervals scattered about the nominal, or samples missing between them."""
    out = []
    intervals = stats.get("intervals") or 0
    if intervals:
        nominal = stats["nominal_dt"]
        if stats["jittered"] > JITTER_SHARE * intervals:
            out.append(
                finding(
                    "sample_jitter",
                    f"{stats['jittered'] / intervals:.1%} of the sample intervals differ from the "
                    f"nominal {nominal:.6g} s by over {JITTER_TOLERANCE:.0%}: timestamps from a "
                    "jittery clock; rates and hold boundaries are still computed from them",
                    share=stats["jittered"] / intervals,
                    nominal_dt=nominal,
                )
            )
        jittery = stats["jittered"] > JITTER_SHARE * intervals  # then gaps are not countable
        if stats["dropped_intervals"] > DROPPED_SHARE * intervals and not jittery:
            out.append(
                finding(
                    "dropped_samples",
                    f"{stats['missing_samples']} samples are missing in {stats['dropped_intervals']} "
                    f"places (intervals of 1.75 to {GAP_INTERVALS} nominal {nominal:.6g} s): a logger "
                    "that drops data",
                    missing=stats["missing_samples"],
                    places=stats["dropped_intervals"],
                    nominal_dt=nominal,
                )
            )
    return out


UNIT_RATIOS = (  # gyro over reference, what it means, how to declare it
    (math.pi / 180, "the gyro columns look like rad/s", '{"gyro": "rad/s"}'),
    (180 / math.pi, "ref_rate looks like rad/s", '{"ref_rate": "rad/s"}'),
    (1000.0, "the gyro columns look like mdps", '{"gyro": "mdps"}'),
    (1e-3, "ref_rate looks like mdps", '{"ref_rate": "mdps"}'),
)


def unit_meaning(values: np.ndarray) -> str | None:
    """What a gyro-over-reference ratio shared by ``values`` means, or None."""
    for factor, what, declare in UNIT_RATIOS:
        for sign in (1.0, -1.0):
            if np.all(np.abs(values / (sign * factor) - 1) < UNIT_MATCH):
                return (
                    f"{what}{' and the reference sign is opposite' if sign < 0 else ''}; "
                    f"declare it in the log's metadata gyrocal.units as {declare}"
                )
    if np.all(values > 5) and np.ptp(values) < UNIT_MATCH * np.median(values):
        return (
            f"the gyro columns look like raw counts (about {np.median(values):.4g} LSB per "
            "deg/s); convert them to deg/s"
        )
    return None


def rate_ratio_check(ratios: dict, turning: dict, source=None) -> None:
    """Segmentation's check. ``ratios``: per axis, gyro over reference of the turning holds
    it rejected for disagreeing; ``turning``: per axis, how many turn. Where most of an
    axis' holds disagree by one common ratio, that ratio is a mistake in the log: say which
    (an error). A few disagreeing holds are left to segmentation, which rejects them."""
    common = {}
    for a, ratio in ratios.items():
        if len(ratio) < max(2, 0.5 * turning[a]):
            continue
        q1, median, q3 = np.percentile(ratio, [25, 50, 75])
        if np.isfinite(median) and q3 - q1 <= UNIT_MATCH * abs(median):
            common[a] = (median, int(len(ratio)))
    if not common:
        return
    values = np.array([m for m, _ in common.values()])
    if len(common) == 3 and np.ptp(values) <= UNIT_MATCH * np.abs(values).min():
        held = (
            f"{sum(n for _, n in common.values())} of {sum(turning.values())} turning holds "
            f"read {np.median(values):.4g} times the reference"
        )
    else:
        held = ", ".join(
            f"{n} of {turning[a]} turning holds about {a} read {m:.4g} times the reference"
            for a, (m, n) in common.items()
        )
    meaning = unit_meaning(values)
    if meaning is None and np.all(np.abs(values + 1) < SCALE_TOLERANCE):
        meaning = (AXIS_SIGN if len(common) < 3 else REFERENCE_SIGN).format(axes=", gyro_".join(common))
    if meaning is not None:
        raise ImplausibleInputError(f"{held}: {meaning}", source=source)


REFERENCE_SIGN = (
    "ref_rate has the opposite sign convention (positive is right-handed about the rig axis, which points up)"
)
AXIS_SIGN_CAUSE = "a left-handed axis convention or a reversed mount label"
AXIS_SIGN = "gyro_{axes} has the opposite sign: " + AXIS_SIGN_CAUSE


def observation_findings(obs, axis_mounts: bool, source=None, *, model_reads_accel=False) -> list[Finding]:
    """Warnings from the holds: accelerometer units and, for a protocol that mounts one
    axis on the rig axis at a time (``axis_mounts``), mounts against gravity and whether
    every axis turned both ways on each of its mounts."""
    out = []
    if not len(obs):
        return out
    from_mounts = "accel_source" in obs and bool((obs["accel_source"] == "mount").all())
    accel = (
        np.column_stack([np.asarray(obs[f"accel_{a}"], float) for a in AXES])
        if all(f"accel_{a}" in obs for a in AXES) and not from_mounts
        else None
    )
    if from_mounts and model_reads_accel:
        out.append(
            finding(
                "accel_from_mounts",
                "the log has no accelerometer: the model's terms read the specific force each "
                "mount implies (the table's axis up, no fixture tilt, no centripetal force); "
                "applying the calibration needs an accelerometer in the log it compensates",
            )
        )
    if accel is not None:
        accel = accel[np.all(np.isfinite(accel), axis=1)]
    if accel is not None and len(accel):
        g = float(np.median(np.linalg.norm(accel, axis=1)))
        if 9.0 <= g <= 10.6:
            message = (
                f"the accelerometer reads {g:.3g} at rest: m/s², not g; set the log's "
                'metadata gyrocal.units to {"accel": "m/s^2"}'
            )
            if model_reads_accel:
                raise ImplausibleInputError(message + " (the model's terms read it)", source=source)
            out.append(finding("accel_units", message, magnitude=g))
        elif not 0.8 <= g <= 1.2:
            out.append(
                finding(
                    "accel_scale",
                    f"the accelerometer's magnitude at rest is {g:.4g}, "
                    "1 g expected: a wrong unit or sensitivity",
                    magnitude=g,
                )
            )
        elif axis_mounts and "mount" in obs and "mount_source" in obs:
            out += _mounts_against_gravity(obs)
    if axis_mounts and {"axis", "ref_rate", "mount"} <= set(obs.columns):
        out += _balance(obs)
        out += _holds_off_their_line(obs)
    return out


def _holds_off_their_line(obs) -> list[Finding]:
    """Turning holds whose output is off where the same rate on the same axis is not at the
    other temperature points. Per point and axis, output against reference rate is fitted
    by a line robustly (the median of pairwise slopes, Theil–Sen: a least-squares line would
    bend towards a bad hold); a scale-factor nonlinearity, an asymmetry or a vibration
    leaves residuals that depend on the rate and repeat at every point, a wrong reference or
    a corrupted output one residual alone. So each residual is compared with the median of
    its rate's residuals over the points; a hold off by over GROSS_RESIDUAL noise floors and
    ten robust deviations of those differences is reported."""
    axes = np.asarray(obs["axis"]).astype(str)
    ref = np.asarray(obs["ref_rate"], float)
    point = np.asarray(obs["point"]) if "point" in obs else np.zeros(len(obs))
    if len(np.unique(point)) < 3 or not all(f"gyro_{b}" in obs for b in AXES):
        return []  # no median to compare with
    decade = 10.0 ** np.floor(np.log10(np.maximum(np.abs(ref), 1e-9)))
    nominal = np.round(ref / decade, 1) * decade  # the rate the protocol set, to 2 digits
    outputs = np.column_stack([np.asarray(obs[f"gyro_{b}"], float) for b in AXES])
    floors = np.column_stack(
        [
            np.asarray(obs[f"floor_{b}"], float)
            if f"floor_{b}" in obs
            else np.asarray(obs[f"std_{b}"], float) / np.sqrt(np.asarray(obs["n"], float))
            for b in AXES
        ]
    )
    off, worst, turning = [], 0.0, 0
    for ia, a in enumerate(AXES):
        if f"rate_{a}" not in obs:
            continue
        x = np.asarray(obs[f"rate_{a}"], float)
        resid = _off_the_line(x, outputs, point, (axes == a) & (ref != 0))
        rows = np.flatnonzero(np.isfinite(resid[:, 0]))
        turning += rows.size
        if not rows.size:
            continue
        # each output's residual at the typical point, rate by rate
        keys, group = np.unique(nominal[rows], return_inverse=True)
        typical = np.array([np.median(resid[rows][group == k], axis=0) for k in range(len(keys))])
        d = np.abs(resid[rows] - typical[group])
        counts = np.bincount(group, minlength=len(keys))
        spread = 1.4826 * np.median(d[:, ia])
        others = np.max(np.delete(d, ia, axis=1), axis=1)
        # The turning output alone: a bias that moved (a warm-up) moves every output.
        bad = (
            (counts[group] >= 3)
            & (d[:, ia] > GROSS_RESIDUAL * floors[rows, ia])
            & (d[:, ia] > 10 * spread)
            & (others < 0.1 * d[:, ia])
        )
        off += [int(r) for r in rows[bad]]
        if bad.any():
            worst = max(worst, float(np.max(d[bad, ia] / floors[rows[bad], ia])))
    if not off:
        return []
    holds = np.asarray(obs["hold"])[off] if "hold" in obs else np.array(off)
    return [
        finding(
            "holds_disagree_with_reference",
            f"{len(off)} of {turning} turning holds are off by over {GROSS_RESIDUAL:g} noise "
            f"floors (worst {worst:.0f}×) where their rate on their axis is not at the other "
            "temperature points: their reference rate or their gyro output is not what the "
            "rig did; the fit is pulled towards them",
            holds=[int(h) for h in holds],
            of=turning,
            worst=worst,
        )
    ]


def _off_the_line(x: np.ndarray, outputs: np.ndarray, point: np.ndarray, turning: np.ndarray) -> np.ndarray:
    """Every output's residual (n, 3) from its Theil–Sen line against the turning rate ``x``,
    per temperature point, about the point's median residual; NaN for holds not ``turning``
    or of a point with under five of them."""
    resid = np.full((len(x), 3), np.nan)
    for p in np.unique(point):
        rows = np.flatnonzero((point == p) & turning)
        if rows.size < 5:
            continue
        xi, yi = x[rows], outputs[rows]
        i, j = np.triu_indices(rows.size, 1)
        keep = xi[i] != xi[j]
        slope = (
            np.median((yi[j] - yi[i])[keep] / (xi[j] - xi[i])[keep, None], axis=0)
            if keep.any()
            else np.zeros(3)
        )
        r = yi - slope * xi[:, None]
        resid[rows] = r - np.median(r, axis=0)
    return resid


def _mounts_against_gravity(obs) -> list[Finding]:
    labelled = np.asarray(obs["mount_source"]).astype(str) == "column"
    a = np.column_stack([np.asarray(obs[f"accel_{x}"], float) for x in AXES])
    ok = labelled & np.all(np.isfinite(a), axis=1)
    if not ok.any():
        return []
    a = a[ok]
    axis = np.argmax(np.abs(a), axis=1)
    dominant = np.abs(a[np.arange(len(a)), axis]) / np.linalg.norm(a, axis=1)
    seen = np.where(a[np.arange(len(a)), axis] > 0, "+", "-").astype(object) + np.array(AXES)[axis]
    labels = np.asarray(obs["mount"]).astype(str)[ok]
    clear = dominant > 0.9  # gravity along one axis, as a turntable mount has it
    wrong = clear & (labels != seen.astype(str))
    if wrong.sum() <= 0.1 * clear.sum():
        return []
    pairs = sorted({f"{lab}→{s}" for lab, s in zip(labels[wrong], seen[wrong], strict=False)})
    return [
        finding(
            "mount_contradicts_gravity",
            f"{int(wrong.sum())} of {int(clear.sum())} holds carry a mount label that gravity "
            f"on the accelerometer contradicts ({', '.join(pairs)}: label → the axis that "
            "points up); the rotating axis and its sign come from the labels",
            holds=int(wrong.sum()),
            of=int(clear.sum()),
            pairs=pairs,
        )
    ]


def _balance(obs) -> list[Finding]:
    rate = np.asarray(obs["ref_rate"], float)
    turning = np.abs(rate) > 0
    axes = np.asarray(obs["axis"]).astype(str)
    mounts = np.asarray(obs["mount"]).astype(str)
    problems = []
    for a in AXES:
        on = turning & (axes == a)
        if not on.any():
            problems.append(f"no hold turns the {a} axis")
            continue
        if not (rate[on] > 0).any() or not (rate[on] < 0).any():
            problems.append(f"the {a} axis turns only {'forward' if (rate[on] > 0).any() else 'in reverse'}")
    used = sorted(set(mounts[turning]))
    both = [a for a in AXES if f"+{a}" in used and f"-{a}" in used]
    if both:
        problems += [
            f"mount {s}{a} is missing while {', '.join(f'±{b}' for b in both)} "
            f"{'has' if len(both) == 1 else 'have'} both"
            for a in AXES
            if a not in both
            for s in "+-"
            if f"{s}{a}" not in used and f"{'-' if s == '+' else '+'}{a}" in used
        ]
    if not problems:
        return []
    return [
        finding(
            "protocol_unbalanced",
            "the protocol is unbalanced: " + "; ".join(problems) + ": errors that a "
            "balanced protocol averages out (a g-sensitivity, a scale asymmetry) go into "
            "the fitted terms",
            problems=problems,
            mounts=used,
        )
    ]


# Rejections that are part of every protocol (handling between mounts, the short holds at
# the edges of a pause); the others mean the log or the rig misbehaved.
ROUTINE_REJECTIONS = ("handling_motion", "too_short")
# A working rig never makes these, so one is worth a word; others (a hold not steady, a
# temperature still moving, clipping on a fast hold) only when more than a few.
NEVER_ROUTINE = ("gyro_disagrees", "mount_mismatch", "mount_changes")
REJECTED_SHARE = 0.02


def rejection_findings(info: Mapping[str, Any]) -> list[Finding]:
    """A warning when segmentation rejected more than a few holds for what a working rig
    does not do (clipped output, a gyro that disagrees with the reference, instability)."""
    rejected = {
        k: int(v)
        for k, v in (info.get("rejected_by_reason") or {}).items()
        if k not in ROUTINE_REJECTIONS and v
    }
    total = sum(rejected.values())
    candidates = int(info.get("holds_accepted") or 0) + sum(
        int(v) for v in (info.get("rejected_by_reason") or {}).values()
    )
    if total < max(3, REJECTED_SHARE * candidates) and not any(k in rejected for k in NEVER_ROUTINE):
        return []
    return [
        finding(
            "holds_rejected",
            f"{total} of {candidates} holds were rejected ("
            + ", ".join(f"{k}: {v}" for k, v in sorted(rejected.items()))
            + "): the "
            "calibration rests on the rest; the report's segment list shows each one",
            rejected=rejected,
            candidates=candidates,
        )
    ]
