"""Small simulated logs, made once per test session (seconds of data per hold)."""

from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path

from gyrocal.run import blas_threads  # noqa: F401 - before numpy: one BLAS thread, as the CLI has

# isort: split
import numpy as np
import pytest
from hypothesis import settings

# CI runs the same examples every time (every commit green); `pytest --hypothesis-profile
# explore` searches afresh with many more, to hunt for new failures.
settings.register_profile("default", derandomize=True, deadline=None, max_examples=50)
settings.register_profile("explore", max_examples=2000, deadline=None)
settings.load_profile("default")

from gyrocal.simulate import GyroUnit, TurntableProtocol, load_truth, simulate_unit  # noqa: E402 (after the profile)

# CI (.ci/run) sets GYROCAL_REQUIRE_DEPS=1: there a test whose dependency is missing fails
# instead of being skipped, so a green CI has run every test. `make test` installs all of
# them (test extras, Debian packages, the C kernel built on install).
REQUIRE_DEPS = bool(os.environ.get("GYROCAL_REQUIRE_DEPS"))


def needs(found: dict[str, bool], install: str) -> pytest.MarkDecorator:
    """Mark tests that need each named dependency (name -> whether it is there): a missing
    one skips them, saying how to install it, or fails them under GYROCAL_REQUIRE_DEPS."""
    missing = [name for name, ok in found.items() if not ok]
    reason = f"missing {' and '.join(missing)} ({install})"
    if missing and REQUIRE_DEPS:
        return pytest.mark.missing_dependency(reason)
    return pytest.mark.skipif(bool(missing), reason=reason)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Before any fixture is built: a fixture may itself need the dependency."""
    for mark in item.iter_markers("missing_dependency"):
        pytest.fail(f"{mark.args[0]}; GYROCAL_REQUIRE_DEPS is set", pytrace=False)


# The files that take a minute or more on two cores, longest first (pytest --durations,
# per file). `make test` hands whole files to the workers (pytest-xdist, --dist loadfile)
# in collection order; these come first, so that none of them starts last and leaves one
# worker busy alone at the end. The SLURM tests wait minutes for the scheduler's time
# limits whatever the machine's speed. A file not named here keeps its place after them.
LONGEST_FIRST = (
    "tests/workflow/test_slurm.py",
    "tests/diagnose/test_independent_zoo.py",
    "tests/diagnose/test_missing_effects.py",
    "tests/diagnose/test_fix_lines.py",
    "tests/diagnose/test_sharp_shapes.py",
    "tests/workflow/test_fleet_workflow.py",  # makes fleet_run, which the next ones read
    "tests/workflow/test_faults.py",
    "tests/workflow/test_fleet_reruns.py",
    "tests/terms/test_histories.py",
    "tests/workflow/test_browser.py",
    "tests/fit/test_noise_floor.py",
    "tests/workflow/test_cluster.py",
    "tests/terms/test_user_terms.py",
    "tests/run/test_shards.py",
    "tests/workflow/test_object_storage.py",
)


@pytest.hookimpl(wrapper=True)
def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker more than the cores. The end-to-end tests wait for minutes
    (SLURM's time limits, the guard's timeouts, jobs held mid-write) with a core idle; the
    extra worker's file runs meanwhile. PYTEST_XDIST_AUTO_NUM_WORKERS, if set, is taken as is."""
    workers = yield
    return workers if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS") else workers + 1


def pytest_configure(config):
    # pytest-xdist would otherwise hand out the files with the most tests first.
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """The longest files first (LONGEST_FIRST), the others in collection order; a notebook
    the suite runs (nbmake: docs/tutorial.ipynb, over 10 s) is out of the quick loop."""
    for item in items:
        if item.nodeid.endswith(".ipynb"):
            item.add_marker(pytest.mark.slow)
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


# Ten-degree spacing as in seed 000 Table 1, over a span short enough for quick tests.
TEMPS = (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0)


def make_log(directory, name="U001", *, seed=1, unit=None, **rig):
    path = directory / f"{name}.parquet"
    protocol = TurntableProtocol.quick(**{"temperatures": TEMPS, **rig})
    simulate_unit(
        path,
        rig=protocol,
        unit=unit or GyroUnit.seed000(),
        rng=np.random.default_rng(seed),
        device=name,
        seed=seed,
    )
    return path


@pytest.fixture(scope="session")
def logs(tmp_path_factory):
    """name -> path of session-wide simulated logs."""
    d = tmp_path_factory.mktemp("logs")
    return {
        "complete": make_log(d, "complete"),
        "no_mount": make_log(d, "no_mount", seed=2, mount_column=False),
        "random_unit": make_log(
            d,
            "random_unit",
            seed=3,
            unit=GyroUnit.random(np.random.default_rng(30)),
            temperatures=(0.0, 20.0, 40.0),
        ),
    }


@pytest.fixture(scope="session")
def complete_run(logs):
    from gyrocal.pipeline.chain import run

    return run(logs["complete"])


@pytest.fixture(scope="session")
def truth(logs):
    return {k: load_truth(v) for k, v in logs.items()}


def truth_coefficients(unit: GyroUnit, temp: float) -> dict[str, float]:
    """The model's coefficients implied by a simulated unit at one temperature."""
    K, B = unit.K(temp), unit.B(temp)
    out = {}
    for i, a in enumerate("xyz"):
        out[f"bias.{a}"] = B[i]
        out[f"scale.{a}"] = K[i, i] - 1.0
        for j, b in enumerate("xyz"):
            if a != b:
                out[f"misalignment.{a}.{b}"] = K[i, j]
    return out


