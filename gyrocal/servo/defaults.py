"""The servo protocol's settings by default (a config's ``protocols.servo`` overrides them
key by key); read without importing the protocol's code."""

from ..model import DEFAULT_TERMS

DEFAULTS = {"options": {}, "model": {"terms": list(DEFAULT_TERMS)}, "diagnosis": {}}
