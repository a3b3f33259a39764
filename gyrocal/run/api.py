"""gyrocal from Python: the functions behind the command line, for notebooks and scripts.

A log is a path (a Parquet file, or a folder of them read as one), a pandas DataFrame or a
pyarrow Table with the contract's columns (docs/log-format.md). A frame or table is written
to a temporary Parquet file first and read from there exactly as a file is, so a result
does not depend on how its log was handed over; the calibration's provenance then hashes
those bytes and names the log ``name``.

Every call runs numpy's BLAS on one thread, as the command line does, and gives the
caller's setting back afterwards: gyrocal's matrices are small, and a second thread only
spins when the other cores are busy.
"""

from __future__ import annotations

import contextlib
import functools
import html
import json
import os
import tempfile
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from ..calibration.file import Calibration, dumps, load_calibration, save_calibration
from ..io.errors import ConfigError
from ..pipeline.config import ModelSettings, Settings, read_yaml
from ..protocols import registry

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa

    from ..calibration.apply import ApplyCounts
    from ..pipeline.chain import Run

LogLike: TypeAlias = "str | os.PathLike[str] | pd.DataFrame | pa.Table"

__all__ = [
    "Calibration",
    "CalibrationResult",
    "Diagnosis",
    "LogLike",
    "Noise",
    "Settings",
    "apply",
    "calibrate",
    "diagnose",
    "load_calibration",
    "load_settings",
    "noise",
    "read_log",
    "simulate_log",
]

TABLE_NAME = "log.parquet"  # the name a frame or table is given in a calibration's provenance


