"""gyrocal: temperature calibration of tri-axial MEMS gyroscopes from rig logs."""

__version__ = "0.1.0"
