"""Names and versions of the JSON documents gyrocal writes (contract section 5), in a module
of their own so that commands which only recognise a file need not import what reads it."""

CALIBRATION = "gyrocal.calibration/1"
FAILURE = "gyrocal.failure/1"
