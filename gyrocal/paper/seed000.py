"""Seed 000 (multi-temperature turntable calibration): Tables 3 and 4 and Eq 23, regenerated.

The paper's unit is simulated (:meth:`GyroUnit.seed000`: Eq 23's K_g at 25 °C) over its
protocol (Table 1 set points, Table 2 rates, three mounts, 60 s holds after 1 h soaks) and
calibrated by gyrocal's own chain: per-point fits (Eq 13-19), three-point Lagrange
interpolation (Eq 21-22). Two sessions are simulated:

* the calibration grid; Table 3 is its leave-temperature-out validation on hold means;
* a test session at 25 °C, the temperature of the paper's Table 4 comparison, compensated
  by the grid interpolated to its holds (proposed), by the single-temperature calibration
  of the grid point nearest 25 °C (traditional), and not at all; Table 4 is on samples.

The full regeneration renders both sessions as rig logs (8.3 M rows for the grid) and runs
them through ingest and segmentation; ``quick`` draws the hold means directly
(:func:`gyrocal.simulate.observations.observations`), skipping the thermal path, handling
and segmentation, in a fraction of a second.
"""

from __future__ import annotations

import functools
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..fit.thermal import fit_model
from ..fit.validate import METHODS, validate
from ..pipeline.chain import calibrate_observations, run, segment_log
from ..pipeline.config import Settings
from ..simulate.observations import observations
from ..simulate.turntable import SEED000_RATES, SEED000_TEMPERATURES, TurntableProtocol, render
from ..simulate.unit import GyroUnit
from ..terms import AXES
from .table import PaperRow, PaperTable

SEED = "000"
TEST_TEMPERATURE = 25.0  # °C, chamber set point of the Table 4 session (Section 4)
RIG = TurntableProtocol()  # the seed protocol: Tables 1-2, 60 s holds at 100 Hz, 1 h soaks

# Table 3, per (rotating axis, output axis): uncompensated mean, RMS; proposed mean, RMS (deg/s).
TABLE3 = {
    ("x", "x"): (-0.0302, 0.1783, 0.0013, 0.0532),
    ("x", "y"): (-0.0538, 4.0177, -0.0050, 0.0011),
    ("x", "z"): (-0.0242, 0.2459, -9.9029e-3, 0.0015),
    ("y", "x"): (-0.0330, 4.0446, -0.0014, 0.0018),
    ("y", "y"): (-0.0471, 0.1789, 0.0017, 0.0568),
    ("y", "z"): (-0.0197, 0.1644, 0.0035, 0.0011),
    ("z", "x"): (-0.0315, 0.2695, 1.260e-4, 9.253e-4),
    ("z", "y"): (-0.0455, 0.1143, 0.0033, 0.0016),
    ("z", "z"): (-0.0257, 0.3621, -0.0025, 0.0263),
}
# Table 4: uncompensated, traditional, proposed (deg/s); reduction of the proposed method's
# RMS against uncompensated and against traditional (%), as printed.
TABLE4 = {
    ("x", "x"): (0.1453, 0.1271, 0.0931, 35.93, 26.75),
    ("x", "y"): (3.9339, 0.0474, 0.0473, 98.78, 2.110),
    ("x", "z"): (0.2391, 0.0492, 0.0488, 79.59, 8.130),
    ("y", "x"): (3.9576, 0.0467, 0.0467, 98.82, 0.0),
    ("y", "y"): (0.1374, 0.1287, 0.0957, 30.35, 25.64),
    ("y", "z"): (0.1656, 0.0486, 0.0486, 70.65, 0.0),
    ("z", "x"): (-0.0307, 9.8550e-4, -4.3855e-4, 98.57, 55.50),
    ("z", "y"): (-0.0418, 0.0069, 0.0017, 95.93, 75.36),
    ("z", "z"): (-0.0292, -0.0060, -0.0031, 89.38, 48.33),
}
# Eq 23: K_g at 25 °C in the paper's order (Eq 14), each with its place in gyrocal's K
# (output row, input column): the paper's K_ab is the a rate's share in the b output (Eq 11).
EQ23 = (
    ("K_xx", ("x", "x"), 1.0005),
    ("K_yy", ("y", "y"), 1.0005),
    ("K_zz", ("z", "z"), 1.0017),
    ("K_yx", ("x", "y"), -0.0188),
    ("K_zx", ("x", "z"), 0.0012),
    ("K_xy", ("y", "x"), 0.0187),
    ("K_zy", ("y", "z"), 5.2027e-4),
    ("K_xz", ("z", "x"), -0.0011),
    ("K_yz", ("z", "y"), -7.5133e-4),
    ("B_x", "x", -0.0303),
    ("B_y", "y", -0.0435),
    ("B_z", "z", -0.0261),
)


