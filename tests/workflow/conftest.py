"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``."""

from ..conftest import (  # noqa: F401
    FLEET_CONFIG,
    REPO,
    assert_every_file_whole,
    leftovers,
    needs,
    snakemake,
    snakemake_command,
)
