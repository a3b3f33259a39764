"""Where a calibration fails on the other session only at the temperature points reached from
the other side: a bias that depends on the direction the temperature came from.

Within one session each point is reached one way, so its bias holds the hysteresis and no
term of that session can see it; a second session that reaches some points from the other
side moves their bias by twice the hysteresis, and the others not at all. The configured
model's calibration is carried to the other session and each point's mean error there (per
output axis, weighted by the holds' floors) is compared with two readings: one offset for
every point (the unit's bias changed between power-ons) and that offset plus a step where
the direction of approach differs. The second reading is the finding where it fits within
chance and the first does not (F-test).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..fit.model import columns_of
from ..terms import AXES
from .findings import Approach
from .sessions import CARRIES_WITHIN, POINT_MATCH
from .stats import chi2_sf, f_sf
from .where import one_way_points


def _point_means(other: pd.DataFrame, errors: np.ndarray, floor: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each point's weighted mean error per axis and its standard error, with the point's
    temperature and label."""
    points = np.asarray(other["point"])
    labels, temps, means, errs = [], [], [], []
    for p in np.unique(points):
        rows = points == p
        w = 1.0 / floor[rows] ** 2
        ok = np.isfinite(errors[rows]) & np.isfinite(w)
        w = np.where(ok, w, 0.0)
        total = w.sum(axis=0)
        if not np.all(total > 0):
            continue
        labels.append(p)
        temps.append(float(np.median(other["temp"].to_numpy(float)[rows])))
        means.append((np.where(ok, errors[rows], 0.0) * w).sum(axis=0) / total)
        errs.append(1.0 / np.sqrt(total))
    return np.array(temps), np.array(means), np.array(errs), np.array(labels)


def _within_the_bar(other, labels, change, offset, shift, errors, floor) -> bool:
    """Whether the other session's holds, less the offset and the step of their point's
    direction (``change`` at the points ``labels``), err within
    :data:`.sessions.CARRIES_WITHIN` times their floor: a point mean of hundreds of holds
    resolves what no hold would feel."""
    points = np.asarray(other["point"])
    step = np.zeros(len(other))
    for p, c in zip(labels, change, strict=True):
        step[points == p] = c
    left = errors - offset[None, :] - step[:, None] * shift[None, :]
    ok = np.all(np.isfinite(left), axis=1) & np.all(np.isfinite(floor), axis=1)
    if not ok.any():
        return False
    return bool(np.sqrt(np.mean(left[ok] ** 2)) <= CARRIES_WITHIN * np.sqrt(np.mean(floor[ok] ** 2)))


def _tied(temps, means, errs, change: float, alpha: float) -> Approach:
    """Every point reached from the other side, the same way round: the step is one offset
    at every point. It explains the failure where that offset is real (against none) and
    leaves nothing beyond chance; a bias the unit took at power-on would leave the same."""
    w = 1.0 / errs**2
    offset = (means * w).sum(axis=0) / w.sum(axis=0)
    left = float(np.sum(((means - offset) / errs) ** 2))
    none = float(np.sum((means / errs) ** 2))
    dof = means.size - len(AXES)
    p = float(chi2_sf(none - left, len(AXES)))
    left_p = float(chi2_sf(left, dof)) if dof > 0 else 1.0
    points = [float(np.round(t, 1)) for t in temps]
    return Approach(
        points=points,
        same=[],
        shift={a: float(offset[i] / change) for i, a in enumerate(AXES)},
        offset={a: 0.0 for a in AXES},
        p_value=p,
        left_p_value=left_p,
        explains=p < alpha / 2 and left_p >= alpha / 2,
        tied=True,
    )


def direction_of_approach(
    obs: pd.DataFrame,
    other: pd.DataFrame,
    errors: np.ndarray,
    floor: np.ndarray,
    alpha: float,
    here: dict[float, str] | None,
) -> Approach | None:
    """The finding where the configured model's errors on ``other`` (``errors``, ``floor``:
    per hold, :func:`gyrocal.fleet.drift.hold_errors`) step with the direction each point
    was reached from, which differs between the sessions at some points and not at others;
    None where the sessions cannot show it (a point reached both ways within a session, or no
    point whose direction differs); where every point's differs the same way round, the
    step and an offset are one (:func:`_tied`). ``here``: this session's
    :func:`.where.one_way_points`."""
    ways = [here, one_way_points(other, columns_of(other))]
    if ways[0] is None or ways[1] is None or "point" not in other:
        return None
    temps, means, errs, labels = _point_means(other, errors, floor)
    before = np.array(list(ways[0]))
    change = np.full(len(temps), np.nan)
    for i, t in enumerate(temps):
        k = int(np.argmin(np.abs(before - t))) if before.size else -1
        here = min(ways[1], key=lambda u: abs(u - t))
        if k >= 0 and abs(before[k] - t) <= POINT_MATCH and abs(here - t) <= POINT_MATCH:
            change[i] = (ways[1][here] - ways[0][float(before[k])]) / 2.0  # -1, 0 or +1
    known = np.isfinite(change)
    if known.sum() >= 3 and np.all(change[known] == change[known][0]) and change[known][0] != 0:
        return _tied(temps[known], means[known], errs[known], float(change[known][0]), alpha)
    if known.sum() < 3 or not (np.any(change[known] != 0) and np.any(change[known] == 0)):
        return None
    temps, means, errs, labels, change = temps[known], means[known], errs[known], labels[known], change[known]
    chi2 = {}
    shift = np.zeros(len(AXES))
    offset = np.zeros(len(AXES))
    for reading, columns in (
        ("offset", [np.ones_like(change)]),
        ("direction", [np.ones_like(change), change]),
    ):
        total = 0.0
        for a in range(len(AXES)):
            x = np.column_stack(columns) / errs[:, a : a + 1]
            y = means[:, a] / errs[:, a]
            beta, *_ = np.linalg.lstsq(x, y, rcond=None)
            total += float(np.sum((y - x @ beta) ** 2))
            if reading == "direction":
                offset[a], shift[a] = beta
        chi2[reading] = total
    n, k0, k1 = means.size, len(AXES), 2 * len(AXES)
    if n <= k1:
        return None
    f = ((chi2["offset"] - chi2["direction"]) / (k1 - k0)) / (chi2["direction"] / (n - k1))
    p = float(f_sf(f, k1 - k0, n - k1))
    left = float(chi2_sf(chi2["direction"], n - k1))
    # beyond chance in the points' means may still be within what a hold may err
    within = left < alpha / 2 and _within_the_bar(other, labels, change, offset, shift, errors, floor)
    return Approach(
        points=[float(np.round(t, 1)) for t, c in zip(temps, change, strict=True) if c != 0],
        same=[float(np.round(t, 1)) for t, c in zip(temps, change, strict=True) if c == 0],
        shift={a: float(shift[i]) for i, a in enumerate(AXES)},
        offset={a: float(offset[i]) for i, a in enumerate(AXES)},
        p_value=p,
        left_p_value=left,
        explains=p < alpha / 2 and (left >= alpha / 2 or within),
        left_within_bar=within,
    )
