"""What each step of the diagnosis finds: frozen, typed results.

Each finding writes itself into the diagnosis file with :meth:`to_dict`, whose keys are the
file's (``docs/effects.md``); the steps that make them are in :mod:`.steps`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from .sessions import CarryOver
from .where import CovariateRow, FitQuality, Leftover


class _Written:
    """A finding written as its fields, in their order."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]


def explained_by(finding: LabTest | MountingTest | WithinNoise | TimeDrift | Approach | None) -> bool:
    """A test was made and its finding explains the excess."""
    return finding is not None and finding.explains


@dataclass(frozen=True)
class ExcessTest:
    """Does the configured model explain the data (question 1 of the module docstring)?

    ``fits``: the in-sample χ² is within chance (half the significance). ``faint``: it is
    not, but sqrt(χ²/dof) is within the noise floor's own uncertainty of 1, or within
    CARRIES_WITHIN with the held-out error within the practical bar, or (with another session
    on which the calibration carries) the held-out error alone within CARRIES_WITHIN. ``bound``: the
    held-out figure's own uncertainty as a ratio (:func:`.stats.chance_bound`); ``tolerance``:
    what a held-out error may be, in units of what a correct model leaves, and still be
    explained (:func:`.stats.explained_tolerance`). ``resolvable``: the held-out error
    misses what a correct model leaves by more than ``bound``, so a term has something to
    take away; ``next_fails``: the calibration fails on the other session in practice, which
    resolves what the points left out could not (``open``: either)."""

    quality: FitQuality
    alpha: float
    fits: bool
    faint: bool
    factor: float
    bound: float
    tolerance: float
    resolvable: bool
    validation_rms: float
    expected_rms: float
    next_fails: bool = False

    @property
    def explains(self) -> bool:
        return self.fits or self.faint

    @property
    def open(self) -> bool:
        return self.resolvable or self.next_fails


@dataclass(frozen=True)
class LabTest(_Written):
    """The excess against the turning table's angle (:func:`.lab.lab_fixed`)."""

    p_value: float
    parameters: int
    chi2_before: float
    chi2_after: float
    dof: int
    share_of_excess: float
    left_p_value: float
    offsets_p_value: float
    explains: bool


@dataclass(frozen=True)
class MountingTest(_Written):
    """The excess against an offset per mounting (:func:`.lab.mounting_fixed`)."""

    p_value: float
    parameters: int
    mountings: int
    chi2_after: float
    dof: int
    share_of_excess: float
    left_p_value: float
    orientation_p_value: float
    drift_p_value: float
    direction_p_value: float
    explains: bool
    rival_share: float = 0.0  # the largest share of the excess any rival takes


@dataclass(frozen=True)
class BetweenPoints(_Written):
    """Each temperature point left out and interpolated from the others, against its own
    fit (:func:`.between.between_points`); ``points`` and ``worst`` are rows of the table."""

    points: list[dict[str, Any]]
    worst: dict[str, Any]
    p_value: float
    temperature_points: int
    fails: bool
    failing: list[float]


@dataclass(frozen=True)
class WithinNoise(_Written):
    """The χ² test with the slow noise the static data cannot rule out at its upper bound,
    and, where that alone does not explain the excess, the fixture's seating at its
    repeatability beside it (``seating_change``, rad: the RMS of each mounting's rotation
    fitted; ``seating_repeatability``, rad: its prior; None where it was not needed).
    ``drowned``: terms that take more than chance from the excess under white noise but not
    from what that wander leaves (:func:`.steps.beyond_slow_noise`), with that test's p."""

    excess_p_value: float
    chi2_red: float
    expected_rms: float
    static_seconds: float
    explains: bool
    seating_change: float | None = None
    seating_repeatability: float | None = None
    drowned: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class Negligible(_Written):
    """An excess within the noise floor's own uncertainty, or within the bar a calibration
    meets on its next session in sample and on the holds left out (``held_out``, its error
    there over what a correct model leaves), and the covariate its residuals follow beyond
    chance, if any (Bonferroni over the covariates)."""

    factor: float
    held_out: float
    floor_uncertainty: float
    covariate: str | None
    p_value: float


