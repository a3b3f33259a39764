"""Command line (contract section 6). Errors: one line on stderr, exit 2 for bad input."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import NamedTuple

from . import blas_threads  # noqa: F401 - first: it sets the BLAS thread count numpy will read

# isort: split
from .. import __version__
from ..calibration.export import add_export_parser
from ..calibration.lookup import add_lookup_parser
from ..calibration.registry import add_drift_parser, add_registry_parser
from ..io.errors import ConfigError, GyrocalError
from ..paper import add_parser as add_paper_parser
from ..protocols import registry

EPILOG = "Rates in deg/s, temperatures in °C. See README.md for the rig log contract."


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _settings(args):
    """Settings from --config (YAML) or --settings-json, then --model and --add-term."""
    from dataclasses import replace

    from ..pipeline.config import ModelSettings, Settings, read_yaml
    from ..terms.user import load_term_file

    for path in getattr(args, "terms", None) or ():
        load_term_file(path)
    settings = Settings.load(args.config) if getattr(args, "config", None) else Settings()
    if getattr(args, "settings_json", None):
        values = _json_object(args.settings_json, "--settings-json")
        base = settings.to_dict()
        settings = Settings.from_dict(
            {k: values.get(k, base[k]) for k in base} | {k: v for k, v in values.items() if k not in base}
        )
    # A servo or sweep log is fitted with its protocol's model; --model and --add-term
    # then change that model. A protocol with a calibration of its own (the servo's, seed
    # 001's six parameters) ignores the model: there they only change what the diagnosis reads.
    protocol = getattr(args, "protocol", None)
    if args.command in ("calibrate", "fit"):
        from .api import refuse_own_model

        refuse_own_model(protocol, bool(getattr(args, "model", None) or getattr(args, "add_term", None)))
    settings = settings.for_protocol(protocol)
    if getattr(args, "model", None):
        values = read_yaml(args.model)
        values = values.get("model", values)
        try:
            model = ModelSettings.from_dict(values)
        except ConfigError as exc:
            raise ConfigError(str(exc), source=args.model) from None
        settings = replace(settings, model=model)
    if getattr(args, "terms", None):  # --terms FILE: the model's term files, as in a config
        files = tuple(f for f in args.terms if f not in settings.model.term_files)
        settings = replace(
            settings, model=replace(settings.model, term_files=settings.model.term_files + files)
        )
    if getattr(args, "add_term", None):
        settings = replace(settings, model=settings.model.with_terms(tuple(args.add_term)))
        settings.model.build()  # unknown names fail here, before any work
    return settings


def _num(value, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def _json_object(text: str | None, option: str) -> dict:
    import json

    if not text:
        return {}
    try:
        values = json.loads(text)
    except ValueError as exc:
        raise ConfigError(f"{option} is not valid JSON ({exc})") from None
    if not isinstance(values, dict):
        raise ConfigError(f"{option} must be a JSON object")
    return values


def _meta(args) -> dict:
    return {k: getattr(args, k, None) for k in ("device", "batch", "session", "protocol")}


class SimulationInputs(NamedTuple):
    """What `gyrocal simulate` renders with: the rig, the published unit (--unit seed000,
    else None), and the errors beyond the unit's model (--effects, --noise)."""

    rig: object
    published: object
    effects: dict
    noise: dict | str | None


# The rig's fields the simulate command sets, by the option that sets them
RIG_OPTIONS = {
    "temperatures": "--temperatures",
    "rates": "--rates",
    "mounts": "--mounts",
    "sample_rate": "--sample-rate",
    "soak_s": "--soak-s",
    "hold_s": "--hold-s",
    "handling_s": "--handling-s",
    "accel_columns": "--no-accel",
    "mount_column": "--no-mount-column",
}


def _simulation_inputs(args) -> SimulationInputs:
    """The rig, unit and errors the options ask for; a malformed option is refused here."""
    from ..simulate import published_unit, rig_for

    knobs = {k: getattr(args, k) for k in RIG_OPTIONS if k in vars(args)}
    knobs.update(
        accel_columns=False if args.no_accel else None, mount_column=False if args.no_mount_column else None
    )
    rig = rig_for(args.protocol, args.preset, knobs, RIG_OPTIONS)
    published = published_unit(args.protocol) if args.unit == "seed000" else None
    effects = _json_object(args.effects, "--effects")
    noise = None
    if args.noise is not None:
        noise = _json_object(args.noise, "--noise") if args.noise.lstrip().startswith("{") else args.noise
    if args.bias_shift is not None and len(args.bias_shift) != 3:
        raise ConfigError(f"--bias-shift takes three numbers (deg/s, x,y,z), got {len(args.bias_shift)}")
    return SimulationInputs(rig, published, effects, noise)


def cmd_simulate(args) -> int:
    from ..simulate import simulate

    if (args.out is None) == (args.log is None):
        raise ConfigError("give either --out DIR (a fleet with its manifest) or --log FILE")
    inputs = _simulation_inputs(args)
    if args.log is not None:
        return _simulate_one_log(args, inputs)
    if args.bias_shift is not None:
        raise ConfigError("--bias-shift applies to one unit's log: use it with --log")
    manifest = simulate(
        args.out,
        protocol=args.protocol,
        units=args.units,
        seed=args.seed,
        rig=inputs.rig,
        unit=inputs.published,
        batch=args.batch,
        session=args.session,
        device_prefix=args.device_prefix,
        effects=inputs.effects,
        noise=inputs.noise,
    )
    print(f"wrote {args.units} log(s) and manifest {manifest}")
    return 0


