"""The hand-rotation protocol (Ferraris) as a registered :class:`gyrocal.protocols.registry.Protocol`.

Its faces and turns are holds of the common schema (:mod:`gyrocal.protocols.ferraris.segment`), so
the calibration file is the common 12-parameter model fitted at the session's temperature:
the bias from the six faces, each column of ``K`` from the turn about that axis, the
accelerometer-read terms (``--add-term g_sensitivity``) from the faces' gravity. Validation
is the common one for a single temperature: each face is compensated by the fit of the
others; a turn is the only observation of its column, so it is scored in-sample.

The report also shows Ferraris' own closed-form equations on the same observations
(:func:`closed_form`) and every turn's integrated angle before and after compensation."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict

import numpy as np

from ...terms import AXES
from ..registry import OwnAnalysis, Protocol, SettingsView, register
from .defaults import DEFAULTS

# The report reads this module for its sections and figure: what segmentation, the fits
# and their tables import (pandas, the log reader) is imported where they run.
if TYPE_CHECKING:
    import pandas as pd

    from ...io.holds import Segmentation
    from ...io.log import RigLog


class ClosedForm(NamedTuple):
    """Ferraris' parameters (``w = K w_true + B + K_ga f``), in deg/s and deg/s/g."""

    K: np.ndarray  # 3×3: scale and cross-axis
    B: np.ndarray  # 3: bias
    K_ga: np.ndarray | None  # 3×3 acceleration sensitivity, None without the gravity terms


def closed_form(obs: pd.DataFrame, *, gravity_terms: bool = True) -> ClosedForm:
    """Ferraris' estimator on the faces and turns, as imucal computes it.

    Gyro bias: the mean of the six faces' means. Acceleration sensitivity (with
    ``gravity_terms``): ``K_ga = (U_p − U_a) / 2``, per g, from opposite faces. Each column
    of ``K``: the turn's integral of the output, less the bias and the sensitivity times its
    mean specific force, over the known angle."""
    from ...io.log import FACES, TURNS

    face = {r.section: r for r in obs[obs["phase"] == "face"].itertuples()}
    turn = {r.section: r for r in obs[obs["phase"] == "turn"].itertuples()}
    mean = lambda r: np.array([r.gyro_x, r.gyro_y, r.gyro_z])  # noqa: E731
    B = np.mean([mean(face[f]) for f in FACES], axis=0)
    K_ga = None
    if gravity_terms:
        K_ga = np.column_stack([(mean(face[f"{a}_p"]) - mean(face[f"{a}_a"])) / 2.0 for a in AXES])
    K = np.empty((3, 3))
    for j, label in enumerate(TURNS):
        r = turn[label]
        offset = B.copy()
        if K_ga is not None and hasattr(r, "accel_x"):
            offset = offset + K_ga @ np.array([r.accel_x, r.accel_y, r.accel_z])
        K[:, j] = (mean(r) - offset) * r.duration / r.angle
    return ClosedForm(K, B, K_ga)


def turn_angles(obs: pd.DataFrame, K: np.ndarray, B: np.ndarray, K_ga=None) -> pd.DataFrame:
    """Each turn's angle about its axis as the raw output integrates it and as compensated
    (``K⁻¹ (w − B − K_ga f)`` integrated over the turn), against the known angle."""
    import pandas as pd

    turns = obs[obs["phase"] == "turn"]
    rows = []
    Kinv = np.linalg.inv(K)
    for r in turns.itertuples():
        j = AXES.index(r.section[0])
        w = np.array([r.gyro_x, r.gyro_y, r.gyro_z])
        offset = B + (K_ga @ np.array([r.accel_x, r.accel_y, r.accel_z]) if K_ga is not None else 0.0)
        compensated = Kinv @ (w - offset) * r.duration
        rows.append(
            {
                "turn": r.section,
                "known_deg": float(r.angle),
                "raw_deg": float(w[j] * r.duration),
                "compensated_deg": float(compensated[j]),
                # read minus known in magnitude: + reads too much of a turn
                "error_raw_deg": float(abs(w[j] * r.duration) - abs(r.angle)),
                "error_deg": float(abs(compensated[j]) - abs(r.angle)),
                "off_axis_deg": float(np.hypot(*np.delete(compensated, j))),
            }
        )
    return pd.DataFrame(rows)


class FerrarisAnalysis(TypedDict):
    """Ferraris' closed form beside the common fit (JSON-plain, for the report)."""

    protocol: str
    method: str
    K: list[list[float]]
    B: list[float]
    K_ga: list[list[float]] | None
    turns: list[dict[str, Any]]  # every turn's angle, raw and compensated (turn_angles)
    faces: list[dict[str, Any]]  # section, t_start, t_end, n of each face


def ferraris_analysis(obs: pd.DataFrame) -> FerrarisAnalysis:
    """Ferraris' closed form beside the common fit, for the report: its parameters and every
    turn's angle, uncompensated and compensated by it."""
    cf = closed_form(obs, gravity_terms="accel_x" in obs)
    angles = turn_angles(obs, cf.K, cf.B, cf.K_ga)
    return {
        "protocol": "ferraris",
        "method": "Ferraris closed form (as imucal computes it)",
        "K": cf.K.tolist(),
        "B": cf.B.tolist(),
        "K_ga": None if cf.K_ga is None else cf.K_ga.tolist(),
        "turns": angles.to_dict(orient="records"),
        "faces": obs.loc[obs["phase"] == "face", ["section", "t_start", "t_end", "n"]].to_dict(
            orient="records"
        ),
    }


class Ferraris(Protocol):
    name = "ferraris"
    description = "hand rotations: six static faces and a full turn about each axis (Ferraris)"
    defaults = DEFAULTS
    report_section = "protocols/ferraris_section.html.j2"
    without = ("temp", "ref_rate")
    one_temperature = True

    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        from .segment import segment_ferraris

        return segment_ferraris(log, settings.protocol_options("ferraris"))

    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        """The static faces: where the unit lay still."""
        faces = seg.observations[seg.observations["phase"] == "face"]
        return faces["t_start"].to_numpy(float), faces["t_end"].to_numpy(float)

    def analysis(self, obs: pd.DataFrame) -> OwnAnalysis:
        return OwnAnalysis(ferraris_analysis(obs), [])


FERRARIS = register(Ferraris())
