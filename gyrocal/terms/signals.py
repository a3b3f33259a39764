"""The signals an effect term reads, defined once per sample for fit and apply alike.

A term (:mod:`gyrocal.terms`) turns inputs into regressor columns. Its inputs are of two
kinds:

* **hold-constant**: the true rate in the sensor frame (``rate_x/y/z``), ``ref_rate``, the
  accelerometer (``accel_x/y/z``) and the temperature ``temp``. Within a hold the rig turns
  at one rate on one mount at a stable temperature, so these are the hold's means.
* **series signals**, which change within a hold and may depend on the whole record before
  it: ``t`` (seconds since the log's first sample, i.e. since power-on for a log that
  starts with the unit), ``temp_rate`` (°C/min, the least-squares slope over a centred
  window, :func:`temperature_rate`) and the temperature through a first-order
  lag of time constant τ (``data.lag("temp", tau)``, :func:`first_order_lag`).

Series signals come from a :class:`Series`: the session's time and temperature record. At
apply time that is the log's own samples. For the fit it is a :class:`Series` of bin means
(at most ``MAX_BINS`` bins of about 1 s, written by segmentation as ``history.parquet``),
and a hold's regressor is the mean of the per-sample regressor over the hold, taken by the
trapezoid rule over the record's points inside the hold (:func:`quadrature_inputs`). So one definition serves both:
the fit never sees a hold-level stand-in of ``t`` or of the lag, and a user never handles
hold columns.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict

import numpy as np

from ..io.errors import MissingInputError

if TYPE_CHECKING:
    import pandas as pd

SERIES_INPUTS = frozenset({"t", "t_mount", "temp_rate", "temp_lag", "rate_history", "accel_history"})
# The record's further columns (bin means, like the temperature) and the inputs they stand for
# in a history: a history of the rate is that of the gyro's output, which apply has as the fit
# does; a constant difference (the bias, a scale's few per cent) is the model's to absorb.
RECORD_COLUMNS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
RECORD_SOURCE = {"rate_x": "gyro_x", "rate_y": "gyro_y", "rate_z": "gyro_z"}
# spans, rate, grid point, when the unit was last mounted and when its log last resumed (s),
# and the face of the fixture the unit is mounted on (+1 or -1 along its turning axis)
HOLD_PLUMBING = frozenset({"t_start", "t_end", "temp_rate", "point", "mounted_at", "resumed_at", "sign"})
HOLD_INPUTS = frozenset({"rate_x", "rate_y", "rate_z", "ref_rate", "accel_x", "accel_y", "accel_z", "temp"})
MAX_BINS = 50_000
# The lag (s) a play or Duhem operator of the temperature reads it through, in the fit, in
# apply and in firmware alike: a sensor's noise of 0.034 °C per sample falls to 0.003 °C at
# 25 Hz and 0.008 °C at 5 Hz, under the narrowest dead band (w/20 of 0.75 °C), for 2 s of
# the temperature's travel (0.017 °C at 30 °C/h). Longer costs a fit: on the zoo's sweep
# hysteresis a 5-s lag's delay at each turn left 3 times the floor on the next ramp, where
# the effect follows the temperature itself; 1 s and 2 s left 0.99 and 1.00.
TEMPERATURE_SMOOTHING_S = 2.0
TEMP_RATE_WINDOW_S = 60.0


def bin_width(duration_s: float, window_s: float) -> float:
    """Bins of the record: 1 s, or a twentieth of the temperature-rate window if shorter,
    widened so that a record has at most ``MAX_BINS``. The fit's record (bin means) and
    apply's samples share them, so both see the same temperature rate."""
    return max(min(1.0, window_s / 20.0), float(duration_s) / MAX_BINS)