def _simulate_one_log(args, inputs: SimulationInputs) -> int:
    """One log of one unit: the unit follows from its device id, the noise from the session
    too, so every session of a device is the same physical unit."""
    import numpy as np

    from ..simulate import simulate_unit
    from ..simulate.fleet import unit_for

    device = args.device or "U001"
    unit, seed = unit_for(device, args.session, seed000=args.unit == "seed000", protocol=args.protocol)
    if args.bias_shift is not None and not hasattr(unit, "bias_poly"):
        raise ConfigError(
            f"--bias-shift applies to units with a bias polynomial, not to a {args.protocol} unit"
        )
    unit = _with_bias_shift(unit, args.bias_shift)
    Path(args.log).parent.mkdir(parents=True, exist_ok=True)
    simulate_unit(
        args.log,
        protocol=args.protocol,
        rig=inputs.rig,
        unit=unit,
        rng=np.random.default_rng(seed),
        device=device,
        batch=args.batch,
        session=args.session,
        seed=seed,
        effects=inputs.effects,
        noise=inputs.noise,
    )
    print(f"wrote {args.log}")
    return 0


def _with_bias_shift(unit, shift):
    """The unit after its bias moved by ``shift`` (deg/s x,y,z: a unit that drifted since);
    the unit itself when ``shift`` is None."""
    from dataclasses import replace

    import numpy as np

    if shift is None:
        return unit
    poly = np.array(unit.bias_poly, dtype=float)
    poly[:, 0] += np.array(shift)
    return replace(unit, bias_poly=tuple(map(tuple, poly)))


def _stage(args, stage: str, outputs, work) -> int:
    from .stages import run_stage

    return run_stage(stage, outputs, _meta(args), work, record_failures=args.record_failures)


def cmd_segment(args) -> int:
    from ..io.unit_folder import STAGE_PARTS, UNIT_FILES, clear_stage, pack_stage
    from .stages import segment_stage

    settings = _settings(args)
    out = Path(args.out)
    files = [out / UNIT_FILES[k] for k in STAGE_PARTS["segment"]]
    clear_stage(out, "segment")
    status = _stage(args, "segment", files, lambda: segment_stage(args.log, out, settings, _meta(args)))
    pack_stage(out, "segment")
    print(f"segmentation -> {out}")
    return status


def cmd_noise(args) -> int:
    """The session's noise: IEEE Std 952 terms of its static stretches, per temperature point
    and pooled (gyrocal.fit.floor); the whole characterisation as JSON with -o."""
    from ..calibration.file import dumps
    from .api import noise as session_noise

    noise = session_noise(args.log, protocol=args.protocol, settings=_settings(args)).document
    if args.output:
        from ..io.atomic import write_text

        write_text(args.output, dumps(noise))
    if "session" not in noise:
        print(f"{args.log}: {noise['reason']}; no noise model")
        return 0
    print(
        f"{args.log}: {noise['stretches']} static stretches, {noise['static_seconds']:.1f} s "
        "(terms per axis x / y / z)"
    )
    print(
        f"{'static data':>22}  {'ARW deg/sqrt(h)':>24}  {'bias instability deg/h':>24}  "
        f"{'RRW deg/h/sqrt(h)':>24}"
    )
    rows = [
        ("all", noise["session"]),
        *((f"{p['temp']:.4g} C ({p['seconds']:.0f} s)", p) for p in noise["points"]),
    ]
    for label, entry in rows:
        if "terms" not in entry:
            print(f"{label:>22}  no static stretch to fit")
            continue
        t = entry["terms"]
        print(
            f"{label:>22}  "
            + "  ".join(
                f"{' / '.join(f'{v:.3g}' for v in t[k]):>24}" for k in ("arw", "bias_instability", "rrw")
            )
        )
    if "resolves" in noise:
        print(f"  {noise['resolves']['text']}")
    return 0


def cmd_fit(args) -> int:
    from ..io.unit_folder import UNIT_FILES
    from .stages import fit_stage

    settings = _settings(args)
    return _stage(
        args,
        "fit",
        [Path(args.unit) / UNIT_FILES["calibration"]],
        lambda: fit_stage(args.unit, settings, _meta(args)),
    )


def cmd_validate(args) -> int:
    from ..io.unit_folder import UNIT_FILES, VALIDATION_TABLES, clear_stage, pack_stage
    from .stages import validate_stage

    settings = _settings(args)
    files = [Path(args.unit) / UNIT_FILES[k] for k in ("validation", *VALIDATION_TABLES)]
    clear_stage(args.unit, "validate")
    status = _stage(args, "validate", files, lambda: validate_stage(args.unit, settings))
    pack_stage(args.unit, "validate")
    return status


