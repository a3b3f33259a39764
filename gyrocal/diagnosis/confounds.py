"""Inputs the protocol moves together, named beside the fix.

In a fixed rate order each rate is entered from the same one, so an effect of this hold's
rate (a range switch, a scale's curve) and one of the rate before it (a slow pole, heat
left by the last turn) group the holds alike: where-it-fails puts the excess on both, and
the data cannot say which. Where the temperature points are visited in the order of their
temperature, time since power-on and the temperature rise together in the same way. The
fix offered reads one; the verdict says the other reading fits the protocol as well where a
candidate of it explains the data too, and which protocol would tell them apart (another
rate order, another order of the temperature points).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .findings import Confound
from .where import SETTLING_ROW

TIED = 0.8  # the share of holds whose previous rate their own rate fixes, for a fixed order
TIED_IN_TIME = 0.9  # |rank correlation| of the holds' start times and temperatures
NAMED_SHARE = 0.1  # of the excess on the rival's row, below which it groups nothing worth naming
TEMPERATURE_ROWS = ("temperature",)
TIME_ROWS = ("time",)
PREVIOUS_ROW = "previous hold's rate"
OWN_RATE_ROWS = ("reference rate", "|rate|", "direction", "reference rate (own axis)", "|rate| (own axis)")
RATE_ORDER_WOULD_TELL = (
    "a session in another rate order (shuffled, or the rates visited in reverse) would tell "
    "them apart: an effect of the hold's own rate keeps its value at each rate, one of the "
    "rate before it moves with the order"
)


def temperature_order_would_tell(way: str) -> str:
    """The protocol change that tells time from temperature, given this session's order."""
    other = "rising" if way == "falling" else "falling"
    return (
        f"a session visiting the temperature points in another order ({other}, or out of order) "
        "would tell them apart: an effect of the temperature keeps its value at each point, one "
        "of time since power-on moves with the order"
    )


MOUNTING_WOULD_TELL = (
    "the other session, the unit mounted again, would tell them apart: an offset of the "
    "fixture comes anew with each mounting, the sensor's g-sensitivity stays; so would "
    "mounting each orientation again at another temperature point, or six mounts"
)
MOUNT_ROWS = ("mount", "mounting", "rotating axis")
JUDGED_BY_A_LEFT_OUT_MOUNT = 4  # mounts from which one can be left out of a fix on the rest


def rate_order_tie(obs: pd.DataFrame, data: dict, previous: np.ndarray) -> float:
    """The share of holds whose previous rate on the same mounting (``previous``,
    :func:`.where.history_columns`) is the one most often before their own rate on their
    turning axis: 1 where the order is fixed, about the inverse of the number of rates where
    it is shuffled."""
    axis = obs["axis"].astype(str).to_numpy() if "axis" in obs else np.zeros(len(obs), dtype=str)
    frame = pd.DataFrame(
        {"axis": axis, "rate": np.round(data["ref_rate"], 3), "previous": np.round(previous, 3)}
    )
    counts = frame.groupby(["axis", "rate", "previous"]).size()
    most = counts.groupby(level=["axis", "rate"]).max().sum()
    return float(most / max(len(frame), 1))


def _reads_history(term: str) -> bool:
    return "lag(" in term


def rate_order_confound(obs, data, best, candidates, covariates, alpha: float, previous) -> Confound | None:
    """Where the fix reads the rate (or its history) in a protocol whose rate order ties each
    rate to the one before it (:func:`rate_order_tie` of :data:`TIED` or more) and
    where-it-fails puts part of the excess on the other reading's rows: that reading, the
    best candidate of it that explains the data too (if any), and what would tell. Not
    where the fix reads the history and the output settles within its holds (beyond
    ``alpha``/2): an effect of the hold's own rate does not."""
    from .verdict import term_reads

    if best is None or "rate" not in term_reads(best.term):
        return None
    history = _reads_history(best.term)
    if history and any(r["covariate"] == SETTLING_ROW and r["p_value"] < alpha / 2 for r in covariates):
        return None  # the output settles within its holds: only the history reading does that
    names = OWN_RATE_ROWS if history else (PREVIOUS_ROW,)
    rows = [r for r in covariates if set(r["covariate"].split(" = ")) & set(names)]
    share = max((r.get("share_of_excess") or 0.0 for r in rows), default=0.0)
    if not share >= NAMED_SHARE:
        return None
    tie = rate_order_tie(obs, data, previous)
    if tie < TIED:
        return None
    rivals = [
        c
        for c in candidates
        if c.status == "ranked"
        and c.explains_excess
        and "rate" in term_reads(c.term)
        and _reads_history(c.term) != history
    ]
    rival = min(rivals, key=lambda c: c.validation_rms_with) if rivals else None
    return Confound(
        reading="the rate before the hold" if history else "the hold's own rate",
        rival="the hold's own rate" if history else "the rate before the hold",
        share=float(share),
        tied=tie,
        rival_term=rival.term if rival else None,
        rival_rms=float(rival.validation_rms_with) if rival else None,
        would_tell=RATE_ORDER_WOULD_TELL,
        tie=f"in this protocol's rate order {tie:.0%} of the holds are entered from the same rate",
    )


