"""The sweep protocol's settings by default (a config's ``protocols.sweep`` overrides them
key by key); read without importing the protocol's code. Its options are the config
schema's (``$defs/sweep_options``)."""

from ..registry import ProtocolDefaults, option_defaults

DEFAULTS: ProtocolDefaults = {
    "options": option_defaults("sweep"),
    "model": {"kind": "continuous", "terms": ["bias", "bias_temp_poly(degree=1)"]},
    "diagnosis": {
        "candidates": ["bias_temp_poly(degree=2)", "bias_temp_poly(degree=3)"],
        "ladder": [{"name": "modified: + ΔT² (seed 003 Eq 16)", "add": ["bias_temp_poly(degree=2)"]}],
    },
}