def cmd_analyse(args) -> int:
    from ..io.unit_folder import clear_stage, pack_stage
    from .stages import analyse_stage, report_stage

    settings = _settings(args)
    clear_stage(args.unit, "analyse")
    verdict = analyse_stage(
        args.unit, settings, _meta(args), record_failures=args.record_failures, other=args.other_session
    )
    print(f"calibration, validation and diagnosis -> {args.unit}")
    if verdict is not None:
        print(f"  {verdict}")
    status = 0
    if args.report:  # the workflow's report, in the same process: no second start-up
        status = _stage(args, "report", [args.report], lambda: report_stage(args.unit, args.report, settings))
        print(f"report -> {args.report}")
    pack_stage(args.unit, "analyse")
    return status


def cmd_report(args) -> int:
    from .stages import report_stage

    settings = _settings(args)
    return _stage(args, "report", [args.output], lambda: report_stage(args.unit, args.output, settings))


def cmd_shard(args) -> int:
    from ..fleet.manifest import read_manifest, write_shards

    extra = args.snakemake_args[1:] if args.snakemake_args[:1] == ["--"] else args.snakemake_args
    if extra and not args.run:
        raise ConfigError(f"{' '.join(extra)}: options for each shard's workflow need --run")
    if args.at_once < 1:
        raise ConfigError(f"--at-once {args.at_once}: at least 1 shard at a time")
    rows = read_manifest(args.manifest)
    paths = write_shards(rows, args.size, args.out)
    print(f"{len(rows)} unit sessions in {len(paths)} shard{'s' if len(paths) != 1 else ''} -> {args.out}")
    if not args.run:
        return 0
    import functools

    from .shards import day_view, run_shards

    configfile = Path(args.configfile or "config/config.yaml").resolve()
    runs = run_shards(
        paths,
        Path(args.out),
        extra,
        at_once=args.at_once,
        snakefile=Path(args.snakefile),
        configfile=configfile if args.configfile or configfile.is_file() else None,
        echo=functools.partial(print, flush=True),
    )
    totals = day_view(runs, Path(args.out))
    stopped = [r.name for r in runs if r.status != 0]
    print(
        f"{totals.units} unit sessions: {totals.ok} calibrated, {totals.failed} failed "
        f"-> {Path(args.out) / 'index.html'}"
        + (f"; the workflow stopped on {', '.join(stopped)}" if stopped else "")
    )
    return 1 if stopped else 0


def cmd_fleet(args) -> int:
    from ..fleet.manifest import read_manifest
    from .stages import fleet_stage

    rows = read_manifest(args.manifest)
    settings = None
    if args.settings_json is not None:
        from ..fleet.summary import FleetSettings

        settings = FleetSettings.from_dict(_json_object(args.settings_json, "--settings-json"))
    fleet_stage(
        rows,
        args.results,
        args.reports,
        args.output,
        args.bundle,
        settings,
        args.eol,
        args.table,
        args.registry,
        args.history,
    )
    print(f"fleet summary of {len(rows)} unit sessions -> {args.output}")
    return 0


def cmd_calibrate(args) -> int:
    import shlex

    from .api import calibrate

    made = calibrate(
        args.log,
        settings=_settings(args),
        protocol=args.protocol,
        device=args.device,
        batch=args.batch,
        session=args.session,
    )
    made.save(args.output)
    if args.tables:
        made.save_tables(args.tables)
    if args.report:
        made.report(args.report, command=" ".join(map(shlex.quote, sys.argv)))
    result = made.run
    s = result.validation.summary
    print(f"calibration -> {args.output}")
    print(
        f"  {result.segmentation.info['holds_accepted']} holds, "
        f"{s['temperature_points']} temperature points "
        f"({result.calibration.grid.span[0]:.1f} to {result.calibration.grid.span[1]:.1f} °C)"
    )
    print(
        f"  leave-{s['held_out']}-out RMS {s['validation_rms']:.3g} deg/s: noise floor "
        f"{s['noise_floor']:.3g} ({s['excess']:.2f}x), expected of a correct model "
        f"{_num(s['expected_rms'], '.3g')} ({_num(s['excess_over_expected'], '.2f')}x); "
        + (f"single-temperature {s['single_rms']:.3g}, " if s.get("single_rms") is not None else "")
        + f"uncompensated {s['uncompensated_rms']:.3g}"
    )
    for p in result.calibration.extra.get("profiled", []):
        print(
            f"  {p['term']} {p['parameter']} = {p['value']:.4g}"
            + (f" ± {p['stderr']:.2g}" if p.get("stderr") is not None else "")
        )
        if p["at_bound"]:
            print(
                f"gyrocal: warning: {p['term']} {p['parameter']} is at a bound of "
                f"{p['bounds'][0]:g} to {p['bounds'][1]:g}: the effect may be absent or "
                "another one missing (a continuous model needs temperature terms); check the "
                "fit before widening the bounds",
                file=sys.stderr,
            )
    for w in result.calibration.extra.get("warnings", []):
        print(f"gyrocal: warning: {w['code']}: {w['message']}", file=sys.stderr)
    if args.report:
        print(f"  report -> {args.report}")
    return 0


