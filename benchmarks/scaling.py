"""Benchmark: calibrate and diagnose against the number of holds, with slow wander in the noise.

Logs come from ``benchmarks/zoo`` (written without reading gyrocal), a complete unit
(``effect="none"``, seed 1) with coloured noise (a Gauss-Markov bias and a rate random walk)
at 10 Hz, simulated once into a cache outside the repository (``$GYROCAL_BENCH_CACHE``, else
``~/.cache/gyrocal/benchmarks``):

* ``sweep``      — the sweep protocol, -20 → 60 → -20 °C with three 20-minute dwells, its
                   ramps slowed to make the log 4, 16 and 64 hours long (``--hours``);
* ``turntable``  — the six-mount turntable protocol on 4, 8, 16 and 24 set points from -20
                   to 55 °C (``--points``; set points closer than the segmentation's
                   ``temp_gap``, 2 °C, are one temperature point: 64 of them are one);
* ``issue``      — the sweep of issue 28, 15.4 h (554,400 rows), beside the full seed-000
                   turntable protocol at 100 Hz (``benchmarks/process.py``'s log), for the
                   issue's ratios.

For each log, ``gyrocal calibrate`` and ``gyrocal diagnose`` run as whole processes
(imports included), interleaved, ``--repeat`` times; printed are the holds, the median wall
time with its quartiles, and the peak resident memory (the process's own ``ru_maxrss``).
Then the paired ratios: the issue's sweep against the 100 Hz turntable's calibrate, its
diagnose against its calibrate, and the 64-hour sweep against the 16-hour one.

``--dense`` also runs each process with the fit's whitening replaced by the dense
covariance and LAPACK's Cholesky (``tests/fit/wander_reference.py``, what gyrocal did before
issue 28, without its cap of 3,000 holds), once per size, until one takes longer than
``--dense-timeout`` seconds or its covariance would take more than 4 GiB.

    python benchmarks/scaling.py [--repeat 3] [--hours 4,16,64] [--points 4,8,16,24] [--dense]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from host import cores, cpu_name
from process import CACHE, ROOT, log_at, quartiles

PROCESSES = ("calibrate", "diagnose")
DENSE = (
    "import sys; sys.path[:0] = [sys.argv.pop(1)]; import gyrocal.run.blas_threads; "
    "import gyrocal.fit.model, tests.fit.wander_reference as r; "
    "gyrocal.fit.model._whiteners = r.dense_model_whiteners; "
    "from gyrocal.run.cli import main; sys.argv[0] = 'gyrocal'; sys.exit(main())"
)


def zoo_log(path: Path, protocol: str, **session) -> Path:
    """A complete zoo unit (seed 1) with coloured noise, one session at 10 Hz, simulated
    once to ``path``."""
    if not path.exists():
        sys.path.insert(0, str(ROOT))
        from benchmarks.zoo.generator import make_unit, write_session

        path.parent.mkdir(parents=True, exist_ok=True)
        print(f"# simulating {path} (once)", flush=True)
        unit = make_unit(effect="none", protocol=protocol, noise="coloured", seed=1)
        write_session(unit, path, session=0, seed=123, rate_hz=10.0, **session)
    return path


def sweep_log(hours: float) -> Path:
    """A zoo sweep ``hours`` long: -20 → 60 → -20 °C with three 20-minute dwells, so its
    ramps take hours - 1 h."""
    return zoo_log(
        CACHE / "zoo_sweep" / f"sweep_{hours:g}h.parquet", "sweep", ramp_c_per_h=160.0 / (hours - 1.0)
    )


def turntable_log(points: int) -> Path:
    """A zoo six-mount turntable session on ``points`` set points from -20 to 55 °C."""
    temps = [-20.0 + 75.0 * k / (points - 1) for k in range(points)]
    return zoo_log(CACHE / "zoo_turntable" / f"turntable6_{points}pt.parquet", "turntable6", temps=temps)


def run(argv: list[str], timeout: float | None = None) -> tuple[float, float, str] | None:
    """(wall seconds, peak RSS MiB, stdout) of one process; None when it ran out of time."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env)
        while True:  # blocking without a timeout: the wall time is the process's own
            pid, status, usage = os.wait4(proc.pid, 0 if timeout is None else os.WNOHANG)
            wall = time.perf_counter() - t0
            if pid:
                break
            if wall > timeout:
                proc.kill()
                os.wait4(proc.pid, 0)
                return None
            time.sleep(0.05)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} failed: {err.read().decode()[-500:]}")
        return wall, usage.ru_maxrss / 1024, out.read().decode()


def commands(log: Path, scratch: Path, protocol: str, dense: bool) -> dict[str, list[str]]:
    head = [sys.executable, "-c", DENSE, str(ROOT)] if dense else [sys.executable, "-m", "gyrocal"]
    options = ["--protocol", protocol] if protocol != "turntable" else []
    return {
        "calibrate": [*head, "calibrate", str(log), *options, "-o", str(scratch / "cal.json")],
        "diagnose": [*head, "diagnose", str(log), *options, "-o", str(scratch / "diag.json")],
    }


def holds_of(stdout: str) -> int:
    found = re.search(r"(\d+) holds", stdout)
    return int(found.group(1)) if found else -1


