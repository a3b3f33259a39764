"""Benchmark: a servo calibration judged on the next session of the same unit, on units
gyrocal's authors did not write (``benchmarks/zoo``), beside a turntable calibration of the
same kind of unit.

Each zoo unit (effect ``none``, white noise) is calibrated by gyrocal's servo protocol on
session 0 and judged on session 1, which the calibration never saw (new mounts, new noise).
The zoo's servo mounts by hand, 2-6° off the axis in a random direction, new every session:
there the true rate's direction is unknown beyond the commanded axis, so two judges:

* ``magnitude`` — RMS over the revolutions of |compensated rate| − servo speed: blind to the
  mount's tilt, what a hand-mounted servo can judge;
* ``nominal``   — RMS length of the compensated rate minus the commanded rate vector (the
  servo speed along the nominal axis): the vector a user meets, which the new mount's tilt
  sets a floor to.

Each figure is raw ÷ compensated on session 1 (how many times the error falls). ``truth``
compensates with the unit's true K and B from the generator: the best any calibration
could do. Cases:

* ``hand``     — the zoo's servo as it is (three mounts, each turned both ways);
* ``six mounts`` — the zoo's ``servo_six_mounts``: each of the six rotations on a mount of
  its own, turned one way;
* ``fixture``  — the zoo's servo with ``misalign_deg=[0, 0.05]``: a fixture holding the axes to 0.05°;
* ``six axes`` — sessions 0 and 1 back to back as one log (each axis mounted twice: twelve
  rotations about six hand-placed axes), judged on session 2;
* ``turntable`` — the same unit seeds as ``turntable3`` units: gyrocal's default turntable
  calibration of session 0 re-validated on session 1 (:func:`gyrocal.fleet.drift.revalidate`:
  uncompensated ÷ interpolated RMS of the hold means, the true rate vector known).

Before them, the Monte-Carlo study of the cross-axis terms
(:func:`gyrocal.protocols.servo.montecarlo.cross_axis_study`: seed 001's units with ±1 % cross-axis
terms, Section III's hand mounts or a fixture, three axes, three axes twice or six axes, at
a low noise and the paper's two levels): the next session's median error over the floor and
the median improvement, by each judge and the truth.

    python benchmarks/servo_next_session.py [--units 12] [--turntable-units 6] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

MODELS = ("auto", "seed001", "fixture", "symmetric")
FIXTURE_DEG = [0.0, 0.05]


def _settings(model: str):
    from gyrocal.pipeline.config import Settings

    return Settings.from_dict({"protocols": {"servo": {"options": {"calibration": model}}}})


def _revolutions(path):
    from gyrocal.io.log import read_log
    from gyrocal.protocols.servo import find_rotations
    from gyrocal.protocols.servo.fit import nominal_rates

    r = find_rotations(read_log(path)).revolutions
    m = r[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    omega = r["ref_rate"].to_numpy()
    return m, omega, nominal_rates(r["direction"], omega)


def _judge(K, B, path) -> dict:
    """raw ÷ compensated on the log at ``path`` by both judges, and the compensated RMS."""
    m, omega, commanded = _revolutions(path)
    w = np.linalg.solve(K, (m - B).T).T
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    out = {}
    for judge, error in (
        ("magnitude", lambda x: np.linalg.norm(x, axis=1) - omega),
        ("nominal", lambda x: np.linalg.norm(x - commanded, axis=1)),
    ):
        out[judge] = rms(error(m)) / rms(error(w))
        out[f"{judge}_rms"] = rms(error(w))
    return out


def _concatenate(paths, out):
    """Logs one after another as one log (times shifted to follow on, 1 s apart)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    tables, offset = [], 0.0
    for p in paths:
        t = pq.read_table(p)
        shifted = pc.add(t.column("t"), offset - pc.min(t.column("t")).as_py())
        tables.append(t.set_column(t.schema.get_field_index("t"), "t", shifted))
        offset = pc.max(shifted).as_py() + 1.0
    pq.write_table(pa.concat_tables(tables), out, compression="zstd")
    return out


def servo_unit(seed: int, folder: Path) -> list[dict]:
    from benchmarks.zoo.generator import B_of_T, K_of_T, make_unit, write_session
    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.chain import run

    unit = make_unit(effect="none", protocol="servo", seed=seed)
    truth = K_of_T(unit, 25.0), B_of_T(unit, 25.0)
    rows = []
    for case, overrides, sessions in (
        ("hand", {}, 2),
        ("six mounts", {"servo_six_mounts": True}, 2),
        ("fixture", {"misalign_deg": FIXTURE_DEG}, 2),
        ("six axes", {}, 3),
    ):
        logs = []
        for s in range(sessions):
            path = folder / f"servo-{seed}-{case.replace(' ', '')}-s{s}.parquet"
            write_session(unit, path, session=s, seed=1000 * seed + s, **overrides)
            logs.append(path)
        if case == "six axes":
            fit_log, judge_log = _concatenate(logs[:2], folder / f"servo-{seed}-six-s01.parquet"), logs[2]
        else:
            fit_log, judge_log = logs
        row = {"unit": seed, "case": case, "truth": _judge(*truth, judge_log)}
        for model in MODELS:
            try:
                result = run(fit_log, _settings(model), protocol="servo")
            except GyrocalError as exc:
                row[model] = {"error": str(exc).splitlines()[0]}
                continue
            (K,), (B,) = result.calibration.matrices_at(np.array([25.0]))
            row[model] = {
                **_judge(K, B, judge_log),
                "used": result.calibration.extra["servo"]["model"]["used"],
            }
        rows.append(row)
    return rows