def cmd_diagnose(args) -> int:
    """The diagnosis: its verdict and the line that adds the missing term on the terminal;
    with -o the whole of it as JSON (without, it is written to scratch space and read back,
    so what is printed is the same either way)."""
    import tempfile

    from .api import diagnose_log, other_session_folder
    from .stages import diagnose_stage, run_stage

    settings = _settings(args)
    if (args.log is None) == (args.unit is None):
        raise ConfigError("give the log, or --unit DIR of a segmented unit")
    if args.record_failures and not args.output:  # the record would go nowhere, the exit be 0
        raise ConfigError("--record-failures writes the failure to -o FILE: give -o")

    residuals = args.residuals or False

    def tell(verdict, output):
        if args.output:
            print(f"diagnosis -> {args.output}")
        else:
            print(f"diagnosis of {args.log or args.unit}")
        print(f"  {verdict}")
        import json

        doc = json.loads(Path(output).read_text())
        offered, nxt = doc.get("best"), doc.get("next_session") or {}
        if nxt.get("excess") is not None:  # what the calibration meets: said, not only in the JSON
            fixed = ((offered or {}).get("next_session") or {}).get("excess")
            print(
                f"  on the other session ({doc.get('other_session', 'given')}): "
                f"{nxt['excess']:.3g} times the floor with this model"
                + (f", {fixed:.3g} with the fix" if fixed is not None else "")
            )
        if offered:
            print(f"  to add it: gyrocal calibrate LOG -o CAL.json {offered['option']}")
            if offered.get("unit_config_line"):
                lines = offered["unit_config_line"].replace("\n", "\n    ")
                print(f"  or for this unit alone, in the workflow's config:\n    {lines}")

    def work():
        with tempfile.TemporaryDirectory(prefix="gyrocal-diagnose-") as scratch:
            output = args.output or Path(scratch) / "diagnosis.json"
            if args.unit is not None:
                other = other_session_folder(args.other_session, settings, _meta(args), Path(scratch))
                verdict = diagnose_stage(
                    args.unit, settings, _meta(args), output=output, residuals=residuals, other=other
                )
            else:
                verdict = diagnose_log(
                    Path(args.log),
                    settings,
                    _meta(args),
                    Path(scratch),
                    output=output,
                    other=args.other_session,
                    residuals=residuals,
                )
            tell(verdict, output)

    outputs = [o for o in (args.output, args.residuals) if o]
    # A diagnosis written as the unit's own part joins its archive, and replaces the
    # residuals there (written again or left out).
    owned = ()
    if args.unit is not None and args.output:
        from ..io.unit_folder import UNIT_FILES, clear_stage, pack_stage

        unit_diagnosis = (Path(args.unit) / UNIT_FILES["diagnosis"]).resolve()
        if Path(args.output).resolve() == unit_diagnosis:
            owned = ("diagnosis", "residuals")
            clear_stage(args.unit, "diagnose", owned)
    status = run_stage("diagnose", outputs, _meta(args), work, record_failures=args.record_failures)
    if owned:
        pack_stage(args.unit, "diagnose", owned)
    return status


def cmd_apply(args) -> int:
    from ..calibration.apply import apply_calibration
    from ..calibration.file import load_calibration
    from ..terms.user import load_term_file
    from .api import apply_warnings

    for path in args.terms or ():
        load_term_file(path)
    cal = load_calibration(args.calibration)
    counts = apply_calibration(cal, args.log, args.output)
    for message in apply_warnings(cal, counts):
        warnings.warn(message, stacklevel=1)
    print(f"{counts['rows']} rows compensated -> {args.output}")
    return 0


def cmd_verify(args) -> int:
    """Whether a log is the one a calibration records as its input, by the hash algorithm
    its record names (BLAKE3 or SHA-256)."""
    import json

    from ..io.errors import CalibrationFileError
    from ..io.log import verify_source

    try:
        doc = json.loads(Path(args.calibration).read_text())
        record = doc["provenance"]["input"]
    except OSError as exc:
        raise CalibrationFileError(f"cannot read ({exc.strerror})", source=args.calibration) from None
    except (ValueError, KeyError, TypeError):
        raise CalibrationFileError("holds no provenance.input record", source=args.calibration) from None
    if not isinstance(record, dict):
        raise CalibrationFileError("provenance.input is not a record", source=args.calibration)
    algorithm = verify_source(record, args.log)
    print(f"{args.log} is the input of {args.calibration} ({algorithm})")
    return 0


