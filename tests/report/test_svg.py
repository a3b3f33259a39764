"""The reports' SVG plotter: compact path data that still says where every point is, no more
points than pixels, escaped text, the same bytes on every run."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gyrocal.report import svg

NUMBER = re.compile(r"[MmLlHhVvZz]|-?(?:\d+\.?\d*|\.\d+)")


def polylines(d: str) -> list[np.ndarray]:
    """The absolute vertices of path data made of M and relative l (or m … h0) commands."""
    tokens = NUMBER.findall(d)
    lines, x, y, k, command = [], 0.0, 0.0, 0, None
    while k < len(tokens):
        tok = tokens[k]
        if tok in "MmLlHhVvZz":
            command = tok
            k += 1
            if tok in "Hh":  # the dots' zero-length strokes
                assert tokens[k] == "0"
                k += 1
            continue
        a, b = float(tokens[k]), float(tokens[k + 1])
        k += 2
        if command == "M":
            x, y = a, b
            lines.append([(x, y)])
        elif command == "m":
            x, y = x + a, y + b
            lines.append([(x, y)])
        elif command == "l":
            x, y = x + a, y + b
            lines[-1].append((x, y))
        else:
            raise AssertionError(f"unexpected command {command}")
    return [np.array(line) for line in lines]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-5000, 5000), st.floats(-5000, 5000)), min_size=1, max_size=40))
def test_path_data_gives_back_every_vertex_to_a_twentieth_of_a_pixel(points):
    px, py = np.array(points).T
    (line,) = polylines(svg.Panel._path(px, py))
    assert line.shape == (len(points), 2)
    assert np.all(np.abs(line - np.column_stack([px, py])) <= 0.05 + 1e-9)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(-30000, 30000), st.integers(-30000, 30000)), min_size=1, max_size=40))
def test_dots_are_relative_moves_that_add_up_exactly(points):
    tenths = np.array(points)
    dots = polylines(svg._dots(tenths / 10.0))
    assert np.allclose(np.array([d[0] for d in dots]) * 10, tenths, atol=1e-6)


def test_a_path_breaks_where_a_value_is_missing():
    lines = polylines(svg.Panel._path(np.arange(6.0), np.array([1, 2, np.nan, 4, 5, 6.0])))
    assert [len(line) for line in lines] == [2, 3]


def _rendered(build) -> str:
    fig = svg.Figure(400, 300)
    (panel,) = fig.grid(1, 1)
    build(panel)
    return str(fig)


def test_a_series_longer_than_its_panel_is_wide_becomes_its_envelope():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 1, 200_000)
    y = np.sin(20 * x) + rng.normal(0, 0.1, x.size)
    text = _rendered(lambda p: p.line(x, y))
    width = 400 - 64 - 14
    assert len(text) < 40 * width  # a few bytes per pixel column, not per sample
    (path,) = [m for m in re.findall(r'<path d="([^"]+)"[^>]*fill="#333"', text)]
    (outline,) = polylines(path)
    assert len(outline) <= 2 * (width + 1)
    # the envelope reaches the extremes of the data: the highest and lowest samples
    panel = svg.Panel(64, 26, width, 300 - 26 - 44)
    panel.items, panel._xs, panel._ys = [], [], []
    panel.line(x, y)
    panel._limits()
    assert outline[:, 1].min() == pytest.approx(float(panel.sy(y.max())), abs=0.06)
    assert outline[:, 1].max() == pytest.approx(float(panel.sy(y.min())), abs=0.06)


def test_markers_on_the_same_pixel_are_drawn_once():
    one = _rendered(lambda p: p.markers([0.0, 1.0], [0.0, 1.0]))
    many = _rendered(lambda p: p.markers(np.r_[np.zeros(5000), 1.0], np.r_[np.zeros(5000), 1.0]))
    assert many == one


def test_text_from_data_is_escaped_and_the_figure_is_the_same_twice():
    def build(panel):
        panel.markers([0, 1, 2], [1, 2, 3], label="<b>&")
        panel.xticks = (np.arange(3.0), ["<script>", 'a"b', "ok"])
        panel.legend_at = "upper right"

    first, second = _rendered(build), _rendered(build)
    assert first == second
    assert "<script>" not in first and "&lt;script&gt;" in first and "&lt;b&gt;&amp;" in first
    assert "a&quot;b" in first


@pytest.mark.parametrize(
    "lo,hi", [(0.0, 1.0), (-0.013, 0.052), (-400.0, 400.0), (57.0, 59.0), (1e-6, 3e-6), (12345.0, 98765.0)]
)
def test_ticks_are_round_cover_the_range_and_read_apart(lo, hi):
    ticks = svg.nice_ticks(lo, hi)
    assert 3 <= len(ticks) <= 11
    assert ticks[0] >= lo - 1e-12 and ticks[-1] <= hi + 1e-12
    assert ticks[0] - lo < (hi - lo) / 2 and hi - ticks[-1] < (hi - lo) / 2
    labels = [svg.tick_label(v, ticks) for v in ticks]
    assert len(set(labels)) == len(labels), labels


def test_log_axes_tick_decades_or_one_two_five():
    assert [lab for _, lab in zip(*_ticks(1e-4, 1e-1), strict=False)] == ["10⁻⁴", "10⁻³", "10⁻²", "10⁻¹"]
    assert [lab for _, lab in zip(*_ticks(0.5, 6.0), strict=False)] == ["0.5", "1", "2", "5"]


def _ticks(lo, hi):
    panel = svg.Panel(0, 0, 100, 100)
    return panel._ticks((lo, hi), True)


def test_an_envelope_stays_inside_its_panel_and_keeps_its_gaps():
    x = np.linspace(0, 2, 20_000)
    y = np.sin(x * 7)
    y[5000:6000] = np.nan  # a gap in the record
    fig = svg.Figure(400, 300)
    (panel,) = fig.grid(1, 1)
    panel.line(x, y)
    panel.band(x, y - 0.1, y + 0.1)
    panel.xlim = (0.0, 1.0)  # half the record lies beyond the panel
    text = str(fig)
    paths = re.findall(r'<path d="([^"]+)"[^>]*fill="#333"', text)
    outlines = [line for d in paths for line in polylines(d)]
    assert len(outlines) == 4  # line and band, each broken at the gap
    right = panel.left + panel.w
    assert all(line[:, 0].max() <= right + 0.6 and line[:, 0].min() >= panel.left - 0.6 for line in outlines)


def test_residuals_by_a_category_with_missing_values_leave_those_out():
    import pandas as pd

    from gyrocal.io.columns import Columns
    from gyrocal.report import plots

    frame = Columns.from_frame(
        pd.DataFrame(
            {
                "mount": ["+x", None, "+z", "+x"],
                "z_x": [0.1, 0.2, 0.3, 0.4],
                "z_y": [0.0, 1.0, 2.0, 3.0],
                "z_z": [1.0, 1.0, 1.0, 1.0],
            }
        )
    )
    text = plots.residuals(frame, [("mount", "mount")])
    labels = re.findall(r">([^<]+)</text>", text)
    assert "+x" in labels and "+z" in labels and "nan" not in labels and "None" not in labels
    assert plots.residuals(frame.assign(mount=np.array([None] * 4, object)), [("mount", "mount")]).startswith(
        "<svg"
    )
    with_nan = plots.residuals(
        frame.assign(mount=np.array(["+x", np.nan, "+z", "+x"], object)), [("mount", "mount")]
    )
    assert "nan" not in re.findall(r">([^<]+)</text>", with_nan)


@pytest.mark.parametrize("values", [[1.0, 1 + 1e-12, 1 + 2e-12, 1 + 2e-12], [2.0, 2.0, 2.0], [1e-3] * 4])
def test_a_histogram_of_equal_values_draws_a_bar_a_bin_wide(values):
    """A fleet whose units agree to within rounding: one bar as wide as the others would be
    (the axis spans a tenth of the value each side), not one as narrow as the rounding."""
    from gyrocal.report import plots

    page = plots.histogram(np.array(values), "scale")
    band = re.findall(r'<path[^>]*d="(M[\d.]+ [\d.]+l[^"]*Z)"', page)[0]
    steps = [float(v) for v in re.findall(r"-?[\d.]+", band[band.index("l") :])]
    widths = [abs(dx) for dx, dy in zip(steps[::2], steps[1::2], strict=False) if dx and not dy]
    assert min(widths) > 40  # pixels: a bin of a 244-px panel, not a hair
    lo, hi = (float(t.replace("−", "-")) for t in re.findall(r"<text[^>]*>([^<]*)</text>", page)[:5:4])
    assert lo == pytest.approx(0.9 * values[0], rel=1e-6) and hi == pytest.approx(1.1 * values[0], rel=1e-6)
