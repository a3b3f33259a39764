"""Figures for the reports, as inline SVG that is the same, byte for byte, on every run.

Figures are built with ``matplotlib.figure.Figure`` (no global pyplot state), saved as SVG
with a fixed hash salt, no date, and text kept as text; data strings never go into a figure.
"""

from __future__ import annotations

import io

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

AXES = ("x", "y", "z")
AXIS_COLOURS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728"}
METHOD_STYLE = {"uncompensated": ("#7f7f7f", "o"), "single": ("#ff7f0e", "s"),
                "interpolated": ("#1f77b4", "^")}
REASON_COLOURS = ["#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf",
                  "#ff7f0e", "#7f7f7f", "#2ca02c", "#1f77b4"]
_RC = {"svg.hashsalt": "gyrocal", "svg.fonttype": "none", "font.size": 9,
       "axes.grid": True, "grid.alpha": 0.3, "axes.spines.top": False,
       "axes.spines.right": False}


def to_svg(fig: Figure) -> str:
    buf = io.StringIO()
    with matplotlib.rc_context(_RC):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": "gyrocal"},
                    bbox_inches="tight", dpi=110)  # dpi: the rasterised data layers
    svg = buf.getvalue()
    return svg[svg.index("<svg"):]  # inline: drop the XML prolog and doctype


def figure(w: float, h: float, rows: int = 1, cols: int = 1, **kw):
    with matplotlib.rc_context(_RC):
        fig = Figure(figsize=(w, h), layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axes


def timeline(timeline: pd.DataFrame, segments: pd.DataFrame) -> str:
    """Temperature, reference rate and gyro over the session; accepted holds shaded,
    rejected segments marked by reason (seed 000 Section 3.2's protocol, as found)."""
    with matplotlib.rc_context(_RC):
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
    with matplotlib.rc_context(_RC):
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
    with matplotlib.rc_context(_RC):
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
    with matplotlib.rc_context(_RC):
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
    with matplotlib.rc_context(_RC):
        fig, ax = figure(3.3, 2.4)
        ax = ax[0, 0]
        if values.size:
            ax.hist(values, bins=min(20, max(3, values.size)), color="#1f77b4")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
        ax.set_title(label, fontsize=8)
        ax.set_ylabel("units")
        return to_svg(fig)
