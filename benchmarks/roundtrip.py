"""Benchmark: every calibration file ``gyrocal calibrate`` writes is read by every reader.

Units come from generators gyrocal's authors did not write: ``benchmarks/zoo`` (turntable
on three and six mounts, sweep, servo; written from the log contract and the physics) and
``tests/protocols/ferraris_gen`` (hand rotations). Each unit is drawn at random: protocol, noise kind,
an effect of the zoo or none, the unit's coefficient sizes and white noise scaled by decades
across their range, and a model of every kind a user may ask for (library terms, ``drop=``,
profiled terms, empirical splines, formulas, the die's temperature, user term files; grid
models with each interpolation and continuous models).

Two sessions of each unit are calibrated with ``gyrocal calibrate`` as a user runs it (the
command line's own entry, in process), and each file then goes to every reader: ``apply``
(on the other session), ``export`` (C header), ``lookup``, the workflow's ``validate`` and
``report`` stages (the file put in a segmented unit's folder), ``revalidate`` on the other
session and the ``drift`` table of the two. Each reader's outcome is one of

* ``read``       — the reader took the file and did its work;
* ``refused``    — the reader refused the file as malformed or inconsistent (the count the
                   issue asks to be zero);
* ``not for it`` — the reader does not serve this kind of calibration and says so in one
                   line (a term beyond the firmware rule for ``export``; a servo's hand mount
                   for ``revalidate``): by design, listed with its reason;
* ``failed``     — anything else (an internal error, a traceback): a bug.

    python benchmarks/roundtrip.py [--units 200] [--seed 0] [--jobs 2] [--out FILE]

Prints a row per unit, then the counts per reader and outcome; exit status 1 when a file
was refused or a reader failed.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PROTOCOLS = ("turntable3", "turntable6", "sweep", "servo", "ferraris", "static")
READERS = ("apply", "export", "lookup", "validate", "report", "revalidate", "drift")
# Effects of the zoo that every protocol's log carries (the rest need a protocol of theirs).
EFFECTS = (
    "none",
    "none",
    "g_sensitivity",
    "scale_quadratic",
    "scale_cubic",
    "warmup",
    "die_lag",
    "temp_rate",
    "bias_quadratic_temp",
    "run_to_run_bias",
    "hysteresis",
)
FERRARIS_KINDS = ("clean", "annotated", "steps", "temperature", "gsens", "fast", "shuffled", "sections_only")

# A term file, as a user writes one (docs/effects.md): the model may name its term.
USER_TERMS = '''
from dataclasses import dataclass
import numpy as np
from gyrocal.terms import AXES, Term, register_term

@register_term("user_rate_abs")
@dataclass(frozen=True)
class RateTimesAbsRate(Term):
    """An odd second-order scale error, written by hand. [1/(deg/s)]"""

    unit = "1/(deg/s)"

    def coefficients(self):
        return [f"user_rate_abs.{a}" for a in AXES]

    def columns(self, data):
        return {f"user_rate_abs.{a}": data[f"rate_{a}"] * np.abs(data[f"rate_{a}"]) for a in AXES}
'''

# (label, the model's settings as calibrate takes them): per protocol family. "terms" are
# added with --add-term; "model" replaces the protocol's model (--model YAML).
TURNTABLE_MODELS = [
    ("default", {}),
    ("linear interpolation", {"model": {"interpolation": "linear"}}),
    ("spline interpolation", {"model": {"interpolation": "spline"}}),
    ("poly interpolation", {"model": {"interpolation": "poly", "degree": 2}}),
    ("scale_quadratic", {"terms": ["scale_quadratic"]}),
    ("scale_cubic + scale_asymmetry", {"terms": ["scale_cubic", "scale_asymmetry"]}),
    ("g_sensitivity", {"terms": ["g_sensitivity"], "mounts": 6}),
    ("g_sensitivity drop", {"terms": ['g_sensitivity(drop=["x.z", "y.z", "z.z"])'], "mounts": 3}),
    ("temp_rate (profiled)", {"terms": ["temp_rate"]}),
    ("temp_lag (profiled)", {"terms": ["temp_lag"]}),
    ("die_temperature", {"terms": ["die_temperature"]}),
    # Knots at quantiles of the session's time, as the diagnosis offers them ({knots_t}).
    ("smooth(t)", {"terms": ['smooth(input="t", knots={knots_t})']}),
    (
        "smooth(rate_own)",
        {"terms": ['smooth(input="rate_own", knots=[-400, -100, 0, 100, 400], by="rate_own")']},
    ),
    (
        "formula exp(-t/tau) profiled",
        {
            "terms": [
                "expression(label='decay_t', formula='exp(-t / tau)', parameters={'tau': 900.0}, "
                "profile={'tau': [100.0, 9000.0]})"
            ]
        },
    ),
    ("formula fixed", {"terms": ["expression(label='rate_cube', formula='rate_own ** 3')"]}),
    ("user term file", {"terms": ["user_rate_abs"], "term_file": True}),
    (
        "continuous",
        {
            "model": {
                "kind": "continuous",
                "terms": [
                    "bias",
                    "scale",
                    "misalignment",
                    "bias_temp_poly(degree=3)",
                    "scale_temp_poly",
                    "misalignment_temp",
                ],
            }
        },
    ),
    (
        "continuous + die_temperature",
        {
            "model": {
                "kind": "continuous",
                "terms": [
                    "bias",
                    "scale",
                    "misalignment",
                    "bias_temp_poly(degree=2)",
                    "scale_temp_poly",
                    "die_temperature",
                ],
            }
        },
    ),
]
SWEEP_MODELS = [
    ("default", {}),
    (
        "bias_temp_poly(degree=2)",
        {"model": {"kind": "continuous", "terms": ["bias", "bias_temp_poly(degree=2)"]}},
    ),
    ("die_temperature", {"terms": ["die_temperature"]}),
    ("temp_rate (profiled)", {"terms": ["temp_rate"]}),
    ("smooth(temp)", {"terms": ['smooth(input="temp", knots=[-20, 0, 20, 40, 60])']}),
    (
        "formula profiled",
        {
            "terms": [
                "expression(label='decay_t', formula='exp(-t / tau)', parameters={'tau': 900.0}, "
                "profile={'tau': [100.0, 9000.0]})"
            ]
        },
    ),
    ("grid", {"model": {"kind": "grid", "terms": ["bias"], "interpolation": "linear"}}),
]
FERRARIS_MODELS = [
    ("default", {}),
    ("g_sensitivity", {"terms": ["g_sensitivity"]}),
]
# A unit lying still (tests/protocols/chamber's host-stamped IMU): the bias, or a drift in time too.
STATIC_MODELS = [
    ("default", {}),
    (
        "formula profiled",
        {
            "terms": [
                "expression(label='decay_t', formula='exp(-t / tau)', parameters={'tau': 60.0}, "
                "profile={'tau': [10.0, 600.0]})"
            ]
        },
    ),
]
MODELS = {
    "turntable": TURNTABLE_MODELS,
    "sweep": SWEEP_MODELS,
    "servo": [("default", {})],
    "ferraris": FERRARIS_MODELS,
    "static": STATIC_MODELS,
}


def draw_case(index: int, seed: int = 0) -> dict:
    """The unit ``index`` of a benchmark run: everything drawn from (seed, index)."""
    rng = np.random.default_rng([seed, index, 35])
    protocol = PROTOCOLS[index % len(PROTOCOLS)]  # every protocol equally often
    family = protocol.rstrip("36") if protocol.startswith("turntable") else protocol
    models = MODELS[family]
    label, model = models[int(rng.integers(len(models)))]
    if protocol.startswith("turntable") and model.get("mounts"):
        protocol = f"turntable{model['mounts']}"
    case = {
        "index": index,
        "protocol": protocol,
        "family": family,
        "model_label": label,
        "model": model,
        "unit_seed": int(rng.integers(1, 10_000)),
    }
    if family == "static":
        case["noise_scale"] = float(10 ** rng.uniform(-1.0, 1.0))
        return case
    if family == "ferraris":
        kinds = [k for k in FERRARIS_KINDS if not (label == "g_sensitivity" and k == "sections_only")]
        case["kind"] = kinds[int(rng.integers(len(kinds)))]  # g_sensitivity reads the accelerometer
        return case
    case["noise"] = "coloured" if rng.random() < 0.3 else "white"
    case["effect"] = (
        EFFECTS[int(rng.integers(len(EFFECTS)))]
        if family != "servo"
        else ("none", "g_sensitivity", "scale_quadratic")[int(rng.integers(3))]
    )
    # The unit's sizes across their range: a decade below to a decade above the drawn ones.
    case["coefficient_scale"] = float(10 ** rng.uniform(-1.5, 1.0))
    case["noise_scale"] = float(10 ** rng.uniform(-1.0, 1.0))
    return case


def _unit_overrides(unit_seed: int, case: dict) -> dict:
    from benchmarks.zoo.generator import _draw_base, _draw_noise

    base, noise = _draw_base(unit_seed), _draw_noise(unit_seed, case["noise"])
    k = case["coefficient_scale"]
    return {
        "s0": base["s0"] * k,
        "s1": base["s1"] * k,
        "M": base["M"] * k,
        "b0": base["b0"] * k,
        "b1": base["b1"] * k,
        "arw_dps_rthz": noise["arw_dps_rthz"] * case["noise_scale"],
    }


def write_logs(case: dict, folder: Path, *, small: bool = False) -> list[Path]:
    """Two sessions of the case's unit. ``small``: a shorter protocol (the test suite's)."""
    logs = [folder / f"s{s}.parquet" for s in (0, 1)]
    if case["family"] == "ferraris":
        from tests.protocols.ferraris_gen.generate import session

        for s, path in enumerate(logs):
            session(case["kind"], case["unit_seed"] * 10 + s, path)
        return logs
    if case["family"] == "static":  # arrival-stamped, stalls and bunches: tests/protocols/chamber
        from tests.protocols.chamber.generator import NoiseModel, host_stamped_log, write_contract

        noise = NoiseModel(arw_deg_rt_h=0.3 * case["noise_scale"])
        for s, path in enumerate(logs):
            write_contract(
                host_stamped_log(
                    case["unit_seed"] * 10 + s, duration_s=60.0 if small else 300.0, noise=noise
                ),
                path,
            )
        return logs
    from benchmarks.zoo.generator import make_unit, write_session

    unit = make_unit(
        effect=case["effect"],
        protocol=case["protocol"],
        noise=case["noise"],
        seed=case["unit_seed"],
        **_unit_overrides(case["unit_seed"], case),
    )
    options = {}
    if case["family"] == "sweep":
        options = {"ramp_c_per_h": 60.0 if small else 45.0}
    elif case["family"] == "turntable" and small:
        options = {
            "temps": [-10.0, 10.0, 30.0, 50.0],
            "rates": [0.0, 50.0, -50.0, 200.0, -200.0],
            "hold_s": 8.0,
            "soak_s": 120.0,
        }
    rate = 2.0 if case["family"] == "sweep" else (10.0 if small or case["family"] != "servo" else 25.0)
    for s, path in enumerate(logs):
        write_session(unit, path, session=s, seed=1000 * case["unit_seed"] + s, rate_hz=rate, **options)
    return logs


def _cli(argv: list[str]) -> tuple[int, str]:
    """gyrocal's command line in this process: its exit status and what it wrote to stderr."""
    from gyrocal.run.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(argv)
    return status, err.getvalue().strip()