def temperature_rate(
    t: np.ndarray, temp: np.ndarray, window_s: float = TEMP_RATE_WINDOW_S, weights: np.ndarray | None = None
) -> np.ndarray:
    """Temperature rate (°C/min) at every sample: the least-squares slope of the logged
    temperature over a centred window, computed on bin means (:func:`bin_width`) by one
    convolution and interpolated to the samples. ``weights`` count the samples behind each
    point when the points are themselves bin means. Non-finite inputs give NaN.

    Bins without samples are filled linearly; the series is extended at both ends by odd
    reflection, which keeps a linear trend, so the slope near the ends is not biased to 0.
    """
    rate = np.full(len(t), np.nan)
    good = np.isfinite(t) & np.isfinite(temp)
    if good.sum() < 2:
        return rate
    tg, Tg = t[good], temp[good]
    wg = np.ones(len(tg)) if weights is None else np.asarray(weights, float)[good]
    width = bin_width(tg[-1] - tg[0], window_s)
    index = np.floor((tg - tg[0]) / width).astype(np.int64)
    counts = np.bincount(index, weights=wg)
    sums = np.bincount(index, weights=wg * Tg)
    filled = counts > 0
    centres = (np.arange(len(counts)) + 0.5) * width
    means = np.interp(centres, centres[filled], sums[filled] / counts[filled])
    half = max(int(round(window_s / width / 2)), 1)
    if len(means) <= 2 * half:  # the whole log is shorter than the window: one slope
        lags = centres - centres.mean()
        rate[good] = 60.0 * np.sum(lags * means) / max(np.sum(lags**2), 1e-300)
        return rate
    padded = np.pad(means, half, mode="reflect", reflect_type="odd")
    lags = np.arange(-half, half + 1, dtype=float)
    slope = np.convolve(padded, lags[::-1] / (np.sum(lags**2) * width), mode="valid")  # °C/s
    rate[good] = 60.0 * np.interp(tg - tg[0], centres, slope)
    return rate


