"""The calibration file, its review, and what reads it: apply, firmware export, lookup.
May import: io, terms, fit."""
