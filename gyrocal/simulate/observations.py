"""Observation tables drawn directly from a unit (no log, no segmentation): the hold means
a turntable protocol would give, for Monte Carlo studies of the fit and the diagnosis."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..io.log import MOUNTS
from .unit import GyroUnit


def observations(
    unit: GyroUnit,
    rng: np.random.Generator,
    *,
    temperatures=(-10.0, 0.0, 10.0, 20.0, 30.0, 40.0),
    rates=(0.1, 1.0, 10.0, 50.0, 100.0, 200.0, 400.0),
    mounts=("+x", "+y", "+z"),
    samples: int = 600,
    sample_rate: float = 100.0,
    temp_rate_sd: float = 0.0,
) -> pd.DataFrame:
    """One row per hold, in the columns segmentation writes. ``temp_rate_sd`` (°C/min)
    spreads the holds' temperature rates, as the door openings of a real chamber do."""
    rows = []
    sigma = unit.noise_std(sample_rate)
    for p, temp in enumerate(temperatures):
        for mount in mounts:
            axis, sign = "xyz".index(mount[1]), 1.0 if mount[0] == "+" else -1.0
            for ref in [0.0] + [s * r for r in rates for s in (1.0, -1.0)]:
                w_true = np.zeros(3)
                w_true[axis] = sign * ref
                force = np.zeros(3)
                force[axis] = sign
                t = temp + rng.normal(0.0, 0.02)
                rate = rng.normal(0.0, temp_rate_sd) if temp_rate_sd else 0.0
                ideal = (
                    unit.K(t) @ w_true
                    + unit.B(t)
                    + unit.effects(w_true[None], force[None], np.array([rate]))[0]
                )
                std = sigma * rng.uniform(0.9, 1.1, 3)
                w = ideal + rng.normal(0.0, std / np.sqrt(samples))
                # What segmentation reports is the sample std of the hold, not the true one.
                std = std * np.sqrt(rng.chisquare(samples - 1, 3) / (samples - 1))
                rows.append(
                    dict(
                        hold=len(rows),
                        t_start=len(rows) * 10.0,
                        t_end=len(rows) * 10.0 + 6.0,
                        duration=6.0,
                        n=samples,
                        mount=mount,
                        axis="xyz"[axis],
                        sign=sign,
                        mount_source="column",
                        ref_rate=ref,
                        temp=t,
                        temp_rate=rate,
                        point=p,
                        **{f"rate_{a}": w_true[i] for i, a in enumerate("xyz")},
                        **{f"gyro_{a}": w[i] for i, a in enumerate("xyz")},
                        **{f"std_{a}": std[i] for i, a in enumerate("xyz")},
                        **{f"accel_{a}": force[i] for i, a in enumerate("xyz")},
                    )
                )
    obs = pd.DataFrame(rows)
    obs["mount"] = pd.Categorical(obs["mount"], categories=MOUNTS)
    obs["point_temp"] = obs.groupby("point")["temp"].transform("mean")
    return obs
