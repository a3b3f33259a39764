"""The settings, and the chain that takes one log through its protocol to its calibration.
May import: io, terms, fit, calibration, protocols."""
