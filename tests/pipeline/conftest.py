"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``."""

from ..conftest import make_log, truth_coefficients  # noqa: F401