def _outcome(status: int, err: str) -> tuple[str, str]:
    errors = [
        line
        for line in err.splitlines()
        if line.startswith("gyrocal: ") and "warning" not in line.split(":")[1]
    ]
    message = errors[-1] if errors else err.splitlines()[-1] if err else ""
    if status == 0:
        return "read", ""
    if "internal error" in message:
        return "failed", message
    if "cannot export for firmware" in message or "known true rate" in message:
        return "not for it", message
    return "refused", message


def _settings_args(case: dict, folder: Path, log: Path) -> list[str]:
    model = case["model"]
    import pyarrow.parquet as pq

    t = pq.read_table(log, columns=["t"])["t"].to_numpy()
    knots_t = [round(float(q)) for q in np.quantile(t - t[0], [0.02, 0.25, 0.5, 0.75, 0.98])]
    args = ["--protocol", "turntable" if case["family"] == "turntable" else case["family"]]
    if model.get("term_file"):
        path = folder / "my_terms.py"
        path.write_text(USER_TERMS)
        args += ["--terms", str(path)]
    if "model" in model:
        import yaml

        path = folder / "model.yaml"
        path.write_text(yaml.safe_dump({"model": model["model"]}))
        args += ["--model", str(path)]
    for term in model.get("terms", ()):
        args += ["--add-term", term.replace("{knots_t}", str(knots_t))]
    return args


