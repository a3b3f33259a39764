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

from ..fit.model import columns_of
from ..fit.thermal import GridFit, diagonal, global_terms, interpolation_weights
from ..terms import AXES
from .findings import SENSOR_LEAD, BetweenPoints, Unexplained
from .stats import chi2_sf, p_text

# Points the interpolation reads at once: with one point left out, at least this many must
# remain, or the point is interpolated by a lower-order rule than the calibration uses (three
# points leave two: a line, where the calibration runs a parabola).
STENCIL = {"lagrange3": 3, "linear": 2, "spline": 4}


def _floor_factor(fit, names) -> np.ndarray:
    """Per coefficient, what brings a fit's covariance up to what the noise floor says: a
    fit's matrix is scaled by its own reduced χ², which a few holds estimate poorly and can
    put below 1 (square roots: the factor of a standard error)."""
    return np.sqrt(
        np.array(
            [
                max(1.0, fit.chi2[a] / fit.dof[a]) / (fit.chi2[a] / fit.dof[a]) if fit.chi2[a] > 0 else 1.0
                for a in (n.split(".")[1] for n in names)
            ]
        )
    )


def _floored(covariance: np.ndarray, fit, names) -> np.ndarray:
    """``covariance`` of coefficients ``names`` of ``fit`` (or mapped from it) at least as
    large as the noise floor says."""
    factor = _floor_factor(fit, names)
    return covariance * np.outer(factor, factor)


def _uncertainty(fit) -> np.ndarray:
    """A point fit's covariance at least as large as the noise floor says."""
    return _floored(fit.covariance, fit, fit.names)


class _Points:
    """What the test reads of a grid calibration: each point's coefficients and covariance
    as the calibration fitted them, and those the other points interpolate there.

    A grid fitted point by point (:class:`GridFit`): each point's own fit, and the others'
    fits interpolated (independent of it). A joint grid without global terms, each hold at
    its own temperature: each node's coefficients from the joint fit (its own holds weigh it
    nearly alone), and the grid fitted again without the point's holds. Fitted point by
    point, a hold taken off its point (warm after the chamber's door) would be read at the
    point and move its scale: the interpolation would then miss points that have no such
    holds, a failure of the fit, not of the sensor between points."""

    def __init__(self, fitted):
        self.fitted = fitted
        self.joint = not isinstance(fitted, GridFit)

    def own(self, point: int) -> tuple[np.ndarray, np.ndarray]:
        f = self.fitted.point_fit(point)
        if not self.joint:
            return f.values, _uncertainty(f)
        return f.values, _floored(f.covariance, self.fitted.fit, self.fitted.names)

    def others(self, point: int, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list] | None:
        """The others' coefficients at ``at`` and their covariance, with the interpolation's
        weights and the points they fall on."""
        loo = self.fitted.leave_out(point)
        if loo is None or loo.outside(at).any():
            return None
        values = loo.coefficients_at(at)[0]
        weights = loo.grid.weights(at)[0]
        if not self.joint:
            cov = np.einsum("p,pcd->cd", weights**2, np.array([_uncertainty(f) for f in loo.fits]))
        else:
            cov = _floored(loo.covariance_at(at)[0], loo.fit, loo.names)
        return values, cov, weights, list(loo.used_points())


def _points(fitted) -> _Points | None:
    """The test's view of ``fitted``; None where the points share coefficients (a model
    with global terms: no point's calibration is its own)."""
    if isinstance(fitted, GridFit):
        return _Points(fitted)
    if getattr(fitted, "point_ids", None) and not global_terms(fitted.model):
        return _Points(fitted)
    return None


