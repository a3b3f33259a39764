"""The servo protocol (seed 001) as a registered :class:`gyrocal.protocols.registry.Protocol`: whole
revolutions of six hand-mounted rotations as observations; the calibration file holds the
paper's six-parameter fit (Algorithm 1, Levenberg–Marquardt beside it), validated by
leaving revolutions out."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict

import numpy as np

from ...fit.floor import quiet_runs
from ...fit.model import observation_floor
from ...terms import AXES
from ..registry import OwnAnalysis, Protocol, SettingsView, checked_options, register
from .defaults import DEFAULTS

# The report reads this module for its sections and figure: what segmentation, the fits
# and their tables import (pandas, the log reader) is imported where they run.
if TYPE_CHECKING:
    import pandas as pd

    from ...calibration.file import Calibration
    from ...fit.validate import Validation
    from ...io.holds import Segmentation
    from ...io.log import RigLog


def _temperature_slopes(log: RigLog, t_start: np.ndarray, t_end: np.ndarray) -> np.ndarray:
    """Least-squares temperature slope (°C/min) over each [t_start, t_end] sample range."""
    from ...io.holds import range_sums, regression_rate

    t = log.column("t")
    lo = np.searchsorted(t, t_start, side="left")
    hi = np.searchsorted(t, t_end, side="right")
    return regression_rate(range_sums(t, log.column("temp"), lo, hi))


def segment_servo(log: RigLog, options: dict) -> Segmentation:
    """Seed 001 rotations cut into whole revolutions (:func:`gyrocal.protocols.servo.find_rotations`),
    one observation per revolution (Eq 8). The mount of a revolution is the rotation's
    direction as the data show it (``+x``: the gyro's x reads the servo speed positive),
    and its reference rate the servo speed, so the common model sees the rate vector
    ``±ω`` along that axis. The noise of a revolution mean is the white-noise level
    (successive differences) over √n: the servo's ripple cancels over a whole revolution
    and must not inflate the floor."""
    from ...io.holds import Segmentation, hold_table, no_stable_periods, segments_of_holds, timeline
    from . import find_rotations

    rot = find_rotations(log, min_revolutions=checked_options("servo", options)["min_revolutions"])
    rev = rot.revolutions
    gyro = rev[[f"gyro_{a}" for a in AXES]].to_numpy()
    noise = rev[[f"gyro_{a}_noise" for a in AXES]].to_numpy()
    t_start, t_end = rev["t_start"].to_numpy(), rev["t_end"].to_numpy()
    temp = rev["temp"].to_numpy()
    obs = hold_table(
        t_start=t_start,
        t_end=t_end,
        n=rev["n"].to_numpy(),
        mount=rev["direction"].to_numpy(dtype=object),
        mount_source="data",
        ref_rate=rev["ref_rate"].to_numpy(),
        gyro=gyro,
        std=noise,
        temp=temp,
        temp_rate=_temperature_slopes(log, t_start, t_end),
        point=np.zeros(len(rev), np.int64),
        point_temp=np.full(len(rev), float(np.mean(temp))),
    )
    obs["rotation"] = rev["rotation"].to_numpy()
    obs["revolution"] = rev["revolution"].to_numpy()
    for i, a in enumerate(AXES):
        obs[f"gyro_{a}_noise"] = noise[:, i]
    segments = segments_of_holds(obs, "revolution")
    info = {
        "protocol": "servo",
        "path": str(log.path),
        "rows_read": log.rows_read,
        "rows_dropped": log.rows_dropped,
        "rows_used": int(rev["n"].sum()),
        "sample_rate": float((len(log.column("t")) - 1) / max(np.ptp(log.column("t")), 1e-12)),
        "typical_hold_s": float(np.median(t_end - t_start)),
        "holds_accepted": int(len(obs)),
        "rotations": int(rev["rotation"].nunique()),
        "directions": list(rot.directions),
        "warnings": list(rot.warnings),
    }
    return Segmentation(obs, segments, no_stable_periods(), timeline(log), info)


SERVO_TERMS = ("bias", "scale")
CROSS_TERMS = ("bias", "scale", "misalignment")
# How the report's headline names each model's validated figure, and the parameters a
# held-out error's leverage counts (the fixture model: a regression of four per output axis).
MODEL_LABELS = {
    "seed001": "Seed 001 six-parameter calibration",
    "symmetric": "Servo calibration with the symmetric cross-axis terms (nine parameters)",
    "fixture": "Servo calibration with every cross-axis term (twelve parameters, fixture)",
}
LEVERAGE = {"seed001": 6, "symmetric": 9, "fixture": 4}


def _servo_input(obs: pd.DataFrame) -> pd.DataFrame:
    """Revolution means in the form :func:`gyrocal.protocols.servo.fit.fit_observations` reads: the
    servo speed as |ref_rate|, the white-noise level per axis, the sample count and the
    rotation's direction."""
    cols = ["gyro_x", "gyro_y", "gyro_z", "n", *[f"gyro_{a}_noise" for a in AXES]]
    missing = [c for c in cols if c not in obs]
    if missing:
        from ...io.errors import InputError

        raise InputError(f"servo observations lack {', '.join(missing)}: segment the log with protocol servo")
    out = obs[cols].copy()
    out["ref_rate"] = obs["ref_rate"].abs()
    out["direction"] = obs["mount"].astype(str).to_numpy()
    return out


def servo_model(obs: pd.DataFrame, model: str, seed001=None):
    """(fit, model used, why) of the configured servo ``model`` (:func:`gyrocal.protocols.servo.fit.fit_model`)."""
    from .fit import fit_model

    return fit_model(_servo_input(obs), model, seed001=seed001)


def servo_fits(obs: pd.DataFrame):
    """(Algorithm 1, Levenberg–Marquardt) on every whole revolution (seed 001 Eq 8 per
    revolution, Eq 4–7, Algorithm 1)."""
    from .fit import fit_observations

    data = _servo_input(obs)
    return fit_observations(data, method="iterative"), fit_observations(data, method="lm")


def servo_calibration(
    obs: pd.DataFrame, *, reference_temperature: float, meta: dict, provenance: dict, model: str = "auto"
):
    """The calibration file of a servo session at the session's mean temperature, by the
    servo ``model`` (:data:`gyrocal.protocols.servo.fit.MODELS`): seed 001's ``K = diag(1/k)``,
    ``B = −b`` of Algorithm 1 (:mod:`gyrocal.protocols.servo.fit` gives the mapping) as the terms bias
    and scale, or a full K (the symmetric or the fixture model) as bias, scale and
    misalignment; both seed-001 fits, the convergence trace and the model's choice carried
    along."""
    from ...calibration.file import Calibration
    from ...fit.model import Model
    from ...fit.thermal import TemperatureGrid

    iterative, lm = servo_fits(obs)
    fit, used, why = servo_model(obs, model, iterative)
    model_terms = Model.from_spec(SERVO_TERMS if used == "seed001" else CROSS_TERMS)
    values, errors = fit.coefficients(), fit.coefficient_errors()
    names = tuple(model_terms.names)
    temp = float(np.mean(obs["temp"]))
    grid = TemperatureGrid(
        np.array([temp]),
        names,
        np.array([[values[n] for n in names]]),
        np.array([[errors[n] for n in names]]),
    )
    if not (np.isfinite(grid.values).all() and np.isfinite(grid.stderr).all()):
        from ...io.errors import IdentifiabilityError

        raise IdentifiabilityError("the servo fit gave non-finite parameters or errors", parameters=names)
    both = np.r_[iterative.k, iterative.b], np.r_[lm.k, lm.b]
    servo = {
        "method": "seed 001 Algorithm 1 (iterative least squares); Levenberg–Marquardt beside it",
        "iterative": iterative.summary(),
        "lm": lm.summary(),
        "settled_at": int(iterative.settled_at()),
        "max_difference_lm": float(np.max(np.abs(both[0] - both[1]))),
        "revolutions": int(len(obs)),
        "rotations": int(obs["rotation"].nunique()) if "rotation" in obs else None,
        "model": {
            "configured": model,
            "used": used,
            "why": why,
            **({} if used == "seed001" else {"fit": fit.summary()}),
        },
    }
    points = [{"temperature": temp, "holds": int(len(obs)), "used": True}]
    return Calibration(
        model_terms,
        grid,
        reference_temperature,
        meta,
        provenance=provenance,
        extra={"points": points, "servo": servo},
    )


def _used_model(cal) -> str:
    """The servo model a calibration holds (seed 001's for files written before the choice)."""
    return ((cal.extra.get("servo") or {}).get("model") or {}).get("used", "seed001")


def _refit(data: pd.DataFrame, used: str):
    """The servo model ``used`` fitted again on a subset (leave-one-out): the same model,
    not a new choice."""
    from .fit import DEG, fit_fixture, fit_observations, fit_symmetric, nominal_rates, observation_arrays

    if used == "seed001":
        return fit_observations(data, method="iterative")
    m, omega, m_sem, directions = observation_arrays(data)
    if used == "fixture":
        return fit_fixture(m, nominal_rates(directions, omega), m_sem=m_sem)
    return fit_symmetric(m / DEG, omega / DEG)


class Compensated(NamedTuple):
    """The revolution means, raw and compensated by the calibration's model."""

    m: np.ndarray  # (n, 3) raw means
    omega: np.ndarray  # servo speed of each
    K: np.ndarray  # the calibration's K at the session's temperature
    in_sample: np.ndarray  # compensated by the calibration itself
    validated: np.ndarray  # compensated by the model fitted on the other revolutions
    held_out: bool  # False: every direction has one revolution, validated is in-sample


class Scores(NamedTuple):
    """Each revolution's error, raw, in-sample and validated, and its noise floor."""

    errors: dict[str, np.ndarray]
    floor: np.ndarray
    quantity: str  # what the error measures


def servo_validation(obs: pd.DataFrame, cal: Calibration) -> Validation:
    """Each revolution compensated by the calibration's model fitted on the other
    revolutions (when every rotation has two or more; otherwise in-sample, and said so),
    per rotation direction, beside the uncompensated error and the noise floor of each
    revolution mean (the white-noise level over √n) (:func:`_scores`)."""
    import pandas as pd

    from ...fit.validate import Validation

    used = _used_model(cal)
    data = _servo_input(obs)
    comp = _compensate(obs, data, cal, used)
    scores = _scores(obs, data, comp, used)
    holds = pd.DataFrame(
        {
            "hold": obs["hold"].to_numpy(),
            "direction": obs["mount"].astype(str).to_numpy(),
            "rotation": obs["rotation"].to_numpy() if "rotation" in obs else np.arange(len(obs)),
            "omega": comp.omega,
            "noise_floor": scores.floor,
            **{f"{name}_error": e for name, e in scores.errors.items()},
        }
    )
    table = _by_direction(holds, scores.errors)
    summary = _validation_summary(obs, comp, scores, used)
    by_temperature = pd.DataFrame(
        {
            "temp": [summary["reference_temperature"]],
            "holds": [len(obs)],
            "validated_rms": [summary["validation_rms"]],
            "noise_floor": [summary["noise_floor"]],
        }
    )
    return Validation(holds, table, table.iloc[0:0], by_temperature, summary)


def _compensate(obs: pd.DataFrame, data: pd.DataFrame, cal: Calibration, used: str) -> Compensated:
    """Each revolution compensated by the calibration, and by the model fitted again
    without it; leaving a revolution out keeps the fit identifiable while its direction
    has another."""
    m = data[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    omega = data["ref_rate"].to_numpy()
    (K,), (B,) = cal.matrices_at(np.array([float(np.mean(obs["temp"]))]))
    # K⁻¹ = diag(k) for seed 001's model, as Eq 1 compensates
    in_sample = (m - B) * (1.0 / np.diag(K)) if used == "seed001" else np.linalg.solve(K, (m - B).T).T
    held_out = bool(obs["mount"].astype(str).value_counts().min() >= 2)
    validated = in_sample.copy()
    if held_out:
        for r in range(len(obs)):  # one refit per revolution (a few dozen), not per sample
            keep = np.arange(len(obs)) != r
            fit = _refit(data.iloc[keep], used)
            validated[r] = fit.compensate(m[r : r + 1])[0]
    return Compensated(m, omega, K, in_sample, validated, held_out)


def _scores(obs: pd.DataFrame, data: pd.DataFrame, comp: Compensated, used: str) -> Scores:
    """Seed 001's and the symmetric model are scored on what they match, the compensated
    rate's magnitude against the servo speed (Eq 2; the mount's tilt does not enter it),
    its floor the noise projected on the rotation axis; the fixture model on the length of
    the compensated rate's difference from the commanded rate vector, its floor the noise
    of all three axes. The noise is the session's noise model where segmentation made one,
    else the white-noise level over √n (segment_servo stores it as the revolutions' std)."""
    from .fit import nominal_rates

    noise = observation_floor(obs) @ np.abs(np.linalg.inv(comp.K)).T
    if used == "fixture":
        rates = nominal_rates(data["direction"], comp.omega)
        error = lambda rate: np.linalg.norm(rate - rates, axis=1)  # noqa: E731
        floor = np.sqrt((noise**2).sum(axis=1))
        quantity = "length of the compensated rate's difference from the commanded rate vector"
    else:
        error = lambda rate: np.linalg.norm(rate, axis=1) - comp.omega  # noqa: E731
        direction = comp.validated / np.linalg.norm(comp.validated, axis=1)[:, None]
        floor = np.sqrt(((direction * noise) ** 2).sum(axis=1))
        quantity = "magnitude of the compensated rate minus the servo speed"
    errors = {
        "uncompensated": error(comp.m),
        "in_sample": error(comp.in_sample),
        "validated": error(comp.validated),
    }
    return Scores(errors, floor, quantity)


def _by_direction(holds: pd.DataFrame, errors: dict[str, np.ndarray]) -> pd.DataFrame:
    """Per rotation direction: its revolutions, their noise floor and each error's mean
    and RMS."""
    import pandas as pd

    rows = []
    for d, part in holds.groupby("direction", sort=False):
        row = {
            "direction": d,
            "revolutions": int(len(part)),
            "noise_floor": float(np.sqrt(np.mean(part["noise_floor"] ** 2))),
        }
        for name in errors:
            e = part[f"{name}_error"].to_numpy()
            row[f"{name}_mean"], row[f"{name}_rms"] = float(e.mean()), float(np.sqrt(np.mean(e**2)))
        rows.append(row)
    return pd.DataFrame(rows)


def _validation_summary(obs: pd.DataFrame, comp: Compensated, scores: Scores, used: str) -> dict[str, Any]:
    """The validation's summary, in the common validation's keys. A correct model of p
    parameters leaves the floor ×√(1 + p/n) on held-out revolutions (leverage p/n on
    average), ×√(1 − p/n) in-sample; p revolutions leave nothing."""
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    n, p = len(obs), LEVERAGE[used]
    noise_floor = rms(scores.floor)
    expected = (
        noise_floor * np.sqrt(1 + p / n)
        if comp.held_out
        else (noise_floor * np.sqrt(1 - p / n) if n > p else None)
    )
    validation = rms(scores.errors["validated"])
    ratio = lambda a, b: a / b if b else None  # noqa: E731 - None, never inf, in the JSON
    return {
        "validation_rms": validation,
        "noise_floor": noise_floor,
        "excess": ratio(validation, noise_floor),
        "expected_rms": None if expected is None else float(expected),
        "excess_over_expected": ratio(validation, expected),
        "uncompensated_rms": rms(scores.errors["uncompensated"]),
        "single_rms": None,
        "in_sample_rms": rms(scores.errors["in_sample"]),
        "reference_temperature": float(np.mean(obs["temp"])),
        "held_out": "revolution" if comp.held_out else "nothing (one revolution per direction: in-sample)",
        "scored": "all",
        "holds_scored": int(n),
        "temperature_points": 1,
        "model_kind": "servo",
        "servo_model": used,
        "quantity": scores.quantity,
        "validated_as": f"{MODEL_LABELS[used]}; validated",
    }


class ServoAnalysis(TypedDict):
    """The servo's own methods for the report (JSON-plain)."""

    protocol: str
    iterative: dict[str, Any]  # Algorithm 1's fit (ServoFit.summary)
    lm: dict[str, Any]  # Levenberg–Marquardt's
    settled_at: int  # the iteration Algorithm 1 settled at
    max_difference_lm: float  # the largest difference of a parameter between the two


def servo_analysis(obs: pd.DataFrame) -> ServoAnalysis:
    """Both fits of every whole revolution, for the report."""
    iterative, lm = servo_fits(obs)
    return {
        "protocol": "servo",
        "iterative": iterative.summary(),
        "lm": lm.summary(),
        "settled_at": int(iterative.settled_at()),
        "max_difference_lm": float(np.max(np.abs(np.r_[iterative.k, iterative.b] - np.r_[lm.k, lm.b]))),
    }


class Servo(Protocol):
    """Whole revolutions as observations. The calibration is seed 001's own; the diagnosis
    fits the 12-parameter model on the revolution means (the hand-mounting tilt of each axis
    lands in the misalignment) beside it."""

    name = "servo"
    description = "servo-aided six-observation calibration: hand-mounted rotations (seed 001)"
    known_rate = False
    one_temperature = True
    report_sections = "protocols/servo_sections.html.j2"
    validated_as = "Seed 001 six-parameter calibration; validated"
    defaults = DEFAULTS

    def segment(self, log: RigLog, settings: SettingsView) -> Segmentation:
        return segment_servo(log, settings.protocol_options("servo"))

    def static(self, log: RigLog, seg: Segmentation, max_temp_rate: float) -> tuple[np.ndarray, np.ndarray]:
        """The pauses between rotations (reference rate 0), in quiet blocks only, since the
        unit is turned by hand between rotations."""
        t = log.column("t")
        gyro = np.column_stack([log.column(f"gyro_{a}") for a in AXES])
        return quiet_runs(t, gyro, log.column("ref_rate") == 0, float(seg.info["sample_rate"]))

    def calibrate(
        self, obs: pd.DataFrame, settings: SettingsView, meta: dict, provenance: dict
    ) -> Calibration:
        return servo_calibration(
            obs,
            reference_temperature=settings.model.reference_temperature,
            meta=meta,
            provenance=provenance,
            model=settings.protocol_options("servo")["calibration"],
        )

    def validate(self, obs: pd.DataFrame, cal: Calibration) -> Validation:
        return servo_validation(obs, cal)

    def analysis(self, obs: pd.DataFrame) -> OwnAnalysis:
        return OwnAnalysis(servo_analysis(obs), [])

    def validation_figure(self, holds: pd.DataFrame) -> str:
        from ...report import plots

        return plots.servo_errors(holds)


SERVO = register(Servo())
