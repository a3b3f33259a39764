"""The sweep protocol's settings by default (a config's ``protocols.sweep`` overrides them
key by key); read without importing the protocol's code."""

DEFAULTS = {
    "options": {"window_s": 20.0, "point_span": "auto"},
    "model": {"kind": "continuous", "terms": ["bias", "bias_temp_poly(degree=1)"]},
    "diagnosis": {
        "candidates": ["bias_temp_poly(degree=2)", "bias_temp_poly(degree=3)"],
        "ladder": [{"name": "modified: + ΔT² (seed 003 Eq 16)", "add": ["bias_temp_poly(degree=2)"]}],
    },
}