def first_order_lag(t: np.ndarray, x: np.ndarray, tau: float, initial: float | None = None) -> np.ndarray:
    """``y`` with ``τ dy/dt = x − y`` and ``y(t_0) = x(t_0)`` (equilibrium at the start), or
    ``initial`` when given (the state a record given in pieces carries over).

    Exact for ``x`` linear between samples (ramp-invariant discretisation), so bin means
    and raw samples of the same record give the same lagged signal to O((Δt/τ)²): with
    ``a = exp(−Δt/τ)``, ``y_k = a y_{k−1} + x_k − a x_{k−1} − (x_k − x_{k−1}) (τ/Δt)(1 − a)``.
    The recursion ``y_k = a_k y_{k−1} + u_k`` is solved in closed form by cumulative sums,
    in chunks of at most 50 time constants, so that the running products stay in floating
    range; a gap longer than that starts afresh."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    y = np.empty_like(x)
    if len(x) == 0:
        return y
    if not (np.isfinite(tau) and tau > 0):
        raise ValueError(f"a lag time constant must be positive, got {tau!r}")
    dt = np.diff(t)
    lam = dt / tau  # time constants per step
    a = np.exp(-lam)
    ratio = np.where(dt > 0, tau / np.where(dt > 0, dt, 1.0), 0.0)
    u = np.where(dt > 0, x[1:] - a * x[:-1] - (x[1:] - x[:-1]) * ratio * (1.0 - a), 0.0)
    y[0] = x[0] if initial is None else float(initial)
    y[1:] = _decay_scan(lam, a, u, y[0])
    return y


def _decay_scan(lam: np.ndarray, a: np.ndarray, u: np.ndarray, start_value: float) -> np.ndarray:
    """``y_k = a_k y_{k−1} + u_k`` (``a_k = exp(−lam_k)``) from ``y_0 = start_value``, for
    k ≥ 1, in closed form by cumulative sums, in chunks of at most 50 decay units so that
    the running products stay in floating range; a step of more than that starts afresh."""
    y = np.empty(len(lam) + 1)
    y[0] = start_value
    cum = np.concatenate([[0.0], np.cumsum(lam)])
    start, state = 1, y[0]
    while start < len(y):
        if lam[start - 1] > 50.0:  # a gap of many time constants: the past is forgotten
            y[start] = u[start - 1] + a[start - 1] * state
            state, start = y[start], start + 1
            continue
        stop = min(max(int(np.searchsorted(cum, cum[start - 1] + 50.0, side="right")), start + 1), len(y))
        big = np.flatnonzero(lam[start : stop - 1] > 50.0)
        if big.size:
            stop = start + 1 + int(big[0])
        p = np.exp(-np.cumsum(lam[start - 1 : stop - 1]))  # Π a up to k, >= e^-50
        y[start:stop] = p * (state + np.cumsum(u[start - 1 : stop - 1] / p))
        state, start = y[stop - 1], stop
    return y[1:]


class LagFilter:
    """:func:`first_order_lag` of a record given in consecutive pieces (``apply``'s
    batches): the last point and its output carry the state. Points where time or input
    is not finite are skipped and read NaN, as the fit's record leaves them out."""

    def __init__(self, tau: float):
        self.tau = float(tau)
        self.last: tuple[float, float, float] | None = None  # t, x, y

    def __call__(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
        out = np.full(len(x), np.nan)
        good = np.isfinite(t) & np.isfinite(x)
        if not good.any():
            return out
        tg, xg = t[good], x[good]
        if self.last is None:
            y = first_order_lag(tg, xg, self.tau)
        else:
            lt, lx, ly = self.last
            y = first_order_lag(np.r_[lt, tg], np.r_[lx, xg], self.tau, initial=ly)[1:]
        self.last = (float(tg[-1]), float(xg[-1]), float(y[-1]))
        out[good] = y
        return out


class CarriedFilter:
    """An operator ``op(x, size, state) -> (y, state)`` over a record given in consecutive
    pieces, the state carried from piece to piece. Points where time or input is not
    finite are skipped and read NaN."""

    def __init__(self, op, size: float):
        self.op, self.size, self.state = op, float(size), None

    def __call__(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        out = np.full(len(x), np.nan)
        good = np.isfinite(x) & np.isfinite(np.asarray(t, dtype=float))
        if good.any():
            out[good], self.state = self.op(x[good], self.size, self.state)
        return out


def _carrying_last(play):
    """A play operator ``play(x, width, initial)`` as :class:`CarriedFilter` runs it: its
    state is its last output."""

    def run(x, width, last):
        y = play(x, width, last)
        return y, float(y[-1])

    return run


def temperature_play(x: np.ndarray, width: float, initial: float | None = None) -> np.ndarray:
    """:func:`play_operator` of the temperature, started as a unit brought from the room
    (:data:`ROOM_C`) to the record's first value, as :func:`duhem_operator` is: a record
    that starts cold begins falling, one that starts hot rising. Started at its first value
    instead, the direction at the first temperature point would be nobody's, and a session
    that starts elsewhere would meet a different one there."""
    x = np.asarray(x, dtype=float)
    if initial is None and len(x):
        initial = float(np.clip(ROOM_C, x[0] - 0.5 * width, x[0] + 0.5 * width))
    return play_operator(x, width, initial)


class SampleRecord:
    """The record as ``apply`` meets it: a batch of the log's own samples. Each history
    (:meth:`Inputs.history`) runs over them, causally, from the state the previous batch
    left (``states``, shared from batch to batch), as firmware would run it; the fit's
    hold means of the same history, from the record's bins, agree to O((Δt/τ)²) (for a
    play or Duhem operator of the temperature, τ the lag it reads the temperature by).
    Everything else (the temperature rate, a lag of the temperature) reads ``bins``, the
    record the fit read."""

    def __init__(self, bins: Series | None, samples: dict, states: dict):
        self.bins, self.samples, self.states = bins, samples, states
        self.t0 = bins.t0 if bins is not None else 0.0
        self._done: dict = {}

    def __getitem__(self, rows):
        return self

    def __deepcopy__(self, memo):
        return self

    def at(
        self, name: str, times: np.ndarray, tau: float | None = None, window: float | None = None
    ) -> np.ndarray:
        if self.bins is None:
            raise MissingInputError(f"{name} needs the session's record, which is not at hand here")
        return self.bins.at(name, times, tau, window)

    def column(self, name: str) -> np.ndarray:
        source = RECORD_SOURCE.get(name, name)
        if source not in self.samples:
            raise MissingInputError(f"a history of {name} needs it in the log's samples")
        return self.samples[source]

    def history(
        self, key, values, operator: str, size: float, times: np.ndarray, smooth: bool = False
    ) -> np.ndarray:
        cache = (key, operator, float(size), bool(smooth))
        if cache not in self._done:  # once per batch: the filter's state moves on once
            run = self.states.setdefault(cache, FILTERS[operator](size))
            x = np.asarray(values(self), dtype=float)
            if smooth:  # the temperature, through the lag its operators read it by
                x = self.states.setdefault(("smooth", *cache), LagFilter(TEMPERATURE_SMOOTHING_S))(
                    self.samples["t"], x
                )
            self._done[cache] = run(self.samples["t"], x)
        y, t = self._done[cache], self.samples["t"]
        if len(times) == len(t):
            return y
        kept = np.isfinite(t)  # apply's rows with every input finite: a subset of the batch
        return np.interp(times, t[kept], y[kept])


class SeriesMetadata(TypedDict):
    """What the history file's metadata keeps of a :class:`Series` beside its columns."""

    t0: float
    temp_rate_window_s: float


@dataclass(frozen=True, eq=False)
class Series:
    """A session's time (s since its first sample) and temperature (°C) record, with the
    series signals derived from it on demand (cached). Shared by every subset of a
    session's holds: indexing it returns itself, so it rides along when observation columns
    are subset row by row."""

    t: np.ndarray
    temp: np.ndarray
    t0: float = 0.0  # the first sample's time in the log's own clock
    temp_rate_window_s: float = TEMP_RATE_WINDOW_S
    weight: np.ndarray | None = None  # samples behind each point, when they are bin means
    # Further signals of the record, bin means as ``temp`` (RECORD_COLUMNS: the gyro's output
    # in deg/s, the accelerometer in g), for inputs with a history (:meth:`Inputs.history`).
    record: dict = field(default_factory=dict, repr=False, compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __getitem__(self, rows):
        return self

    def __deepcopy__(self, memo):
        return self

    def signal(self, name: str, tau: float | None = None, window: float | None = None) -> np.ndarray:
        key = (name, tau, window)
        if key not in self._cache:
            if name == "temp_rate":
                value = temperature_rate(self.t, self.temp, window or self.temp_rate_window_s, self.weight)
            elif name == "temp":
                value = self.temp
            else:
                raise KeyError(name)
            if tau is not None:
                value = first_order_lag(self.t, value, tau)
            self._cache[key] = value
        return self._cache[key]

    def at(
        self, name: str, times: np.ndarray, tau: float | None = None, window: float | None = None
    ) -> np.ndarray:
        """A signal at ``times`` (s since the first sample), linear between record points;
        ``window``: the temperature rate's window, when not the session's."""
        return np.interp(times, self.t, self.signal(name, tau, window))

    def column(self, name: str) -> np.ndarray:
        """A record input at the record's points: ``t``, ``temp``, ``temp_rate``, and the
        rates (the gyro's output) and specific force where the record holds them."""
        if name in ("temp", "temp_rate"):
            return self.signal(name)
        if name == "t":
            return self.t
        source = RECORD_SOURCE.get(name, name)
        if source not in self.record:
            what = "rates" if source.startswith("gyro") else "specific force"
            raise MissingInputError(
                f"a history of {name} needs the session's record of {what}, "
                "which this record lacks (segment the log again, with the "
                "columns logged)"
            )
        return self.record[source]

    def history(
        self, key, values, operator: str, size: float, times: np.ndarray, smooth: bool = False
    ) -> np.ndarray:
        """``values(self)`` (the record's points, from :meth:`column`), named ``key`` for
        the cache, through ``operator`` of ``size`` at ``times``: ``lag``, a first-order lag
        of time constant ``size`` s; ``play``, the play (backlash) operator of width
        ``size`` (``temperature_play``: started from the room); ``duhem``, the direction of
        travel relaxing over ``size`` of travel. ``smooth``: the input through a lag of
        :data:`TEMPERATURE_SMOOTHING_S` first (a play or Duhem operator of the temperature)."""
        cache = ("history", key, operator, float(size), bool(smooth))
        if cache not in self._cache:
            x = np.asarray(values(self), dtype=float)
            if smooth:
                x = first_order_lag(self.t, x, TEMPERATURE_SMOOTHING_S)
            self._cache[cache] = (
                first_order_lag(self.t, x, size)
                if operator == "lag"
                else play_operator(x, size)
                if operator == "play"
                else temperature_play(x, size)
                if operator == "temperature_play"
                else duhem_operator(x, size)[0]
            )
        return np.interp(times, self.t, self._cache[cache])

    # -- the history file ----------------------------------------------------------------
    def to_frame(self) -> pd.DataFrame:
        import pandas as pd  # a report reads a calibration without pandas

        weight = np.ones(len(self.t)) if self.weight is None else self.weight
        return pd.DataFrame(
            {
                "t": self.t,
                "temp": self.temp,
                "n": weight,
                **{k: self.record[k] for k in RECORD_COLUMNS if k in self.record},
            }
        )

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, meta: Mapping[str, Any]) -> Series:
        return cls(
            frame["t"].to_numpy(float),
            frame["temp"].to_numpy(float),
            float(meta["t0"]),
            float(meta["temp_rate_window_s"]),
            frame["n"].to_numpy(float),
            {k: frame[k].to_numpy(float) for k in RECORD_COLUMNS if k in frame},
        )

    def metadata(self) -> SeriesMetadata:
        return {"t0": self.t0, "temp_rate_window_s": self.temp_rate_window_s}


def history(
    t: np.ndarray,
    temp: np.ndarray,
    t0: float | None = None,
    *,
    window_s: float = TEMP_RATE_WINDOW_S,
    record: dict | None = None,
) -> Series:
    """A session's record as bin means, in the bins :func:`temperature_rate` uses, times
    counted from ``t0`` (default: the first sample); ``record``: further columns
    (:data:`RECORD_COLUMNS`) binned alike."""
    t = np.asarray(t, dtype=float)
    if not len(t):
        return Series(np.empty(0), np.empty(0), 0.0 if t0 is None else float(t0), window_s, np.empty(0))
    bins = HistoryBins(float(t[0]), float(t[-1]), t0, window_s=window_s)
    bins.push(t, temp, record)
    return bins.result()


class HistoryBins:
    """:func:`history` of a record given in consecutive pieces (a log read batch by batch):
    each bin's samples are summed in one piece, in order, so the result is the same to the
    bit whatever the pieces. ``t_first`` and ``t_last`` are the record's first and last
    times (the bin width depends on its duration). Further columns (the gyro's output, the
    accelerometer) are binned alike when every piece gives them."""

    def __init__(
        self, t_first: float, t_last: float, t0: float | None = None, *, window_s: float = TEMP_RATE_WINDOW_S
    ):
        self.t0 = float(t_first) if t0 is None else float(t0)
        self.rel_first = float(t_first) - self.t0
        self.width = bin_width((float(t_last) - self.t0) - self.rel_first, window_s)
        self.window_s = window_s
        self._carry: dict | None = None
        self._out: list[dict] = []
        self._first: dict | None = None  # every column's first sample
        self._last: dict | None = None  # and its last

    def push(self, t: np.ndarray, temp: np.ndarray, record: dict | None = None) -> None:
        columns = {
            "t": np.asarray(t, dtype=float) - self.t0,
            "temp": np.asarray(temp, dtype=float),
            **{k: np.asarray(v, dtype=float) for k, v in (record or {}).items()},
        }
        if not len(columns["t"]):
            return
        if self._first is None:
            self._first = {k: v[0] for k, v in columns.items()}
        elif set(columns) != set(self._first):
            raise ValueError("every piece of a record must give the same columns")
        self._last = {k: v[-1] for k, v in columns.items()}
        index = np.floor((columns["t"] - self.rel_first) / self.width).astype(np.int64)
        if self._carry is not None:
            # the carried bin takes this piece's first samples of it, and only they are joined
            # to it: a bin's mean does not depend on which others are reduced beside it
            carried = self._carry
            head = int(np.searchsorted(index, carried["index"][0], side="right"))
            joined = {
                k: np.concatenate((carried[k], v[:head])) for k, v in (("index", index), *columns.items())
            }
            index, columns = index[head:], {k: v[head:] for k, v in columns.items()}
            if not len(index):  # the bin goes on past this piece
                self._carry = joined
                return
            self._reduce(joined.pop("index"), joined)
        split = int(np.searchsorted(index, index[-1], side="left"))  # the last bin may go on
        self._reduce(index[:split], {k: v[:split] for k, v in columns.items()})
        self._carry = {"index": index[split:], **{k: v[split:] for k, v in columns.items()}}

    def _reduce(self, index, columns) -> None:
        if not len(index):
            return
        index = index - index[0]
        counts = np.bincount(index)
        filled = counts > 0
        means = {k: np.bincount(index, weights=v)[filled] / counts[filled] for k, v in columns.items()}
        means["n"] = counts[filled].astype(float)
        self._out.append(means)

    def result(self) -> Series:
        if self._carry is not None:
            carry = self._carry
            self._reduce(carry.pop("index"), carry)
            self._carry = None
        first, last = self._first, self._last
        if not self._out or first is None or last is None:  # no sample pushed
            return Series(np.empty(0), np.empty(0), self.t0, self.window_s, np.empty(0))
        out = {k: np.concatenate([part[k] for part in self._out]) for k in self._out[0]}
        # The first and last samples themselves bound the record (with no weight of their
        # own: they are in the first and last bins), so that a lag starts from the same
        # state as on the samples and nothing is extrapolated at the ends.
        if out["t"][0] > first["t"]:
            out = {k: np.r_[0.0 if k == "n" else first[k], v] for k, v in out.items()}
        if out["t"][-1] < last["t"]:
            out = {k: np.r_[v, 0.0 if k == "n" else last[k]] for k, v in out.items()}
        record = {k: out[k] for k in RECORD_COLUMNS if k in out}
        return Series(out["t"], out["temp"], self.t0, self.window_s, out["n"], record)


def play_operator(x: np.ndarray, width: float, initial: float | None = None) -> np.ndarray:
    """The play (backlash) operator of ``width``: ``y_k = clip(y_{k-1}, x_k − w/2, x_k + w/2)``,
    ``y_0 = x_0`` (or ``initial``). The output stays where it was until the input has moved
    half the width away, then follows it at that distance: ``2 (x − y) / w`` is +1 while the
    input rises, −1 while it falls, and moves between them as it turns back over a width.

    Each step is a clip, and clips compose into clips: ``clip(clip(y, a, b), c, d)`` is
    ``clip(y, clip(a, c, d), clip(b, c, d))``. The prefix compositions are found by a
    doubling scan (log2 n vectorised passes), so a record of 50,000 points costs 16 passes."""
    x = np.asarray(x, dtype=float)
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"a play operator's width must be positive, got {width!r}")
    if not len(x):
        return x.copy()
    lo, hi = x - 0.5 * width, x + 0.5 * width
    step = 1
    while step < len(x):
        # prefix[k] = f_k ∘ … ∘ f_{k−step+1} applied after prefix[k − step]
        new_lo = np.clip(lo[:-step], lo[step:], hi[step:])
        new_hi = np.clip(hi[:-step], lo[step:], hi[step:])
        lo[step:], hi[step:] = new_lo, new_hi
        step *= 2
    start = x[0] if initial is None else float(initial)
    return np.clip(start, lo, hi)


# The dead band of the Duhem operator, as a part of its width: travel within it (a sensor's
# noise) moves nothing.
DUHEM_BAND = 0.05
# Where a unit's temperature comes from before its record: the room (the datasheets' 25 °C).
ROOM_C = 25.0


def duhem_operator(
    x: np.ndarray, width: float, state: tuple[float, float, float] | None = None
) -> tuple[np.ndarray, tuple[float, float, float] | None]:
    """The direction of travel of ``x`` as a Duhem hysteresis: a state in [−1, 1] that
    relaxes toward +1 while ``x`` rises and −1 while it falls, by a factor ``e`` per
    ``width`` of travel (``ds/dU = (sign(dx) − s) / w``, solved exactly step by step). Travel is counted on :func:`play_operator` of
    ``DUHEM_BAND · width``, so noise within that band moves nothing. The record starts from
    the state of a unit taken from the room (:data:`ROOM_C`, with no direction yet) to the
    record's first value, or continues ``state`` (the play operator's output, the last
    direction, the last value: a record given in pieces). Returns the states and the state
    to continue from."""
    x = np.asarray(x, dtype=float)
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"a Duhem operator's width must be positive, got {width!r}")
    if not len(x):
        return x.copy(), state
    if state is None:
        half = 0.5 * DUHEM_BAND * width
        y_last = float(np.clip(ROOM_C, x[0] - half, x[0] + half))
        direction = float(np.sign(x[0] - ROOM_C)) if abs(x[0] - ROOM_C) > half else 0.0
        state = (y_last, direction, direction * -float(np.expm1(-abs(y_last - ROOM_C) / width)))
    y_last, direction, s_last = state
    y = play_operator(x, DUHEM_BAND * width, y_last)
    step = np.diff(np.r_[y_last, y])
    sign = np.sign(step)
    moved = np.where(sign != 0, np.arange(len(x)), -1)
    last = np.maximum.accumulate(moved)
    target = np.where(last >= 0, sign[np.maximum(last, 0)], direction)
    # Within a step the input moves one way: the state relaxes toward that step's direction
    # over its travel exactly, s_k = d_k + (s_{k−1} − d_k) e^{−|Δ_k|/w}, whatever the steps'
    # sizes (a coarse step and the same travel in fine ones give the same state).
    lam = np.abs(step) / width
    a = np.exp(-lam)
    s = _decay_scan(lam, a, (1.0 - a) * target, s_last)
    return s, (float(y[-1]), float(target[-1]), float(s[-1]))


