"""The sampling of a log read from its time stamps: the nominal rate, the logger's real gaps,
and stamps that arrive in bunches.

Two kinds of log break the median interval that a clocked logger's stamps allow:

* a burst logger (a chamber test: 5 s at 50 Hz every 5 minutes) pauses for minutes between
  bursts; each burst is a run of its own, and the samples over time of the whole log say
  nothing of the rate;
* a host that stamps samples on arrival delivers them late, and after a stall all at once,
  a millisecond apart: the median interval is shorter than the mean, and a stall looks like a
  gap although no sample is missing.

A stall and a real gap are told apart by what follows: after a stall the samples that fell due
in it arrive in a bunch, so the stretch of twice the stall's length from its start holds about
as many samples as the rate gives; after a real gap only its second half does. The rate itself
is samples over time within the runs between real gaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAP_CANDIDATE = 10.0  # an interval this many times the median may be a gap or a stall
CAUGHT_UP = 0.75  # share of the expected samples that marks a stall made up by a bunch
BURSTY_CV = 0.5  # intervals scattering more than this (std/mean) are bursty stamps
SPAN = 32  # samples over which the nominal interval is read
REACH = 128  # samples: the shortest stretch a stall's catching up is judged over


@dataclass(frozen=True)
class Sampling:
    """``rate`` (Hz): samples over time within the runs; ``run_starts``/``run_stops``: row
    index ranges [start, stop) between real gaps; ``stalls``: intervals that a bunch of
    samples made up, with ``longest_stall_s``; ``interval_cv``: the intervals' scatter over
    their mean within the runs."""

    rate: float
    run_starts: np.ndarray
    run_stops: np.ndarray
    stalls: int
    longest_stall_s: float
    interval_cv: float

    @property
    def bursty(self) -> bool:
        """Stamps that do not follow a clock: stalls made up later, or intervals scattering
        by more than half their mean."""
        return self.stalls > 0 or self.interval_cv > BURSTY_CV

    def warning(self) -> str | None:
        """One line for the output's warnings, None for a clocked logger."""
        if not self.bursty:
            return None
        stalls = (
            f"; {self.stalls} stalls up to {self.longest_stall_s:.3g} s made up by bunched samples, not gaps"
            if self.stalls
            else ""
        )
        return (
            f"time stamps are bursty (intervals scatter {self.interval_cv:.0%} of their mean"
            f"{stalls}): stamped on arrival rather than by the sensor's clock; the nominal rate "
            f"{self.rate:.4g} Hz is samples over time"
        )


def sampling(t: np.ndarray) -> Sampling:
    """The :class:`Sampling` of strictly increasing stamps ``t`` (s)."""
    t = np.asarray(t, float)
    n = len(t)
    if n < 2:
        return Sampling(0.0, np.array([0]), np.array([n]), 0, 0.0, 0.0)
    dt = np.diff(t)
    # The nominal interval from spans of SPAN samples: arrivals in packets or bunches make
    # the median of single intervals the bunch's spacing, not the sensor's.
    span = min(SPAN, n - 1)
    nominal = float(np.median((t[span:] - t[:-span]) / span))
    candidate = np.flatnonzero(dt > GAP_CANDIDATE * nominal)
    gap = np.zeros(len(candidate), bool)
    if len(candidate) and nominal > 0:
        # after a stall, what fell due in it arrives: the stretch from its start, twice its
        # length (and no shorter than REACH samples, the time a host's queue takes to drain),
        # holds about the samples the rate gives; a dropout of a few samples is no gap either
        reach = np.maximum(2.0 * dt[candidate], REACH * nominal)
        held = np.searchsorted(t, t[candidate] + reach, side="right") - (candidate + 1)
        gap = held < CAUGHT_UP * reach / nominal
    cuts = candidate[gap] + 1
    starts, stops = np.r_[0, cuts], np.r_[cuts, n]
    span = float(np.sum(t[stops - 1] - t[starts]))
    rate = (n - len(starts)) / span if span > 0 else 0.0
    within = np.delete(dt, candidate[gap])
    cv = float(np.std(within) / np.mean(within)) if within.size else 0.0
    stalls = candidate[~gap]
    return Sampling(
        float(rate), starts, stops, int(len(stalls)), float(dt[stalls].max()) if len(stalls) else 0.0, cv
    )
