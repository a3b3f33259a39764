"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``; the
small fleet the scheduler tests run and its local run; what the tests read from Snakemake's
output."""

from pathlib import Path

import pytest

from ..conftest import (  # noqa: F401
    FLEET_CONFIG,
    REPO,
    assert_every_file_whole,
    leftovers,
    made_once,
    needs,
    shard_the_day,
    snakemake,
    snakemake_command,
)

# The small fleet the scheduler tests (test_cluster.py, test_slurm.py) run and compare with
# a local run: two good units in two batches, and a corrupt log, whose unit fails alone.
GOOD = [("B1", "A1", "2026-01-01"), ("B2", "A2", "2026-01-02")]
BAD = ("B2", "BAD", "2026-01-02")
CORRUPT = Path("logs", "corrupt.parquet")
HEADER = "device\tbatch\tsession\tprotocol\tpath\n"
ROW = "{1}\t{0}\t{2}\tturntable\tdemo/logs/{0}/{1}/{2}.parquet\n"
GOOD_ROWS = "".join(ROW.format(*u) for u in GOOD)
BAD_ROW = f"BAD\tB2\t{BAD[2]}\tturntable\t{CORRUPT}\n"
CONFIG = """devices: devices.tsv
demo: {folder: demo/logs, preset: quick, temperatures: [0, 20, 40], rates: [10, 100, 400]}
model: {terms: [bias, scale, misalignment]}
diagnosis: {ladder: []}
"""


def fleet_folder(path: Path, rows: str = GOOD_ROWS + BAD_ROW) -> Path:
    """A workflow folder of the small fleet's settings for ``rows`` (the corrupt log too if
    they name it)."""
    path.mkdir(exist_ok=True)
    (path / "devices.tsv").write_text(HEADER + rows)
    (path / "config.yaml").write_text(CONFIG)
    if str(CORRUPT) in rows:
        (path / CORRUPT).parent.mkdir(exist_ok=True)
        (path / CORRUPT).write_bytes(b"PAR1 not a parquet file")
    return path


@pytest.fixture(scope="session")
def small_fleet_local(tmp_path_factory, worker_id) -> Path:
    """The small fleet run locally on two cores, once for the whole run (made_once): what a
    run through a scheduler must give byte for byte."""

    def make(wd):
        fleet_folder(wd)
        out = snakemake(wd)
        assert out.returncode == 0, out.stderr[-3000:]

    return made_once(tmp_path_factory, worker_id, "small-fleet-local", make)


def job_counts(out) -> dict[str, int]:
    """Jobs per rule from Snakemake's job statistics (dry run or real)."""
    text = out.stdout + out.stderr
    stats = text[text.index("Job stats") :].split("\n\n")[0]
    return {line.split()[0]: int(line.split()[1]) for line in stats.splitlines()[3:] if line.strip()}