def drift_chord(fitted, obs) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Where leaving a point out leaves fewer points than the calibration's stencil (three
    points leave two: a line where the calibration runs a parabola), what the calibration
    itself says that leave-out misses at the holds it scores: per hold, the calibration
    interpolated from the other points less the calibration from all of them, carried to
    the outputs by the model's columns (errors (n, 3)); the same difference's variance from
    the points' coefficient covariances (n, 3), the part of it the noise makes; and the
    holds the validation scores (inside the span of the points left in). Beyond the noise it
    is the temperature curvature every gyro has (seed 003 Eq 16's ΔT²), which such a
    leave-out judges by a rule the calibration does not use. None where the others leave
    the stencil whole or the model is off a grid."""
    grid = getattr(fitted, "grid", None)
    temps = None if grid is None else grid.temperatures
    if grid is None or len(temps) < 3 or len(temps) - 1 >= STENCIL.get(grid.method, grid.degree + 1):
        return None
    used = list(getattr(fitted, "point_ids", ()) or fitted.used_points())  # grid order
    if len(used) != len(temps):
        return None
    data = fitted.model.transform_inputs(columns_of(obs))
    point, temp = np.asarray(data["point"]).astype(int), np.asarray(data["temp"], float)
    design = fitted.model.design(data)
    n, names = len(temp), list(grid.names)
    x = np.column_stack([np.broadcast_to(np.asarray(design[c], dtype=float), (n,)) for c in names])
    mine = np.array([[AXES.index(c.split(".")[1]) == i for c in names] for i in range(len(AXES))])
    to_output = mine.T.astype(float)  # (C, 3): each coefficient's output axis
    cov = grid.covariance if grid.covariance is not None else diagonal(grid.stderr**2)
    errors, variance = np.zeros((n, len(AXES))), np.zeros((n, len(AXES)))
    use = np.zeros(n, dtype=bool)
    for p in np.unique(point):
        rows = np.flatnonzero(point == p)
        if int(p) not in used:  # a point the fit dropped is scored with the whole calibration
            use[rows] = ~grid.outside(temp[rows])
            continue
        k = used.index(int(p))
        others = np.arange(len(temps)) != k
        inside = (temp[rows] >= temps[others][0]) & (temp[rows] <= temps[others][-1])
        use[rows] = inside
        rows = rows[inside]
        if rows.size == 0:
            continue
        weights = np.zeros((rows.size, len(temps)))
        weights[:, others] = interpolation_weights(grid.method, temps[others], temp[rows], degree=grid.degree)
        weights -= grid.weights(temp[rows])
        delta = weights @ grid.values  # (rows, C): left out less whole
        errors[rows] = -(x[rows] * delta) @ to_output  # a coefficient too large takes its excess off
        for i in range(len(AXES)):
            xa = x[rows] * mine[i]
            variance[rows, i] = np.einsum("np,nc,pcd,nd->n", weights**2, xa, cov, xa)
    if not (np.all(np.isfinite(errors)) and np.all(np.isfinite(variance))):
        return None
    return errors, variance, use


def seating_variance(obs, mounting: np.ndarray, sigma: float) -> dict[int, np.ndarray]:
    """Per temperature point, the variance (rad²) the fixture's seating gives the misalignment
    fitted there against each axis' rate: σ² over the mountings at the point that turn that
    axis (each seats the unit at its own small rotation, independent of the others')."""
    if "point" not in obs:
        return {}
    rates = np.abs(obs[["rate_x", "rate_y", "rate_z"]].to_numpy(float)) > 0
    points, mounting = obs["point"].to_numpy(), np.asarray(mounting)
    out = {}
    for p in np.unique(points):
        at = points == p
        turning = np.array([np.unique(mounting[at & rates[:, j]]).size for j in range(3)])
        out[int(p)] = np.where(turning > 0, sigma**2 / np.maximum(turning, 1), 0.0)
    return out


def _with_seating(names, pick, own_cov, others_cov, point, weights, used, seating) -> tuple:
    """The two covariances with the fixture's seating on each misalignment's diagonal: the
    point's own mountings', and the other points' carried by the interpolation's weights."""
    if not seating:
        return own_cov, others_cov
    own_cov, others_cov = own_cov.copy(), others_cov.copy()
    for k in pick:
        part = names[k].split(".")
        if part[0] != "misalignment":
            continue
        j = AXES.index(part[2])
        own_cov[k, k] += seating.get(int(point), np.zeros(3))[j]
        others_cov[k, k] += float(
            sum(w**2 * seating.get(int(q), np.zeros(3))[j] for w, q in zip(weights, used, strict=True))
        )
    return own_cov, others_cov


def between_points(
    fitted, alpha: float, seating: dict[int, np.ndarray] | None = None
) -> BetweenPoints | None:
    """Per interior point, χ² of (fitted - interpolated) scale and misalignment against the
    sum of both covariances (the point's and the others' taken as independent); the largest,
    Bonferroni over the points, judged at ``alpha``/2. None for a model with global terms
    (its points share coefficients), or with no interior point to leave out.

    ``seating`` (:func:`seating_variance`): each mounting's own small rotation on the fixture
    moves the misalignment fitted at its point; a calibration meets it as part of the
    rig's scatter, so it joins the covariances (the interpolation carries the other points'
    by its weights squared)."""
    view = _points(fitted)
    if view is None:
        return None
    names = list(fitted.names)
    pick = [i for i, n in enumerate(names) if n.split(".")[0] in ("scale", "misalignment")]
    used = list(fitted.used_points())
    grid = fitted.grid
    stencil = STENCIL.get(grid.method, grid.degree + 1)
    if not pick or len(used) < stencil + 1:
        return None
    temps = fitted.points.set_index("point").loc[used, "temp"].to_numpy(dtype=float)
    points = []
    for p, temp in zip(used[1:-1], temps[1:-1], strict=False):
        at = np.array([temp])
        others = view.others(int(p), at)
        if others is None:
            continue
        own_values, own_cov = view.own(int(p))
        own_cov, others_cov = _with_seating(names, pick, own_cov, others[1], p, others[2], others[3], seating)
        diff = (own_values - others[0])[pick]
        cov = (own_cov + others_cov)[np.ix_(pick, pick)]
        if not (np.all(np.isfinite(diff)) and np.all(np.isfinite(cov))):
            continue
        # A coefficient held fixed has no variance: the pseudo-inverse leaves it out, and
        # the degrees of freedom are those left.
        rank = int(np.linalg.matrix_rank(cov))
        if rank == 0:
            continue
        chi2 = float(diff @ np.linalg.pinv(cov) @ diff)
        parts = {}
        for part in ("scale", "misalignment"):
            sub = [k for k, i in enumerate(pick) if names[i].split(".")[0] == part]
            sub_cov = cov[np.ix_(sub, sub)]
            sub_rank = int(np.linalg.matrix_rank(sub_cov)) if sub else 0
            parts[part] = (
                float(chi2_sf(float(diff[sub] @ np.linalg.pinv(sub_cov) @ diff[sub]), sub_rank))
                if sub_rank
                else 1.0
            )
        sd = np.sqrt(np.diag(cov))
        z = np.divide(diff, sd, out=np.zeros_like(diff), where=sd > 0)
        worst = int(np.argmax(np.abs(z)))
        points.append(
            {
                "temp": float(temp),
                "chi2": chi2,
                "dof": rank,
                "p_value": float(chi2_sf(chi2, rank)),
                "coefficient": names[pick[worst]],
                "difference": float(diff[worst]),
                "z": float(z[worst]),
                "scale_p_value": parts["scale"],
                "misalignment_p_value": parts["misalignment"],
            }
        )
    if not points:
        return None
    tested = len(points)
    for r in points:  # Bonferroni over the points
        for key in ("p_value", "scale_p_value", "misalignment_p_value"):
            r[key] = min(1.0, tested * r[key])
    top = min(points, key=lambda r: r["p_value"])
    return BetweenPoints(
        points=points,
        worst=top,
        p_value=top["p_value"],
        temperature_points=len(used),
        fails=bool(top["p_value"] < alpha / 2),
        failing=[r["temp"] for r in points if r["p_value"] < alpha / 2],
    )


OWN_POINT_SHARE = 0.9  # a mounting belongs to the point that holds this share of its holds


REVERSAL_SIGMAS = 3.0  # a step between neighbouring points this many standard errors is real


def reverses(fitted, coefficient: str) -> bool:
    """Whether ``coefficient``, fitted point by point, steps up and down across temperature:
    two steps between neighbouring points, each beyond :data:`REVERSAL_SIGMAS` of their
    combined uncertainty, of opposite sign. A warp past a transition moves it one way."""
    view = _points(fitted)
    if view is None:
        return False
    names = list(fitted.names)
    if coefficient not in names:
        return False
    k = names.index(coefficient)
    used = list(fitted.used_points())
    order = np.argsort(fitted.points.set_index("point").loc[used, "temp"].to_numpy(dtype=float))
    own = [view.own(int(used[i])) for i in order]
    values = np.array([v[k] for v, _ in own])
    var = np.array([c[k, k] for _, c in own])
    steps = np.diff(values)
    real = np.abs(steps) > REVERSAL_SIGMAS * np.sqrt(var[1:] + var[:-1])
    signs = np.sign(steps[real])
    return bool(signs.size > 1 and np.any(signs[1:] != signs[:-1]))


def tilted_per_point(
    check: BetweenPoints, alpha: float, mounting: np.ndarray, points: np.ndarray, fitted=None
) -> bool:
    """Whether what fails between the points is the misalignment alone, stepping up and down
    across temperature (:func:`reverses`; ``fitted``, the grid fit, where known), at points
    that each mount the unit anew (each mounting's holds, but for a stray one at a point's
    change, at one point). A fixture seats the unit at a slightly different tilt each time,
    and here each point has mountings of its own; a package warp past a transition tilts the
    sense axes too, but one way with temperature, and a package's stresses show in its scale."""
    failing = [r for r in check.points if r["p_value"] < alpha / 2]
    if not failing or any(
        r["scale_p_value"] < alpha / 2 or r["misalignment_p_value"] >= alpha / 2 for r in failing
    ):
        return False
    if fitted is not None and not reverses(fitted, check.worst["coefficient"]):
        return False
    mounting, points = np.asarray(mounting), np.asarray(points)
    if np.unique(points).size < 2:
        return False
    for stretch in np.unique(mounting):
        _, counts = np.unique(points[mounting == stretch], return_counts=True)
        if counts.max() < OWN_POINT_SHARE * counts.sum():
            return False
    return True


def tilted_reason(check: BetweenPoints) -> Unexplained:
    """The verdict's why, where the misalignment alone fails between points each mounted anew
    (:func:`tilted_per_point`)."""
    top = check.worst
    return Unexplained(
        reason="the mounting",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"the misalignment interpolated from the other points misses the one fitted at "
            f"{top['temp']:.0f} °C ({top['coefficient']} by {abs(top['z']):.3g} standard errors), "
            "while the scale meets its interpolation; it steps up and down across temperature, "
            "and every temperature point mounts the unit anew. A tilt the fixture gives each "
            "mounting reads so; a package warp would tilt the sense axes one way with "
            "temperature: the mounting's, which no term of the sensor carries to the next "
            "mounting (with one mounting per point the data cannot rule out the sensor's "
            "misalignment changing sharply between the points)"
        ),
        would_tell=(
            "one orientation mounted twice at a point, or the unit left on its mount across two "
            "points (a tilt changes with the mounting, the sensor's misalignment with the "
            "temperature)"
        ),
    )


def between_reason(check: BetweenPoints, held_out: float | None) -> Unexplained:
    """The verdict's why and what would tell, for a calibration that fails between points."""
    top = check.worst
    temps = ", ".join(f"{t:.0f}" for t in check.failing)
    error = (
        f"; left out, a point's holds err {held_out:.3g} times what a correct model would leave"
        if held_out is not None
        else ""
    )
    return Unexplained(
        reason="between temperature points",
        term=None,
        lead=SENSOR_LEAD,
        text=(
            f"the calibration does not hold between the temperature points (leaving out "
            f"the point at {top['temp']:.0f} °C, the one interpolated from the other "
            f"points misses its {top['coefficient']} by {abs(top['z']):.3g} standard errors "
            f"({top['difference']:.3g}; scale and misalignment together p "
            f"{p_text(check.p_value)}){error}). The sensor's scale or misalignment changes "
            f"between the points more than interpolation across {check.temperature_points} "
            "points follows: with temperature, more sharply than they resolve, or with "
            "time, since the points follow each other in time; a calibration per point "
            "absorbs either at the points themselves, so no term fitted to them shows it"
        ),
        would_tell=(
            f"more temperature points around {temps} °C (or a temperature sweep "
            "held at rates in both directions) and the first point revisited at "
            "the end of the session"
        ),
    )
