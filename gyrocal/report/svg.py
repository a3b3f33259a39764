"""A small SVG plotter for the reports: figures that cost what they show.

matplotlib takes 8–10 s and about 1 MB to draw a unit report's figures, most of it layout
and markers drawn one by one. Here a figure is a few panels of paths written straight to
SVG text:

* no more points than pixels: a series longer than its panel is wide becomes its envelope
  (min and max per pixel column), and markers falling on the same pixel in the same colour
  are drawn once;
* coordinates with one decimal (a tenth of a pixel), one path per series and colour;
* the same bytes on every run (no ids, no dates, sorted inputs), text escaped, nothing
  fetched: fonts are the browser's sans-serif.

Tick labels are placed with an estimate of text width (0.6 em per character), so margins are
fixed per figure rather than measured.
"""

from __future__ import annotations

import functools
import html
import math

import numpy as np

FONT = 11  # px, tick labels; axis labels and titles one px larger
CHAR = 0.6  # em per character, for the width of a label
GRID = "#e3e3e3"
INK = "#333"


def _f(v: float) -> str:
    """A coordinate with at most one decimal."""
    s = f"{v:.1f}"
    return s[:-2] if s.endswith(".0") else s


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def _tenths(t: int) -> str:
    """An integer count of tenths as the shortest SVG number: 12 -> 1.2, -3 -> -.3, 40 -> 4."""
    whole, frac = divmod(abs(int(t)), 10)
    text = (str(whole) if whole else "") + (f".{frac}" if frac else "")
    return ("-" if t < 0 else "") + (text or "0")


@functools.cache
def _token(t: int) -> tuple[str, bool, bool, bool]:
    """``_tenths(t)``; whether it starts with a sign, starts with a point, has a point."""
    text = _tenths(t)
    return text, text[0] == "-", text[0] == ".", "." in text


def _numbers(values) -> str:
    """Numbers (in tenths) joined as SVG path data: a space only where no sign or second
    decimal point separates them already."""
    out, previous_dot = [], None
    for t in np.asarray(values).tolist():
        text, minus, leading_dot, has_dot = _token(t)
        if previous_dot is not None and not (minus or (leading_dot and previous_dot)):
            out.append(" ")
        out.append(text)
        previous_dot = has_dot
    return "".join(out)


def _dots(points: np.ndarray) -> str:
    """Zero-length strokes at each point (drawn as dots by a round or square cap), each a
    relative move from the one before."""
    t = np.round(np.asarray(points, float) * 10).astype(np.int64)
    out = [f"M{_tenths(t[0, 0])} {_tenths(t[0, 1])}h0"]
    for dx, dy in np.diff(t, axis=0).tolist():
        a, b = _token(dx), _token(dy)
        out.append(f"m{a[0]}{'' if b[1] or (b[2] and a[3]) else ' '}{b[0]}h0")
    return "".join(out)


def text_width(text: str, size: float = FONT) -> float:
    return len(str(text)) * size * CHAR


