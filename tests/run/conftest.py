"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``."""

from ..conftest import FLEET_CONFIG, REPO, shard_the_day  # noqa: F401