# The filter apply runs for each history, by operator.
FILTERS = {
    "lag": LagFilter,
    "play": lambda w: CarriedFilter(_carrying_last(play_operator), w),
    "temperature_play": lambda w: CarriedFilter(_carrying_last(temperature_play), w),
    "duhem": lambda w: CarriedFilter(duhem_operator, w),
}


class Inputs(dict):
    """What a term's ``columns`` reads: input arrays by name (one value per evaluation
    point: a quadrature node of a hold, or a sample), plus :meth:`lag`. Records what was
    read, so the library knows which terms vary within a hold."""

    def __init__(self, columns, series: Series | None = None, times: np.ndarray | None = None):
        super().__init__(columns)
        self.series = series
        self.times = times
        self.read: set[str] = set()
        # At quadrature nodes (:func:`quadrature_inputs`): each hold's first node, the weights
        self.plan: tuple[np.ndarray, np.ndarray] | None = None

    def __getitem__(self, name):
        if name == "sign" and not dict.__contains__(self, name):
            return self._off_the_fixture()  # optional: no input a stream must have
        self.read.add(name)
        if name == "t_mount" and not dict.__contains__(self, name):
            return self._since_mounting()
        try:
            return super().__getitem__(name)
        except KeyError:
            shown = sorted(k for k in self if k not in ("series", "t_start", "t_end", "point"))
            raise MissingInputError(f"{name} is not an input here (inputs: {', '.join(shown)})") from None

    def _off_the_fixture(self) -> np.ndarray:
        """``sign``, the fixture's face, where no face is known (apply, in the field): 0, so
        that a term of the fixture's faces adds nothing off it."""
        like = next(
            (dict.get(self, c) for c in ("t", "rate_x", "temp") if dict.get(self, c) is not None), None
        )
        if like is None:
            raise MissingInputError("sign is not an input here: no hold or sample to give it for")
        return np.zeros(np.shape(like))

    def _since_mounting(self) -> np.ndarray:
        """``t_mount``: seconds since the unit was last mounted, from each hold's
        ``mounted_at`` (segmentation's, the end of the handling before it) at ``t``. A
        stream without mountings (apply, in the field) is long since mounted: infinite, where
        whatever relaxes after a mounting has settled."""
        t = dict.get(self, "t")
        if t is None:
            raise MissingInputError("t_mount is not an input here: it needs the time (t)")
        mounted = dict.get(self, "mounted_at")
        if mounted is None:
            return np.full(np.shape(t), np.inf)
        t0 = self.series.t0 if self.series is not None else 0.0
        return np.maximum(np.asarray(t, float) - (np.asarray(mounted, float) - t0), 0.0)

    def temp_rate_over(self, window_s: float) -> np.ndarray:
        """The temperature rate (°C/min) over a centred window of ``window_s`` seconds."""
        self.read.add("temp_rate")
        if self.series is None or self.times is None:
            raise MissingInputError(
                "a temperature rate over a chosen window needs the session's "
                "temperature record, which is not at hand here"
            )
        return self.series.at("temp_rate", self.times, window=float(window_s))

    def lag(self, name: str, tau: float) -> np.ndarray:  # noqa: D417
        """``name`` (``temp`` or ``temp_rate``) through a first-order lag of ``tau`` seconds
        (``tau = 0``: the record itself, never clamped to a calibrated range)."""
        self.read.add("temp_lag")
        if self.series is None or self.times is None:
            raise MissingInputError(
                f"the lag of {name} needs the session's temperature record, "
                "which is not at hand here (observations segmented before "
                "gyrocal kept it: segment the log again)"
            )
        try:
            tau = float(tau)
        except (TypeError, ValueError):
            raise MissingInputError(f"a lag time constant must be a number of seconds, got {tau!r}") from None
        if not (np.isfinite(tau) and tau >= 0):
            raise MissingInputError(f"a lag time constant must be a number of seconds >= 0, got {tau!r}")
        if name not in ("temp", "temp_rate"):
            raise MissingInputError(f"only temp and temp_rate can be lagged, not {name}")
        return self.series.at(name, self.times, tau or None)

    def history(
        self, key, values, operator: str, size: float, reads=frozenset(), smooth: bool = False
    ) -> np.ndarray:
        """A signal of the record through an operator of ``size`` (:data:`FILTERS`: a
        first-order lag of time constant ``size`` s, a play operator of width ``size``, the
        temperature's play from the room, a Duhem state), at this evaluation's times:
        ``values(series)`` gives the signal at the record's points (:meth:`Series.column`),
        ``key`` names it for the cache, ``reads`` the inputs it rests on (``rate_history``,
        ``accel_history``); ``smooth``: through a lag of :data:`TEMPERATURE_SMOOTHING_S`
        first (the temperature's play and Duhem state)."""
        self.read.add("temp_lag")
        self.read.update(reads)
        if self.series is None or self.times is None:
            raise MissingInputError(
                "an input with a history needs the session's record, which is "
                "not at hand here (observations segmented before gyrocal kept "
                "it: segment the log again)"
            )
        size = float(size)
        if not (np.isfinite(size) and size > 0):
            raise MissingInputError(
                f"a {operator}'s {'time constant' if operator == 'lag' else 'width'} "
                f"must be a positive number, got {size!r}"
            )
        return self.series.history(key, values, operator, size, self.times, smooth)


