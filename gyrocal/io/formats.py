"""Names and versions of the JSON documents gyrocal writes (contract section 5), and the
plain values they hold, in a module of their own so that commands which only recognise a
file need not import what reads it."""

import math

import numpy as np

CALIBRATION = "gyrocal.calibration/1"
FAILURE = "gyrocal.failure/1"


def finite_or_none(value):
    """inf and NaN have no place in a file: they become None (printed as –)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_safe(value):
    """Nested values with numpy scalars and arrays as Python numbers and lists, inf/NaN as None."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    return finite_or_none(value)
