"""The one Jinja environment of gyrocal's HTML pages: unit, fleet, drift and failure reports
and the papers' tables.

Templates come from ``gyrocal/report/templates``; every string from data is escaped (autoescape),
a name a template uses but is not given is an error, and the pages share the number formats
below as filters.
"""

from __future__ import annotations

import jinja2
import numpy as np


def _bytecode_cache():
    """Compiled templates kept between processes (a per-user folder in the temporary
    directory, keyed by each template's source): compiling the unit report's template
    costs a report process a tenth of a second. None where that folder is unsafe."""
    try:
        return jinja2.FileSystemBytecodeCache()
    except (OSError, RuntimeError):
        return None


ENV = jinja2.Environment(
    loader=jinja2.PackageLoader("gyrocal.report", "templates"),
    autoescape=jinja2.select_autoescape(["html", "j2"]),
    undefined=jinja2.StrictUndefined,
    keep_trailing_newline=True,
    bytecode_cache=_bytecode_cache(),
)


def fmt(value, digits: int = 4) -> str:
    """Numbers as engineers read them: fixed for ordinary sizes, scientific otherwise."""
    if value is None or isinstance(value, str):
        return "–" if value is None else value
    value = float(value)
    if not np.isfinite(value):
        return "–"
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:.{digits}g}"
    return f"{value:.{max(digits - 1, 1)}e}"


def pvalue(value) -> str:
    """p-values below double precision's resolution of 1 - p print as a bound."""
    return "< 1e-16" if value is not None and float(value) < 1e-16 else fmt(value, 2)


ENV.filters["fmt"] = fmt
ENV.filters["pvalue"] = pvalue
ENV.filters["prel"] = lambda v: pvalue(v) if pvalue(v).startswith("<") else "= " + pvalue(v)


def render_page(template: str, **context) -> str:
    """The page ``template`` (a file in ``gyrocal/report/templates``) filled with ``context``."""
    return ENV.get_template(template).render(**context)


def write_failure(outputs, rec: dict) -> None:
    """A failure record (:mod:`gyrocal.io.failure`) in every output of a stage: a page saying
    what failed for HTML, the record itself for Parquet and JSON."""
    from pathlib import Path

    from ..io import atomic, failure

    for out in map(Path, outputs):
        if out.suffix == ".html":
            out.parent.mkdir(parents=True, exist_ok=True)
            atomic.write_text(out, render_page("failure.html.j2", r=rec))
        else:
            failure.write([out], rec)