@dataclass(frozen=True)
class TimeDrift(_Written):
    """A bias drifting linearly in time within each temperature point: the rival no term can
    beat (:func:`.effects.time_drift`). ``rival_of``: a named term that fits the excess as
    well, so neither can be named."""

    validation_rms: float
    expected_rms: float
    explains: bool
    option: str
    config_line: str
    leftover: Leftover | None
    next_session: CarryOver | None
    rival_of: str | None = None


# How the verdict's sentence on a finding no term holds begins.
SENSOR_LEAD = "No term of the sensor can hold it"
FREE_SHAPE_LEAD = "No term of free shape can be offered"


@dataclass(frozen=True)
class Unexplained:
    """Why no term was offered, and what protocol would tell. ``lead`` is given for a
    finding no term of the sensor can hold (the lab, the mounting, between points); the
    others open with :data:`FREE_SHAPE_LEAD`, written after the rest."""

    reason: str
    term: str | None
    text: str
    would_tell: str
    lead: str | None = None

    @property
    def opening(self) -> str:
        return self.lead or FREE_SHAPE_LEAD

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"reason": self.reason, "term": self.term}
        if self.lead:
            out["lead"] = self.lead
        out.update(text=self.text, would_tell=self.would_tell)
        if not self.lead:
            out["lead"] = FREE_SHAPE_LEAD
        return out


@dataclass(frozen=True)
class Where:
    """Where the excess lives (question 2): the covariate table, its heat maps, the leading
    row (the first that takes a share of the excess) and a negligible excess's note."""

    covariates: list[CovariateRow]
    heatmaps: dict[str, Any]
    lead: CovariateRow | None
    negligible: Negligible | None


@dataclass(frozen=True)
class Approach(_Written):
    """The other session's errors against the direction each temperature point was reached
    from (:func:`.approach.direction_of_approach`): the points reached from the other side
    there and those reached the same way (°C), the step of the bias between the sides and
    the offset at every point (deg/s, per axis), the F-test of the step against the offset
    alone and the χ² tail of what the step leaves; ``explains``: the step is real and leaves
    nothing beyond chance. ``tied``: every point was reached from the other side, one way
    round, so the step and the offset are one (a turn-on bias would leave the same)."""

    points: list[float]
    same: list[float]
    shift: dict[str, float]
    offset: dict[str, float]
    p_value: float
    left_p_value: float
    explains: bool
    tied: bool = False
    left_within_bar: bool = False  # what is left beyond chance, within CARRIES_WITHIN x the holds' floor


@dataclass(frozen=True)
class Confound(_Written):
    """Two readings of the excess the protocol moves together (:mod:`.confounds`): what the
    fix reads and the rival input, the rival row's share of the excess, how tightly the
    protocol ties them (the share of holds one fixes the other for; for time and temperature
    the rank correlation of the holds' start times and temperatures), the best candidate of
    the rival reading that explains the data too (its term and validation RMS, deg/s; None
    where none does) and the protocol that would tell them apart."""

    reading: str
    rival: str
    share: float
    tied: float
    rival_term: str | None
    rival_rms: float | None
    would_tell: str
    tie: str  # how the protocol ties them, in words


@dataclass(frozen=True)
class FloorsDiffer(_Written):
    """The other session's noise floor against this one's, made the same way from each
    session's own static data: their ratio, and how far from 1 their own uncertainties let
    it be (three of their combined relative errors, :func:`.stats.floor_uncertainty`)."""

    ratio: float
    tolerance: float
    # The other session's floor the smaller, and its errors, failing against it, within
    # CARRIES_WITHIN times what a correct model leaves under this session's noise: the noise
    # this session's static data caught (a bias that jumps, bursts) is in the other's holds.
    covers_other: bool = False
