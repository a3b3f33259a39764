"""Figures for the reports, as inline SVG that is the same, byte for byte, on every run.

The unit report's figures and the fleet's histograms are drawn by :mod:`gyrocal.report.svg`
(no more points than pixels, a few kB each, no matplotlib import); the papers' figures, the
fleet's drift and outlier pages and the servo's Monte Carlo are drawn once per fleet by
matplotlib (:func:`figure`, :func:`to_svg`: a ``Figure`` without pyplot state, a fixed hash
salt, no date, text kept as text). Data strings are escaped wherever they enter a figure.
"""

from __future__ import annotations

import io
import math
from typing import TYPE_CHECKING

import numpy as np

from ..io import AXES, atomic
from ..io.columns import present
from . import svg

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

    from ..io.columns import Columns

AXIS_COLOURS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728"}
METHOD_STYLE = {
    "uncompensated": ("#7f7f7f", "o"),
    "single": ("#ff7f0e", "s"),
    "interpolated": ("#1f77b4", "^"),
}
REASON_COLOURS = [
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#bcbd22",
    "#17becf",
    "#ff7f0e",
    "#7f7f7f",
    "#2ca02c",
    "#1f77b4",
]
# The one style of the matplotlib figures. The hash salt fixes the ids inside an SVG and the
# metadata leaves the date out, so a figure is the same bytes on every run.
STYLE = {
    "svg.hashsalt": "gyrocal",
    "svg.fonttype": "none",
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
}
SVG_METADATA = {"Date": None, "Creator": "gyrocal"}
WIDTH = 900  # px: a full-width figure


def _matplotlib():
    import matplotlib

    matplotlib.use("Agg")
    return matplotlib


def figure_style(overrides: dict | None = None):
    """Context to draw and save matplotlib figures in: :data:`STYLE`, with ``overrides``."""
    return _matplotlib().rc_context({**STYLE, **(overrides or {})})


def to_svg(fig: Figure) -> str:
    buf = io.StringIO()
    with figure_style():
        fig.savefig(
            buf, format="svg", metadata=SVG_METADATA, bbox_inches="tight", dpi=110
        )  # dpi: the rasterised data layers
    text = buf.getvalue()
    return text[text.index("<svg") :]  # inline: drop the XML prolog and doctype


def write_svg(text: str, path_or_none) -> str:
    """``text`` written to ``path_or_none`` (atomically) when given; returned either way."""
    if path_or_none is not None:
        atomic.write_text(path_or_none, text)
    return text