def measure(name: str, log: Path, protocol: str, repeat: int) -> dict:
    import pyarrow.parquet as pq

    rows = pq.read_metadata(log).num_rows
    with tempfile.TemporaryDirectory() as scratch:
        argv = commands(log, Path(scratch), protocol, dense=False)
        runs = {p: [] for p in PROCESSES}
        for _ in range(repeat):
            for p in PROCESSES:
                runs[p].append(run(argv[p]))
    holds = holds_of(runs["calibrate"][0][2])
    for p in PROCESSES:
        q1, q2, q3 = quartiles([w for w, _, _ in runs[p]])
        peak = max(m for _, m, _ in runs[p])
        print(
            f"{name:<22} {rows:>10,} {holds:>6} {p:<10} {q2:>8.2f} {f'({q1:.2f}–{q3:.2f})':>14} {peak:>9.0f}",
            flush=True,
        )
    return {
        "rows": rows,
        "holds": holds,
        **{p: [w for w, _, _ in runs[p]] for p in PROCESSES},
        "log": log,
        "protocol": protocol,
    }


DENSE_BYTES = 4 << 30  # the dense covariance's arrays (six of n x n doubles) at most


def measure_dense(name: str, case: dict, timeout: float) -> bool:
    """One dense run of each process; False when one did not finish in ``timeout`` s, or
    would not fit DENSE_BYTES (a shared machine)."""
    need = 6 * 8 * case["holds"] ** 2
    if need > DENSE_BYTES:
        print(
            f"{name:<22} {case['rows']:>10,} {case['holds']:>6} dense: not run (its covariance "
            f"arrays alone take {need / 2**30:.1f} GiB)",
            flush=True,
        )
        return False
    with tempfile.TemporaryDirectory() as scratch:
        argv = commands(case["log"], Path(scratch), case["protocol"], dense=True)
        for p in PROCESSES:
            result = run(argv[p], timeout)
            if result is None:
                print(
                    f"{name:<22} {case['rows']:>10,} {case['holds']:>6} {p:<10} dense: not "
                    f"finished in {timeout:g} s",
                    flush=True,
                )
                return False
            wall, peak, _ = result
            print(
                f"{name:<22} {case['rows']:>10,} {case['holds']:>6} {p:<10} {wall:>8.2f} "
                f"{'(dense, once)':>14} {peak:>9.0f}",
                flush=True,
            )
    return True


def paired(a: list[float], b: list[float]) -> str:
    q1, q2, q3 = quartiles([x / y for x, y in zip(a, b, strict=False)])
    return f"{q2:.2f}× ({q1:.2f}–{q3:.2f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--hours", default="4,16,64", help="sweep lengths, h ('' for none)")
    parser.add_argument("--points", default="4,8,16,24", help="turntable set points ('' for none)")
    parser.add_argument("--no-issue", action="store_true", help="skip the issue's sweep and turntable")
    parser.add_argument("--dense", action="store_true", help="the dense fit beside, where it finishes")
    parser.add_argument("--dense-timeout", type=float, default=900.0)
    args = parser.parse_args()
    load = os.getloadavg()
    print(
        f"# {dt.datetime.now():%Y-%m-%d %H:%M}, {cpu_name()}, {cores()}, Python "
        f"{sys.version.split()[0]}; load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; "
        f"{args.repeat} interleaved runs per process"
    )
    print(
        f"{'log':<22} {'rows':>10} {'holds':>6} {'process':<10} {'wall s':>8} {'(quartiles)':>14} "
        f"{'peak MiB':>9}"
    )
    cases: dict[str, dict] = {}
    if not args.no_issue:
        cases["turntable 100 Hz, seed"] = measure(
            "turntable 100 Hz, seed", log_at(100.0), "turntable", args.repeat
        )
        cases["issue sweep 15.4 h"] = measure("issue sweep 15.4 h", sweep_log(15.4), "sweep", args.repeat)
    for hours in (float(h) for h in args.hours.split(",") if h):
        cases[f"sweep {hours:g} h"] = measure(f"sweep {hours:g} h", sweep_log(hours), "sweep", args.repeat)
    for points in (int(p) for p in args.points.split(",") if p):
        name = f"turntable6 {points} pt"
        cases[name] = measure(name, turntable_log(points), "turntable", args.repeat)

    print()
    if "issue sweep 15.4 h" in cases:
        sweep, table = cases["issue sweep 15.4 h"], cases["turntable 100 Hz, seed"]
        print(
            f"issue sweep calibrate ÷ turntable 100 Hz calibrate, paired: "
            f"{paired(sweep['calibrate'], table['calibrate'])}"
        )
        print(
            f"issue sweep diagnose ÷ its calibrate, paired: {paired(sweep['diagnose'], sweep['calibrate'])}"
        )
    for small, big in (("sweep 16 h", "sweep 64 h"), ("turntable6 4 pt", "turntable6 16 pt")):
        if small in cases and big in cases:
            for p in PROCESSES:
                print(
                    f"{big} ÷ {small}, {p}, paired: {paired(cases[big][p], cases[small][p])} "
                    f"for {cases[big]['holds'] / cases[small]['holds']:.2f}× the holds"
                )
    if args.dense:
        print()
        for kind in ("sweep", "turntable6"):
            for name, case in cases.items():
                if name.startswith(kind) and not measure_dense(name, case, args.dense_timeout):
                    break


if __name__ == "__main__":
    main()
