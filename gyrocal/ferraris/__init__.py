"""Hand-rotation (Ferraris) calibration: six static faces and a full turn about each axis,
the known angle as the reference (docs/log-format.md, docs/method.md "Hand rotations")."""

# The contract extension's section labels (docs/log-format.md): a face per sensor axis up
# (p) and down (a), a full turn about each axis.
FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
TURNS = ("x_rot", "y_rot", "z_rot")
LABELS = FACES + TURNS