def figure(w: float, h: float, rows: int = 1, cols: int = 1, **kw):
    """A matplotlib figure of w × h inches and its axes grid."""
    _matplotlib()
    from matplotlib.figure import Figure

    with figure_style():
        fig = Figure(figsize=(w, h), layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axes


def panels(names: list, row_height: float):
    """A matplotlib figure of one panel per name, three to a row, the spare panels hidden:
    (figure, [(axis, name), ...]). Call it inside :func:`figure_style`."""
    cols = min(3, max(len(names), 1))
    rows = max(math.ceil(len(names) / cols), 1)
    fig, axes = figure(10, row_height * rows + 0.4, rows, cols)
    flat = list(axes.ravel())
    for axis in flat[len(names) :]:
        axis.set_visible(False)
    return fig, list(zip(flat, names, strict=False))


def _legend_above(fig: svg.Figure, entries: list, y: float, columns: int = 4) -> None:
    width = columns * (24 + max((svg.text_width(e[0], svg.FONT - 1) for e in entries), default=0)) + 8
    fig.extra.append(svg.legend(entries, None, "", x=max((fig.width - width) / 2, 4), y=y, columns=columns))


def timeline(timeline: Columns, segments: Columns) -> str:
    """Temperature, reference rate and gyro over the session; accepted holds shaded,
    rejected segments marked by reason (seed 000 Section 3.2's protocol, as found)."""
    rejected = segments[segments["kind"] == "rejected"]
    reasons = sorted(set(rejected["reason"].astype(str).tolist()))
    legend_rows = math.ceil((len(reasons) + 1) / 4)
    top = 30 + 15 * legend_rows
    fig = svg.Figure(WIDTH, top + 3 * 150 + 2 * 14 + 44)
    temp, ref, gyro = fig.grid(3, 1, top=top, vgap=14)
    start = float(timeline["t_start"][0]) if len(timeline) else 0.0
    hours = lambda t: (np.asarray(t, float) - start) / 3600.0  # noqa: E731
    t = hours((timeline["t_start"] + timeline["t_end"]) / 2)
    temp.line(t, timeline["temp"], colour="#444", width=1.0)
    temp.ylabel = "temperature, °C"
    ref.band(t, timeline["ref_min"], timeline["ref_max"], colour="#444", opacity=0.9, step=True)
    ref.ylabel = "reference, deg/s"
    for a in AXES:
        gyro.band(
            t,
            timeline[f"gyro_{a}_min"],
            timeline[f"gyro_{a}_max"],
            colour=AXIS_COLOURS[a],
            opacity=0.6,
            step=True,
            label=a,
        )
    gyro.ylabel, gyro.xlabel, gyro.legend_at = "gyro, deg/s", "time since start, h", "upper right"
    holds = segments[segments["kind"] == "hold"]
    entries = [(f"accepted hold ({len(holds)})", "vspan", {"colour": "#2ca02c", "opacity": 0.25})]
    ref.vspan(hours(holds["t_start"]), hours(holds["t_end"]), "#2ca02c", 0.25)
    for k, reason in enumerate(reasons):
        group = rejected[rejected["reason"].astype(str) == reason]
        colour = REASON_COLOURS[k % len(REASON_COLOURS)]
        for panel in (temp, ref, gyro):
            panel.vspan(hours(group["t_start"]), hours(group["t_end"]), colour, 0.3)
        entries.append((f"{reason} ({len(group)})", "vspan", {"colour": colour, "opacity": 0.3}))
    lo = min(float(np.nanmin(t)) if len(t) else 0.0, 0.0)
    for panel in (temp, ref, gyro):
        panel.xlim = (
            lo,
            float(np.nanmax(hours(segments["t_end"])))
            if len(segments)
            else (float(np.nanmax(t)) if len(t) else 1.0),
        )
    temp.show_xticklabels = ref.show_xticklabels = False
    _legend_above(fig, entries, 6)
    return str(fig)


def parameters(
    grid_temps: np.ndarray, values: dict, stderr: dict, curve_temps: np.ndarray, curve: dict
) -> str:
    """Scale-factor errors, cross-axis terms and biases against temperature with 1-sigma
    error bars and the interpolation between points (seed 000 Figs. 4-6)."""
    groups = [
        ("scale-factor error, ppm", [f"scale.{a}" for a in AXES], 1e6),
        (
            "cross-axis term K[a,b], ×10⁻³",
            [f"misalignment.{a}.{b}" for a in AXES for b in AXES if a != b],
            1e3,
        ),
        ("bias, deg/s", [f"bias.{a}" for a in AXES], 1.0),
    ]
    fig = svg.Figure(WIDTH, 300)
    for panel, (label, names, scale) in zip(fig.grid(1, 3, hgap=70), groups, strict=False):
        for k, name in enumerate(n for n in names if n in values):
            colour = (
                REASON_COLOURS[(k + 3) % len(REASON_COLOURS)]
                if len(names) > 3
                else AXIS_COLOURS[name.split(".")[1]]
            )
            v = np.asarray(values[name], float) * scale
            e = np.asarray(stderr[name], float) * scale
            panel.errorbars(grid_temps, v - e, v + e, colour=colour)
            panel.markers(grid_temps, v, colour=colour, size=5, label=".".join(name.split(".")[1:]))
            panel.line(curve_temps, np.asarray(curve[name], float) * scale, colour=colour, width=1.0)
        panel.title, panel.xlabel, panel.legend_at = label, "temperature, °C", "upper right"
    return str(fig)


def by_temperature(table: Columns) -> str:
    """Leave-temperature-out RMS per held-out point and method, with the noise floor."""
    fig = svg.Figure(640, 300)
    (panel,) = fig.grid(1, 1, left=78)
    panel.ylog = True
    for method, (colour, marker) in METHOD_STYLE.items():
        panel.line(table["temp"], table[f"{method}_rms"], colour=colour, width=1.3)
        panel.markers(
            table["temp"], table[f"{method}_rms"], colour=colour, shape=marker, size=6, label=method
        )
    panel.line(table["temp"], table["noise_floor"], colour="#000", dash="5 3", label="noise floor")
    clamped = table[np.asarray(table["clamped"], bool)]
    panel.markers(
        clamped["temp"],
        clamped["interpolated_rms"],
        colour="#000",
        shape="x",
        size=9,
        label="outside the remaining range",
    )
    panel.xlabel, panel.ylabel = "held-out temperature, °C", "RMS error of hold means, deg/s"
    panel.legend_at = "upper right"
    return str(fig)


def error_distribution(holds: Columns, method: str) -> str:
    """Error of each hold mean against the reference rate, one panel per rotating axis
    (rows) and output axis (columns), coloured by temperature (seed 000 Figs. 7-8)."""
    rows = holds[holds["method"] == method]
    lo, hi = data_span(holds["temp"]) if len(holds) else (0.0, 1.0)
    fig = svg.Figure(WIDTH, 640)
    grid = fig.grid(3, 3, right=110, hgap=60, vgap=52)
    for i, rot in enumerate(AXES):
        g = rows[rows["axis"] == rot]
        inside = ~np.asarray(g["clamped"], bool)
        colours = np.array(svg.COOLWARM, dtype=object)[
            svg.palette_index(np.asarray(g["temp"], float), lo, hi, len(svg.COOLWARM))
        ]
        for j, out in enumerate(AXES):
            panel = grid[3 * i + j]
            x, y = np.asarray(g["ref_rate"], float), np.asarray(g[f"err_{out}"], float)
            panel.markers(x[inside], y[inside], colour=colours[inside], size=4)
            if method != "uncompensated" and (~inside).any():  # clamped: hollow
                panel.markers(x[~inside], y[~inside], colour="#888", size=5, hollow=True)
            panel.title = f"{rot} rotates, {out} output"
            if i == 2:
                panel.xlabel = "reference rate, deg/s"
            if j == 0:
                panel.ylabel = "error, deg/s"
    fig.colourbar(WIDTH - 86, 120, 14, 400, svg.COOLWARM, lo, hi if hi > lo else lo + 1, "temperature, °C")
    return str(fig)


def data_span(values) -> tuple[float, float]:
    """Least and greatest value, a missing one (NaN) skipped; NaN where none is there."""
    values = np.asarray(values, float)
    values = values[~np.isnan(values)]
    return (float(values.min()), float(values.max())) if values.size else (math.nan, math.nan)


def histogram(values: np.ndarray, label: str) -> str:
    """Distribution of one quantity across the fleet's calibrated units."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    fig = svg.Figure(300, 210)
    (panel,) = fig.grid(1, 1, left=46, right=10, top=24, bottom=30)
    panel.title, panel.ylabel = label, "units"
    if values.size:
        centre, span = float(np.median(values)), float(np.ptp(values))
        # One value, or several equal to within rounding: bars around it a tenth of it wide
        # each side, not bins as narrow as the rounding.
        half = 0.1 * abs(centre) or 0.5
        spread = None if span > 1e-9 * max(1.0, abs(centre)) else (centre - half, centre + half)
        counts, edges = np.histogram(values, bins=min(20, max(3, values.size)), range=spread)
        panel.band(
            np.repeat(edges, 2)[1:-1],
            np.zeros(2 * len(counts)),
            np.repeat(counts, 2),
            colour="#1f77b4",
            opacity=1.0,
        )
    return str(fig)


def residuals(frame: Columns, covariates: list[tuple[str, str]]) -> str:
    """Normalised residuals (residual ÷ noise floor) of every observation and output axis
    against each covariate; a model that explains the data leaves a band of about ±2."""
    n = len(covariates)
    rows = -(-n // 3)
    fig = svg.Figure(WIDTH, 44 + rows * 200)
    grid = fig.grid(rows, 3, count=n, top=12, vgap=56)
    z = {a: np.asarray(frame[f"z_{a}"], float) for a in AXES}
    finite = np.concatenate([v[np.isfinite(v)] for v in z.values()] + [np.array([-3.0, 3.0])])
    ylim = (float(finite.min()) * 1.04, float(finite.max()) * 1.04)
    for k, (panel, (label, column)) in enumerate(zip(grid, covariates, strict=False)):
        x = frame[column]
        ticks = None
        if x.dtype.kind not in "biuf":  # categories side by side; a missing one not drawn
            labels = x.astype(str)
            there = present(x)
            ticks = np.unique(labels[there]).tolist()
            x = np.full(len(labels), np.nan)
            x[there] = np.searchsorted(np.array(ticks), labels[there])
            panel.xticks = (np.arange(len(ticks), dtype=float), ticks)
            panel.xlim = (-0.6, len(ticks) - 0.4)
        panel.hspan(-2, 2, "#2ca02c", 0.1)
        for m, a in enumerate(AXES):
            offset = (m - 1) * 0.15 if ticks is not None else 0.0
            panel.markers(
                np.asarray(x, float) + offset,
                z[a],
                colour=AXIS_COLOURS[a],
                size=3.5,
                opacity=0.7,
                label=a if k == 0 else None,
            )
        panel.ylim, panel.xlabel = ylim, label
        if k % 3 == 0:
            panel.ylabel = "residual ÷ floor"
        else:
            panel.show_yticklabels = False
    if grid:
        grid[0].legend_at = "upper right"
    return str(fig)


def shape_estimate(estimate: dict) -> str:
    """The diagnosis' smooth estimate of the residuals (or of the scale change, for a
    product with the own rate) against the leading input, per output axis, with its ±2σ
    band: the shape a term of the missing effect should have."""
    x = np.asarray(estimate["x"], dtype=float)
    unit = estimate["unit"]
    if unit == "s" and x.max() > 600:
        x, unit = x / 60.0, "min"
    product = estimate["of"] == "scale change"
    factor, ylabel = (1e6, "scale change, ×10⁻⁶") if product else (1.0, "residual, deg/s")
    fig = svg.Figure(WIDTH, 250)
    grid = fig.grid(1, 3, left=78, hgap=40)
    lows, highs = [], []
    for panel, a in zip(grid, AXES, strict=False):
        curve = estimate["axes"].get(a)
        panel.hline(0.0, colour="#000", width=0.6)
        if curve is not None:
            low, high = np.asarray(curve["low"], float) * factor, np.asarray(curve["high"], float) * factor
            panel.band(x, low, high, colour=AXIS_COLOURS[a], opacity=0.2)
            panel.line(x, np.asarray(curve["fit"], float) * factor, colour=AXIS_COLOURS[a], width=1.5)
            lows.append(np.nanmin(low))
            highs.append(np.nanmax(high))
        panel.title, panel.xlabel = f"output {a}", f"{estimate['input']}, {unit}"
    if lows:  # one scale for the three outputs
        lo, hi = min(min(lows), 0.0), max(max(highs), 0.0)
        pad = (hi - lo) * 0.04 or 1.0
        for k, panel in enumerate(grid):
            panel.ylim = (lo - pad, hi + pad)
            panel.show_yticklabels = k == 0
    grid[0].ylabel = ylabel
    return str(fig)


def heatmaps(maps: list[tuple[str, str, dict]]) -> str:
    """RMS of the normalised residuals per cell (1: as noise would give), one panel per
    map; keys are ``"row|column"`` with numeric columns (reference rate)."""
    fig = svg.Figure(WIDTH, 40 + 270 * len(maps))
    grid = fig.grid(len(maps), 1, left=110, right=120, top=14, vgap=90, bottom=76)
    for panel, (row_label, col_label, cells) in zip(grid, maps, strict=False):
        keys = [k.split("|") for k in cells]
        row_keys = sorted({r for r, _ in keys}, key=_sort_key)
        col_keys = sorted({c for _, c in keys}, key=float)
        values = np.full((len(row_keys), len(col_keys)), np.nan)
        for (r, c), v in zip(keys, cells.values(), strict=False):
            values[row_keys.index(r), col_keys.index(c)] = v
        top = max(float(np.nanmax(values)) if np.isfinite(values).any() else 5.0, 5.0)
        index = svg.palette_index(np.nan_to_num(values, nan=1.0), 0.5, top, len(svg.HEAT), log=True)
        colours = np.where(np.isfinite(values), np.array(svg.HEAT, dtype=object)[index], None)
        panel.cells(values, colours)
        every = max(len(row_keys) // 16, 1)  # labels a line apart at most
        panel.yticks = (np.arange(0, len(row_keys), every, dtype=float), row_keys[::every])
        step = max(len(col_keys) // 12, 1)
        panel.xticks = (
            np.arange(0, len(col_keys), step, dtype=float),
            [f"{float(c):g}" for c in col_keys[::step]],
        )
        panel.rotate_xticks = True
        panel.xlabel, panel.ylabel = col_label, row_label
        fig.colourbar(
            panel.left + panel.w + 16,
            panel.top,
            14,
            panel.h,
            svg.HEAT,
            0.5,
            top,
            "RMS residual ÷ floor",
            log=True,
        )
    return str(fig)


def _sort_key(text: str):
    try:
        return (0, float(text), "")
    except ValueError:
        return (1, 0.0, text)


def ladder(rows: list[dict]) -> str:
    """Validation RMS of each model of the ladder, falling toward the noise floor."""
    steps = [i for i, r in enumerate(rows) if "validation_rms" in r]  # numbered as in the table
    rows = [rows[i] for i in steps]
    fig = svg.Figure(640, 280)
    (panel,) = fig.grid(1, 1, left=78)
    x = np.array(steps, float)
    panel.ylog = True
    for key, colour, shape, dash, label in (
        ("validation_rms", "#1f77b4", "o", None, "validation RMS"),
        ("expected_rms", "#ff7f0e", "s", "2 3", "expected of a correct model"),
    ):
        y = [r[key] for r in rows]
        panel.line(x, y, colour=colour, dash=dash)
        panel.markers(x, y, colour=colour, shape=shape, size=6 if shape == "o" else 4, label=label)
    panel.line(x, [r["noise_floor"] for r in rows], colour="#000", dash="5 3", label="noise floor")
    panel.xticks = (x, [f"step {int(i)}" for i in x])
    panel.xlim = (x.min() - 0.3, x.max() + 0.3) if x.size else None
    panel.ylabel, panel.legend_at = "RMS error of hold means, deg/s", "upper right"
    return str(fig)


def sweep_drift(train: pd.DataFrame, verify: pd.DataFrame, models: dict) -> str:
    """Seed 003: drift error of each window against temperature, training and verification
    sweeps, with each drift model's curve over the training range."""
    fig = svg.Figure(WIDTH, 270)
    grid = fig.grid(1, 3, left=72, hgap=56)
    order = np.argsort(train["temp"].to_numpy(), kind="stable")
    curve = train.iloc[order]
    predictions = {name: model.predict(curve) for name, model in models.items()}
    for i, (panel, a) in enumerate(zip(grid, AXES, strict=False)):
        panel.markers(
            train["temp"],
            train[f"err_{a}"],
            colour="#999999",
            size=2.5,
            label="training sweep" if i == 0 else None,
        )
        if verify is not train:
            panel.markers(
                verify["temp"],
                verify[f"err_{a}"],
                colour="#2ca02c",
                size=2.5,
                label="verification sweep" if i == 0 else None,
            )
        for (name, predicted), dash in zip(
            predictions.items(), ("5 3", None, "1 2", "6 2 1 2"), strict=False
        ):
            panel.line(
                curve["temp"], predicted[:, i], colour=svg.INK, dash=dash, label=name if i == 0 else None
            )
        panel.title, panel.xlabel = f"gyro {a}", "temperature, °C"
    grid[0].ylabel, grid[0].legend_at = "drift error, deg/s", "upper left"
    return str(fig)