class Quadrature(NamedTuple):
    """What the quadrature over holds needs (:func:`quadrature_inputs`): the session's record
    and each hold's span (first and last time, s since the record's start), both None
    without a record."""

    series: Series | None
    span: tuple[np.ndarray, np.ndarray] | None


def hold_inputs(data) -> tuple[Inputs, Quadrature]:
    """Inputs at hold level (each hold's own columns; ``t`` its mid time) and what the
    quadrature needs: the series and each hold's span. Without a record (observation
    tables from before this format, hand-built tests), series signals are not inputs and
    ``temp_rate`` is the hold's own slope."""
    series = data.get("series") if hasattr(data, "get") else None
    # A term sees its inputs, not the observation table's other columns (noise terms, hold
    # numbers): what it reads in the fit, apply can give it for every sample.
    columns = {k: v for k, v in data.items() if k in HOLD_INPUTS or k in HOLD_PLUMBING}
    span = None
    if series is not None and "t_start" in columns:
        lo = np.asarray(columns["t_start"], float) - series.t0
        hi = np.asarray(columns["t_end"], float) - series.t0
        columns["t"] = 0.5 * (lo + hi)
        span = (lo, hi)
    return Inputs(columns, series, columns.get("t") if series is not None else None), Quadrature(series, span)


