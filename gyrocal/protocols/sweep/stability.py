"""Bias stability before and after drift compensation (seed 003, Eq 30-32, Tables 2-7).

Eq 30 defines bias stability as the mean square error between the evaluated output x and
its reference x': BS = mean((x − x')²), in (deg/s)². Eq 31 applies it three times:

    BS1  raw output                                    against the rig's reference rate
    BS2  output compensated by the conventional f(ΔT)  against the same reference
    BS3  output compensated by the modified f(ΔT, ΔT²) against the same reference

Eq 32 prints P_i = BS_{i+1} / BS_i, but every row of Tables 3-7 has P1 = BS2/BS1,
P2 = BS3/BS1 and P3 = P2/P1 (= BS3/BS2, the "≈ 10 %"): e.g. Table 3, x axis,
3.885e-4 / 15.3711 = 2.528e-5 = P2. The tables' definition is used here. Table 2 has one
compensated column (the modified model) and its improvement BS2/BS1.

The evaluated data are the verification sweep's: its windows (means, so the noise enters
divided by the window's sample count) or its samples (the paper's figures).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from ...io import AXES
from ...io.errors import InputError, MissingInputError
from ...io.log import GYRO, MOUNTS
from .models import TARGETS, DriftModel


def bias_stability(x, reference=0.0) -> np.ndarray:
    """Eq 30: mean over rows of (x − reference)², per column ((deg/s)²)."""
    d = np.asarray(x, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    if d.shape[0] == 0:
        raise InputError("bias stability of no samples; expected at least one")
    if not np.isfinite(d).all():
        raise InputError("bias stability input holds non-finite values")
    return np.mean(d * d, axis=0)


def improvements(bs1, bs2, bs3=None) -> dict[str, np.ndarray]:
    """P1 = BS2/BS1, and with BS3: P2 = BS3/BS1, P3 = P2/P1 (Tables 3-7's columns)."""
    bs1, bs2 = np.asarray(bs1, dtype=float), np.asarray(bs2, dtype=float)
    if (bs1 <= 0).any() or (bs3 is not None and (bs2 <= 0).any()):
        raise InputError("bias stability of zero: no scatter to compare against")
    out = {"P1": bs2 / bs1}
    if bs3 is not None:
        out["P2"] = np.asarray(bs3, dtype=float) / bs1
        out["P3"] = out["P2"] / out["P1"]
    return out


def reference_errors(data, *, mount: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Raw error (n, 3) against the reference and the gyro output it came from (n, 3).

    Windows (a table with ``err_x/y/z``): their errors and means. Samples (a RigLog or a
    table with ``gyro_x/y/z`` and ``ref_rate``): output minus the reference rate along the
    mount axis, the mount from ``mount``, else the ``mount`` column, else none needed when
    the reference is 0 throughout.
    """
    if isinstance(data, pd.DataFrame) and set(TARGETS) <= set(data.columns):
        err = data[list(TARGETS)].to_numpy(dtype=np.float64)
        raw = data[list(GYRO)].to_numpy(dtype=np.float64) if set(GYRO) <= set(data.columns) else err
        return err, raw
    if hasattr(data, "column") and hasattr(data, "batches"):
        col = data.column
        has = data.__contains__
    elif isinstance(data, pd.DataFrame):

        def col(name):
            return data[name].to_numpy()

        has = data.columns.__contains__
    else:
        raise InputError(
            f"bias stability needs sweep windows, samples or a RigLog, got {type(data).__name__}"
        )
    missing = [c for c in (*GYRO, "ref_rate") if not has(c)]
    if missing:
        raise MissingInputError(f"samples lack {', '.join(missing)}")
    raw = np.column_stack([col(c) for c in GYRO]).astype(np.float64)
    ref = np.asarray(col("ref_rate"), dtype=np.float64)
    expected = np.zeros_like(raw)
    if mount is not None:
        if mount not in MOUNTS:
            raise InputError(f"mount must be one of {' '.join(MOUNTS)}, got {mount!r}")
        code = np.full(len(ref), MOUNTS.index(mount))
    elif has("mount"):
        m = col("mount")
        code = (
            np.asarray(m, dtype=np.int64)
            if np.asarray(m).dtype.kind in "iu"
            else pd.Categorical(m, categories=MOUNTS).codes.astype(np.int64)
        )
    else:
        code = None
    if code is None or (code < 0).any():
        if np.any(ref != 0):
            raise MissingInputError(
                "samples turn at a non-zero reference rate but give no mount; pass mount= or a mount column"
            )
    else:
        rows = np.arange(len(ref))
        expected[rows, code // 2] = np.where(code % 2 == 0, 1.0, -1.0) * ref
    return raw - expected, raw


def stability_table(data, models, *, mount: str | None = None) -> pd.DataFrame:
    """Bias stabilities and improvements per axis, in the shape of Tables 2-7.

    ``models``: one :class:`DriftModel` (Table 2: columns BS1, BS2, P1 = BS2/BS1), or the
    conventional and the modified model as a pair or a mapping with those keys (Tables 3-7:
    BS1, BS2, BS3, P1, P2, P3). ``data`` are verification windows or samples
    (:func:`reference_errors`); their ΔT is counted from each model's own ``t_ref``.
    """
    if isinstance(models, DriftModel):
        chain = [models]
    elif isinstance(models, Mapping):
        missing = [k for k in ("conventional", "modified") if k not in models]
        if missing:
            raise InputError(f"models mapping lacks {', '.join(missing)}; expected conventional and modified")
        chain = [models["conventional"], models["modified"]]
    elif isinstance(models, Sequence) and len(models) in (1, 2):
        chain = list(models)
    else:
        raise InputError("models must be one DriftModel, a (conventional, modified) pair or a mapping")
    if not all(isinstance(m, DriftModel) for m in chain):
        raise InputError("models must be DriftModel instances")
    err, _ = reference_errors(data, mount=mount)
    bs = [bias_stability(err)] + [bias_stability(err - m.predict(data)) for m in chain]
    table = pd.DataFrame({f"BS{i + 1}": v for i, v in enumerate(bs)}, index=pd.Index(AXES, name="axis"))
    for name, value in improvements(*bs).items():
        table[name] = value
    table.attrs.update(
        n=int(len(err)),
        level="windows"
        if isinstance(data, pd.DataFrame) and set(TARGETS) <= set(data.columns)
        else "samples",
        models=[f"{m.kind}({m.inputs})" for m in chain],
    )
    return table