def cmd_revalidate(args) -> int:
    """A calibration judged on another session of its unit: that session's holds compensated
    as the validation stage compensates, their RMS against the noise floor and against what a
    correct calibration leaves (gyrocal.fleet.drift.revalidate); the figures as JSON with -o."""
    from ..calibration.file import dumps, load_calibration
    from ..fleet.drift import revalidate
    from ..io.errors import InputError
    from ..io.formats import json_safe
    from ..pipeline.chain import segment_log
    from ..terms.user import load_term_file

    for path in args.terms or ():  # before the calibration: its own terms come from them
        load_term_file(path)
    cal = load_calibration(args.calibration)
    made_by = cal.meta.get("protocol") or registry.DEFAULT
    if not registry.get(made_by).known_rate:  # refused before the log is read
        raise InputError(
            f"a {made_by} calibration cannot be revalidated: {made_by} holds carry "
            "no known true rate to score it against",
            source=args.calibration,
        )
    args.protocol = args.protocol or made_by
    try:
        r = revalidate(cal, segment_log(args.log, _settings(args), args.protocol).observations)
    except InputError as exc:  # the new session's holds do not serve
        if exc.source is not None:
            raise
        raise InputError(str(exc), source=args.log) from None
    limit = r["expected_rms"] * r["limit_over_expected"] / r["noise_floor"]
    verdict = (
        "the calibration carries over to this session"
        if r["holds"]
        else f"it misses this session by {r['excess']:.3g} times the floor (noise and its own "
        f"uncertainty explain up to {limit:.3g} times)"
    )
    if args.output:
        from ..io.atomic import write_text

        write_text(
            args.output,
            dumps(
                json_safe(
                    {
                        "format": "gyrocal.revalidation/1",
                        **{k: cal.meta.get(k) for k in ("device", "batch", "session")},
                        "calibration": Path(args.calibration).name,
                        "log": Path(args.log).name,
                        **{k: v for k, v in r.items() if k not in ("device", "calibration_session", "table")},
                        "verdict": verdict,
                        "table": r["table"].to_dict("records"),
                    }
                )
            ),
        )
    print(
        f"revalidation of {args.calibration} ({cal.meta.get('device')}, session "
        f"{cal.meta.get('session')}) on {args.log}" + (f" -> {args.output}" if args.output else "")
    )
    print(
        f"  {r['holds_scored']} holds scored"
        + (
            f", {r['holds_left_out']} beyond the calibrated {cal.grid.span[0]:.1f} to "
            f"{cal.grid.span[1]:.1f} °C left out"
            if r["holds_left_out"]
            else ""
        )
    )
    print(
        f"  hold-mean RMS {r['validation_rms']:.3g} deg/s: noise floor {r['noise_floor']:.3g} "
        f"({r['excess']:.2f}x), expected of a correct calibration {r['expected_rms']:.3g} "
        f"({r['excess_over_expected']:.2f}x); single-temperature {r['single_rms']:.3g}, "
        f"uncompensated {r['uncompensated_rms']:.3g}"
    )
    print(f"  {verdict}")
    return 0


def cmd_import(args) -> int:
    """A rig's CSV/TSV, a ROS 2 bag or an MCAP file as a contract log (docs/import.md)."""
    from ..importer import import_log

    summary = import_log(
        args.source,
        args.output,
        args.map,
        fmt=args.format,
        sample_rate=args.sample_rate,
        sections=args.sections,
    )
    start, end = summary.span
    print(
        f"{summary.rows} rows -> {args.output}: t {start:.6g} to {end:.6g} s "
        f"({end - start:.6g} s); {'; '.join(summary.mapped)}"
    )
    for note in summary.notes:
        print(f"gyrocal: note: {note}", file=sys.stderr)
    return 0


class OneLineParser(argparse.ArgumentParser):
    """Usage mistakes are bad input too: one line on stderr, exit status 2."""

    def error(self, message):
        self.exit(2, f"gyrocal: error: {' '.join(message.split())} (see {self.prog} --help)\n")


# The workflow's stages: commands on a unit's results folder (or a fleet's manifest) that
# the Snakefile runs. `gyrocal --help` lists them under a heading of their own, after the
# commands a user runs on a log or a calibration.
STAGES = ("segment", "fit", "validate", "analyse", "report", "fleet")


class _Listing(argparse.Action):
    """Help only: commands listed under a heading of their own, as the subparsers list
    theirs. It sits in an argument group, not among the parser's actions, so it parses
    nothing and stays out of the usage line."""

    def __init__(self, choices_actions, metavar: str, help: str):
        super().__init__(option_strings=[], dest=argparse.SUPPRESS, nargs=0, metavar=metavar, help=help)
        self._choices_actions = choices_actions

    def _get_subactions(self):
        return self._choices_actions

    def __call__(self, parser, namespace, values, option_string=None):  # never parsed
        raise NotImplementedError


def _list_stages_apart(parser: argparse.ArgumentParser, sub) -> None:
    """Move the stages' lines of the subparsers' help into a group of their own: every
    command still parses through ``sub`` (``gyrocal fit --help`` works), only the top-level
    help shows two lists."""
    lines = sub._choices_actions  # argparse's one list of (name, help) lines
    sub._choices_actions = [a for a in lines if a.dest not in STAGES]
    group = parser.add_argument_group(
        "workflow stages", "steps of the workflow (Snakefile) on a unit's results folder or a manifest"
    )
    group._group_actions.append(
        _Listing([a for a in lines if a.dest in STAGES], "STAGE", "gyrocal STAGE --help for its options")
    )


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="gyrocal",
        description="Calibrate MEMS gyroscopes across temperature from rig logs.",
        epilog=EPILOG,
    )
    parser.add_argument("--version", action="version", version=f"gyrocal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = parser.add_subparsers(
        title="commands",
        dest="command",
        required=True,
        metavar="COMMAND",
        help="gyrocal COMMAND --help for its options",
        parser_class=OneLineParser,
    )
    _add_simulate(sub)
    _add_calibrate(sub)
    _add_diagnose(sub)
    _add_apply(sub)
    _add_verify(sub)
    _add_revalidate(sub)
    _add_noise(sub)
    _add_segment(sub)
    _add_fit_and_validate(sub)
    _add_analyse(sub)
    _add_report(sub)
    _add_shard(sub)
    _add_fleet(sub)
    _add_import(sub)
    add_paper_parser(sub)
    add_lookup_parser(sub)
    add_registry_parser(sub)
    add_drift_parser(sub)
    add_export_parser(sub)
    _list_stages_apart(parser, sub)
    return parser