def run_case(case: dict, folder: str | Path, *, small: bool = False) -> dict:
    """Calibrate both sessions, then hand the first session's file to every reader."""
    from gyrocal.calibration.file import load_calibration
    from gyrocal.fleet import drift
    from gyrocal.io.errors import GyrocalError

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    row = {k: v for k, v in case.items() if k != "model"}
    started = time.perf_counter()
    logs = write_logs(case, folder, small=small)
    settings = _settings_args(case, folder, logs[0])
    device = f"R{case['index']:04d}"
    caldir = folder / "calibrations" / device
    caldir.mkdir(parents=True)
    cals = []
    for s, log in enumerate(logs):
        cal = caldir / f"2026-0{s + 1}-01.json"
        status, err = _cli(
            [
                "calibrate",
                str(log),
                "-o",
                str(cal),
                "--device",
                device,
                "--session",
                f"2026-0{s + 1}-01",
                *settings,
            ]
        )
        if status != 0:
            row["calibrate"] = ("failed" if "internal error" in err else "not calibrated", err)
            row["seconds"] = round(time.perf_counter() - started, 1)
            return row
        cals.append(cal)
    row["calibrate"] = ("read", "")
    terms = [a for a in settings if a.endswith(".py")]
    term_args = ["--terms", terms[0]] if terms else []
    out = {}
    out["apply"] = _outcome(
        *_cli(["apply", str(cals[0]), str(logs[1]), "-o", str(folder / "applied.parquet"), *term_args])
    )
    out["export"] = _outcome(*_cli(["export", str(cals[0]), "-o", str(folder / "cal.h")]))
    out["lookup"] = _outcome(
        *_cli(["lookup", str(folder / "calibrations"), device, "--date", "2026-01-15", "--json"])
    )
    # The workflow's stages: the file in a segmented unit's folder, as `fit` leaves it.
    unit = folder / "unit"
    status, err = _cli(["segment", str(logs[0]), "--out", str(unit), *settings_without_model(settings)])
    if status != 0:
        out["validate"] = out["report"] = ("failed", f"segment: {err}")
    else:
        shutil.copy(cals[0], unit / "calibration.json")
        out["validate"] = _outcome(*_cli(["validate", str(unit), *settings]))
        out["report"] = _outcome(
            *_cli(["report", str(unit), "-o", str(folder / "report.html"), *settings_without_model(settings)])
        )
    for name, work in (
        (
            "revalidate",
            lambda: drift.revalidate(load_calibration(cals[0]), _observations(logs[1], case, settings)),
        ),
        ("drift", lambda: drift.parameter_changes([load_calibration(c) for c in cals])),
    ):
        try:
            work()
            out[name] = ("read", "")
        except GyrocalError as exc:
            out[name] = _outcome(2, f"gyrocal: error: {exc}")
        except Exception as exc:  # noqa: BLE001 - a bug, counted
            out[name] = ("failed", f"{type(exc).__name__}: {exc}")
    row.update(out)
    row["seconds"] = round(time.perf_counter() - started, 1)
    return row


