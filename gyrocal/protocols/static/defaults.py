"""The static protocol's settings by default (a config's ``protocols.static`` overrides them
key by key); read without importing the protocol's code. The windows are the sweep's
(gyrocal/protocols/sweep/windows.py) with no temperature span asked of them."""

DEFAULTS = {
    "options": {"window_s": 20.0, "point_span": 10.0, "min_span": 0.0, "min_windows": 2},
    "model": {"kind": "continuous", "terms": ["bias"]},
    "diagnosis": {"candidates": []},
}