def _add_settings_arguments(p, model: bool = True) -> None:
    """The settings a command reads: --config, --settings-json, --terms; with ``model``, the
    model's --model and --add-term too."""
    p.add_argument("--config", help="settings YAML (segmentation:, model:, diagnosis:)")
    p.add_argument("--settings-json", help="settings as one JSON object (segmentation, model, diagnosis)")
    p.add_argument(
        "--terms",
        action="append",
        metavar="FILE",
        help="a Python file registering your own terms (repeatable); it runs as code",
    )
    if model:
        p.add_argument("--model", help="model YAML (terms:, interpolation:, ...)")
        p.add_argument(
            "--add-term", action="append", metavar="NAME", help="add a term to the model (repeatable)"
        )


def _add_unit_arguments(p, failures: bool = True) -> None:
    """Who the log is of (--device, --batch, --session, --protocol); with ``failures``, the
    fleet runs' --record-failures."""
    p.add_argument(
        "--device",
        help="the unit's id, recorded in the outputs (without it: the log's file name, less .parquet)",
    )
    p.add_argument("--batch", help="the unit's production batch, recorded in the outputs")
    p.add_argument("--session", help="the calibration session, e.g. its date, recorded in the outputs")
    p.add_argument(
        "--protocol",
        default=registry.DEFAULT,
        choices=registry.names(),
        help=f"how the rig moved the unit: which segmentation and model apply (default {registry.DEFAULT})",
    )
    if failures:
        p.add_argument(
            "--record-failures",
            action="store_true",
            help="on failure write failure records to the outputs and exit 0 (fleet runs; diagnose needs -o)",
        )


def _add_simulate(sub) -> None:
    p = sub.add_parser("simulate", help="write simulated rig logs with ground truth")
    p.add_argument(
        "--protocol",
        default=registry.DEFAULT,
        choices=registry.names(),
        help=f"the rig's protocol to simulate (default {registry.DEFAULT})",
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", help="folder for N units' logs, truth JSON and devices.tsv")
    where.add_argument("--log", help="one log of the unit --device at session --session")
    p.add_argument("--units", type=int, default=1, help="with --out: how many units (default 1)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the units and noise (default 0)")
    p.add_argument(
        "--preset",
        choices=["seed", "quick"],
        default="seed",
        help="seed: the full seed-000 protocol; quick: a log of minutes",
    )
    p.add_argument(
        "--unit",
        choices=["random", "seed000"],
        default="random",
        help="random production units, or the seed paper's unit (turntable: seed 000 "
        "Eq 23; sweep: seed 003's L3GD20 sizes)",
    )
    p.add_argument("--device", help="with --log: the unit (its parameters follow from it)")
    p.add_argument("--batch", default="B1", help="the batch the logs record (default B1)")
    p.add_argument("--session", default="2026-01-01", help="the session the logs record (default 2026-01-01)")
    p.add_argument(
        "--device-prefix",
        default="U",
        help="with --out: device ids are this and a number (default U: U001, ...)",
    )
    _add_rig_arguments(p)
    _add_unit_error_arguments(p)
    p.set_defaults(func=cmd_simulate)


def _add_rig_arguments(p) -> None:
    """The simulated rig's knobs, each overriding the preset's value."""
    p.add_argument("--temperatures", type=_floats, help="set points, °C, comma-separated")
    p.add_argument("--rates", type=_floats, help="hold rate magnitudes, deg/s")
    p.add_argument("--mounts", type=lambda s: tuple(s.split(",")), help="e.g. +x,+y,+z")
    p.add_argument("--sample-rate", type=float, metavar="HZ", help="samples per second")
    p.add_argument("--soak-s", type=float, help="seconds the chamber soaks at each set point")
    p.add_argument("--hold-s", type=float, help="seconds of each constant-rate hold")
    p.add_argument("--handling-s", type=float, help="seconds a remount takes by hand")
    p.add_argument("--no-mount-column", action="store_true", help="leave out the mount column")
    p.add_argument("--no-accel", action="store_true", help="leave out the accelerometer columns")


def _add_unit_error_arguments(p) -> None:
    """What the simulated unit gets beyond its drawn parameters: a bias shift, effects, noise."""
    p.add_argument(
        "--bias-shift",
        type=_floats,
        help="with --log: add this to the unit's bias, deg/s x,y,z (a unit that drifted between sessions)",
    )
    p.add_argument(
        "--effects",
        help="errors beyond the seed-000 model as JSON, e.g. "
        "'{\"scale_quadratic\": [1e-6, 0, 0]}' (see GyroUnit)",
    )
    p.add_argument(
        "--noise",
        help="coloured noise beside the white: a grade (low, mid, high) or "
        'levels as JSON, e.g. \'{"bias_instability": 6, "rrw": 20}\' (deg/h, '
        "deg/h/sqrt(h); gyrocal/simulate/noise.py)",
    )


def _add_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="the whole chain for one log -> calibration JSON")
    p.add_argument("log", help="the rig log, .parquet (a CSV: convert it with gyrocal import)")
    p.add_argument("-o", "--output", required=True, help="calibration .json")
    p.add_argument("--report", help="also write an HTML report here")
    p.add_argument("--tables", help="also write observation and validation tables here")
    _add_unit_arguments(p, failures=False)
    _add_settings_arguments(p)
    p.set_defaults(func=cmd_calibrate)