@pytest.fixture
def registry():
    """Terms registered by a test's term files are forgotten afterwards."""
    from gyrocal.terms import TERMS, user

    terms, loaded = dict(TERMS), dict(user._LOADED)
    yield
    TERMS.clear()
    TERMS.update(terms)
    user._LOADED.clear()
    user._LOADED.update(loaded)


def with_rig(**kw):
    return replace(TurntableProtocol.quick(temperatures=TEMPS), **kw)


REPO = Path(__file__).resolve().parents[1]
FLEET_MANIFEST = """device\tbatch\tsession\tprotocol\tpath
A1\tB1\t2026-01-01\tturntable\tdemo/logs/B1/A1/2026-01-01.parquet
A1\tB1\t2026-03-01\tturntable\tdemo/logs/B1/A1/2026-03-01.parquet
A2\tB2\t2026-01-02\tturntable\tdemo/logs/B2/A2/2026-01-02.parquet
BAD\tB2\t2026-01-02\tturntable\tlogs/corrupt.parquet
GONE\tB2\t2026-01-03\tturntable\tlogs/absent.parquet
S1\tB3\t2026-01-04\tservo\tdemo/logs/B3/S1/2026-01-04.parquet
W1\tB3\t2026-01-05\tsweep\tdemo/logs/B3/W1/2026-01-05.parquet
"""
FLEET_CONFIG = """devices: devices.tsv
demo:
  folder: demo/logs
  preset: quick
  temperatures: [0, 20, 40]
  rates: [10, 100, 400]
  units: {A2: {effects: {scale_quadratic: [1.0e-6, -8.0e-7, 6.0e-7]}}}
model: {terms: [bias, scale, misalignment]}
diagnosis: {ladder: [{name: "+ nonlinearity", add: [scale_quadratic]}]}
spec: {turntable: {excess: 5, "parameters": {"bias.*": 0.5}}}
drift: {tolerance: {"bias.*": 0.005}}
"""


def snakemake_command(workdir, *args) -> list[str]:
    """The command that runs the repository's workflow in ``workdir`` with its config.yaml."""
    import sys

    return [
        sys.executable,
        "-m",
        "snakemake",
        "--snakefile",
        str(REPO / "Snakefile"),
        "--directory",
        str(workdir),
        "--configfile",
        str(workdir / "config.yaml"),
        "--cores",
        "2",
        *map(str, args),
    ]


def snakemake(workdir, *args, timeout=900, env=None):
    """Run the repository's workflow in ``workdir`` with its config.yaml."""
    import subprocess

    return subprocess.run(
        snakemake_command(workdir, *args), capture_output=True, text=True, timeout=timeout, env=env
    )


def shard_the_day(folder, *snakemake_args) -> int:
    """``gyrocal shard --run`` of ``folder/day.tsv`` in shards of two units, two at once, into
    ``folder/runs`` with ``folder/config.yaml`` and these Snakemake arguments; its status."""
    from gyrocal.run.cli import main

    return main(
        [
            "shard",
            "--manifest",
            str(folder / "day.tsv"),
            "--size",
            "2",
            "-o",
            str(folder / "runs"),
            "--run",
            "--at-once",
            "2",
            "--configfile",
            str(folder / "config.yaml"),
            "--",
            *map(str, snakemake_args),
        ]
    )


def assert_every_file_whole(wd):
    """Every result, report and summary that exists reads as what its name says."""
    import json

    import pyarrow.parquet as pq

    files = [
        p
        for root in ("results", "reports")
        for p in (wd / root).rglob("*")
        if p.is_file() and not p.name.startswith(".") and "benchmark" not in p.parts
    ]
    assert files
    for path in files:
        if path.suffix == ".parquet":
            pq.read_table(path)
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".html":
            assert path.read_text().rstrip().endswith("</html>"), path


def leftovers(wd):
    """Temporary files and folders (pathlib's * matches hidden names too)."""
    return [
        p
        for root in ("results", "reports")
        for pattern in ("*.tmp", "*.old")
        for p in (wd / root).rglob(pattern)
    ]


def made_once(tmp_path_factory, worker_id, name: str, make) -> Path:
    """The folder ``name``, filled by ``make(folder)`` once for the whole run: the test
    processes pytest-xdist starts share it (a lock on a file beside their temporary
    folders), so that what it holds is made once, not once per process that needs it."""
    import fcntl

    root = tmp_path_factory.getbasetemp()
    root = root if worker_id == "master" else root.parent
    wd = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (wd / ".made").exists():
            shutil.rmtree(wd, ignore_errors=True)
            wd.mkdir(parents=True)
            make(wd)
            (wd / ".made").write_text("")
    return wd


@pytest.fixture(scope="session")
def fleet_run(tmp_path_factory, worker_id):
    """A small fleet through the whole workflow: five demo unit sessions (one device
    twice), one corrupt log and one missing log. Made once for the whole run (made_once)."""

    def make(wd):
        (wd / "logs").mkdir()
        (wd / "logs" / "corrupt.parquet").write_bytes(b"PAR1 not a parquet file")
        (wd / "devices.tsv").write_text(FLEET_MANIFEST)
        (wd / "config.yaml").write_text(FLEET_CONFIG)
        out = snakemake(wd)
        assert out.returncode == 0, out.stderr[-3000:]

    return made_once(tmp_path_factory, worker_id, "fleet-shared", make)


def pytest_report_header(config):
    """The SLURM the scheduler tests run on (tests/workflow/test_slurm.py) and the PostgreSQL
    the registry's tests run on (tests/registry), named in every run."""
    from . import pg
    from .workflow import slurm

    return [
        f"SLURM for the scheduler tests: {slurm.installed_version() or 'not installed'}",
        f"PostgreSQL for the registry tests: {pg.installed_version() or 'not installed'}",
    ]
