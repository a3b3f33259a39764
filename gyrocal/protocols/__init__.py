"""The four protocols (turntable, servo, sweep, hand rotations) beside their registry.
May import: io, simulate, fit, calibration, report."""