def _add_diagnose(sub) -> None:
    p = sub.add_parser("diagnose", help="where the model fails and which effect is missing")
    p.add_argument("log", nargs="?", help="the rig log (or --unit for a segmented unit)")
    p.add_argument("--unit", help="a unit's results folder (workflow stage)")
    p.add_argument(
        "-o",
        "--output",
        help="also write the whole diagnosis here, .json (default: the verdict printed only)",
    )
    p.add_argument("--residuals", help="also write the normalised residuals, .parquet")
    p.add_argument(
        "--other-session",
        metavar="LOG_OR_DIR",
        help="another session of the same unit (its log, or its results folder): "
        "candidates are judged by how they carry over to it",
    )
    _add_unit_arguments(p)
    _add_settings_arguments(p)
    p.set_defaults(func=cmd_diagnose)


def _add_apply(sub) -> None:
    p = sub.add_parser("apply", help="compensate a log with a calibration")
    p.add_argument("calibration", help="calibration .json (gyrocal calibrate's output)")
    p.add_argument("log", help="the log to compensate, .parquet")
    p.add_argument("-o", "--output", required=True, help="the compensated log to write, .parquet")
    p.add_argument(
        "--terms",
        action="append",
        metavar="FILE",
        help="the term file a calibration's own terms come from (repeatable)",
    )
    p.set_defaults(func=cmd_apply)


def _add_verify(sub) -> None:
    p = sub.add_parser("verify", help="check that a log is the input a calibration records (its hash)")
    p.add_argument("calibration", help="calibration .json recording its input's hash")
    p.add_argument("log", help="the log to check, .parquet")
    p.set_defaults(func=cmd_verify)


def _add_revalidate(sub) -> None:
    p = sub.add_parser(
        "revalidate",
        help="judge a calibration on another session of its unit (its RMS against the noise floor)",
    )
    p.add_argument("calibration", help="calibration .json of the unit")
    p.add_argument("log", help="another session's rig log of the same unit")
    p.add_argument("-o", "--output", help="the figures as JSON")
    p.add_argument(
        "--protocol",
        choices=registry.names(),
        help="how to segment the log (default: the calibration's protocol)",
    )
    _add_settings_arguments(p, model=False)
    p.set_defaults(func=cmd_revalidate)


def _add_noise(sub) -> None:
    p = sub.add_parser(
        "noise", help="the noise terms (Allan deviation, IEEE Std 952) of a log's static stretches"
    )
    p.add_argument("log", help="the rig log, .parquet")
    p.add_argument("-o", "--output", help="the whole characterisation as JSON")
    p.add_argument(
        "--protocol",
        choices=registry.names(),
        help="how to find the static stretches (default: static where the reference "
        "rate is 0 throughout and no mount is named, else turntable)",
    )
    _add_settings_arguments(p, model=False)
    p.set_defaults(func=cmd_noise)


def _add_segment(sub) -> None:
    p = sub.add_parser("segment", help="find holds; write the unit's observation tables")
    p.add_argument("log", help="the rig log, .parquet")
    p.add_argument("--out", required=True, help="the unit's results folder")
    _add_unit_arguments(p)
    _add_settings_arguments(p, model=False)
    p.set_defaults(func=cmd_segment)


def _add_fit_and_validate(sub) -> None:
    for name, func, text in (
        ("fit", cmd_fit, "fit the unit's calibration"),
        ("validate", cmd_validate, "validate the unit's calibration"),
    ):
        p = sub.add_parser(name, help=text)
        p.add_argument("unit", help="the unit's results folder")
        _add_unit_arguments(p)
        _add_settings_arguments(p)
        p.set_defaults(func=func)


def _add_analyse(sub) -> None:
    p = sub.add_parser("analyse", help="fit, validate and diagnose the unit in one process")
    p.add_argument("unit", help="the unit's results folder")
    p.add_argument(
        "--other-session",
        metavar="DIR",
        help="the results folder of another session of the unit, segmented: the "
        "diagnosis judges candidates by how they carry over to it",
    )
    p.add_argument(
        "--report", metavar="HTML", help="then write the unit's report here, as `gyrocal report` would"
    )
    _add_unit_arguments(p)
    _add_settings_arguments(p)
    p.set_defaults(func=cmd_analyse)


def _add_report(sub) -> None:
    p = sub.add_parser("report", help="the unit's HTML report")
    p.add_argument("unit", help="the unit's results folder")
    p.add_argument("-o", "--output", required=True, help="the report to write, .html")
    _add_unit_arguments(p)
    _add_settings_arguments(p)
    p.set_defaults(func=cmd_report)


