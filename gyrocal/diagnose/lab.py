"""An effect fixed in the lab, seen through the turning table.

A field that does not turn with the table (the Earth's rotation's horizontal part, a
motor's stray field, a table tilted off the vertical) reaches the sensor's axes as the
cosine and sine of the table's angle, with weights that depend on the mount. Over whole
turns it averages out; over a hold of a fraction of a turn, or at rest, it does not. No
term of the sensor describes it: where the table stood when the session began is not in
the log, so a fit of it does not carry over to another session. The diagnosis tests for
it so that it can say so, rather than call it noise or an effect of the rate.
"""

from __future__ import annotations

import numpy as np

from .stats import chi2_sf, f_sf, p_text


def angle_means(obs) -> np.ndarray:
    """(n, 2): each hold's mean cosine and sine of the table's angle, from its angle at the
    hold's start and its constant rate over its duration."""
    start = np.radians(obs["table_angle"].to_numpy(dtype=float))
    turn = np.radians(obs["ref_rate"].to_numpy(dtype=float) * obs["duration"].to_numpy(dtype=float))
    # The mean of cos and sin over [θ₀, θ₀ + φ] is their value at mid-hold times
    # sin(φ/2) / (φ/2): no cancellation for a hold that hardly turns, exact at rest.
    middle = start + turn / 2
    shrink = np.sinc(turn / (2 * np.pi))
    cos_mean, sin_mean = np.cos(middle) * shrink, np.sin(middle) * shrink
    return np.column_stack([cos_mean, sin_mean])


def lab_fixed(obs, quality, dof: int, alpha: float) -> dict | None:
    """How much of the in-sample excess the table's angle accounts for: each output axis'
    whitened residuals in each mount regressed on the holds' mean cosine and sine of the
    angle (two coefficients per mount and axis), with an F-test against the residuals left
    and a χ² test of what is left. None where the log gives no angle or too few holds."""
    if "table_angle" not in obs or "mount" not in obs:
        return None
    rows = quality.fitted_rows
    z = quality.z[rows]
    floor = quality.floor[rows]
    angle = angle_means(obs)[rows]
    mounts = np.unique(obs["mount"].astype(str).to_numpy()[rows], return_inverse=True)[1]
    points = np.unique(obs["point"].to_numpy()[rows], return_inverse=True)[1] \
        if "point" in obs else np.zeros(len(z), dtype=int)
    # The angle's columns beside each temperature point's bias and rates, as the base model
    # has them, so that what the point's fit took of the effect is counted back: refitted,
    # not the residuals alone regressed.
    rates = np.column_stack([np.ones(len(z)), obs.loc[rows, ["rate_x", "rate_y", "rate_z"]].to_numpy(float)])
    own = np.zeros((len(z), 4 * (points.max() + 1)))
    for k in range(4):
        own[np.arange(len(z)), 4 * points + k] = rates[:, k]
    lab = np.zeros((len(z), 2 * (mounts.max() + 1)))
    for k in range(2):
        lab[np.arange(len(z)), 2 * mounts + k] = angle[:, k]
    before = float(np.nansum(z ** 2))
    gain, q = 0.0, 0
    for i in range(z.shape[1]):
        ok = np.isfinite(z[:, i])
        base = own[ok] / floor[ok, i, None]
        both = np.column_stack([base, lab[ok] / floor[ok, i, None]])
        rank_base, rank_both = np.linalg.matrix_rank(base), np.linalg.matrix_rank(both)
        if rank_both <= rank_base:
            continue
        coef = np.linalg.lstsq(both, z[ok, i], rcond=None)[0]
        kept = np.linalg.lstsq(base, z[ok, i], rcond=None)[0]
        gain += float(np.sum((z[ok, i] - base @ kept) ** 2) - np.sum((z[ok, i] - both @ coef) ** 2))
        q += rank_both - rank_base
    left_dof = dof - q
    if q == 0 or left_dof <= 0:
        return None
    after = before - gain
    f = (gain / q) / (after / left_dof)
    p_value = float(f_sf(f, q, left_dof))
    left_p = float(chi2_sf(after, left_dof))
    excess = max(before - dof, 0.0)
    return {"p_value": p_value, "parameters": int(q), "chi2_before": before, "chi2_after": after,
            "dof": int(left_dof), "share_of_excess": min(gain / excess, 1.0) if excess > 0 else 0.0,
            "left_p_value": left_p,
            "explains": bool(p_value < alpha / 2 and left_p >= alpha / 2)}


def lab_reason(lab: dict) -> dict:
    """The verdict's why and what would tell, for an excess the table's angle explains."""
    return {"reason": "fixed in the lab", "term": None,
            "text": (f"the residuals follow the table's angle ({100 * lab['share_of_excess']:.0f} % of "
                     f"the excess with its cosine and sine in each mount, F-test p "
                     f"{p_text(lab['p_value'])}): an effect fixed in the lab and seen through the "
                     "turning table (the Earth's rotation, a stray field of the motor, a table "
                     "tilted off the vertical), not one of the sensor; where the table stood "
                     "when the session began is not in the log, so nothing fitted to it here "
                     "holds on another session"),
            "would_tell": ("holds lasting whole turns at every rate, over which it averages out, "
                           "or the table's angle logged from its encoder")}