def servo_errors(holds: Columns) -> str:
    """Seed 001: per revolution, the error of the rate's magnitude against the servo speed,
    before calibration and validated after it, with the revolution's noise floor."""
    fig = svg.Figure(WIDTH, 280)
    grid = fig.grid(1, 2, left=78, hgap=70, bottom=60)
    x = np.arange(len(holds), dtype=float)
    labels = holds["direction"].astype(str).tolist()
    for panel, column, title in (
        (grid[0], "uncompensated_error", "uncompensated"),
        (grid[1], "validated_error", "validated (leave-one-revolution-out)"),
    ):
        if column == "validated_error":
            floor = np.asarray(holds["noise_floor"], float)
            panel.band(x, -2 * floor, 2 * floor, colour="#2ca02c", opacity=0.15, label="±2 noise floor")
            panel.legend_at = "upper right"
        panel.hline(0.0, colour="#000", width=0.6)
        panel.markers(x, holds[column], colour="#1f77b4", size=5)
        panel.title, panel.xlabel = title, "revolution (rotation direction)"
        panel.xticks = (x, labels)
        panel.rotate_xticks = len(labels) > 12
        panel.xlim = (-0.5, len(labels) - 0.5) if labels else None
    grid[0].ylabel = "|ω| error, deg/s"
    return str(fig)


