"""Between the temperature points: does the calibration interpolated from the other points
meet the one fitted at each point?

A calibration per temperature point absorbs any shape of temperature at the points
themselves, so the fit's residuals cannot show an effect that changes sharply between
them (a package warping past a glass transition). Leaving a point out can: the scale and
misalignment interpolated from the other points (seed 000 Eq 21-22) should meet those fitted
at the point within the two calibrations' uncertainties. The bias is left out of the test:
slow wander moves it between points by more than the floor of a hold says, while scale
and misalignment, seen in the difference of holds in both directions, are immune to it.
"""

from __future__ import annotations

import numpy as np

from .stats import chi2_sf, p_text


def between_points(fitted, alpha: float) -> dict | None:
    """Per interior point, χ² of (fitted - interpolated) scale and misalignment against the
    sum of both covariances; the largest, Bonferroni over the points, judged at ``alpha``/2.
    None for fits not made per point, or with no interior point left out."""
    if getattr(fitted, "kind", None) != "grid" or not hasattr(fitted, "point_fit"):
        return None
    names = list(fitted.names)
    pick = [i for i, n in enumerate(names) if n.split(".")[0] in ("scale", "misalignment")]
    used = list(fitted.used_points())
    if not pick or len(used) < 3:
        return None
    temps = fitted.points.set_index("point").loc[used, "temp"].to_numpy(dtype=float)
    points = []
    for p, temp in zip(used[1:-1], temps[1:-1]):
        loo = fitted.leave_out(int(p))
        at = np.array([temp])
        if loo is None or loo.outside(at).any():
            continue
        own = fitted.point_fit(int(p))
        diff = (own.values - loo.coefficients_at(at)[0])[pick]
        cov = (own.covariance + loo.covariance_at(at)[0])[np.ix_(pick, pick)]
        try:
            chi2 = float(diff @ np.linalg.solve(cov, diff))
        except np.linalg.LinAlgError:
            continue
        if not np.isfinite(chi2):
            continue
        z = diff / np.sqrt(np.diag(cov))
        worst = int(np.argmax(np.abs(z)))
        points.append({"temp": float(temp), "chi2": chi2, "dof": len(pick),
                       "coefficient": names[pick[worst]], "difference": float(diff[worst]),
                       "z": float(z[worst])})
    if not points:
        return None
    top = max(points, key=lambda r: r["chi2"])
    p_value = min(1.0, len(points) * float(chi2_sf(top["chi2"], top["dof"])))
    return {"points": points, "worst": top, "p_value": p_value, "temperature_points": len(used),
            "fails": bool(p_value < alpha / 2)}


def between_reason(check: dict, held_out: float | None) -> dict:
    """The verdict's why and what would tell, for a calibration that fails between points."""
    top = check["worst"]
    temps = ", ".join(f"{r['temp']:.0f}" for r in check["points"])
    error = (f"; left out, a point's holds err {held_out:.3g} times what a correct model would "
             "leave" if held_out is not None else "")
    return {"reason": "between temperature points", "term": None,
            "text": (f"the calibration does not hold between the temperature points (leaving out "
                     f"the point at {top['temp']:.0f} °C, the one interpolated from the other "
                     f"points misses its {top['coefficient']} by {abs(top['z']):.3g} standard errors "
                     f"({top['difference']:.3g}; scale and misalignment together p "
                     f"{p_text(check['p_value'])}){error}). The sensor's scale or misalignment changes "
                     f"between the points more than interpolation across {check['temperature_points']} "
                     "points follows: with temperature, more sharply than they resolve, or with "
                     "time, since the points follow each other in time; a calibration per point "
                     "absorbs either at the points themselves, so no term fitted to them shows it"),
            "would_tell": (f"more temperature points around {temps} °C (or a temperature sweep "
                           "held at rates in both directions) and the first point revisited at "
                           "the end of the session")}
