"""gyrocal: temperature calibration of tri-axial MEMS gyroscopes from rig logs.

The functions a notebook or script calls (gyrocal.run.api; docs/api.md)::

    import gyrocal
    result = gyrocal.calibrate("U001.parquet")      # a path, a DataFrame or a pyarrow Table
    result.save("U001.json"); result.report("U001.html")
    d = gyrocal.diagnose("U001.parquet", other="U001-next.parquet")
    d.verdict, d.best, d.candidates

They load on first use: ``import gyrocal`` alone, as the command line does, stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = [
    "Calibration",
    "CalibrationResult",
    "Diagnosis",
    "Noise",
    "Settings",
    "__version__",
    "apply",
    "calibrate",
    "diagnose",
    "load_calibration",
    "load_settings",
    "noise",
    "read_log",
    "simulate_log",
]

if TYPE_CHECKING:
    from .run.api import (
        Calibration,
        CalibrationResult,
        Diagnosis,
        Noise,
        Settings,
        apply,
        calibrate,
        diagnose,
        load_calibration,
        load_settings,
        noise,
        read_log,
        simulate_log,
    )


def __getattr__(name: str) -> Any:
    if name in __all__:
        from .run import api

        return getattr(api, name)
    raise AttributeError(f"module 'gyrocal' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(__all__) | {name for name in globals() if name.startswith("__")})