@dataclass(frozen=True)
class Regeneration:
    """What the tables are read from."""

    table_holds: pd.DataFrame  # grid, leave-temperature-out, hold means (validate's table)
    test: pd.DataFrame  # 25 °C session: mean/RMS on samples per method and axis pair
    K25: np.ndarray  # calibration at 25 °C: K (3, 3) and B (3,)
    B25: np.ndarray
    K25_se: np.ndarray  # their standard errors
    B25_se: np.ndarray
    setup: dict


def _stacked(holds: pd.DataFrame, kind: str) -> np.ndarray:
    return holds[[f"{kind}_{a}" for a in AXES]].to_numpy(dtype=float)


def sample_statistics(holds: pd.DataFrame) -> pd.DataFrame:
    """Mean and RMS over samples per method, rotating axis and output axis, from
    validation hold rows: each hold counts with its sample count, its within-hold scatter
    (already mapped through the compensation) adding to the squared error."""
    n = holds["n"].to_numpy(dtype=float)[:, None]
    err, var = _stacked(holds, "err"), _stacked(holds, "var")
    noise = _stacked(holds, "std") ** 2
    frame = pd.DataFrame(
        {"method": holds["method"].astype(str).to_numpy(), "rotating": holds["axis"].astype(str).to_numpy()}
    )
    for i, a in enumerate(AXES):
        frame[f"n_{a}"] = n[:, 0]
        frame[f"e_{a}"] = n[:, 0] * err[:, i]
        frame[f"e2_{a}"] = n[:, 0] * (err[:, i] ** 2 + var[:, i])
        frame[f"f2_{a}"] = n[:, 0] * noise[:, i]
    sums = frame.groupby(["method", "rotating"], sort=True).sum()
    rows = []
    for (method, rotating), s in sums.iterrows():
        for a in AXES:
            rows.append(
                {
                    "method": method,
                    "rotating": rotating,
                    "output": a,
                    "mean": s[f"e_{a}"] / s[f"n_{a}"],
                    "rms": np.sqrt(s[f"e2_{a}"] / s[f"n_{a}"]),
                    "noise_floor": np.sqrt(s[f"f2_{a}"] / s[f"n_{a}"]),
                }
            )
    return pd.DataFrame(rows)


@functools.lru_cache(maxsize=4)
def regeneration(seed: int = 0, quick: bool = False) -> Regeneration:
    """Simulate seed 000's grid and 25 °C sessions and calibrate; cached per (seed, quick)."""
    settings = Settings()
    unit = GyroUnit.seed000()
    grid_seq, test_seq = np.random.SeedSequence(seed).spawn(2)
    make = _drawn_sessions if quick else _rendered_sessions
    sessions = make(unit, settings, np.random.default_rng(grid_seq), np.random.default_rng(test_seq))
    test_holds = _test_session_holds(sessions, settings)
    cal = sessions.calibration
    K, B = cal.matrices_at([TEST_TEMPERATURE])
    K_se, B_se = _stderr_at(cal, TEST_TEMPERATURE)
    setup = _setup(sessions, unit, test_holds)
    return Regeneration(
        sessions.grid_validation.table_holds, sample_statistics(test_holds), K[0], B[0], K_se, B_se, setup
    )


@dataclass(frozen=True)
class _Sessions:
    """The grid session calibrated and validated, the 25 °C session's holds, and how they
    were made (rows: the grid's log rows, or its holds when drawn directly)."""

    grid_obs: pd.DataFrame
    test_obs: pd.DataFrame
    calibration: object
    fitted: object
    grid_validation: object
    rows: int
    how: str


