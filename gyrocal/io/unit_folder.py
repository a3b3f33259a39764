"""The files of a unit session's results folder, which the stages write and the report
reads."""

from __future__ import annotations

from pathlib import Path

from .signals import Series
from .tables import read_table_with_metadata

UNIT_FILES = {
    "observations": "observations.parquet",
    "history": "history.parquet",
    "segments": "segments.parquet",
    "timeline": "timeline.parquet",
    "calibration": "calibration.json",
    "validation": "validation.json",
    "holds": "validation_holds.parquet",
    "table_hold_means": "table_hold_means.parquet",
    "table_samples": "table_samples.parquet",
    "by_temperature": "by_temperature.parquet",
    "diagnosis": "diagnosis.json",
    "residuals": "residuals.parquet",
    "protocol": "protocol.json",
    "free_points": "free_points.parquet",   # continuous models only
}
OPTIONAL_FILES = ("history", "free_points")
# Written by the validation stage beside validation.json (protocol.json: the protocol's own
# methods, the servo's two fits or the sweep's drift models, for the report).
VALIDATION_TABLES = ("holds", "table_hold_means", "table_samples", "by_temperature", "protocol")
DIAGNOSIS_FILES = ("diagnosis", "residuals")


def unit_paths(folder) -> dict[str, Path]:
    return {k: Path(folder) / v for k, v in UNIT_FILES.items()}


def read_observations(paths):
    """A unit's observation table and its metadata (``paths``: the unit's paths, or the
    observations file), the table carrying the session's record when segmentation wrote
    one beside it (``history.parquet``)."""
    observations = Path(paths["observations"] if isinstance(paths, dict) else paths)
    obs, extra = read_table_with_metadata(observations)
    if isinstance(extra.get("info"), dict) and isinstance(extra["info"].get("noise"), dict):
        obs.attrs["static_seconds"] = float(extra["info"]["noise"].get("static_seconds") or 0.0)
    history = observations.with_name(UNIT_FILES["history"])
    if history.exists():
        frame, meta = read_table_with_metadata(history)
        obs.attrs["series"] = Series.from_frame(frame, meta)
    return obs, extra
