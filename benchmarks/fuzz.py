"""Fuzzing campaign: many mutated rig logs through ingest and the command line (issue 17).

The strategies and properties are the test suite's (``tests/io/fuzzing.py``; the suite runs a
few dozen examples of each, this runs thousands). Every example is checked, none stops the
campaign: property violations are collected by where they come from, then each is shrunk by
Hypothesis to a minimal reproducer (the same seed replays the search up to the first
example that shows it).

    python benchmarks/fuzz.py [--examples 3000] [--cli-examples 300] [--seed 0]

Prints the machine and date, the examples run and their outcomes by class (success, each
gyrocal error), the violations with a minimal reproducer each, and the wall time. Exit
status 1 when a property was violated.
"""

from __future__ import annotations

import argparse
import datetime as dt
import platform
import shlex
import sys
import tempfile
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from gyrocal.run import blas_threads  # noqa: F401,E402 - one BLAS thread, as the command line has

# isort: split
import hypothesis  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
from host import cores, cpu_name  # noqa: E402
from hypothesis import HealthCheck, Phase, given, reject, settings  # noqa: E402
from hypothesis import seed as hypothesis_seed  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from tests.io import fuzzing as fz  # noqa: E402

COMMANDS = ("calibrate", "calibrate", "apply")
PROTOCOLS = ("turntable", "turntable", "turntable", "servo", "sweep")


class Found(Exception):
    """Raised in the shrinking pass for the violation being shrunk."""


@dataclass
class Tally:
    """Outcomes by class, and the violations: key -> (examples, first example, message)."""

    outcomes: Counter = field(default_factory=Counter)
    violations: dict = field(default_factory=dict)

    def add(self, outcome: str) -> None:
        self.outcomes[outcome] += 1


def ingest_example(base, scratch):
    strategy = dict(case=fz.cases(), keep=st.sampled_from(fz.PIPELINE_KEEP))

    def run(case, keep):
        path = _write(base, case, fz.fresh(scratch / "ingest"))
        return fz.check_ingest(path, keep, case.read_batch_rows)

    return strategy, run


def cli_example(base, scratch, calibration):
    strategy = dict(
        case=st.one_of(fz.cases(soft=True), fz.cases()),
        command=st.sampled_from(COMMANDS),
        protocol=st.sampled_from(PROTOCOLS),
        ahead=st.booleans(),
    )

    def run(case, command, protocol, ahead):
        folder = fz.fresh(scratch / "cli")
        path = _write(base, case, folder / "in")
        out = fz.fresh(folder / "out")
        outcome, _ = fz.check_cli(
            command, path, out, calibration=calibration, protocol=protocol, as_process_start=ahead
        )
        return f"{command}: {outcome}"

    return strategy, run


def _write(base, case, folder):
    try:
        return fz.write_case(base, case, fz.fresh(folder))
    except fz.Unwritable:
        reject()


def campaign(name, examples, seed, make):
    """Run ``examples`` examples; tally outcomes; shrink each violation found."""
    strategy, run = make()
    tally = Tally()
    started = time.perf_counter()
    count = [0]

    @hypothesis_seed(seed)
    @settings(
        max_examples=examples,
        deadline=None,
        database=None,
        derandomize=False,
        phases=(Phase.generate,),
        suppress_health_check=list(HealthCheck),
    )
    @given(**strategy)
    def explore(**kw):
        count[0] += 1
        try:
            tally.add(run(**kw))
        except fz.Violation as exc:
            key = _key(exc)
            tally.add("violation")
            n, first, text = tally.violations.get(key, (0, kw, str(exc)))
            tally.violations[key] = (n + 1, first, text)

    explore()
    elapsed = time.perf_counter() - started
    minimal = {key: shrink(strategy, run, key, examples, seed) for key in tally.violations}
    return tally, count[0], elapsed, minimal


