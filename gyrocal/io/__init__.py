"""The data in and the files out: logs read and checked, blocks, holds, tables, records.
May import: no other folder of gyrocal."""

# The sensor's three axes, as the log contract names its columns (gyro_x, accel_y, ...) and
# the model its coefficients (scale.z): the one definition every layer imports.
AXES = ("x", "y", "z")
