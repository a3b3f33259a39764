"""Servo-aided six-observation calibration (seed 001): rotations found in a log, Algorithm 1
and its Levenberg-Marquardt reference, and the Monte-Carlo study of Section III."""

from .fit import ServoFit, ServoFitError, fit_iterative, fit_lm, fit_observations
from .rotations import Rotations, find_rotations, g_optimal_warnings

__all__ = ["Rotations", "ServoFit", "ServoFitError", "find_rotations", "fit_iterative", "fit_lm",
           "fit_observations", "g_optimal_warnings"]