def _one_blas_thread(function):
    """Run ``function`` with BLAS on one thread, the caller's setting restored after."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        import scipy.linalg  # noqa: F401 - scipy's own BLAS loads here, so the limit reaches it too
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return wrapper


@contextlib.contextmanager
def _as_path(log: LogLike, name: str | None = None, units: dict[str, str] | None = None) -> Iterator[Path]:
    """A path to read ``log`` from: the path itself, or a temporary Parquet file holding a
    DataFrame or Table (removed on exit), named ``name``, its units declared by ``units``
    (``gyrocal.units``; a DataFrame's ``attrs["gyrocal.units"]`` else). An error about that
    file names the frame or table instead."""
    if isinstance(log, str | os.PathLike):
        yield Path(log)
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..io.errors import GyrocalError

    file_name = _file_name(name)
    kind = "the Table given"
    if not isinstance(log, pa.Table):
        import pandas as pd

        if not isinstance(log, pd.DataFrame):
            raise ConfigError(
                f"a log is a path, a pandas DataFrame or a pyarrow Table, not {type(log).__name__}"
            )
        kind = "the DataFrame given"
        units = units if units is not None else log.attrs.get("gyrocal.units")
        if "t" not in log.columns and log.index.name == "t":  # time as the index, as series often are
            log = log.reset_index()
        log = pa.Table.from_pandas(log, preserve_index=False)
    if units is not None:
        declared = units if isinstance(units, str) else json.dumps(dict(units), sort_keys=True)
        log = log.replace_schema_metadata(
            {**(log.schema.metadata or {}), b"gyrocal.units": declared.encode()}
        )
    with tempfile.TemporaryDirectory(prefix="gyrocal-") as scratch:
        path = Path(scratch) / file_name
        pq.write_table(log, path)
        try:
            yield path
        except GyrocalError as exc:
            if exc.source != os.fspath(path):
                raise
            problem = str(exc).removeprefix(f"{os.fspath(path)}: ")
            raise type(exc)(problem, source=f"{kind} ({file_name})") from None


def _file_name(name: str | None) -> str:
    """A frame's file name for provenance: a bare name, never a path to write elsewhere."""
    if name is None:
        return TABLE_NAME
    if not name or Path(name).name != name or name in (".", ".."):
        raise ConfigError(f"name is the log's file name, without a folder, not {name!r}")
    return name


def load_settings(
    config: str | os.PathLike[str] | None = None,
    *,
    protocol: str = registry.DEFAULT,
    model: str | os.PathLike[str] | None = None,
    add_terms: Iterable[str] = (),
    term_files: Iterable[str | os.PathLike[str]] = (),
) -> Settings:
    """Settings as the command line builds them: ``config`` (the YAML of ``--config``),
    then ``model`` (``--model``'s YAML), ``term_files`` (``--terms``: Python files that
    register terms; they run as code) and ``add_terms`` (``--add-term``, e.g.
    ``"scale_quadratic"`` or the spec a diagnosis offers), settled for ``protocol``."""
    from ..terms.user import load_term_file

    files = tuple(str(f) for f in term_files)
    for path in files:
        load_term_file(path)
    settings = Settings.load(config) if config is not None else Settings()
    settings = settings.for_protocol(protocol)
    if model is not None:
        values = read_yaml(model)
        try:
            chosen = ModelSettings.from_dict(values.get("model", values))
        except ConfigError as exc:
            raise ConfigError(str(exc), source=model) from None
        settings = replace(settings, model=chosen)
    new_files = tuple(f for f in files if f not in settings.model.term_files)
    if new_files:
        settings = replace(
            settings, model=replace(settings.model, term_files=settings.model.term_files + new_files)
        )
    terms = tuple(add_terms)
    if terms:
        settings = replace(settings, model=settings.model.with_terms(terms))
        settings.model.build()  # an unknown name fails here, before any work
    return settings


def refuse_own_model(protocol: str | None, model_changed: bool) -> None:
    """A protocol with a calibration of its own (the servo's, seed 001's six parameters)
    ignores the model: a calibration asked to change it is refused, not quietly made without."""
    if model_changed and registry.get(protocol).calibrate is not None:
        raise ConfigError(
            f"a {protocol} calibration is the protocol's own model; --model and "
            "--add-term change the model the diagnosis reads: use them with "
            "gyrocal diagnose"
        )


def _settings_for(settings: Settings | None, protocol: str, add_terms: Iterable[str]) -> Settings:
    terms = tuple(add_terms)
    if settings is None:
        return load_settings(protocol=protocol, add_terms=terms)
    settings = settings.for_protocol(protocol)
    if terms:
        settings = replace(settings, model=settings.model.with_terms(terms))
        settings.model.build()
    return settings


def read_log(log: LogLike) -> pd.DataFrame:
    """The log as a DataFrame after the contract's checks (required columns, their types,
    declared units: a problem is one :class:`gyrocal.io.errors.GyrocalError` naming the file).
    The columns are as stored, in the units the log declares, which the frame keeps in
    ``attrs["gyrocal.units"]``: the frame given back to :func:`calibrate` reads as the file."""
    from ..io.log import REQUIRED, _open_checked

    with _as_path(log) as path:
        dataset, _, units = _open_checked(path, (), REQUIRED)
        frame = dataset.to_table().to_pandas()
    declared = (dataset.schema.metadata or {}).get(b"gyrocal.units")
    if declared is not None:
        frame.attrs["gyrocal.units"] = declared.decode()
    return frame


@dataclass(frozen=True, repr=False)
class CalibrationResult:
    """A calibrated log: :attr:`calibration` (the model, per temperature point or as one set),
    the segmentation's tables, and the validation (leave-temperature-out) with its summary.
    :meth:`save` writes the calibration file ``gyrocal calibrate -o`` writes."""

    run: Run
    settings: Settings
    protocol: str
    device_given: bool = True  # without a device, the report names the log

    @property
    def calibration(self) -> Calibration:
        return self.run.calibration

    @property
    def observations(self) -> pd.DataFrame:
        """One row per accepted hold: its mean rates, the true rate, temperature, mount ..."""
        return self.run.segmentation.observations

    @property
    def segments(self) -> pd.DataFrame:
        return self.run.segmentation.segments

    @property
    def summary(self) -> Mapping[str, Any]:
        """The validation's figures: ``validation_rms``, ``noise_floor``, ``excess``,
        ``single_rms``, ``uncompensated_rms`` ... (deg/s)."""
        return self.run.validation.summary

    @property
    def by_temperature(self) -> pd.DataFrame:
        """The Mean/RMS table per temperature point: uncompensated, single-temperature and
        interpolated compensation of the held-out holds (seed 000, Tables 4-6)."""
        return self.run.validation.by_temperature

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the calibration file (JSON, docs/calibration-file.md); returns its path."""
        save_calibration(self.calibration, path)
        return Path(path)

    def save_tables(self, folder: str | os.PathLike[str]) -> Path:
        """Write the observation and validation tables as Parquet (``calibrate --tables``)."""
        from ..io.tables import write_table

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        seg, val = self.run.segmentation, self.run.validation
        meta = {"summary": val.summary}
        for name, frame, extra in (
            ("observations", seg.observations, {"info": seg.info}),
            ("segments", seg.segments, {}),
            ("timeline", seg.timeline, {}),
            ("validation_holds", val.holds, meta),
            ("table_hold_means", val.table_holds, meta),
            ("table_samples", val.table_samples, meta),
            ("by_temperature", val.by_temperature, meta),
        ):
            write_table(frame, out / f"{name}.parquet", extra)
        return out

    @_one_blas_thread
    def report(self, path: str | os.PathLike[str], *, command: str = "") -> Path:
        """Write the HTML report ``calibrate --report`` writes (self-contained; the diagnosis
        of this run included); ``command`` is shown as how it was made."""
        from ..diagnosis import diagnose as run_diagnosis
        from ..diagnosis import evaluation_of
        from ..pipeline.chain import settings_used
        from ..report.unit import UnitResults, write_unit_report

        result = self.run
        obs = result.segmentation.observations
        used = settings_used(self.settings, result.calibration)
        base = (
            None
            if result.fitted is None
            else evaluation_of(used, result.fitted, dict(result.validation.summary), "configured model")
        )
        diagnosis = run_diagnosis(used, obs, base=base)
        results = UnitResults.from_run(result, command, diagnosis, registry.analysis(self.protocol, obs))
        results.device_unknown = not self.device_given
        write_unit_report(results, path, registry.get(self.protocol))
        return Path(path)

    def apply(self, log: LogLike, *, units: dict[str, str] | None = None) -> pd.DataFrame:
        """``log`` compensated with this calibration (see :func:`apply`)."""
        return apply(self.calibration, log, units=units)

    @_one_blas_thread
    def check(self, log: LogLike, *, units: dict[str, str] | None = None) -> dict[str, Any]:
        """This calibration on another session of its unit (``gyrocal revalidate``): that
        session's holds compensated as the validation compensates them; ``validation_rms``,
        ``noise_floor``, ``excess`` (times the floor), ``holds`` (whether it carries over) ..."""
        from ..fleet.drift import revalidate
        from ..pipeline.chain import segment_log

        with _as_path(log, units=units) as path:
            observations = segment_log(path, self.settings, self.protocol).observations
        return dict(revalidate(self.calibration, observations))

    @property
    def name(self) -> str:
        """The unit's device id, or the log's file name where none was given."""
        if self.device_given:
            return str(self.calibration.meta.get("device"))
        return str(self.run.segmentation.info["source"]["name"])

    def __repr__(self) -> str:
        s = self.summary
        return (
            f"<CalibrationResult {self.name}: "
            f"{s['temperature_points']} temperature points, held-out RMS {s['validation_rms']:.3g} deg/s "
            f"= {s['excess']:.2f} x the noise floor>"
        )

    def _repr_html_(self) -> str:
        s = self.summary
        rows = [
            ("uncompensated", s.get("uncompensated_rms")),
            ("single-temperature", s.get("single_rms")),
            ("interpolated (held out)", s.get("validation_rms")),
            ("noise floor", s.get("noise_floor")),
        ]
        body = "".join(
            f"<tr><td>{label}</td><td>{'–' if v is None else f'{v:.4g}'}</td></tr>" for label, v in rows
        )
        device = html.escape(self.name)
        return (
            f"<p><b>Calibration of {device}</b>: {s['temperature_points']} temperature points, "
            f"{self.run.segmentation.info.get('holds_accepted', len(self.observations))} holds</p>"
            f"<table><tr><th>compensation</th><th>RMS, deg/s</th></tr>{body}</table>"
        )


@_one_blas_thread
def calibrate(
    log: LogLike,
    *,
    settings: Settings | None = None,
    protocol: str = registry.DEFAULT,
    add_terms: Iterable[str] = (),
    device: str | None = None,
    batch: str | None = None,
    session: str | None = None,
    name: str | None = None,
    units: dict[str, str] | None = None,
) -> CalibrationResult:
    """Calibrate one log end to end (``gyrocal calibrate``): segment its holds, fit the
    model per temperature point (seed 000's 12 parameters, Eq 2-4, and any terms
    ``add_terms`` or ``settings`` add) and validate it leaving temperature points out.
    ``device`` names the unit (default: the log's file name, or ``name`` for a frame);
    ``units`` declares a frame's units as a log's ``gyrocal.units`` does (docs/log-format.md),
    e.g. ``{"gyro": "rad/s"}``: ``pandas.read_parquet`` drops a file's declaration."""
    from ..pipeline.chain import run

    refuse_own_model(protocol, bool(tuple(add_terms)))
    settings = _settings_for(settings, protocol, add_terms)
    with _as_path(log, name, units) as path:
        result = run(path, settings, protocol=protocol, device=device, batch=batch, session=session)
    return CalibrationResult(result, settings, protocol, device is not None)


@dataclass(frozen=True, repr=False)
class Diagnosis:
    """Where the model fails and which effect is missing (``gyrocal diagnose``):
    :attr:`verdict`, :attr:`best` (the fix offered, with the option that adds it),
    :attr:`candidates` and :attr:`document`, the JSON ``diagnose -o`` writes."""

    document: dict[str, Any]
    residuals: pd.DataFrame | None = field(default=None)

    @property
    def verdict(self) -> str:
        return self.document["verdict"]

    @property
    def best(self) -> dict[str, Any] | None:
        """The fix offered (``term``, ``option`` to paste, its held-out figures), or None."""
        return self.document.get("best")

    @property
    def add_term(self) -> str | None:
        """The best fix's term spec, as ``add_terms`` and ``--add-term`` take it."""
        best = self.best
        if not best:
            return None
        return _option_value(best.get("option", ""))

    @property
    def candidates(self) -> pd.DataFrame:
        """Every candidate tried: term, status, held-out RMS with it, p-value, gain ..."""
        import pandas as pd

        keep = ("term", "status", "validation_rms_with", "gain_pct", "p_value", "validated", "significant")
        rows = [{k: c.get(k) for k in keep} for c in self.document.get("candidates", [])]
        return pd.DataFrame(rows, columns=list(keep))

    @property
    def ladder(self) -> list[dict[str, Any]]:
        """The models tried in turn, each with its held-out error (the model ladder)."""
        return list(self.document.get("ladder") or [])

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the diagnosis JSON exactly as ``gyrocal diagnose -o`` writes it."""
        from ..io.atomic import write_text

        write_text(path, dumps(self.document))
        return Path(path)

    def __repr__(self) -> str:
        return f"<Diagnosis: {self.verdict[:120]}{'…' if len(self.verdict) > 120 else ''}>"

    def _repr_html_(self) -> str:
        d = self.document
        parts = [f"<p><b>Verdict.</b> {html.escape(self.verdict)}</p>"]
        if self.best:
            parts.append(f"<p>To add it: <code>{html.escape(str(self.best.get('option', '')))}</code></p>")
        rows = "".join(
            f"<tr><td>{html.escape(str(step.get('name', '')))}</td>"
            f"<td>{html.escape(', '.join(map(str, step.get('terms', ()))))}</td>"
            f"<td>{_fmt(step.get('excess'))}</td><td>{_fmt(step.get('next_excess'))}</td></tr>"
            for step in self.ladder
        )
        if rows:
            parts.append(
                "<table><tr><th>model</th><th>terms</th><th>held-out error / floor</th><th>other session</th></tr>"
                f"{rows}</table>"
            )
        parts.append(
            f"<p>held-out RMS {_fmt(d.get('validation_rms'))} deg/s, noise floor {_fmt(d.get('noise_floor'))}"
            f" ({_fmt(d.get('excess'))} x)</p>"
        )
        return "".join(parts)


def _fmt(value) -> str:
    return "–" if value is None else f"{value:.3g}"


def _option_value(option: str) -> str | None:
    """The value of an ``--add-term VALUE`` option as a diagnosis prints it (one shell word)."""
    import shlex

    words = shlex.split(option)
    return words[words.index("--add-term") + 1] if "--add-term" in words[:-1] else None


def diagnose_log(
    log: Path,
    settings: Settings,
    meta: dict[str, Any],
    scratch: Path,
    *,
    output: Path,
    other: Path | None = None,
    residuals: Path | bool = False,
) -> str:
    """Segment ``log`` into ``scratch`` and write its diagnosis to ``output`` (the
    normalised residuals to ``residuals``); returns the verdict. ``other`` is another
    session's log, or a unit's results folder already segmented. The command line's
    ``diagnose LOG`` and :func:`diagnose` both run this."""
    from .stages import diagnose_stage, segment_stage

    other = other_session_folder(other, settings, meta, scratch)
    segment_stage(log, scratch / "unit", settings, meta)
    return diagnose_stage(scratch / "unit", settings, meta, output=output, residuals=residuals, other=other)


def other_session_folder(other, settings: Settings, meta: dict[str, Any], scratch: Path) -> Path | None:
    """The other session as a results folder: a folder as it is, a log segmented into
    ``scratch`` under the log's name (the diagnosis records the other session by it)."""
    from .stages import segment_stage

    if other is None or Path(other).is_dir():
        return other
    folder = scratch / "other" / Path(other).name.removesuffix(".parquet")
    segment_stage(other, folder, settings, meta)
    return folder


@_one_blas_thread
def diagnose(
    log: LogLike,
    *,
    other: LogLike | None = None,
    settings: Settings | None = None,
    protocol: str = registry.DEFAULT,
    add_terms: Iterable[str] = (),
    device: str | None = None,
    batch: str | None = None,
    session: str | None = None,
    residuals: bool = False,
    units: dict[str, str] | None = None,
) -> Diagnosis:
    """Where the calibration fails and which effect is missing (``gyrocal diagnose``):
    candidate terms fitted and judged out of sample, leaving out a temperature point, a
    mount, a rate level; with ``other`` (another session of the same unit) judged on how
    they carry over to it as well. ``residuals``: keep the normalised residuals too;
    ``units``: a frame's units (both logs'), as :func:`calibrate` takes them."""
    settings = _settings_for(settings, protocol, add_terms)
    meta = {"device": device, "batch": batch, "session": session, "protocol": protocol}
    with contextlib.ExitStack() as stack:
        scratch = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="gyrocal-diagnose-")))
        path = stack.enter_context(_as_path(log, units=units))
        other_path = None if other is None else stack.enter_context(_as_path(other, "other.parquet", units))
        out, frame = scratch / "diagnosis.json", scratch / "residuals.parquet"
        diagnose_log(
            path,
            settings,
            meta,
            scratch,
            output=out,
            other=other_path,
            residuals=frame if residuals else False,
        )
        document = json.loads(out.read_text())
        table = None
        if residuals:
            import pyarrow.parquet as pq

            table = pq.read_table(frame).to_pandas()
    return Diagnosis(document, table)