def _drawn_sessions(unit, settings: Settings, grid_rng, test_rng) -> _Sessions:
    """Both sessions' hold means drawn directly from the unit, the grid calibrated on them."""
    hold_samples = int(round(RIG.hold_s * RIG.sample_rate))
    draw = functools.partial(
        observations,
        unit,
        rates=SEED000_RATES,
        mounts=RIG.mounts,
        samples=hold_samples,
        sample_rate=RIG.sample_rate,
    )
    # The rig's die runs `self_heating` above the chamber: the draws sit where the log's holds do.
    grid_obs = draw(grid_rng, temperatures=[t + RIG.self_heating for t in SEED000_TEMPERATURES])
    test_obs = draw(test_rng, temperatures=(TEST_TEMPERATURE + RIG.self_heating,))
    cal, fitted = calibrate_observations(grid_obs, settings, meta={"device": "seed000"})
    grid_val = validate(
        cal.model, grid_obs, fitted, reference_temperature=settings.model.reference_temperature
    )
    how = "hold means drawn directly from the unit (no log, no segmentation)"
    return _Sessions(grid_obs, test_obs, cal, fitted, grid_val, len(grid_obs), how)


def _rendered_sessions(unit, settings: Settings, grid_rng, test_rng) -> _Sessions:
    """Both sessions rendered as rig logs; the grid's run through the whole chain, the test
    session's segmented."""
    with tempfile.TemporaryDirectory(prefix="gyrocal-seed000-") as tmp:
        grid_log, test_log = Path(tmp) / "grid.parquet", Path(tmp) / "test25.parquet"
        truth = render(RIG, unit, grid_rng, grid_log)
        render(TurntableProtocol(temperatures=(TEST_TEMPERATURE,)), unit, test_rng, test_log)
        result = run(grid_log, settings, device="seed000")
        test_obs = segment_log(test_log, settings).observations
    rows = truth["rows"]
    how = (
        f"rig logs rendered at {RIG.sample_rate:g} Hz ({rows:,} rows for the grid) and "
        "run through ingest, segmentation and calibration"
    )
    return _Sessions(
        result.segmentation.observations,
        test_obs,
        result.calibration,
        result.fitted,
        result.validation,
        rows,
        how,
    )


def _test_session_holds(sessions: _Sessions, settings: Settings) -> pd.DataFrame:
    """The 25 °C session's validation holds. The session joins the grid as one more point
    and, held out like every point, meets the grid without it (proposed) and the
    calibration nearest 25 °C (traditional)."""
    grid_obs, test_obs, cal = sessions.grid_obs, sessions.test_obs, sessions.calibration
    test_obs = test_obs.assign(hold=test_obs["hold"] + int(grid_obs["hold"].max()) + 1, point=-1)
    both = pd.concat([grid_obs, test_obs], ignore_index=True)
    both["point"] = np.unique(both["point_temp"].to_numpy(), return_inverse=True)[1]
    test_point = int(both["point"].iloc[-1])
    both_fit = fit_model(cal.model, both, kind=settings.model.kind, method=settings.model.interpolation)
    both_val = validate(cal.model, both, both_fit, reference_temperature=settings.model.reference_temperature)
    return both_val.holds[both_val.holds["point"] == test_point]


