"""The servo protocol's settings by default (a config's ``protocols.servo`` overrides them
key by key); read without importing the protocol's code."""

from ...fit.model import DEFAULT_TERMS

# The servo calibration's model (gyrocal.protocols.servo.fit.MODELS): auto takes the symmetric
# cross-axis terms where the rotations determine and show them, seed 001's bias and scale
# otherwise (three rotation axes never determine them).
DEFAULTS = {"options": {"calibration": "auto"}, "model": {"terms": list(DEFAULT_TERMS)}, "diagnosis": {}}
