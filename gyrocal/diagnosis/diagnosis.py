"""The diagnosis of one session: every step's finding, built once (:func:`.steps.diagnose`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import pandas as pd

from .effects import Candidate
from .evaluation import Evaluation, LadderRow, add_term_option
from .findings import (
    Approach,
    BetweenPoints,
    Confound,
    FloorsDiffer,
    LabTest,
    MountingTest,
    Negligible,
    TimeDrift,
    Unexplained,
    WithinNoise,
)
from .grain import Grain
from .reading import readable
from .sessions import CarryOver
from .verdict import verdict
from .where import CovariateRow, ShapeEstimate


@dataclass(frozen=True)
class Diagnosis:
    """What the diagnosis found. ``rms_over_floor`` is the in-sample RMS ÷ floor; ``factor``,
    the verdict's "times their noise floor" (sqrt(χ²/dof) where the holds share slow
    wander). ``tolerance``: what a held-out error may be, in units of what a correct model
    leaves, and still be explained; ``noise_model``: the floor comes from the session's noise
    model; ``unrepeated``: the excess did not come back in the other session;
    ``noise_explains``: slow wander the static data cannot rule out accounts for it."""

    base: Evaluation
    significance: float
    chi2_red: dict[str, float]  # overall and per output axis
    rms_over_floor: dict[str, float]
    excess_p_value: float
    explains: bool
    covariates: list[CovariateRow]
    candidates: list[Candidate]
    best: Candidate | None
    partial: list[Candidate]
    heatmaps: dict[str, Any]
    residuals: pd.DataFrame  # observations + resid_, floor_, z_ per axis
    config_line: str  # the model: lines that add the best candidate
    ladder: list[LadderRow]
    within_noise: WithinNoise | None
    next_session: CarryOver | None  # the configured model on another session
    advice: list[str]
    time_drift: TimeDrift | None
    shape_estimate: ShapeEstimate | None  # the residuals against the leading input
    unexplained: Unexplained | None  # why no term was offered
    lab_fixed: LabTest | None
    mounting: MountingTest | None
    between_points: BetweenPoints | None
    factor: float
    negligible: Negligible | None
    one_way: dict[float, str] | None  # point (°C) -> the one direction it was reached in
    approach: Approach | None  # the other session's errors against the direction of approach
    confound: Confound | None  # the fix's input and another the protocol moves with it
    floors_differ: FloorsDiffer | None  # the two sessions' floors, where they differ
    grain: tuple[Grain, ...]  # the fix with each rate level, each mount left out in turn
    tolerance: float
    noise_model: bool
    unrepeated: bool
    noise_explains: bool
    # the shape that fit this session's excess and failed where the calibration carries over
    unrepeated_shape: str | None = None

    @cached_property
    def verdict(self) -> str:
        return verdict(self)

    def to_dict(self) -> dict[str, Any]:
        s = self.base.summary
        return {
            "format": "gyrocal.diagnosis/1",
            "model": {"terms": self.base.terms, "kind": self.base.kind},
            "validation_rms": s["validation_rms"],
            "noise_floor": s["noise_floor"],
            "excess": s["excess"],
            "expected_rms": s["expected_rms"],
            "excess_over_expected": s["excess_over_expected"],
            "held_out": s["held_out"],
            # points logged on their own, scored with their turn-on biases out
            # (gyrocal.fit.validate.own_power_ons): the validation's own figure, and how many
            **{k: s[k] for k in ("validation_rms_as_scored", "rezeroed_stretches") if k in s},
            # the curvature a point left out of too few points misses (.between.drift_chord)
            **({"drift_chord_rms": s["drift_chord_rms"]} if "drift_chord_rms" in s else {}),
            "significance": self.significance,
            "chi2_red": self.chi2_red,
            "rms_over_floor": self.rms_over_floor,
            "excess_p_value": self.excess_p_value,
            "explains_the_data": self.explains,
            "factor": self.factor,
            "verdict": self.verdict,
            "within_noise_uncertainty": _written(self.within_noise),
            "next_session": self.next_session,
            "advice": self.advice,
            "time_drift": _written(self.time_drift),
            "shape_estimate": self.shape_estimate,
            "unexplained": _written(self.unexplained),
            "lab_fixed": _written(self.lab_fixed),
            "mounting": _written(self.mounting),
            "between_points": _written(self.between_points),
            "negligible_excess": _written(self.negligible),
            "approach": _written(self.approach),
            "confound": _written(self.confound),
            "floors_differ": _written(self.floors_differ),
            "grain": [g.to_dict() for g in self.grain],
            "unrepeated": self.unrepeated,
            "unrepeated_shape": self.unrepeated_shape,
            "one_way_points": None
            if self.one_way is None
            else [{"temp": t, "direction": d} for t, d in self.one_way.items()],
            "best": None
            if self.best is None
            else {
                **self.best.to_dict(),
                "config_line": self.config_line,
                "option": " ".join(add_term_option(t) for t in (self.best.term, *self.best.together)),
            },
            "partial": [_partial_row(c) for c in self.partial],
            "candidates": [c.to_dict() for c in self.candidates],
            "covariates": self.covariates,
            "ladder": self.ladder,
        }


def _written(finding) -> dict[str, Any] | None:
    return None if finding is None else finding.to_dict()


def _partial_row(c: Candidate) -> dict[str, Any]:
    return {
        "term": c.term,
        "reads": readable(c.term, c.profiled),
        "validation_rms_with": c.validation_rms_with,
        "expected_rms_with": c.expected_with,
        "gain_pct": c.gain_pct,
        "remaining_excess": c.validation_rms_with / c.expected_with if c.expected_with else None,
        "part_of": c.part_of,
        "option": c.option,
        "config_line": c.config_line,
        "excess_taken": c.excess_taken,
        "offered": c.offered,
        "validated": c.validated,
        "family": c.family,
        "leftover": c.leftover,
        "next_session": c.next_session,
        **({"grain": c.grain.to_dict()} if c.grain is not None else {}),
    }
