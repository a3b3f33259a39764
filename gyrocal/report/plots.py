"""Figures for the reports, as inline SVG that is the same, byte for byte, on every run.

Figures are built with ``matplotlib.figure.Figure`` (no global pyplot state), saved as SVG
with a fixed hash salt, no date, and text kept as text; data strings never go into a figure.
"""

from __future__ import annotations

import io
import math

import matplotlib
import matplotlib.colors
import matplotlib.ticker

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from ..io import atomic  # noqa: E402

AXES = ("x", "y", "z")
AXIS_COLOURS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728"}
METHOD_STYLE = {"uncompensated": ("#7f7f7f", "o"), "single": ("#ff7f0e", "s"),
                "interpolated": ("#1f77b4", "^")}
REASON_COLOURS = ["#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf",
                  "#ff7f0e", "#7f7f7f", "#2ca02c", "#1f77b4"]
# The one style of gyrocal's figures. The hash salt fixes the ids inside an SVG and the
# metadata leaves the date out, so a figure is the same bytes on every run.
STYLE = {"svg.hashsalt": "gyrocal", "svg.fonttype": "none", "font.size": 9,
         "axes.grid": True, "grid.alpha": 0.3, "axes.spines.top": False,
         "axes.spines.right": False}
SVG_METADATA = {"Date": None, "Creator": "gyrocal"}


def figure_style(overrides: dict | None = None):
    """Context to draw and save figures in: :data:`STYLE`, with ``overrides`` (rcParams)."""
    return matplotlib.rc_context({**STYLE, **(overrides or {})})


def to_svg(fig: Figure) -> str:
    buf = io.StringIO()
    with figure_style():
        fig.savefig(buf, format="svg", metadata=SVG_METADATA,
                    bbox_inches="tight", dpi=110)  # dpi: the rasterised data layers
    svg = buf.getvalue()
    return svg[svg.index("<svg"):]  # inline: drop the XML prolog and doctype


def write_svg(svg: str, path_or_none) -> str:
    """``svg`` written to ``path_or_none`` (atomically) when given; returned either way."""
    if path_or_none is not None:
        atomic.write_text(path_or_none, svg)
    return svg


