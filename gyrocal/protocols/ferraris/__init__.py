"""Hand-rotation (Ferraris) calibration: six static faces and a full turn about each axis,
the known angle as the reference (docs/log-format.md, docs/method.md "Hand rotations")."""
