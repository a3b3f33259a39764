"""HTML reports: Jinja2 with autoescape, self-contained (no external requests)."""

from __future__ import annotations

from pathlib import Path

import jinja2
import numpy as np

from .validate import METHODS

_ENV = jinja2.Environment(loader=jinja2.PackageLoader("gyrocal", "templates"),
                          autoescape=jinja2.select_autoescape(["html", "j2"]),
                          undefined=jinja2.StrictUndefined, keep_trailing_newline=True)


def fmt(value, digits: int = 4) -> str:
    """Numbers as engineers read them: fixed for ordinary sizes, scientific otherwise."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    value = float(value)
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:.{digits}g}"
    return f"{value:.{max(digits - 1, 1)}e}"


_ENV.filters["fmt"] = fmt


def write_unit_report(result, path, *, command: str = "") -> None:
    cal, seg, val = result.calibration, result.segmentation, result.validation
    counts = seg.counts()
    html = _ENV.get_template("unit_report.html.j2").render(
        meta=cal.meta, span=cal.grid.span, summary=val.summary, methods=METHODS,
        table_holds=val.table_holds.to_dict("records"),
        table_samples=val.table_samples.to_dict("records"),
        by_temperature=val.by_temperature.to_dict("records"),
        counts_columns=list(counts.columns), counts=[(t, list(r)) for t, r in counts.iterrows()],
        rejected=seg.info["rejected_by_reason"], info=seg.info,
        provenance=cal.provenance, command=command)
    Path(path).write_text(html)
