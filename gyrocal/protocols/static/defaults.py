"""The static protocol's settings by default (a config's ``protocols.static`` overrides them
key by key); read without importing the protocol's code. The windows are the sweep's
(gyrocal/protocols/sweep/windows.py) with no temperature span asked of them; its options are
the config schema's (``$defs/static_options``)."""

from ..registry import ProtocolDefaults, option_defaults

DEFAULTS: ProtocolDefaults = {
    "options": option_defaults("static"),
    "model": {"kind": "continuous", "terms": ["bias"]},
    "diagnosis": {"candidates": []},
}