def settings_without_model(settings: list[str]) -> list[str]:
    """The options of a stage that reads no model (segment, report): all but --model/--add-term."""
    out, skip = [], False
    for a in settings:
        if skip:
            skip = False
            continue
        if a in ("--model", "--add-term"):
            skip = True
            continue
        out.append(a)
    return out


def _observations(log, case, settings_args):
    from gyrocal.pipeline.chain import segment_log
    from gyrocal.run.cli import _settings, build_parser

    args = build_parser().parse_args(
        ["segment", str(log), "--out", "unused", *settings_without_model(settings_args)]
    )
    return segment_log(log, _settings(args), args.protocol).observations


def _one(args) -> dict:
    case, small = args
    with tempfile.TemporaryDirectory(prefix="gyrocal-roundtrip-") as folder:
        try:
            return run_case(case, folder, small=small)
        except Exception as exc:  # noqa: BLE001 - the benchmark counts it and goes on
            row = {k: v for k, v in case.items() if k != "model"}
            row["calibrate"] = ("failed", f"{type(exc).__name__}: {exc}")
            return row


def summarise(rows: list[dict]) -> tuple[str, int]:
    """The counts per reader and outcome as a markdown table, and the number of refusals
    and failures."""
    stages = ("calibrate", *READERS)
    counts = {s: Counter(r[s][0] for r in rows if s in r) for s in stages}
    outcomes = ("read", "not calibrated", "not for it", "refused", "failed")
    lines = ["| reader | " + " | ".join(outcomes) + " |", "|---|" + "---:|" * len(outcomes)]
    for s in stages:
        lines.append(f"| {s} | " + " | ".join(str(counts[s][o]) for o in outcomes) + " |")
    bad = sum(counts[s]["refused"] + counts[s]["failed"] for s in stages)
    return "\n".join(lines), bad


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--small", action="store_true", help="the test suite's shorter protocol")
    ap.add_argument("--out", help="write the rows as JSON here")
    a = ap.parse_args(argv)
    cases = [draw_case(i, a.seed) for i in range(a.units)]
    started = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(_one, [(c, a.small) for c in cases]))
    for r in rows:
        what = r.get("effect") or r.get("kind") or "still, host-stamped"
        line = " ".join(f"{s}={r[s][0]}" for s in ("calibrate", *READERS) if s in r)
        print(f"{r['index']:4d} {r['protocol']:<11} {what:<20} {r['model_label']:<30} {line}")
        for s in ("calibrate", *READERS):
            if s in r and r[s][0] != "read":
                print(f"       {s}: {r[s][1]}")
    table, bad = summarise(rows)
    print(f"\n{len(rows)} units, seed {a.seed}, {time.perf_counter() - started:.0f} s on {a.jobs} jobs\n")
    print(table)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
