"""The calibration file and what reads it: its format, apply, firmware export, lookup.
May import: io, terms, fit."""
