"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``."""

from ..conftest import TEMPS, make_log, needs  # noqa: F401
