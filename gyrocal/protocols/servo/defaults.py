"""The servo protocol's settings by default (a config's ``protocols.servo`` overrides them
key by key); read without importing the protocol's code. Its options are the config
schema's (``$defs/servo_options``): by default the calibration's model is ``auto``, the
symmetric cross-axis terms where the rotations determine and show them, seed 001's bias
and scale otherwise (three rotation axes never determine them)."""

from ...fit.model import DEFAULT_TERMS
from ..registry import ProtocolDefaults, option_defaults

DEFAULTS: ProtocolDefaults = {
    "options": option_defaults("servo"),
    "model": {"terms": list(DEFAULT_TERMS)},
    "diagnosis": {},
}
