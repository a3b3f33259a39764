"""A fix judged at the grain the protocol allows.

Leaving temperature points out tells whether a calibration carries between temperatures.
A term of the rate must also carry to a rate the fit never saw, and one of the orientation
to a mount it never saw: each interior rate level (|ω|; the lowest and highest are ends a
shape would extrapolate to) and each mount is left out in turn, the model refitted on the
rest, and the holds left out scored as the validation scores a held-out point. A mount
whose absence leaves an axis unexcited (three mounts) cannot be left out: the protocol
does not allow that grain, and it is not judged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ..fit.model import Model, columns_of
from ..fit.thermal import fit_model
from ..fit.validate import held_out_errors
from ..io.errors import GyrocalError
from ..pipeline.config import Settings
from .findings import _Written
from .sessions import CARRIES_WITHIN  # the bar a fix meets on data it never saw

MIN_LEVELS = 4  # below this, leaving an interior level out leaves too little to fit a shape


@dataclass(frozen=True)
class Grain(_Written):
    """The configured model's and the fix's error on the holds of a group they never saw,
    each a pooled RMS ÷ the same holds' floor, over ``groups`` groups left out in turn."""

    by: str  # "rate level" or "mount"
    groups: int
    holds: int
    base: float
    fix: float | None  # None: the fix cannot be fitted without a group (a table of the levels)

    @property
    def carries(self) -> bool:
        """The fix leaves the groups it never saw within :data:`CARRIES_WITHIN` times their
        floor."""
        return self.fix is not None and self.fix <= CARRIES_WITHIN

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "carries": self.carries}


def _groups(obs: pd.DataFrame, by: str) -> tuple[np.ndarray, list] | None:
    if by == "mount":
        if "mount" not in obs:
            return None
        labels = obs["mount"].astype(str).to_numpy()
        left_out = sorted(set(labels))
        return (labels, left_out) if len(left_out) > 3 else None
    labels = np.round(np.abs(obs["ref_rate"].to_numpy(dtype=float)), 3)
    levels = np.unique(labels)
    if len(levels) < MIN_LEVELS:
        return None
    return labels, list(levels[1:-1])


def at_profiled(model: Model, profiled) -> Model:
    """``model`` with its nonlinear settings at the values a fit of every hold found
    (``profiled``: its entries, each with its term's label or name, parameter and value)."""
    values = {(p["term"], p["parameter"]): p["value"] for p in profiled or ()}
    terms = []
    for term in model.terms:
        key = getattr(term, "label", None) or term.name
        found = {name: values[key, name] for name in term.nonlinear() if (key, name) in values}
        terms.append(term.with_settings(**found) if found else term)
    return Model(tuple(terms))


def left_out_rms(
    settings: Settings, obs: pd.DataFrame, labels: np.ndarray, left_out: list, profiled=()
) -> float | None:
    """RMS ÷ floor of each group's holds under the model fitted without that group; None
    where a group cannot be left out (what remains does not determine the model). A shape's
    nonlinear settings (a place, a width, a time constant) stay where the fit of every hold
    put them (``profiled``); its size and every other coefficient are refitted without the
    group."""
    m = settings.model
    options = {"kind": m.kind, "method": m.interpolation, "degree": m.degree}
    errors, floors = [], []
    model = at_profiled(m.build(), profiled)
    for group in left_out:
        out = labels == group
        try:
            fitted = fit_model(model, obs[~out], **options, profile=False)
            err, floor = held_out_errors(fitted, columns_of(obs[out]))
        except (GyrocalError, np.linalg.LinAlgError, ValueError):
            return None
        errors.append(err)
        floors.append(floor)
    err, floor = np.concatenate(errors), np.concatenate(floors)
    if not (np.isfinite(err).all() and floor.size):
        return None
    return float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(floor**2)))


def at_the_grain(
    settings: Settings, fixed: Settings, obs: pd.DataFrame, by: str, profiled=()
) -> Grain | None:
    """The configured model (``settings``) and the fix (``fixed``, its nonlinear settings as
    ``profiled`` found them) judged leaving out each group ``by`` (``"rate level"`` or
    ``"mount"``) in turn; None where the protocol does not allow it."""
    grouped = _groups(obs, by)
    if grouped is None:
        return None
    labels, left_out = grouped
    base = left_out_rms(settings, obs, labels, left_out)
    if base is None:
        return None
    fix = left_out_rms(fixed, obs, labels, left_out, profiled)
    return Grain(by, len(left_out), int(np.isin(labels, left_out).sum()), base, fix)


def grains(settings: Settings, fixed: Settings, obs: pd.DataFrame, profiled=()) -> tuple[Grain, ...]:
    """The fix at each grain the protocol allows."""
    found = (at_the_grain(settings, fixed, obs, by, profiled) for by in ("rate level", "mount"))
    return tuple(g for g in found if g is not None)


def grain_sentence(grain: Grain) -> str:
    """What leaving each group out says of the fix, for the verdict."""
    what = "one rate level" if grain.by == "rate level" else "one mount"
    if grain.fix is None:
        return (
            f" Left out {what} at a time, the fix cannot be fitted: it holds a value per "
            f"{grain.by} and says nothing of one it never saw (the configured model leaves "
            f"{grain.base:.3g} times the floor there); a shape of the same input would."
        )
    text = (
        f" Left out {what} at a time, the fix leaves {grain.fix:.3g} times the floor on the "
        f"holds it never saw (the configured model {grain.base:.3g})"
    )
    if grain.carries:
        return text + "."
    between = "rates between the levels" if grain.by == "rate level" else "another mount"
    return text + f": it does not carry to a {grain.by} it never saw; holds at {between} would pin it."