def apply_warnings(cal: Calibration, counts: ApplyCounts) -> list[str]:
    """What an apply has to say: rows beyond the calibrated range by more than the
    calibration's own readings went beyond it (:meth:`Calibration.range_tolerance`), rows
    written NaN."""
    said = []
    if counts["beyond"]:  # beyond by less than the end points' own scatter is no news
        (lo, hi), (below, above) = cal.grid.span, cal.range_tolerance()
        said.append(
            f"{counts['beyond']} of {counts['rows']} rows lie outside the calibrated {lo:g} to {hi:g} °C"
            + (
                f" by more than its own readings' scatter ({below:.2g} below, {above:.2g} °C above)"
                if below or above
                else ""
            )
            + " and use the nearest end's calibration"
        )
    if counts["nonfinite"]:
        said.append(
            f"{counts['nonfinite']} rows with a non-finite gyro or temperature value "
            "(or rates too large to compensate) were written as NaN"
        )
    return said


def apply(
    calibration: Calibration | str | os.PathLike[str], log: LogLike, *, units: dict[str, str] | None = None
) -> pd.DataFrame:
    """``log`` compensated (``gyrocal apply``): every row and column kept, ``gyro_x/y/z``
    the compensated rates in deg/s. Rows outside the calibrated temperatures use the
    nearest end's calibration, with a warning. ``units``: a frame's, as :func:`calibrate`."""
    import pyarrow.parquet as pq

    from ..calibration.apply import apply_calibration

    cal = calibration if isinstance(calibration, Calibration) else load_calibration(calibration)
    with _as_path(log, units=units) as path, tempfile.TemporaryDirectory(prefix="gyrocal-apply-") as scratch:
        out = Path(scratch) / "compensated.parquet"
        counts = _one_blas_thread(apply_calibration)(cal, path, out)
        frame = pq.read_table(out).to_pandas()
    for message in apply_warnings(cal, counts):
        warnings.warn(message, stacklevel=2)
    return frame


