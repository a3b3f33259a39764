"""Servo-aided six-observation calibration (seed 001): rotations found in a log, Algorithm 1
and its Levenberg-Marquardt reference, the models with cross-axis terms, and the
Monte-Carlo study of Section III with what the cross-axis terms cost and gain."""

_WHERE = {
    "CrossAxisFit": "fit",
    "ServoFit": "fit",
    "ServoFitError": "fit",
    "fit_iterative": "fit",
    "fit_lm": "fit",
    "fit_fixture": "fit",
    "fit_model": "fit",
    "fit_observations": "fit",
    "fit_symmetric": "fit",
    "Rotations": "rotations",
    "find_rotations": "rotations",
    "g_optimal_warnings": "rotations",
}

__all__ = [
    "CrossAxisFit",
    "Rotations",
    "ServoFit",
    "ServoFitError",
    "find_rotations",
    "fit_fixture",
    "fit_iterative",
    "fit_lm",
    "fit_model",
    "fit_observations",
    "fit_symmetric",
    "g_optimal_warnings",
]


def __getattr__(name: str):
    """The package's names are imported on first use (PEP 562): registering the protocol
    or reading its defaults imports none of its methods."""
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
