"""The chain from a log to a validated calibration, and the terms identified per unit."""
