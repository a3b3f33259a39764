"""The fit: the model, the noise floor and wander, profiling, the temperature grid, validation.
May import: io, terms."""

# The compensations validation compares (seed 000's Mean/RMS tables): none, the calibration at one
# temperature, and the interpolation across temperature. Here, not in .validate, so a report
# names them without importing the fit's tables.
METHODS = ("uncompensated", "single", "interpolated")
