"""Temperature-sweep drift models of seed 003: windows along a sweep, the conventional and
modified drift models (poly and RBF), bias stability, and the test-design helper.

Typical use::

    windows = sweep_windows(read_log(path))
    train, verify = split_sweeps(windows)[:2]        # or the windows of two logs
    conventional = fit_drift(train, kind="poly", inputs="dT")
    modified = fit_drift(train, kind="rbf", inputs="dT,dT2")
    table = stability_table(verify, {"conventional": conventional, "modified": modified})
"""

from .design import SweepDesign, conduction_time, datasheet_drift, jump_interval, ramp_rate
from .models import DriftModel, fit_drift, rbf_layout
from .stability import bias_stability, improvements, reference_errors, stability_table
from .windows import split_sweeps, sweep_windows

__all__ = ["SweepDesign", "conduction_time", "datasheet_drift", "jump_interval", "ramp_rate",
           "DriftModel", "fit_drift", "rbf_layout", "bias_stability", "reference_errors", "improvements",
           "stability_table", "split_sweeps", "sweep_windows"]