def _stderr_at(cal, temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """The standard errors of the calibration's K (3, 3) and B (3,) at ``temperature``."""
    se = cal.grid.stderr_at([temperature])
    K_se, B_se = np.zeros((3, 3)), np.zeros(3)
    for name, value in se.items():
        parts = name.split(".")
        a = AXES.index(parts[1])
        if parts[0] == "bias":
            B_se[a] = value[0]
        elif parts[0] == "scale":
            K_se[a, a] = value[0]
        else:
            K_se[a, AXES.index(parts[2])] = value[0]
    return K_se, B_se


def _setup(sessions: _Sessions, unit: GyroUnit, test_holds: pd.DataFrame) -> dict:
    """The figures the tables' notes quote: the sessions, the rig and the unit."""
    grid_val, test_obs = sessions.grid_validation, sessions.test_obs
    fitted = sessions.fitted
    return {
        "how": sessions.how,
        "rows": int(sessions.rows),
        "grid_holds": int(len(sessions.grid_obs)),
        "grid_points": int(grid_val.summary["temperature_points"]),
        "scored_holds": int(grid_val.summary["holds_scored"]),
        "point_temps": fitted.points.loc[fitted.points["used"], "temp"].to_numpy(dtype=float),
        "test_holds": int(len(test_obs)),
        "test_temp": float(test_obs["temp"].mean()),
        "reference_temp": float(test_holds["reference_temp"].iloc[0]),
        "noise_sample": float(unit.noise_std(RIG.sample_rate)),
        "noise_hold": float(grid_val.summary["noise_floor"]),
        "noise_density": unit.noise_density,
        "hold_s": RIG.hold_s,
        "sample_rate": RIG.sample_rate,
        "soak_s": RIG.soak_s,
        "self_heating": RIG.self_heating,
        "scale_tc": unit.scale_tc,
        "excess": float(grid_val.summary["excess"]),
    }


def _where(rotating: str, output: str) -> str:
    return f"{rotating.upper()} rotates / {output.upper()} axis"


def _setup_note(s: dict) -> str:
    return (
        f"Simulated unit: seed 000's Eq 23 K_g is the truth at a die temperature of 25 °C; "
        f"white noise {s['noise_density']:g} deg/s/√Hz, i.e. {s['noise_sample']:.4f} deg/s per "
        f"sample at {s['sample_rate']:g} Hz and about {s['noise_hold']:.2g} deg/s on a "
        f"{s['hold_s']:g} s hold mean. Protocol: Table 1 set points (−40 to 50 °C, "
        f"{s['soak_s'] / 3600:g} h soak each; the die runs {s['self_heating']:g} °C above the "
        f"chamber), Table 2 rates (0 and ±0.1 to ±400 deg/s) forward and reverse on mounts "
        f"+x, +y, +z, {s['hold_s']:g} s holds: {s['grid_holds']} holds at {s['grid_points']} "
        f"points; {s['how']}."
    )


def _assumption_note(s: dict) -> str:
    tc = ", ".join(f"{1e6 * v:+.0f}" for v in s["scale_tc"])
    return (
        "The paper publishes K and B at 25 °C only (Eq 23) and their trends over temperature "
        "as curves (Figs. 4-6): the simulated unit's temperature dependence is gyrocal's own "
        f"assumption (scale factor linear in T, {tc} ppm/°C for x, y, z; bias cubic in T), "
        "so figures set by it (uncompensated means and on-axis RMS, the gain over a "
        "single-temperature calibration) can agree in size only, not digit by digit."
    )


def tables(*, seed: int = 0, quick: bool = False) -> list[PaperTable]:
    """Tables 3 and 4 and Eq 23 of seed 000, published beside regenerated."""
    r = regeneration(seed, quick)
    rows23, notes23 = _eq23(r)
    return [
        PaperTable(
            SEED,
            "Table 3",
            "Mean and RMS error: uncompensated and the proposed "
            "(interpolated) calibration, per rotating axis and output axis",
            _table3_rows(r),
            _table3_notes(r.setup),
        ),
        PaperTable(
            SEED,
            "Table 4",
            "RMS error at 25 °C: uncompensated, traditional "
            "(single-temperature) and proposed calibration, and the proposed method's "
            "reductions",
            _table4_rows(r),
            _table4_notes(r.setup),
        ),
        PaperTable(SEED, "Eq. 23", "K_g at 25 °C: the calibration interpolated to 25 °C", rows23, notes23),
    ]


def _table3_rows(r: Regeneration) -> tuple[PaperRow, ...]:
    """Table 3: the grid's leave-temperature-out mean and RMS per axis pair, uncompensated
    and proposed, with the noise floor of hold means."""
    t3 = r.table_holds.set_index(["rotating", "output"])
    rows3 = []
    for (rot, out), (u_mean, u_rms, p_mean, p_rms) in TABLE3.items():
        row, where = t3.loc[(rot, out)], _where(rot, out)
        rows3 += [
            PaperRow(f"{where} / {label}", float(row[column]), published, "deg/s")
            for label, column, published in (
                ("Mean, uncompensated", "uncompensated_mean", u_mean),
                ("Mean, proposed", "interpolated_mean", p_mean),
                ("RMS, uncompensated", "uncompensated_rms", u_rms),
                ("RMS, proposed", "interpolated_rms", p_rms),
                ("noise floor of hold means", "noise_floor", None),
            )
        ]
    return tuple(rows3)


def _table3_notes(s: dict) -> tuple[str, ...]:
    rate_rms = float(np.sqrt(np.mean(np.square((0.0,) + SEED000_RATES * 2))))
    return (
        _setup_note(s),
        f"Proposed: every temperature point is left out in turn and its holds compensated by "
        f"the Lagrange interpolation (Eq 21-22) of the other points, a stricter test than "
        f"compensating the data the calibration was fitted on. The end points (−40 and 50 °C) "
        f"then lie outside the remaining grid and are left out: {s['scored_holds'] // 3} holds "
        f"per rotating axis at the {s['grid_points'] - 2} interior points. Mean and RMS are over hold means "
        f"({s['hold_s']:g} s averages): the paper's proposed RMS on the non-rotating axes "
        f"(0.9-1.8e-3 deg/s) is of that order, far below the per-sample noise.",
        f"The uncompensated cross-axis RMS is K_yx or K_xy (0.0188, 0.0187) times the RMS of "
        f"Table 2's rates ({rate_rms:.1f} deg/s over its 21 rates, 0 and ±0.1 to ±400): "
        f"{0.0187 * rate_rms:.2f}-{0.0188 * rate_rms:.2f} deg/s. The "
        f"paper's 4.02 and 4.04 imply an RMS rate of 215 deg/s, more than the Table 2 grid "
        f"holds even without its 0 deg/s point (196.9 deg/s).",
        "The paper's proposed RMS on the rotating axis (0.053, 0.057, 0.026 deg/s) is 16 to 52 "
        "times its off-axis figures: an error growing with the rate that the 12-parameter "
        "model leaves (a scale-factor nonlinearity of the real device, or the table's own rate "
        "error). The simulated unit has none, so its proposed RMS sits at the noise floor on "
        f"every axis pair (interpolated RMS {s['excess']:.3f} times the floor, pooled); those "
        "three ratios are far below 1 for that reason. Likewise the paper's proposed means (up "
        "to 0.0099 deg/s) are bias its real device did not repeat between calibration and use "
        "(drift, thermal hysteresis); the simulated bias repeats exactly and leaves means of "
        "order 1e-4 deg/s.",
        _assumption_note(s),
    )


def _table4_rows(r: Regeneration) -> tuple[PaperRow, ...]:
    """Table 4: the 25 °C session's RMS over samples per axis pair and method, the proposed
    method's reductions, and the per-sample noise."""
    t4 = r.test.set_index(["method", "rotating", "output"])
    rows4 = []
    for (rot, out), (u, trad, prop, vs_u, vs_t) in TABLE4.items():
        where = _where(rot, out)
        rms = {m: float(t4.loc[(m, rot, out), "rms"]) for m in METHODS}
        rows4 += [
            PaperRow(f"{where} / RMS, uncompensated", rms["uncompensated"], u, "deg/s"),
            PaperRow(f"{where} / RMS, traditional", rms["single"], trad, "deg/s"),
            PaperRow(f"{where} / RMS, proposed", rms["interpolated"], prop, "deg/s"),
            PaperRow(
                f"{where} / reduction vs uncompensated",
                100.0 * (1.0 - rms["interpolated"] / rms["uncompensated"]),
                vs_u,
                "%",
            ),
            PaperRow(
                f"{where} / reduction vs traditional",
                100.0 * (1.0 - rms["interpolated"] / rms["single"]),
                vs_t,
                "%",
            ),
            PaperRow(
                f"{where} / per-sample noise",
                float(t4.loc[("interpolated", rot, out), "noise_floor"]),
                None,
                "deg/s",
            ),
        ]
    return tuple(rows4)


def _table4_notes(s: dict) -> tuple[str, ...]:
    return (
        f"Test session: the same unit at a chamber set point of {TEST_TEMPERATURE:g} °C (die "
        f"{s['test_temp']:.1f} °C), {s['test_holds']} holds over Table 2's rates on the three "
        f"mounts, fresh noise. Proposed: the grid of the Table 3 session interpolated to each "
        f"hold's temperature (Eq 21-22, through the 10, 20 and 30 °C points). Traditional: the "
        f"12-parameter calibration of the single grid point nearest 25 °C (the 20 °C set point, "
        f"die {s['reference_temp']:.1f} °C); the paper does not say at which temperature its "
        f"traditional calibration was made.",
        f"RMS over samples: each hold's mean error plus its within-hold scatter carried through "
        f"the compensation. The per-sample noise ({s['noise_sample']:.4f} deg/s) matches the "
        f"0.047-0.049 deg/s the paper's proposed method leaves on the non-rotating axes, so "
        f"there both methods sit at the noise and the reduction against traditional is near 0, "
        f"as printed.",
        "The paper's Z-rotates rows print negative values in the RMS columns, and their "
        "percentages follow from magnitudes (1 − 4.3855e-4/0.0307 = 98.57 %): these are signed "
        "means, not RMS, so the ratios of those nine figures compare unlike statistics; its "
        "traditional and proposed figures there (4.4e-4 to 0.0069 deg/s) also lie far below the "
        "per-sample noise, which bounds any RMS over samples.",
        "The paper's reductions against traditional on the rotating axes (26.75, 25.64 %) and "
        "for Z rotating come from how its unit's scale factor and bias change between the "
        "traditional calibration's temperature and 25 °C, which is not published; here they "
        "follow from the assumed temperature coefficients over the 5 °C gap.",
        _assumption_note(s),
    )


def _eq23(r: Regeneration) -> tuple[tuple[PaperRow, ...], tuple[str, ...]]:
    """Eq 23: the calibration at 25 °C beside the truth it was simulated from, and how many
    standard errors the largest deviation is."""
    z, rows23 = [], []
    for name, where, published in EQ23:
        if isinstance(where, tuple):
            row, col = AXES.index(where[0]), AXES.index(where[1])
            value, se = r.K25[row, col], r.K25_se[row, col]
        else:
            a = AXES.index(where)
            value, se = r.B25[a], r.B25_se[a]
        z.append(abs(value - published) / se if se > 0 else 0.0)
        rows23.append(PaperRow(name, float(value), published, "deg/s" if name[0] == "B" else ""))
    notes23 = (
        "The simulated unit is built from Eq 23 (its K and B at a die temperature of 25 °C), so "
        "this table checks that the calibration, interpolated to 25 °C, recovers its truth; it "
        "does not test the paper. Eq 23 lists K_ab, the a rate's share in the b output (Eq 11): "
        "gyrocal's misalignment.b.a.",
        f"Largest deviation: {max(z):.2f} standard errors of the interpolated calibration (scale "
        f"factors to about {1e6 * float(np.max(np.diag(r.K25_se))):.1f} ppm, biases to "
        f"{float(np.max(r.B25_se)):.1e} deg/s).",
    )
    return tuple(rows23), notes23


def figures(out_dir, *, seed: int = 0, quick: bool = False) -> list[Path]:
    """Fig. 9's comparison: RMS per rotating and output axis for the three methods at
    25 °C, regenerated (bars) beside the paper's Table 4 (markers)."""
    from ..report import plots

    r = regeneration(seed, quick)
    t4 = r.test.set_index(["method", "rotating", "output"])
    pairs = list(TABLE4)
    x = np.arange(len(pairs))
    styles = (
        ("uncompensated", "uncompensated", 0),
        ("single", "traditional", 1),
        ("interpolated", "proposed", 2),
    )
    fig, ax = plots.figure(8, 3.6)
    ax = ax[0, 0]
    for method, label, k in styles:
        colour = plots.METHOD_STYLE[method][0]
        regenerated = [t4.loc[(method, rot, out), "rms"] for rot, out in pairs]
        published = [abs(TABLE4[p][k]) for p in pairs]
        ax.bar(x + (k - 1) * 0.27, regenerated, width=0.27, color=colour, label=f"{label}, regenerated")
        ax.plot(
            x + (k - 1) * 0.27,
            published,
            "_",
            color="k",
            ms=9,
            mew=1.5,
            label="paper, Table 4" if k == 0 else None,
        )
    ax.set_yscale("log")
    ax.set_xticks(x, [f"{rot} rot.\n{out} out" for rot, out in pairs], fontsize=8)
    ax.set_ylabel("RMS error at 25 °C, deg/s")
    ax.set_title("The paper's Z-rotates figures are signed means: their magnitude is shown", fontsize=8)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside upper center", ncol=4, fontsize=7)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{SEED}-fig-9-rms-at-25c.svg"
    plots.write_svg(plots.to_svg(fig), path)
    return [path]
