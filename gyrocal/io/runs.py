"""A unit session's record of the models it was analysed with: ``runs.json`` beside its
calibration, one entry per model (its figures in the session and on the unit's other
session, and the fix its diagnosis named), so that the report and the fleet summary show
how the error fell since the last model.

The workflow declares the file nowhere: Snakemake removes a job's outputs before the job
runs, and this record must outlive them. Only the configured model and the results decide
an entry, never the clock, so running the same model again leaves the record as it was;
but a report (and the fleet summary) drawn over a record of several models says so, and
differs from one drawn after a first run: the one thing in a unit folder that depends on
what ran before.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TypedDict

from . import atomic

FILE = "runs.json"
FORMAT = "gyrocal.runs/1"
KEPT = 20  # models remembered per unit session, the newest last


class RunModel(TypedDict):
    """The model a run fitted."""

    kind: str  # "grid" or "continuous"
    terms: list[str]  # each term's spec string


class NextSession(TypedDict):
    """A run's figure on the unit's other session."""

    session: str
    excess: float


class RunFix(TypedDict):
    """The fix a run's diagnosis named, with its figures."""

    term: str
    together: list[str]
    reads: str | None
    excess: float  # its validation RMS over the noise floor
    next_excess: float | None  # on the other session
    option: str | None
    config_line: str | None


class RunEntry(TypedDict):
    """One run of a unit session: its model as configured (``key``, a hash of the model
    settings) and as fitted, its figures in the session and on the other one, its fix."""

    key: str
    config_sha256: str | None
    entry: str | None
    model: RunModel
    dropped: list[str]  # terms added for identification and not kept
    validation_rms: float
    noise_floor: float
    excess: float
    held_out: str | None
    next_session: NextSession | None
    fix: RunFix | None


def read_runs(folder) -> list[RunEntry]:
    """The unit session's runs, oldest first; none where the record is missing or cannot be
    read (it is rewritten whole by the next run)."""
    path = Path(folder) / FILE
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    runs = doc.get("runs") if isinstance(doc, dict) and doc.get("format") == FORMAT else None
    return [r for r in runs if _well_formed(r)] if isinstance(runs, list) else []


def _well_formed(run) -> bool:
    """An entry the report and the fleet summary can read: its model's terms and kind, and
    finite figures in the session."""
    if not isinstance(run, dict) or not isinstance(run.get("key"), str):
        return False
    model = run.get("model")
    numbers = [run.get(k) for k in ("excess", "validation_rms", "noise_floor")]
    nxt, fix = run.get("next_session"), run.get("fix")
    return (
        isinstance(model, dict)
        and isinstance(model.get("terms"), list)
        and model.get("kind") in ("grid", "continuous")
        and all(isinstance(v, (int, float)) and math.isfinite(v) for v in numbers)
        and (
            nxt is None
            or (
                isinstance(nxt, dict)
                and isinstance(nxt.get("excess"), (int, float))
                and isinstance(nxt.get("session"), str)
            )
        )
        and (
            fix is None
            or (
                isinstance(fix, dict)
                and isinstance(fix.get("term"), str)
                and isinstance(fix.get("excess"), (int, float))
            )
        )
    )


def record_run(folder, run: RunEntry) -> list[RunEntry]:
    """Add ``run`` (with its model's ``key``) as the newest entry, replacing an earlier entry
    of the same model; returns the runs."""
    runs = [r for r in read_runs(folder) if r["key"] != run["key"]] + [run]
    runs = runs[-KEPT:]
    text = json.dumps({"format": FORMAT, "runs": _finite(runs)}, indent=1, sort_keys=True, allow_nan=False)
    atomic.write_text(Path(folder) / FILE, text + "\n")
    return runs


def last_two(runs: list[RunEntry], config_sha256: str | None) -> tuple[RunEntry | None, RunEntry | None]:
    """The run that made the calibration of settings hash ``config_sha256`` (the newest entry,
    when it is that one) and the run of the model before it, its figure on the other session
    kept only where that session is this run's too."""
    if not runs or config_sha256 is None or runs[-1].get("config_sha256") != config_sha256:
        return None, None
    current, previous = runs[-1], (runs[-2] if len(runs) > 1 else None)
    if previous is not None and (previous.get("next_session") or {}).get("session") != (
        current.get("next_session") or {}
    ).get("session"):
        previous = {
            **previous,
            "next_session": None,
            "fix": previous["fix"] and {**previous["fix"], "next_excess": None},
        }
    return current, previous


def _finite(value):
    """``value`` with every non-finite number as null: the record holds no NaN."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