def time_temperature_tie(data: dict) -> float:
    """The rank correlation of the holds' start times and temperatures: ±1 where the points
    are visited in the order of their temperature, near 0 out of order or up and down."""
    t, temp = (pd.Series(np.asarray(data[k], dtype=float)) for k in ("t_start", "temp"))
    if len(t) < 3 or t.nunique() < 2 or temp.nunique() < 2:
        return 0.0
    rho = t.corr(temp, method="spearman")
    return float(rho) if np.isfinite(rho) else 0.0


def time_temperature_confound(data, best, candidates, covariates) -> Confound | None:
    """Where the fix reads time since power-on and not the temperature (or the other way
    round), the points are visited in the order of their temperature (|ρ| of
    :data:`TIED_IN_TIME` or more) and where-it-fails puts part of the excess on the other
    one's row: that reading, its best candidate that explains the data too, and what would
    tell."""
    from .verdict import term_inputs, term_reads

    if best is None:
        return None
    reads = term_reads(best.term)
    on_time = "t" in term_inputs(best.term) and not reads & {"temperature", "thermal"}
    on_temperature = "temperature" in reads and "time" not in reads
    if not (on_time or on_temperature):
        return None
    names = TEMPERATURE_ROWS if on_time else TIME_ROWS
    rows = [r for r in covariates if set(r["covariate"].split(" = ")) & set(names)]
    share = max((r.get("share_of_excess") or 0.0 for r in rows), default=0.0)
    rho = time_temperature_tie(data)
    if not share >= NAMED_SHARE or abs(rho) < TIED_IN_TIME:
        return None
    rival_kind = "temperature" if on_time else "time"
    rivals = [
        c
        for c in candidates
        if c.status == "ranked"
        and c.explains_excess
        and rival_kind in term_reads(c.term)
        and not ({"time"} if on_time else {"temperature"}) & term_reads(c.term)
    ]
    rival = min(rivals, key=lambda c: c.validation_rms_with) if rivals else None
    way = "rising" if rho > 0 else "falling"
    return Confound(
        reading="time since power-on" if on_time else "the temperature",
        rival="the temperature" if on_time else "time since power-on",
        share=float(share),
        tied=abs(rho),
        rival_term=rival.term if rival else None,
        rival_rms=float(rival.validation_rms_with) if rival else None,
        would_tell=temperature_order_would_tell(way),
        tie=f"in this session the temperature points are visited {way} (rank correlation of time "
        f"and temperature {rho:+.2f})",
    )


def mounting_confound(obs, best, covariates, stretch, other_session: bool) -> Confound | None:
    """Where the fix reads the specific force, this session mounts each of its (fewer than
    :data:`JUDGED_BY_A_LEFT_OUT_MOUNT`) mounts once (``stretch``: each hold's mounting,
    :func:`.where.history_columns`) and no other session judged the fix: the specific force
    then takes one value per mounting, so an offset the fixture gave each mounting fits as
    well as the fix, and none of the protocol's holds can tell which. Nothing of the sensor
    carries the fixture's reading, so it has no rival term."""
    from .verdict import term_reads

    if best is None or other_session or "mount" not in obs or "accel" not in term_reads(best.term):
        return None
    mounts = obs["mount"].astype(str).nunique()
    mountings = int(np.unique(np.asarray(stretch)).size)
    if mounts >= JUDGED_BY_A_LEFT_OUT_MOUNT or mountings > mounts:
        return None
    rows = [r for r in covariates if set(r["covariate"].split(" = ")) & set(MOUNT_ROWS)]
    share = max((r.get("share_of_excess") or 0.0 for r in rows), default=0.0)
    if not share >= NAMED_SHARE:
        return None
    return Confound(
        reading="the specific force",
        rival="the mounting",
        share=float(share),
        tied=1.0,
        rival_term=None,
        rival_rms=None,
        would_tell=MOUNTING_WOULD_TELL,
        tie=f"in this session each of the {mounts} mounts is mounted once and the specific force "
        "takes one value on each",
    )