def allan(noise: dict) -> str:
    """Overlapping Allan deviation of the session's static stretches per axis (error bars: the
    confidence interval from the edf), the fitted IEEE Std 952 model and its slopes (-1/2 angle
    random walk, 0 bias instability, +1/2 rate random walk), and each temperature point's
    curve in grey."""
    from ..fit.floor import terms_of

    session = noise["session"]
    curve = session["allan"]
    tau = np.asarray(curve["tau_s"], float)
    adev, lo, hi = (np.asarray(curve[k], float) for k in ("adev", "lo", "hi"))
    terms = terms_of(session)
    grid_tau = np.geomspace(tau[0], tau[-1], 120)
    model = terms.adev(grid_tau)
    arw, bi, rrw = (
        np.atleast_1d(np.asarray(getattr(terms, k), float)) for k in ("arw", "bias_instability", "rrw")
    )
    fig = svg.Figure(WIDTH, 300)
    grid = fig.grid(1, 3, left=78, hgap=40)
    everything = [adev, lo, hi, model]
    for i, (panel, a) in enumerate(zip(grid, AXES, strict=False)):
        panel.xlog = panel.ylog = True
        for point in noise.get("points", []):
            if "allan" in point:
                panel.line(
                    point["allan"]["tau_s"],
                    np.asarray(point["allan"]["adev"], float)[:, i],
                    colour="#bbbbbb",
                    width=0.8,
                )
                everything.append(np.asarray(point["allan"]["adev"], float))
        panel.errorbars(tau, lo[:, i], hi[:, i], colour=AXIS_COLOURS[a])
        panel.markers(tau, adev[:, i], colour=AXIS_COLOURS[a], size=5, label="measured")
        panel.line(grid_tau, model[:, i], colour="#000", width=1.2, label="fitted model")
        slopes = (
            ("−½: angle random walk", arw[i] / 60.0 / np.sqrt(grid_tau), "1 2"),
            ("0: bias instability", np.full_like(grid_tau, 0.6643 * bi[i] / 3600.0), "5 3"),
            ("+½: rate random walk", rrw[i] / 3600.0**1.5 * np.sqrt(grid_tau / 3.0), "6 2 1 2"),
        )
        for label, line, dash in slopes:
            if np.all(line > 0):
                panel.line(grid_tau, line, colour="#000", width=0.8, dash=dash, label=label)
        panel.xlabel, panel.title = "averaging time τ, s", f"gyro {a}"
    values = np.concatenate([np.ravel(v) for v in everything])
    values = values[np.isfinite(values) & (values > 0)]
    if values.size:  # one scale for the three axes
        ylim = (float(values.min()) / 1.3, float(values.max()) * 1.3)
        for k, panel in enumerate(grid):
            panel.ylim = ylim
            panel.show_yticklabels = k == 0
    grid[0].ylabel, grid[2].legend_at = "Allan deviation, deg/s", "upper right"
    return str(fig)