@dataclass(frozen=True, repr=False)
class Noise:
    """The session's noise (IEEE Std 952 terms of its static stretches, ``gyrocal noise``):
    :attr:`document` as ``noise -o`` writes it, :meth:`to_frame` a row per temperature point."""

    document: dict[str, Any]

    def to_frame(self) -> pd.DataFrame:
        """ARW (deg/√h), bias instability (deg/h) and RRW (deg/h/√h) per axis, for the
        pooled static data (``temp`` NaN) and each temperature point."""
        import numpy as np
        import pandas as pd

        rows = []
        entries = [("all", np.nan, self.document.get("session", {}))]
        entries += [("point", p["temp"], p) for p in self.document.get("points", [])]
        for kind, temp, entry in entries:
            terms = entry.get("terms")
            if not terms:
                continue
            row: dict[str, Any] = {"data": kind, "temp": temp}
            for name in ("arw", "bias_instability", "rrw"):
                for axis, value in zip("xyz", terms[name], strict=True):
                    row[f"{name}_{axis}"] = value
            rows.append(row)
        return pd.DataFrame(rows)

    def _repr_html_(self) -> str:
        if "session" not in self.document:
            return f"<p>No noise model: {html.escape(str(self.document.get('reason')))}</p>"
        return self.to_frame().to_html(index=False, float_format=lambda v: f"{v:.3g}")