def figure(w: float, h: float, rows: int = 1, cols: int = 1, **kw):
    with figure_style():
        fig = Figure(figsize=(w, h), layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axes


def panels(names: list, row_height: float):
    """A figure of one panel per name, three to a row, the spare panels hidden:
    (figure, [(axis, name), ...]). Call it inside :func:`figure_style`."""
    cols = min(3, max(len(names), 1))
    rows = max(math.ceil(len(names) / cols), 1)
    fig, axes = figure(10, row_height * rows + 0.4, rows, cols)
    flat = list(axes.ravel())
    for axis in flat[len(names):]:
        axis.set_visible(False)
    return fig, list(zip(flat, names))


def timeline(timeline: pd.DataFrame, segments: pd.DataFrame) -> str:
    """Temperature, reference rate and gyro over the session; accepted holds shaded,
    rejected segments marked by reason (seed 000 Section 3.2's protocol, as found)."""
    with figure_style():
        fig, ax = figure(10, 6.5, 3, 1, sharex=True)
        ax = ax[:, 0]
        hours = lambda t: (np.asarray(t) - timeline["t_start"].iloc[0]) / 3600.0  # noqa: E731
        t = hours((timeline["t_start"] + timeline["t_end"]) / 2)
        ax[0].plot(t, timeline["temp"], color="#444", lw=0.8)
        ax[0].set_ylabel("temperature, °C")
        ax[1].fill_between(t, timeline["ref_min"], timeline["ref_max"], color="#444", lw=0.6,
                           step="mid", rasterized=True)
        ax[1].set_ylabel("reference, deg/s")
        for a in AXES:
            ax[2].fill_between(t, timeline[f"gyro_{a}_min"], timeline[f"gyro_{a}_max"],
                               color=AXIS_COLOURS[a], alpha=0.7, lw=0.4, step="mid", label=a,
                               rasterized=True)
        ax[2].set_ylabel("gyro, deg/s")
        ax[2].set_xlabel("time since start, h")
        ax[2].legend(loc="upper right", ncol=3, fontsize=8)
        holds = segments[segments["kind"] == "hold"]
        for s, e in zip(hours(holds["t_start"]), hours(holds["t_end"])):
            ax[1].axvspan(s, e, color="#2ca02c", alpha=0.25, lw=0, rasterized=True)
        rejected = segments[segments["kind"] == "rejected"]
        for k, (reason, group) in enumerate(rejected.groupby("reason", sort=True)):
            colour = REASON_COLOURS[k % len(REASON_COLOURS)]
            for j, (s, e) in enumerate(zip(hours(group["t_start"]), hours(group["t_end"]))):
                for axis in ax:
                    axis.axvspan(s, e, color=colour, alpha=0.3, lw=0,
                                 label=f"{reason} ({len(group)})" if axis is ax[0] and j == 0 else None)
        ax[1].axvspan(0, 0, color="#2ca02c", alpha=0.25, label=f"accepted hold ({len(holds)})")
        handles = ax[0].get_legend_handles_labels()[0] + ax[1].get_legend_handles_labels()[0]
        if handles:
            fig.legend(handles=handles, loc="outside upper center", ncol=4, fontsize=8)
        return to_svg(fig)


def parameters(grid_temps: np.ndarray, values: dict, stderr: dict, curve_temps: np.ndarray,
               curve: dict) -> str:
    """Scale-factor errors, cross-axis terms and biases against temperature with 1-sigma
    error bars and the interpolation between points (seed 000 Figs. 4-6)."""
    groups = [("scale-factor error, ppm", [f"scale.{a}" for a in AXES], 1e6),
              ("cross-axis term K[a,b], ×10⁻³", [f"misalignment.{a}.{b}" for a in AXES for b in AXES
                                                  if a != b], 1e3),
              ("bias, deg/s", [f"bias.{a}" for a in AXES], 1.0)]
    with figure_style():
        fig, ax = figure(10, 3.2, 1, 3)
        for axis, (label, names, scale) in zip(ax[0], groups):
            for k, name in enumerate(n for n in names if n in values):
                colour = REASON_COLOURS[(k + 3) % len(REASON_COLOURS)] if len(names) > 3 \
                    else AXIS_COLOURS[name.split(".")[1]]
                short = ".".join(name.split(".")[1:])
                axis.errorbar(grid_temps, np.asarray(values[name]) * scale,
                              yerr=np.asarray(stderr[name]) * scale, fmt="o", ms=3, capsize=2,
                              color=colour, label=short)
                axis.plot(curve_temps, np.asarray(curve[name]) * scale, color=colour, lw=0.8)
            axis.set_title(label, fontsize=9)
            axis.set_xlabel("temperature, °C")
            axis.legend(fontsize=7, ncol=2)
        return to_svg(fig)


def by_temperature(table: pd.DataFrame) -> str:
    """Leave-temperature-out RMS per held-out point and method, with the noise floor."""
    with figure_style():
        fig, ax = figure(7, 3.2)
        ax = ax[0, 0]
        for method, (colour, marker) in METHOD_STYLE.items():
            ax.plot(table["temp"], table[f"{method}_rms"], marker=marker, color=colour, label=method)
        ax.plot(table["temp"], table["noise_floor"], "k--", lw=1, label="noise floor")
        clamped = table[table["clamped"]]
        ax.plot(clamped["temp"], clamped["interpolated_rms"], "x", color="k", ms=9,
                label="outside the remaining range")
        ax.set_yscale("log")
        ax.set_xlabel("held-out temperature, °C")
        ax.set_ylabel("RMS error of hold means, deg/s")
        ax.legend(fontsize=7)
        return to_svg(fig)


def error_distribution(holds: pd.DataFrame, method: str) -> str:
    """Error of each hold mean against the reference rate, one panel per rotating axis
    (rows) and output axis (columns), coloured by temperature (seed 000 Figs. 7-8)."""
    rows = holds[holds["method"] == method]
    with figure_style():
        fig, ax = figure(10, 7.5, 3, 3, sharex="row")
        lo, hi = float(holds["temp"].min()), float(holds["temp"].max())
        for i, rot in enumerate(AXES):
            g = rows[rows["axis"] == rot]
            for j, out in enumerate(AXES):
                axis = ax[i, j]
                inside = ~g["clamped"].to_numpy()
                sc = axis.scatter(g["ref_rate"][inside], g[f"err_{out}"][inside], c=g["temp"][inside],
                                  s=8, vmin=lo, vmax=hi, cmap="coolwarm", rasterized=True)
                if method != "uncompensated" and (~inside).any():  # clamped: hollow
                    axis.scatter(g["ref_rate"][~inside], g[f"err_{out}"][~inside], s=10,
                                 facecolors="none", edgecolors="#888", lw=0.6, rasterized=True)
                axis.set_title(f"{rot} rotates, {out} output", fontsize=8)
                if i == 2:
                    axis.set_xlabel("reference rate, deg/s")
                if j == 0:
                    axis.set_ylabel("error, deg/s")
        fig.colorbar(sc, ax=ax, label="temperature, °C", shrink=0.6)
        return to_svg(fig)


def histogram(values: np.ndarray, label: str) -> str:
    """Distribution of one quantity across the fleet's calibrated units."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    with figure_style():
        fig, ax = figure(3.3, 2.4)
        ax = ax[0, 0]
        if values.size:
            ax.hist(values, bins=min(20, max(3, values.size)), color="#1f77b4")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
        ax.set_title(label, fontsize=8)
        ax.set_ylabel("units")
        return to_svg(fig)


def residuals(frame: pd.DataFrame, covariates: list[tuple[str, str]]) -> str:
    """Normalised residuals (residual ÷ noise floor) of every observation and output axis
    against each covariate; a model that explains the data leaves a band of about ±2."""
    n = len(covariates)
    cols = 3
    rows = -(-n // cols)
    with figure_style():
        fig, ax = figure(10, 2.3 * rows, rows, cols, sharey=True)
        flat = ax.ravel()
        for axis, (label, column) in zip(flat, covariates):
            x = frame[column]
            ticks = None
            if not pd.api.types.is_numeric_dtype(x):  # categories side by side
                ticks = [c for c in pd.unique(x.astype(str)) if c != "nan"]
                ticks.sort()
                x = x.astype(str).map({c: i for i, c in enumerate(ticks)}).astype(float)
            for k, a in enumerate(AXES):
                offset = (k - 1) * 0.15 if ticks is not None else 0.0
                axis.scatter(np.asarray(x, float) + offset, frame[f"z_{a}"], s=5,
                             color=AXIS_COLOURS[a], label=a, alpha=0.7, lw=0, rasterized=True)
            axis.axhspan(-2, 2, color="#2ca02c", alpha=0.08, lw=0)
            if ticks is not None:
                axis.set_xticks(range(len(ticks)), ticks)
            axis.set_xlabel(label)
        for axis in flat[n:]:
            axis.set_visible(False)
        for axis in ax[:, 0]:
            axis.set_ylabel("residual ÷ floor")
        flat[0].legend(fontsize=7, ncol=3, loc="upper right")
        return to_svg(fig)


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
    with figure_style():
        fig, ax = figure(10, 2.6, 1, 3, sharey=True)
        for axis, a in zip(ax[0], AXES):
            curve = estimate["axes"].get(a)
            axis.axhline(0.0, color="k", lw=0.6)
            if curve is not None:
                axis.fill_between(x, np.asarray(curve["low"]) * factor, np.asarray(curve["high"]) * factor,
                                  color=AXIS_COLOURS[a], alpha=0.2, lw=0)
                axis.plot(x, np.asarray(curve["fit"]) * factor, color=AXIS_COLOURS[a], lw=1.5)
            axis.set_title(f"output {a}", fontsize=9)
            axis.set_xlabel(f"{estimate['input']}, {unit}", parse_math=False)
        ax[0, 0].set_ylabel(ylabel)
        return to_svg(fig)


def heatmaps(maps: list[tuple[str, str, dict]]) -> str:
    """RMS of the normalised residuals per cell (1: as noise would give), one panel per
    map; keys are ``"row|column"`` with numeric columns (reference rate)."""
    with figure_style():
        fig, ax = figure(10, 3.0 * len(maps), len(maps), 1)
        for axis, (row_label, col_label, cells) in zip(ax[:, 0], maps):
            keys = [k.split("|") for k in cells]
            row_keys = sorted({r for r, _ in keys}, key=_sort_key)
            col_keys = sorted({c for _, c in keys}, key=float)
            grid = np.full((len(row_keys), len(col_keys)), np.nan)
            for (r, c), v in zip(keys, cells.values()):
                grid[row_keys.index(r), col_keys.index(c)] = v
            image = axis.imshow(grid, aspect="auto", cmap="magma_r", interpolation="nearest",
                                norm=matplotlib.colors.LogNorm(vmin=0.5, vmax=max(np.nanmax(grid), 5.0)))
            axis.set_yticks(range(len(row_keys)), row_keys)
            step = max(len(col_keys) // 12, 1)
            axis.set_xticks(range(0, len(col_keys), step),
                            [f"{float(c):g}" for c in col_keys[::step]], rotation=45)
            axis.set_xlabel(col_label)
            axis.set_ylabel(row_label)
            axis.grid(False)
            fig.colorbar(image, ax=axis, label="RMS residual ÷ floor")
        return to_svg(fig)


def _sort_key(text: str):
    try:
        return (0, float(text), "")
    except ValueError:
        return (1, 0.0, text)


def ladder(rows: list[dict]) -> str:
    """Validation RMS of each model of the ladder, falling toward the noise floor."""
    steps = [i for i, r in enumerate(rows) if "validation_rms" in r]  # numbered as in the table
    rows = [rows[i] for i in steps]
    with figure_style():
        fig, ax = figure(7, 3.0)
        ax = ax[0, 0]
        x = np.array(steps)
        ax.plot(x, [r["validation_rms"] for r in rows], "o-", color="#1f77b4", label="validation RMS")
        ax.plot(x, [r["expected_rms"] for r in rows], "s:", color="#ff7f0e", ms=4,
                label="expected of a correct model")
        ax.plot(x, [r["noise_floor"] for r in rows], "k--", lw=1, label="noise floor")
        ax.set_xticks(x, [f"step {i}" for i in x])
        ax.set_yscale("log")
        ax.set_ylabel("RMS error of hold means, deg/s")
        ax.legend(fontsize=7)
        return to_svg(fig)


def sweep_drift(train: pd.DataFrame, verify: pd.DataFrame, models: dict) -> str:
    """Seed 003: drift error of each window against temperature, training and verification
    sweeps, with each drift model's curve over the training range."""
    with figure_style():
        fig, axes = figure(7.5, 2.6, 1, 3)
        for i, a in enumerate("xyz"):
            ax = axes[0, i]
            ax.plot(train["temp"], train[f"err_{a}"], ".", ms=2, color="#999999", label="training sweep")
            if verify is not train:
                ax.plot(verify["temp"], verify[f"err_{a}"], ".", ms=2, color="#2ca02c",
                        label="verification sweep")
            order = np.argsort(train["temp"].to_numpy())
            curve = train.iloc[order]
            for (name, model), style in zip(models.items(), ("--", "-", ":", "-.")):
                ax.plot(curve["temp"], model.predict(curve)[:, i], style, lw=1, label=name)
            ax.set_title(f"gyro {a}")
            ax.set_xlabel("temperature, °C")
            if i == 0:
                ax.set_ylabel("drift error, deg/s")
        axes[0, 0].legend(fontsize=6)
        return to_svg(fig)


def servo_errors(holds: pd.DataFrame) -> str:
    """Seed 001: per revolution, the error of the rate's magnitude against the servo speed,
    before calibration and validated after it, with the revolution's noise floor."""
    with figure_style():
        fig, axes = figure(7.5, 2.6, 1, 2)
        x = np.arange(len(holds))
        labels = holds["direction"].astype(str).to_numpy()
        for ax, column, title in ((axes[0, 0], "uncompensated_error", "uncompensated"),
                                  (axes[0, 1], "validated_error", "validated (leave-one-revolution-out)")):
            ax.plot(x, holds[column], "o", ms=3, color="#1f77b4")
            if column == "validated_error":
                floor = holds["noise_floor"].to_numpy()
                ax.fill_between(x, -2 * floor, 2 * floor, color="#2ca02c", alpha=0.15, lw=0,
                                label="±2 noise floor")
                ax.legend(fontsize=7)
            ax.axhline(0, color="k", lw=0.6)
            ax.set_title(title)
            ax.set_xticks(x, labels, fontsize=6)
            ax.set_xlabel("revolution (rotation direction)")
        axes[0, 0].set_ylabel("|ω| error, deg/s")
        return to_svg(fig)


def allan(noise: dict) -> str:
    """Overlapping Allan deviation of the session's static stretches per axis (error bars: the
    confidence interval from the edf), the fitted IEEE Std 952 model and its slopes (-1/2 angle
    random walk, 0 bias instability, +1/2 rate random walk), and each temperature point's
    curve in grey."""
    from ..fit.floor import terms_of
    session = noise["session"]
    curve = session["allan"]
    tau = np.asarray(curve["tau_s"])
    adev, lo, hi = (np.asarray(curve[k]) for k in ("adev", "lo", "hi"))
    terms = terms_of(session)
    grid = np.geomspace(tau[0], tau[-1], 200)
    model = terms.adev(grid)
    arw, bi, rrw = (np.atleast_1d(np.asarray(getattr(terms, k), float))
                    for k in ("arw", "bias_instability", "rrw"))
    with figure_style():
        fig, ax = figure(10, 3.4, 1, 3, sharey=True)
        for i, a in enumerate(AXES):
            axis = ax[0, i]
            for point in noise.get("points", []):
                if "allan" in point:
                    axis.loglog(point["allan"]["tau_s"], np.asarray(point["allan"]["adev"])[:, i],
                                color="#bbbbbb", lw=0.7)
            axis.errorbar(tau, adev[:, i], yerr=[adev[:, i] - lo[:, i], hi[:, i] - adev[:, i]],
                          fmt="o", ms=3, color=AXIS_COLOURS[a], lw=0.8, label="measured")
            axis.loglog(grid, model[:, i], color="k", lw=1, label="fitted model")
            slopes = (("−½: angle random walk", arw[i] / 60.0 / np.sqrt(grid)),
                      ("0: bias instability", np.full_like(grid, 0.6643 * bi[i] / 3600.0)),
                      ("+½: rate random walk", rrw[i] / 3600.0 ** 1.5 * np.sqrt(grid / 3.0)))
            for (label, line), style in zip(slopes, (":", "--", "-.")):
                if np.all(line > 0):
                    axis.loglog(grid, line, "k", ls=style, lw=0.7, label=label)
            axis.set_xlabel("averaging time τ, s")
            axis.set_title(f"gyro {a}")
        ax[0, 0].set_ylabel("Allan deviation, deg/s")
        ax[0, 2].legend(fontsize=7, loc="best")
        return to_svg(fig)
