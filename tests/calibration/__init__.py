"""The calibration file, applying it, looking it up, exporting it to firmware."""