def nice_ticks(lo: float, hi: float, count: int = 5) -> np.ndarray:
    """Round tick values (1, 2, 2.5, 5 × 10^k) covering [lo, hi], about ``count`` of them."""
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if np.isfinite(lo) else np.array([0.0])
    raw = (hi - lo) / max(count, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    ticks = first + step * np.arange(int(math.floor((hi - first) / step + 1e-9)) + 1)
    return np.where(np.abs(ticks) < step * 1e-9, 0.0, ticks)


def tick_label(v: float, ticks: np.ndarray) -> str:
    """Enough significant digits to tell the ticks apart, no more."""
    if v == 0:
        return "0"
    step = float(np.min(np.diff(ticks))) if len(ticks) > 1 else abs(v)
    mag = max(abs(float(np.max(np.abs(ticks)))), abs(v))
    if mag >= 1e5 or mag < 1e-3:
        digits = max(int(math.ceil(math.log10(mag / step))) + 1, 1) if step > 0 else 2
        return f"{v:.{digits - 1}e}".replace("e-0", "e-").replace("e+0", "e").replace("e+", "e")
    decimals = max(0, -int(math.floor(math.log10(step) + 1e-9))) if step > 0 else 0
    if step > 0 and abs(round(step * 10**decimals) - step * 10**decimals) > 1e-6:
        decimals += 1
    return f"{v:.{decimals}f}".replace("-", "−")


SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _decade(k: int) -> str:
    return "1" if k == 0 else f"10{str(k).translate(SUPERSCRIPT)}"


class Panel:
    """One plotting area at (left, top) of w × h px. Items are collected with their data,
    the limits are settled when the figure is written (the data's range plus 4 %, or as set)."""

    def __init__(self, left: float, top: float, w: float, h: float):
        self.left, self.top, self.w, self.h = left, top, w, h
        self.items: list = []
        self.xlog = self.ylog = False
        self.xlim: tuple | None = None
        self.ylim: tuple | None = None
        self._xs: list = []
        self._ys: list = []
        self.title = self.xlabel = self.ylabel = ""
        self.xticks: tuple | None = None  # (values, labels): categories
        self.yticks: tuple | None = None
        self.legend_at: str | None = None  # "upper right", "upper left", "lower right", None
        self.grid = True
        self.show_xticklabels = True
        self.show_yticklabels = True
        self.rotate_xticks = False
        self.ticks_right = False  # a colour bar's scale

    # ---------------------------------------------------------------- data items
    def _extent(self, x=None, y=None):
        for store, v, log in ((self._xs, x, self.xlog), (self._ys, y, self.ylog)):
            if v is None:
                continue
            v = np.asarray(v, float).ravel()
            v = v[np.isfinite(v) & ((v > 0) if log else True)]
            if v.size:
                store.append((float(v.min()), float(v.max())))

    def line(self, x, y, colour=INK, width=1.0, dash=None, label=None, opacity=1.0):
        x, y = np.asarray(x, float), np.asarray(y, float)
        self._extent(x, y)
        self.items.append(("line", x, y, dict(colour=colour, width=width, dash=dash, opacity=opacity), label))

    def markers(self, x, y, colour=INK, size=4.0, shape="o", label=None, hollow=False, opacity=1.0):
        """Markers of diameter ``size`` px; ``colour`` one colour or one per point."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        self._extent(x, y)
        self.items.append(
            (
                "markers",
                x,
                y,
                dict(colour=colour, size=size, shape=shape, hollow=hollow, opacity=opacity),
                label,
            )
        )

    def errorbars(self, x, lo, hi, colour=INK, width=0.8, cap=2.0):
        x, lo, hi = (np.asarray(v, float) for v in (x, lo, hi))
        self._extent(x, np.r_[lo, hi])
        self.items.append(("errorbars", x, (lo, hi), dict(colour=colour, width=width, cap=cap), None))

    def band(self, x, lo, hi, colour=INK, opacity=0.25, step=False, label=None):
        x, lo, hi = (np.asarray(v, float) for v in (x, lo, hi))
        self._extent(x, np.r_[lo, hi])
        self.items.append(("band", x, (lo, hi), dict(colour=colour, opacity=opacity, step=step), label))

    def vspan(self, x0, x1, colour, opacity=0.25, label=None):
        """Vertical stripes from x0[i] to x1[i] over the whole height."""
        x0, x1 = np.atleast_1d(np.asarray(x0, float)), np.atleast_1d(np.asarray(x1, float))
        self._extent(np.r_[x0, x1], None)
        self.items.append(("vspan", x0, x1, dict(colour=colour, opacity=opacity), label))

    def hspan(self, y0, y1, colour, opacity=0.1):
        self.items.append(("hspan", None, (y0, y1), dict(colour=colour, opacity=opacity), None))

    def hline(self, y, colour=INK, width=0.8, dash=None, label=None):
        self.items.append(("hline", None, y, dict(colour=colour, width=width, dash=dash), label))

    def cells(self, grid: np.ndarray, colours: np.ndarray):
        """A heat map: grid[i, j] drawn as the cell (j, i) in ``colours[i, j]`` (None: empty);
        x from -0.5 to columns - 0.5, y from rows - 0.5 (bottom) to -0.5 (top)."""
        rows, cols = grid.shape
        self.xlim, self.ylim = (-0.5, cols - 0.5), (rows - 0.5, -0.5)
        self.items.append(("cells", None, None, dict(colours=colours), None))
        self.grid = False

    # ---------------------------------------------------------------- scales
    def _limits(self):
        def settle(spans, log, fixed):
            if fixed is not None:
                return fixed
            if not spans:
                return (1.0, 10.0) if log else (0.0, 1.0)
            lo, hi = min(s[0] for s in spans), max(s[1] for s in spans)
            if log:
                lo, hi = math.log10(lo), math.log10(hi)
            if hi - lo <= 1e-9 * max(abs(lo), abs(hi)):  # one value, up to rounding
                lo = hi = (lo + hi) / 2
            pad = (hi - lo) * 0.04 if hi > lo else (abs(lo) * 0.1 or 0.5)
            lo, hi = lo - pad, hi + pad
            return (10**lo, 10**hi) if log else (lo, hi)

        self.X = settle(self._xs, self.xlog, self.xlim)
        self.Y = settle(self._ys, self.ylog, self.ylim)

    @staticmethod
    def _fraction(v, lim, log: bool):
        """Where values lie between the limits, 0 at the first and 1 at the second (NaN for
        a non-positive value on a log scale)."""
        v = np.asarray(v, float)
        lo, hi = lim
        if log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v, lo, hi = np.log10(np.where(v > 0, v, np.nan)), math.log10(lo), math.log10(hi)
        return (v - lo) / (hi - lo)

    def sx(self, x):
        return self.left + self._fraction(x, self.X, self.xlog) * self.w

    def sy(self, y):
        return self.top + self.h - self._fraction(y, self.Y, self.ylog) * self.h

    def _clampx(self, px):
        return np.clip(px, self.left, self.left + self.w)

    def _clampy(self, py):
        return np.clip(py, self.top, self.top + self.h)

    # ---------------------------------------------------------------- drawing
    def render(self) -> list[str]:
        self._limits()
        out = [self._axes_back()]
        for kind, x, y, style, _ in self.items:
            out.append(getattr(self, f"_draw_{kind}")(x, y, **style))
        out.append(self._axes_front())
        if self.legend_at:
            out.append(self._legend())
        return [s for s in out if s]

    def _ticks(self, lim, log):
        lo, hi = min(lim), max(lim)
        if log:
            k0, k1 = math.ceil(math.log10(lo) - 1e-9), math.floor(math.log10(hi) + 1e-9)
            if k1 - k0 >= 1:
                stride = max(1, math.ceil((k1 - k0 + 1) / 7))
                ks = list(range(k0, k1 + 1, stride))
                return np.array([10.0**k for k in ks]), [_decade(k) for k in ks]
            if k1 - k0 >= -1:  # within about two decades: 1, 2 and 5 of each
                ticks = np.array([m * 10.0**k for k in range(k0 - 1, k1 + 1) for m in (1, 2, 5)])
                ticks = ticks[(ticks >= lo * (1 - 1e-9)) & (ticks <= hi * (1 + 1e-9))]
                if ticks.size >= 2:
                    return ticks, [f"{v:g}" for v in ticks]
            ticks = nice_ticks(lo, hi, 4)
            ticks = ticks[ticks > 0]
            return ticks, [tick_label(v, ticks) for v in ticks]
        ticks = nice_ticks(lo, hi)
        return ticks, [tick_label(v, ticks) for v in ticks]

    def _axes_back(self) -> str:
        parts = [
            f'<rect x="{_f(self.left)}" y="{_f(self.top)}" width="{_f(self.w)}" height="{_f(self.h)}" '
            f'fill="#fff" stroke="none"/>'
        ]
        if not self.grid:
            return parts[0]
        xv, _ = self.xticks or self._ticks(self.X, self.xlog)
        yv, _ = self.yticks or self._ticks(self.Y, self.ylog)
        d = []
        for px in self.sx(xv):
            if self.left <= px <= self.left + self.w:
                d.append(f"M{_f(px)} {_f(self.top)}v{_f(self.h)}")
        for py in self.sy(yv):
            if self.top <= py <= self.top + self.h:
                d.append(f"M{_f(self.left)} {_f(py)}h{_f(self.w)}")
        if d:
            parts.append(f'<path d="{"".join(d)}" stroke="{GRID}" stroke-width="1" fill="none"/>')
        return "".join(parts)

    def _axes_front(self) -> str:
        L, T, W, H = self.left, self.top, self.w, self.h
        frame = (
            f"M{_f(L)} {_f(T)}h{_f(W)}v{_f(H)}h{_f(-W)}Z"
            if self.ticks_right
            else f"M{_f(L)} {_f(T)}V{_f(T + H)}H{_f(L + W)}"
        )
        parts = [f'<path d="{frame}" stroke="{INK}" stroke-width="1" fill="none"/>']
        xv, xl = self.xticks or self._ticks(self.X, self.xlog)
        yv, yl = self.yticks or self._ticks(self.Y, self.ylog)
        ticks, labels = [], []
        for _, lab, px in zip(xv, xl, self.sx(xv), strict=False):
            if not (L - 0.5 <= px <= L + W + 0.5):
                continue
            ticks.append(f"M{_f(px)} {_f(T + H)}v4")
            if self.show_xticklabels:
                if self.rotate_xticks:
                    labels.append(
                        f'<text transform="translate({_f(px)} {_f(T + H + 8)}) rotate(-45)" '
                        f'text-anchor="end" dominant-baseline="middle">{_esc(lab)}</text>'
                    )
                else:
                    labels.append(
                        f'<text x="{_f(px)}" y="{_f(T + H + 15)}" text-anchor="middle">{_esc(lab)}</text>'
                    )
        for _, lab, py in zip(yv, yl, self.sy(yv), strict=False):
            if not (T - 0.5 <= py <= T + H + 0.5):
                continue
            if self.ticks_right:
                ticks.append(f"M{_f(L + W)} {_f(py)}h4")
                labels.append(f'<text x="{_f(L + W + 6)}" y="{_f(py + 4)}">{_esc(lab)}</text>')
                continue
            ticks.append(f"M{_f(L)} {_f(py)}h-4")
            if self.show_yticklabels:
                labels.append(f'<text x="{_f(L - 6)}" y="{_f(py + 4)}" text-anchor="end">{_esc(lab)}</text>')
        if ticks:
            parts.append(f'<path d="{"".join(ticks)}" stroke="{INK}" stroke-width="1"/>')
        parts.extend(labels)
        big = FONT + 1
        if self.title:
            parts.append(
                f'<text x="{_f(L + W / 2)}" y="{_f(T - 7)}" text-anchor="middle" '
                f'font-size="{big}">{_esc(self.title)}</text>'
            )
        if self.xlabel:
            below = 32 + (max((text_width(s) for s in xl), default=0) * 0.7 if self.rotate_xticks else 0)
            parts.append(
                f'<text x="{_f(L + W / 2)}" y="{_f(T + H + below)}" text-anchor="middle" '
                f'font-size="{big}">{_esc(self.xlabel)}</text>'
            )
        if self.ylabel:
            room = max((text_width(s) for s in yl), default=20) if self.show_yticklabels else 0
            x = L - room - 14
            parts.append(
                f'<text transform="translate({_f(x)} {_f(T + H / 2)}) rotate(-90)" '
                f'text-anchor="middle" font-size="{big}">{_esc(self.ylabel)}</text>'
            )
        return "".join(parts)

    @staticmethod
    def _path(px, py) -> str:
        """A polyline broken where a point is not finite, in relative steps of tenths of a
        pixel with no digit or separator the SVG grammar does not need."""
        px, py = np.asarray(px, float), np.asarray(py, float)
        ok = np.isfinite(px) & np.isfinite(py)
        starts = np.flatnonzero(ok & ~np.r_[False, ok[:-1]])
        stops = np.flatnonzero(ok & ~np.r_[ok[1:], False]) + 1
        out = []
        for a, b in zip(starts, stops, strict=False):
            tx, ty = np.round(px[a:b] * 10).astype(np.int64), np.round(py[a:b] * 10).astype(np.int64)
            out.append(f"M{_tenths(tx[0])} {_tenths(ty[0])}")
            if b - a > 1:
                steps = np.column_stack([np.diff(tx), np.diff(ty)]).ravel()
                out.append("l" + _numbers(steps))
        return "".join(out)

    def _envelope(self, px, lo, hi):
        """Per pixel column the extremes of the values drawn into it (px sorted)."""
        col = np.floor(px - self.left).astype(np.int64)
        starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
        return (self.left + col[starts] + 0.5, np.fmin.reduceat(lo, starts), np.fmax.reduceat(hi, starts))

    def _inside_x(self, px) -> np.ndarray:
        return (px >= self.left - 0.5) & (px <= self.left + self.w + 0.5)

    @staticmethod
    def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
        """(start, stop) of each run of True in ``mask``."""
        edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
        return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=False))

    def _draw_line(self, x, y, colour, width, dash, opacity):
        px, py = self.sx(x), self.sy(y)
        ok = np.isfinite(px) & np.isfinite(py)
        style = (f' stroke-dasharray="{dash}"' if dash else "") + (
            f' opacity="{opacity}"' if opacity < 1 else ""
        )
        if ok.sum() > self.w and np.all(np.diff(px[ok]) >= 0):
            # more points than pixel columns: the envelope of each stretch without a gap,
            # drawn as a thin band, within the panel's x range
            keep = ok & self._inside_x(px)
            return "".join(
                self._polygon(cx, np.maximum(hi, lo + 0.01), np.minimum(lo, hi), colour, 1.0, width, style)
                for cx, lo, hi in (self._envelope(px[a:b], py[a:b], py[a:b]) for a, b in self._runs(keep))
            )
        # a line leaving the panel breaks off there rather than run along its edge
        outside = (py < self.top - 0.5) | (py > self.top + self.h + 0.5) | ~self._inside_x(px)
        py = np.where(outside, np.nan, py)
        return (
            f'<path d="{self._path(px, py)}" stroke="{colour}" '
            f'stroke-width="{width}" fill="none" stroke-linejoin="round"{style}/>'
        )

    def _polygon(self, cx, top, bottom, colour, opacity, stroke=0.0, style=""):
        d = self._path(np.r_[cx, cx[::-1]], np.r_[top, bottom[::-1]])
        edge = f' stroke="{colour}" stroke-width="{stroke}"' if stroke else ' stroke="none"'
        return f'<path d="{d}Z" fill="{colour}" fill-opacity="{opacity}"{edge}{style}/>'

    def _draw_band(self, x, y, colour, opacity, step):
        lo, hi = y
        px = self.sx(x)
        plo, phi = self._clampy(self.sy(lo)), self._clampy(self.sy(hi))
        ok = np.isfinite(px) & np.isfinite(plo) & np.isfinite(phi)
        if ok.sum() > self.w and np.all(np.diff(px[ok]) >= 0):
            # the envelope per pixel column of each stretch without a gap, within the panel
            keep = ok & self._inside_x(px)
            out = []
            for a, b in self._runs(keep):
                cx, top, bottom = self._envelope(
                    px[a:b], np.fmin(plo[a:b], phi[a:b]), np.fmax(plo[a:b], phi[a:b])
                )
                out.append(self._polygon(cx, top, bottom, colour, opacity))
            return "".join(out)
        px, plo, phi = px[ok], plo[ok], phi[ok]
        if px.size == 0:
            return ""
        if step and px.size > 1:
            mid = (px[1:] + px[:-1]) / 2
            edges = np.r_[px[0] - (mid[0] - px[0]), mid, px[-1] + (px[-1] - mid[-1])]
            px = np.repeat(edges, 2)[1:-1]
            plo, phi = np.repeat(plo, 2), np.repeat(phi, 2)
        return self._polygon(self._clampx(px), phi, plo, colour, opacity)

    def _draw_markers(self, x, y, colour, size, shape, hollow, opacity):
        px, py = self.sx(x), self.sy(y)
        colours = np.broadcast_to(np.asarray(colour, dtype=object), px.shape)
        ok = np.isfinite(px) & np.isfinite(py)
        # One marker per pixel and colour (the rest would be drawn over it), inside the panel:
        # whole points sorted by colour, then x, then y, and the repeats dropped, at once.
        kx, ky = (np.round(np.clip(p[ok], -1e6, 1e6)).astype(np.int64) for p in (px, py))
        inside = (
            (kx >= self.left - 1)
            & (kx <= self.left + self.w + 1)
            & (ky >= self.top - 1)
            & (ky <= self.top + self.h + 1)
        )
        if not inside.any():
            return ""
        names, code = np.unique(colours[ok][inside], return_inverse=True)
        kx, ky, code = kx[inside], ky[inside], code.ravel()
        order = np.lexsort((ky, kx, code))
        kx, ky, code = kx[order], ky[order], code[order]
        new = np.r_[True, (np.diff(code) != 0) | (np.diff(kx) != 0) | (np.diff(ky) != 0)]
        kx, ky, code = kx[new], ky[new], code[new]
        starts = np.flatnonzero(np.r_[True, np.diff(code) != 0])
        out = []
        for first, last in zip(starts, np.r_[starts[1:], len(code)], strict=False):
            c = names[code[first]]
            key = np.column_stack([kx[first:last], ky[first:last]]).astype(float)
            alpha = f' opacity="{opacity}"' if opacity < 1 else ""
            r = size / 2
            if shape in ("o", "s") and not hollow:
                cap = "round" if shape == "o" else "square"
                out.append(
                    f'<path d="{_dots(key)}" stroke="{c}" stroke-width="{_f(size)}" '
                    f'stroke-linecap="{cap}"{alpha}/>'
                )
            elif shape == "^":
                d = "".join(f"M{_f(a)} {_f(b - r)}l{_f(r)} {_f(1.7 * r)}h{_f(-2 * r)}Z" for a, b in key)
                out.append(f'<path d="{d}" fill="{c}"{alpha}/>')
            elif shape == "x":
                d = "".join(
                    f"M{_f(a - r)} {_f(b - r)}l{_f(2 * r)} {_f(2 * r)}m0 {_f(-2 * r)}l{_f(-2 * r)} {_f(2 * r)}"
                    for a, b in key
                )
                out.append(f'<path d="{d}" stroke="{c}" stroke-width="1.3" fill="none"{alpha}/>')
            else:  # hollow circles
                d = "".join(
                    f"M{_f(a - r)} {_f(b)}a{_f(r)} {_f(r)} 0 1 0 {_f(2 * r)} 0a{_f(r)} {_f(r)} 0 1 0 "
                    f"{_f(-2 * r)} 0"
                    for a, b in key
                )
                out.append(f'<path d="{d}" stroke="{c}" stroke-width="0.8" fill="none"{alpha}/>')
        return "".join(out)

    def _draw_errorbars(self, x, y, colour, width, cap):
        lo, hi = y
        px, plo, phi = self.sx(x), self._clampy(self.sy(lo)), self._clampy(self.sy(hi))
        ok = np.isfinite(px) & np.isfinite(plo) & np.isfinite(phi)
        d = "".join(
            f"M{_f(a)} {_f(b)}V{_f(c)}M{_f(a - cap)} {_f(b)}h{_f(2 * cap)}M{_f(a - cap)} {_f(c)}h{_f(2 * cap)}"
            for a, b, c in zip(px[ok], plo[ok], phi[ok], strict=False)
        )
        return f'<path d="{d}" stroke="{colour}" stroke-width="{width}" fill="none"/>' if d else ""

    def _draw_vspan(self, x0, x1, colour, opacity):
        a, b = self._clampx(self.sx(x0)), self._clampx(self.sx(x1))
        keep = np.isfinite(a) & np.isfinite(b)
        d = "".join(
            f"M{_f(p)} {_f(self.top)}h{_f(max(q - p, 0.5))}v{_f(self.h)}h{_f(-max(q - p, 0.5))}Z"
            for p, q in self._merge_px(a[keep], b[keep])
        )
        return f'<path d="{d}" fill="{colour}" fill-opacity="{opacity}"/>' if d else ""

    @staticmethod
    def _merge_px(a, b):
        """Stripes closer than half a pixel drawn as one."""
        order = np.argsort(a, kind="stable")
        out: list[list[float]] = []
        for p, q in zip(a[order], b[order], strict=False):
            if out and p <= out[-1][1] + 0.5:
                out[-1][1] = max(out[-1][1], q)
            else:
                out.append([p, q])
        return out

    def _draw_hspan(self, x, y, colour, opacity):
        a, b = self._clampy(self.sy(y[0])), self._clampy(self.sy(y[1]))
        top, bottom = min(a, b), max(a, b)
        return (
            f'<rect x="{_f(self.left)}" y="{_f(top)}" width="{_f(self.w)}" height="{_f(bottom - top)}" '
            f'fill="{colour}" fill-opacity="{opacity}"/>'
        )

    def _draw_hline(self, x, y, colour, width, dash):
        py = float(self.sy(y))
        if not (self.top <= py <= self.top + self.h):
            return ""
        style = f' stroke-dasharray="{dash}"' if dash else ""
        return (
            f'<path d="M{_f(self.left)} {_f(py)}h{_f(self.w)}" stroke="{colour}" '
            f'stroke-width="{width}"{style}/>'
        )

    def _draw_cells(self, x, y, colours):
        rows, cols = colours.shape
        cw, ch = self.w / cols, self.h / rows
        by_colour: dict[str, list[str]] = {}
        for i in range(rows):
            for j in range(cols):
                if colours[i, j] is not None:
                    by_colour.setdefault(colours[i, j], []).append(
                        f"M{_f(self.left + j * cw)} {_f(self.top + i * ch)}h{_f(cw + 0.3)}v{_f(ch + 0.3)}h{_f(-cw - 0.3)}Z"
                    )
        return "".join(f'<path d="{"".join(d)}" fill="{c}"/>' for c, d in sorted(by_colour.items()))

    def _draw_raw(self, x, y):
        return y

    def _legend(self) -> str:
        entries = [(label, kind, style) for kind, _, _, style, label in self.items if label]
        return legend(entries, self, self.legend_at)


def _swatch(kind: str, style: dict, x: float, y: float) -> str:
    c = style.get("colour", INK)
    if kind in ("band", "vspan"):
        return (
            f'<rect x="{_f(x)}" y="{_f(y - 5)}" width="16" height="9" fill="{c}" '
            f'fill-opacity="{max(style.get("opacity", 0.3), 0.25)}"/>'
        )
    if kind == "markers":
        one = dict(style, colour=c if isinstance(c, str) else INK)
        return _marker_at(x + 8, y, one)
    dash = f' stroke-dasharray="{style["dash"]}"' if style.get("dash") else ""
    return (
        f'<path d="M{_f(x)} {_f(y)}h16" stroke="{c}" stroke-width="{max(style.get("width", 1.0), 1.0)}"'
        f"{dash}/>"
    )


def _marker_at(x: float, y: float, style: dict) -> str:
    p = Panel(0, 0, 1e6, 1e6)
    p.X, p.Y = (0, 1e6), (1e6, 0)
    return p._draw_markers(np.array([x]), np.array([y]), **style)


def legend(
    entries: list, panel: Panel | None, where: str, *, x: float = 0, y: float = 0, columns: int = 1
) -> str:
    """A legend box: in a panel's corner (``where``) or at (x, y) in ``columns``."""
    if not entries:
        return ""
    widths = [24 + text_width(label, FONT - 1) for label, _, _ in entries]
    cols = max(1, min(columns, len(entries)))
    col_w = max(widths)
    rows = math.ceil(len(entries) / cols)
    box_w, box_h = cols * col_w + 8, rows * 15 + 6
    if panel is not None:
        x = panel.left + panel.w - box_w - 4 if "right" in where else panel.left + 4
        y = panel.top + 4 if "upper" in where else panel.top + panel.h - box_h - 4
    parts = [
        f'<rect x="{_f(x)}" y="{_f(y)}" width="{_f(box_w)}" height="{_f(box_h)}" fill="#fff" '
        f'fill-opacity="0.85" stroke="#ccc"/>'
    ]
    for k, (label, kind, style) in enumerate(entries):
        cx = x + 4 + (k % cols) * col_w
        cy = y + 11 + (k // cols) * 15
        parts.append(_swatch(kind, style, cx, cy))
        parts.append(f'<text x="{_f(cx + 21)}" y="{_f(cy + 4)}" font-size="{FONT - 1}">{_esc(label)}</text>')
    return "".join(parts)


class Figure:
    """Panels on a canvas of width × height px; ``str(fig)`` is the SVG."""

    def __init__(self, width: float, height: float):
        self.width, self.height = width, height
        self.panels: list[Panel] = []
        self.extra: list[str] = []

    def panel(self, left, top, w, h) -> Panel:
        p = Panel(left, top, w, h)
        self.panels.append(p)
        return p

    def grid(
        self,
        rows: int,
        cols: int,
        *,
        left=64,
        right=14,
        top=26,
        bottom=44,
        hgap=56,
        vgap=48,
        count: int | None = None,
    ) -> list[Panel]:
        """``rows`` × ``cols`` panels filling the canvas (the first ``count`` of them)."""
        w = (self.width - left - right - hgap * (cols - 1)) / cols
        h = (self.height - top - bottom - vgap * (rows - 1)) / rows
        n = rows * cols if count is None else count
        return [
            self.panel(left + (k % cols) * (w + hgap), top + (k // cols) * (h + vgap), w, h) for k in range(n)
        ]

    def colourbar(self, left, top, w, h, colours: list[str], lo, hi, label: str, log: bool = False) -> Panel:
        """A vertical scale of ``colours`` (bottom to top) from lo to hi, labelled on its right."""
        bar = self.panel(left, top, w, h)
        bar.ylog, bar.ylim, bar.xlim, bar.grid, bar.ticks_right = log, (lo, hi), (0, 1), False, True
        bar.xticks = (np.array([]), [])
        step = h / len(colours)
        bar.items.append(
            (
                "raw",
                None,
                "".join(
                    f'<rect x="{_f(left)}" y="{_f(top + h - (k + 1) * step)}" width="{_f(w)}" height="{_f(step + 0.3)}" '
                    f'fill="{c}"/>'
                    for k, c in enumerate(colours)
                ),
                {},
                None,
            )
        )
        self.extra.append(
            f'<text transform="translate({_f(left + w + 50)} {_f(top + h / 2)}) rotate(-90)" '
            f'text-anchor="middle" font-size="{FONT + 1}">{_esc(label)}</text>'
        )
        return bar

    def __str__(self) -> str:
        body = []
        for p in self.panels:
            body.extend(p.render())
        body.extend(self.extra)
        return (
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{_f(self.width)}" height="{_f(self.height)}" '
            f'viewBox="0 0 {_f(self.width)} {_f(self.height)}" font-family="sans-serif" font-size="{FONT}" '
            f'fill="{INK}">' + "".join(body) + "</svg>"
        )


def palette_index(values: np.ndarray, lo: float, hi: float, n: int, log: bool = False) -> np.ndarray:
    """Which of ``n`` colours each value gets on the scale lo..hi (clipped)."""
    v = np.asarray(values, float)
    if log:
        v, lo, hi = np.log10(np.clip(v, 1e-300, None)), math.log10(lo), math.log10(hi)
    span = hi - lo if hi > lo else 1.0
    return np.clip(((v - lo) / span * n).astype(np.int64), 0, n - 1)


# Diverging blue-white-red for temperatures, sequential light-to-dark for the heat maps.
COOLWARM = [
    "#3b4cc0",
    "#5d7ce6",
    "#82a6fb",
    "#aac7fd",
    "#cdd9ec",
    "#ead4c8",
    "#f7b89c",
    "#f18d6f",
    "#d95847",
    "#b40426",
]
HEAT = ["#fcfdbf", "#fec488", "#fc8961", "#e85362", "#b73779", "#822681", "#51127c", "#1d1147"]
