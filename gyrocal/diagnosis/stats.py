"""The tails and bounds the diagnosis' tests use.

χ² and F tails come from scipy.special as scipy.stats computes them (chi2.sf is chdtrc,
chi2.ppf 2·gammaincinv(df/2, q), f.sf fdtrc; 1 below the support): the same numbers
without importing scipy.stats, which takes longer than a diagnosis.
"""

from __future__ import annotations

import numpy as np
from scipy import special


def chi2_sf(x, df) -> float:
    return float(special.chdtrc(df, 0.0 if x < 0 else x))


def chi2_ppf(q, df) -> float:
    return float(2.0 * special.gammaincinv(df / 2.0, q))


def f_sf(x, df_num, df_den) -> float:
    return float(special.fdtrc(df_num, df_den, 0.0 if x < 0 else x))


def fisher_combined(*p_values) -> float:
    """Fisher's combination of independent p-values (each floored at 1e-300)."""
    p = np.maximum(np.asarray(p_values, dtype=float), 1e-300)
    return chi2_sf(-2.0 * np.sum(np.log(p)), 2 * p.size)


def chance_bound(holds: int, alpha: float) -> float:
    """How far above the RMS a correct model should leave a validation RMS of ``holds``
    holds (three errors each) may lie by chance: ``sqrt(χ²_N(1 − α/2) / N)``."""
    n = 3 * max(int(holds), 1)
    return float(np.sqrt(chi2_ppf(1.0 - alpha / 2, n) / n))


def floor_uncertainty(obs) -> float:
    """The noise floor's own relative uncertainty: it comes from the session's static data,
    T seconds of it, and the Allan deviation at a hold's length τ is then known to about
    ``sqrt(τ / 2T)`` (0 without static data)."""
    static = float(getattr(obs, "attrs", {}).get("static_seconds") or 0.0)
    hold = float(np.median(obs["duration"])) if "duration" in obs else 0.0
    return float(np.sqrt(hold / (2.0 * static))) if static > 0 and hold > 0 else 0.0


def explained_tolerance(obs, holds: int, alpha: float) -> float:
    """How far above what a correct model would leave a validation RMS may lie and still
    count as explained: chance (:func:`chance_bound`) times twice the floor's own relative
    uncertainty (:func:`floor_uncertainty`)."""
    return chance_bound(holds, alpha) * (1.0 + 2.0 * min(floor_uncertainty(obs), 0.5))


def p_text(value: float) -> str:
    return "< 1e-16" if value < 1e-16 else f"= {value:.2g}"