def quadrature_inputs(base: Inputs, series: Series, span) -> Inputs:
    """Inputs at the record's points inside every hold and at its two ends: hold-constant
    columns repeated, series signals from the record. A hold's mean is then the trapezoid
    rule over them (``plan``: each hold's first node and the nodes' weights), which is
    exact for the record's own piecewise-linear interpolant, as apply samples it. The nodes
    of the holds last asked for are kept on the series: a profiled fit asks for the same
    holds' a few dozen times."""
    lo, hi = span
    n = len(lo)
    key = (
        "nodes",
        hashlib.blake2b(
            np.ascontiguousarray(lo, float).tobytes() + np.ascontiguousarray(hi, float).tobytes(),
            digest_size=20,
        ).digest(),
    )
    nodes = series._cache.get(key)
    if nodes is None:
        nodes = _nodes(series, lo, hi)
        for a in nodes:
            a.flags.writeable = False  # shared by the fits that ask for these holds
        kept = [k for k in series._cache if k[0] == "nodes"]
        for old in kept[: len(kept) - NODE_LAYOUTS_KEPT + 1]:
            del series._cache[old]
        series._cache[key] = nodes
    hold, times, starts, weights, temp_rate = nodes
    columns = {}
    for k, v in dict.items(base):
        if k in ("t", "temp_rate"):
            continue
        v = np.asarray(v)
        columns[k] = v[hold] if v.ndim == 1 and len(v) == n else v
    columns["t"] = times
    columns["temp_rate"] = temp_rate
    out = Inputs(columns, series, times)
    out.plan = (starts, weights)
    return out