def static_or_default(path) -> str:
    """The protocol to read a log's noise by, when none is given: a log whose reference
    rate is 0 throughout and that names no mounts lies still (a noise recording, a chamber
    test): its steady windows are its static stretches, whatever its temperature does."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from ..io.errors import GyrocalError
    from ..io.log import open_dataset

    try:  # a file, or a folder of files read as one (the contract)
        source = open_dataset(Path(path))
        names = set(source.schema.names)
        if "mount" in names:
            return registry.DEFAULT
        if "ref_rate" not in names:  # an import without a reference: still, as static reads it
            return "static"
        for batch in source.to_batches(columns=["ref_rate"]):
            if batch.num_rows and pc.any(pc.not_equal(batch.column(0), 0)).as_py():
                return registry.DEFAULT
    except (GyrocalError, OSError, ValueError, pa.ArrowException):
        return registry.DEFAULT  # reading the log says what is wrong with it
    return "static"


@_one_blas_thread
def noise(
    log: LogLike,
    *,
    protocol: str | None = None,
    settings: Settings | None = None,
    units: dict[str, str] | None = None,
) -> Noise:
    """The noise of the log's static stretches, per temperature point and pooled
    (``gyrocal noise``); a log that never turns is read as a static recording. ``units``: a
    frame's, as :func:`calibrate`."""
    from ..pipeline.chain import segment_log

    with _as_path(log, units=units) as path:
        chosen = protocol or static_or_default(path)
        settings = _settings_for(settings, chosen, ())
        return Noise(segment_log(path, settings, chosen).info["noise"])


def simulate_log(
    path: str | os.PathLike[str],
    *,
    device: str = "U001",
    session: str = "2026-01-01",
    batch: str = "B1",
    protocol: str = "turntable",
    preset: str = "quick",
    effects: dict[str, Any] | None = None,
    noise: str | dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write one simulated log (``gyrocal simulate --log``) and return its truth. The unit
    follows from ``device`` and the noise from ``device`` and ``session``, so two sessions
    of a device are the same physical unit; ``effects`` adds errors beyond the 12-parameter
    model (e.g. ``{"scale_quadratic": [2e-6, 0, 0]}``)."""
    import numpy as np

    from ..simulate import rig_for, simulate_unit
    from ..simulate.fleet import unit_for

    unit, seed = unit_for(device, session, protocol=protocol)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return simulate_unit(
        path,
        protocol=protocol,
        rig=rig_for(protocol, preset, {}),
        unit=unit,
        rng=np.random.default_rng(seed),
        device=device,
        batch=batch,
        session=session,
        seed=seed,
        effects=effects,
        noise=noise,
    )