def _key(exc: fz.Violation) -> str:
    """Violations with the same kind and origin are one bug (an internal error: the same
    exception type)."""
    if exc.kind == "exception":
        return exc.detail.split(":", 1)[0]
    if exc.kind.startswith("exit") and "internal error: " in exc.detail:
        return f"{exc.kind}: {exc.detail.split('internal error: ', 1)[1].split(':', 1)[0]}"
    return exc.kind


def shrink(strategy, run, key, examples, seed):
    """The smallest example Hypothesis finds that violates the property the same way."""
    last = {}

    @hypothesis_seed(seed)
    @settings(
        max_examples=examples,
        deadline=None,
        database=None,
        derandomize=False,
        phases=(Phase.generate, Phase.shrink),
        suppress_health_check=list(HealthCheck),
        report_multiple_bugs=False,
    )
    @given(**strategy)
    def replay(**kw):
        try:
            run(**kw)
        except fz.Violation as exc:
            if _key(exc) == key:
                last.update(example=kw, text=str(exc))
                raise Found() from None

    try:
        replay()
    except Found:
        return last
    except Exception as exc:  # noqa: BLE001 - Hypothesis gave up: keep the first example
        return {"text": f"(not shrunk: {type(exc).__name__})"}
    return {"text": "(not seen again on replay)"}


def report(name, examples, tally, count, elapsed, minimal):
    print(f"\n## {name}: {count} examples in {elapsed:.0f} s ({1000 * elapsed / max(count, 1):.0f} ms each)")
    for outcome, n in sorted(tally.outcomes.items(), key=lambda kv: -kv[1]):
        print(f"  {n:6d}  {outcome}")
    if not tally.violations:
        print("  property violations: none")
        return 0
    print(f"  property violations: {len(tally.violations)} distinct")
    for key, (n, first, text) in tally.violations.items():
        print(f"  - {key}: {n} examples; {text[:400]}")
        small = minimal[key]
        if "example" in small:
            print(f"      minimal reproducer: {small['example']!r}")
            print(f"      gives: {small['text'][:400]}")
        else:
            print(f"      first example: {first!r} {small['text']}")
    return len(tally.violations)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=3000, help="ingest examples")
    parser.add_argument(
        "--cli-examples",
        type=int,
        default=None,
        help="command-line examples (default: a tenth of --examples)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    # A RuntimeWarning (arithmetic on NaN or inf, an overflow) is an error, as in
    # tests/io/test_fuzzed_logs.py: stricter than pyproject.toml's gyrocal.* filter, since numpy
    # attributes the warnings of its reductions (a sum that overflows) to its own modules.
    warnings.filterwarnings("error", category=RuntimeWarning)
    cli_examples = args.examples // 10 if args.cli_examples is None else args.cli_examples
    started = time.perf_counter()
    print(
        f"# gyrocal fuzzing campaign, {dt.date.today()}, {cpu_name()}, {cores()}, "
        f"Python {platform.python_version()}, hypothesis {hypothesis.__version__}"
    )
    print(f"# python benchmarks/fuzz.py {shlex.join(map(str, argv if argv is not None else sys.argv[1:]))}")
    failures = 0
    with tempfile.TemporaryDirectory(prefix="gyrocal-fuzz-") as tmp:
        scratch = Path(tmp)
        base_path = fz.make_base_log(scratch)
        base = pq.read_table(base_path)
        calibration = scratch / "base-cal.json"
        status, _, stderr, _ = fz.run_cli(["calibrate", str(base_path), "-o", str(calibration)])
        if status != 0:
            raise SystemExit(f"the base log does not calibrate: {stderr}")
        if args.examples:
            results = campaign("ingest", args.examples, args.seed, lambda: ingest_example(base, scratch))
            failures += report("ingest (read_log as the pipeline reads)", args.examples, *results)
        if cli_examples:
            results = campaign(
                "cli", cli_examples, args.seed, lambda: cli_example(base, scratch, calibration)
            )
            failures += report("command line (calibrate, apply)", cli_examples, *results)
    print(f"\nwall time {time.perf_counter() - started:.0f} s; {failures} distinct property violation(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