def turntable_unit(seed: int, folder: Path) -> dict:
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run, segment_log
    from gyrocal.pipeline.config import Settings

    unit = make_unit(effect="none", protocol="turntable3", seed=seed)
    logs = []
    for s in (0, 1):
        path = folder / f"turntable-{seed}-s{s}.parquet"
        write_session(unit, path, session=s, seed=1000 * seed + s)
        logs.append(path)
    settings = Settings()
    cal = run(logs[0], settings).calibration
    check = revalidate(cal, segment_log(logs[1], settings, "turntable").observations)
    return {
        "unit": seed,
        "case": "turntable",
        "ratio": check["uncompensated_rms"] / check["validation_rms"],
        "validation_rms": check["validation_rms"],
        "excess": check["excess"],
    }


def _spread(values) -> str:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)])
    if not len(v):
        return "–"
    return f"median {np.median(v):.3g} (min {v.min():.3g}, max {v.max():.3g})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=12, help="zoo servo units (seeds 1..N)")
    parser.add_argument("--turntable-units", type=int, default=6, help="zoo turntable3 units (seeds 1..N)")
    parser.add_argument("--out", help="also write every row as JSON")
    args = parser.parse_args(argv)
    import pandas as pd
    from host import cores, cpu_name

    from gyrocal.protocols.servo.montecarlo import cross_axis_study, cross_axis_summary

    started = time.perf_counter()
    study = cross_axis_summary(cross_axis_study(noise=(0.001, 0.035, 0.2)))
    study_s = time.perf_counter() - started
    with tempfile.TemporaryDirectory() as tmp:
        rows = [r for seed in range(1, args.units + 1) for r in servo_unit(seed, Path(tmp))]
        turn = [turntable_unit(seed, Path(tmp)) for seed in range(1, args.turntable_units + 1)]
    print(
        f"# {time.strftime('%Y-%m-%d')}, {cpu_name()}, {cores()}, Python {platform.python_version()}, "
        f"load {os.getloadavg()[0]:.1f}; {args.units} servo units, {args.turntable_units} turntable units, "
        f"{time.perf_counter() - started:.0f} s"
    )
    print(
        f"\nMonte-Carlo study of the cross-axis terms ({study_s:.1f} s): next session ÷ floor, "
        "improvement raw ÷ compensated (medians over 6000 runs)"
    )
    with pd.option_context("display.width", 250, "display.max_columns", 20, "display.max_rows", 200):
        print(study.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    print("\nper unit: raw ÷ compensated on the next session, magnitude / nominal judge (model used)")
    for r in rows:
        cells = []
        for model in MODELS:
            x = r[model]
            cells.append(
                f"{model} "
                + ("refused" if "error" in x else f"{x['magnitude']:.3g}/{x['nominal']:.3g} ({x['used']})")
            )
        print(
            f"unit {r['unit']:2d} {r['case']:10s} truth {r['truth']['magnitude']:.3g}/{r['truth']['nominal']:.3g}; "
            + "; ".join(cells)
        )
    print("\nsummary: how many times the next session's error falls (raw ÷ compensated)")
    for case in ("hand", "six mounts", "fixture", "six axes"):
        part = [r for r in rows if r["case"] == case]
        for judge in ("magnitude", "nominal"):
            print(f"{case:10s} {judge:9s} truth     {_spread(r['truth'][judge] for r in part)}")
            for model in MODELS:
                done = [r[model] for r in part if "error" not in r[model]]
                refused = len(part) - len(done)
                used = sorted({x["used"] for x in done})
                print(
                    f"{'':20s} {model:9s} {_spread(x[judge] for x in done)}"
                    + (f"; used {', '.join(used)}" if model == "auto" else "")
                    + (f"; refused on {refused} of {len(part)}" if refused else "")
                )
    print(
        f"turntable hold means, known rate vector: {_spread(t['ratio'] for t in turn)}; "
        f"next-session RMS ÷ floor {_spread(t['excess'] for t in turn)}"
    )
    if args.out:
        Path(args.out).write_text(json.dumps({"servo": rows, "turntable": turn}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
