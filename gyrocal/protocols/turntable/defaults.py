"""The turntable's settings are the config's top-level ones: it has no defaults of its own."""

DEFAULTS = None