NODE_LAYOUTS_KEPT = 2


def _nodes(series: Series, lo: np.ndarray, hi: np.ndarray) -> tuple:
    """Each node's hold, time and trapezoid weight, each hold's first node, and the
    temperature rate at the nodes."""
    n = len(lo)
    first = np.searchsorted(series.t, lo, side="right")
    last = np.searchsorted(series.t, hi, side="left")
    inside = np.maximum(last - first, 0)
    sizes = inside + 2
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    hold = np.repeat(np.arange(n), sizes)
    position = np.arange(int(sizes.sum())) - starts[hold]  # 0 .. size-1 in a hold
    record = first[hold] + position - 1  # record index, inner nodes
    times = np.where(
        position == 0,
        lo[hold],
        np.where(position == sizes[hold] - 1, hi[hold], series.t[np.clip(record, 0, len(series.t) - 1)]),
    )
    # Trapezoid weights: half the span to each neighbour, over the hold's length.
    before = np.r_[0.0, np.diff(times)]
    after = np.r_[np.diff(times), 0.0]
    before[position == 0] = 0.0
    after[position == sizes[hold] - 1] = 0.0
    length = (hi - lo)[hold]
    weights = np.where(
        length > 0, 0.5 * (before + after) / np.where(length > 0, length, 1.0), 1.0 / sizes[hold]
    )
    return hold, times, starts, weights, series.at("temp_rate", times)


