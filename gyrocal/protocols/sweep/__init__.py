"""Temperature-sweep drift models of seed 003: windows along a sweep, the conventional and
modified drift models (poly and RBF), bias stability, and the test-design helper.

Typical use::

    windows = sweep_windows(read_log(path))
    train, verify = split_sweeps(windows)[:2]        # or the windows of two logs
    conventional = fit_drift(train, kind="poly", inputs="dT")
    modified = fit_drift(train, kind="rbf", inputs="dT,dT2")
    table = stability_table(verify, {"conventional": conventional, "modified": modified})
"""

_WHERE = {
    "SweepDesign": "design",
    "conduction_time": "design",
    "datasheet_drift": "design",
    "jump_interval": "design",
    "ramp_rate": "design",
    "DriftModel": "models",
    "fit_drift": "models",
    "rbf_layout": "models",
    "bias_stability": "stability",
    "improvements": "stability",
    "reference_errors": "stability",
    "stability_table": "stability",
    "split_sweeps": "windows",
    "sweep_windows": "windows",
}

__all__ = [
    "SweepDesign",
    "conduction_time",
    "datasheet_drift",
    "jump_interval",
    "ramp_rate",
    "DriftModel",
    "fit_drift",
    "rbf_layout",
    "bias_stability",
    "reference_errors",
    "improvements",
    "stability_table",
    "split_sweeps",
    "sweep_windows",
]


def __getattr__(name: str):
    """The package's names are imported on first use (PEP 562): registering the protocol
    or reading its defaults imports none of its methods."""
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
