"""The five protocols (turntable, servo, sweep, hand rotations, static) beside their registry.
May import: io, terms, simulate, fit, calibration, report."""