def hold_means_of_lag(data, name: str, tau: float) -> np.ndarray | None:
    """Each hold's mean of ``name`` through a first-order lag of ``tau`` seconds, by the
    quadrature of :func:`quadrature_inputs`; None without the session's record."""
    base, context = hold_inputs(data)
    if context.series is None or context.span is None:
        return None
    if not len(context.span[0]):
        return np.empty(0)
    nodes = quadrature_inputs(base, context.series, context.span)
    assert nodes.times is not None  # quadrature inputs are at their nodes' times
    return node_means(context.series.at(name, nodes.times, float(tau)), nodes.plan)


def node_means(values: np.ndarray, plan) -> np.ndarray:
    """Hold means of a regressor evaluated at the quadrature nodes."""
    starts, weights = plan
    values = np.broadcast_to(np.asarray(values, float), weights.shape)
    return np.add.reduceat(values * weights, starts)


def read_observations(folder) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A unit's observation table and its metadata
    (:func:`gyrocal.io.unit_folder.read_observation_table`), the table carrying the session's
    record as its :class:`Series` (``attrs["series"]``) where segmentation wrote one."""
    from ..io import unit_folder  # Parquet on use: a term file imports this module

    obs, extra = unit_folder.read_observation_table(folder)
    history = unit_folder.read_history(folder)
    if history is not None:
        obs.attrs["series"] = Series.from_frame(*history)
    return obs, extra