def _add_shard(sub) -> None:
    p = sub.add_parser(
        "shard", help="split a day's manifest into shards, a workflow run each (docs/cluster.md)"
    )
    p.add_argument("--manifest", required=True, help="the day's manifest, .tsv (one row per unit session)")
    p.add_argument(
        "--size",
        type=int,
        default=10000,
        help="rows per shard at most (default 10000: under a minute to plan)",
    )
    p.add_argument("-o", "--out", required=True, help="folder for shard-0001.tsv, ...")
    p.add_argument(
        "--run",
        action="store_true",
        help="then run the workflow on each shard in OUT/shard-0001/, ..., and write "
        "the day's view: OUT/index.html and OUT/fleet.parquet",
    )
    p.add_argument(
        "--at-once",
        type=int,
        default=1,
        metavar="N",
        help="with --run: shards whose workflows run side by side (default 1; on a "
        "cluster, as many as its scheduler takes)",
    )
    p.add_argument(
        "--snakefile",
        default="Snakefile",
        help="with --run: the workflow (default ./Snakefile: run from the repository)",
    )
    p.add_argument(
        "--configfile",
        help="with --run: the workflow's settings (default config/config.yaml where it exists)",
    )
    p.add_argument(
        "snakemake_args",
        nargs=argparse.REMAINDER,
        help="with --run, after --: options for each shard's snakemake, such as "
        "--profile profiles/slurm (--cores all where none says how many jobs run)",
    )
    p.set_defaults(func=cmd_shard)


def _add_fleet(sub) -> None:
    p = sub.add_parser("fleet", help="the fleet summary over a manifest")
    p.add_argument("--manifest", required=True, help="the manifest, .tsv (one row per unit session)")
    p.add_argument("--results", default="results", help="root of the units' results folders")
    p.add_argument("--reports", default="reports", help="root of the units' reports")
    p.add_argument("-o", "--output", required=True, help="fleet summary .html")
    p.add_argument("--bundle", help="also gather all reports into this folder")
    p.add_argument(
        "--settings-json",
        help="end of line, outliers and drift as one JSON object "
        "(spec, outliers, drift: see config/config.yaml)",
    )
    p.add_argument("--eol", help="also write the end-of-line verdicts and yields as JSON")
    p.add_argument(
        "--registry",
        help="index the run's calibrations here: a postgresql:// URL or an SQLite file "
        "(default RESULTS/registry.sqlite; '' for none)",
    )
    p.add_argument(
        "--history",
        help="the drift pages' earlier sessions as the workflow's plan recorded them "
        "(results/drift_history.jsonl; default: asked of the registry)",
    )
    p.add_argument(
        "--table",
        help="also write the fleet as one Parquet table, a row per unit session (docs/fleet-table.md)",
    )
    p.set_defaults(func=cmd_fleet)


def _add_import(sub) -> None:
    p = sub.add_parser(
        "import", help="convert a CSV/TSV, ROS 2 bag or MCAP file into a rig log (docs/import.md)"
    )
    p.add_argument("source", help="the CSV/TSV file, rosbag2 directory or .mcap file")
    p.add_argument("-o", "--output", required=True, help="the log to write, .parquet")
    p.add_argument("--map", help="the import map, YAML: columns or topics and their units")
    p.add_argument(
        "--format",
        choices=("csv", "tsv", "ros2", "mcap"),
        help="the source's format (default: from its name)",
    )
    p.add_argument(
        "--sample-rate",
        type=float,
        metavar="HZ",
        help="t = sample index / HZ (the map's time.column, else the row number)",
    )
    p.add_argument(
        "--sections", metavar="FILE", help="a section list in imucal's format: writes the section column"
    )
    p.set_defaults(func=cmd_import)


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"gyrocal: warning: {' '.join(str(message).split())}", file=sys.stderr)


# A command that reads a log starts decoding it at once, on a thread (gyrocal.io.readahead),
# and imports meanwhile what it runs; modules it would import only after the read (the
# noise fit's scipy.optimize and scipy.special, the model fit's scipy.linalg) are imported
# on another thread from the start. Imports hold the GIL; Arrow's decoding does not.
WARM_IMPORTS = ("scipy.linalg", "scipy.special", "scipy.optimize")
READS_A_LOG = {"calibrate", "diagnose", "segment", "noise", "revalidate"}


def _read_ahead(args) -> None:
    log = getattr(args, "log", None)
    if log is not None:
        from ..io import readahead

        readahead.start(log)
    _warm_imports()


def _warm_imports() -> None:
    def load():
        import importlib

        for name in WARM_IMPORTS:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - the command imports it again and says why
                return

    import threading

    threading.Thread(target=load, name="warm-imports", daemon=True).start()


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _one_line_warning
    if argv is None and args.command in READS_A_LOG:
        _read_ahead(args)
    try:
        return args.func(args)
    except GyrocalError as exc:
        print(f"gyrocal: error: {exc}", file=sys.stderr)
        return exc.exit_status
    except KeyboardInterrupt:
        print("gyrocal: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not bad input: one line unless asked for more
        if args.debug:
            raise
        text = " ".join(str(exc).split())
        print(
            f"gyrocal: internal error: {type(exc).__name__}: {text} (rerun with --debug for a traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
