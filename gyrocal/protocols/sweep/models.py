"""Temperature drift models of seed 003: the conventional f(ΔT) and the modified f(ΔT, ΔT²).

Eq 6 (conventional) and Eq 16 (modified) give the drift error of each axis as a function of
the temperature variation ΔT = T − T0, and of ΔT² as well. Two ways to realise f:

``poly``  least squares in the inputs: c0 + c1 ΔT (conventional) or c0 + c1 ΔT + c2 ΔT²
          (modified), weighted by each window's sample count, with standard errors.
``rbf``   a Gaussian radial-basis network (Eq 26-27, 29) on the inputs u, scaled to [0, 1]
          over the training windows so ΔT and ΔT² weigh alike: K kernels
          φ_j = exp(−|u − c_j|² / 2σ_j²), a bias neuron, and direct links from the inputs to
          the outputs (a linear tail), so that offset and trend, which Gaussians represent
          only with large cancelling weights, cost no kernels. Training is deterministic, with no gradient
          descent (Eq 28): centres are K points evenly spaced over the training ΔT range,
          placed on the curve the inputs follow ((ΔT) or (ΔT, ΔT²)), so every centre is an
          input the sweep can produce; each width is ``width`` times the mean distance to the
          neighbouring centres; the output weights are the ridge-regularised least-squares
          solution (ridge λ = ``ridge`` × mean diagonal of ΦᵀWΦ, on the kernels only), which
          is the optimum Eq 28's weight update moves towards for fixed centres and widths.

With a flexible f, ΔT² adds no information to ΔT (it is a function of it): the two RBF
inputs differ only in the geometry of the kernels. The modified model gains where the
conventional one is linear in ΔT, which is what the ``poly`` pair compares.

ΔT of a model is counted from the reference temperature of its training sweep, kept as
``t_ref``: prediction from data with a ``temp`` column uses ``temp − t_ref``, so a
verification sweep that starts elsewhere is compensated with the training sweep's ΔT.
Compensated output (Section 3.2 step 4): raw output minus the predicted drift.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
import pandas as pd

from ...io import AXES
from ...io.errors import (
    CalibrationFileError,
    ConfigError,
    IdentifiabilityError,
    InputError,
    MissingInputError,
)
from ...io.log import GYRO

FORMAT = "gyrocal.drift/1"
KINDS = ("poly", "rbf")
INPUTS = ("dT", "dT,dT2")
TARGETS = ("err_x", "err_y", "err_z")

Rows = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class DriftModel:
    """A fitted drift model for the three axes. Rates in deg/s, temperatures in °C.

    ``coef`` holds per axis the poly coefficients c0, c1(, c2) of ΔT^k (deg/s/°C^k) with
    ``stderr`` beside them, or for ``rbf`` the bias weight w0, the direct-link weights
    a1(, a2) of the scaled inputs and the K kernel weights w1..wK (deg/s). ``centres``
    (K × inputs, scaled units), ``widths``, ``offset`` and ``scale`` (u = (x − offset) / scale)
    describe the network. ``residual_rms`` is the fit's
    weighted RMS over the training windows and ``noise`` the RMS scatter expected of a
    window mean from the noise inside the windows (both deg/s, per axis).
    """

    kind: str
    inputs: str
    t_ref: float
    coef: Rows
    stderr: Rows = ()
    centres: Rows = ()
    widths: tuple[float, ...] = ()
    offset: tuple[float, ...] = ()
    scale: tuple[float, ...] = ()
    ridge: float = 0.0
    residual_rms: tuple[float, ...] = (0.0, 0.0, 0.0)
    noise: tuple[float, ...] = (0.0, 0.0, 0.0)
    n_train: int = 0
    dT_range: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ConfigError(f"drift model kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.inputs not in INPUTS:
            raise ConfigError(f"drift model inputs must be one of {', '.join(INPUTS)}, got {self.inputs!r}")

    @property
    def n_inputs(self) -> int:
        return 1 if self.inputs == "dT" else 2

    # -- evaluation -------------------------------------------------------------------
    def delta_t(self, data) -> np.ndarray:
        """ΔT (°C) of ``data``, counted from this model's ``t_ref``: ``temp − t_ref`` for a
        table or log with a ``temp`` column; a ``dT`` column (taken as counted from
        ``t_ref``) otherwise; a plain array is ΔT itself."""
        if hasattr(data, "column") and hasattr(data, "batches"):  # a RigLog
            x = data.column("temp").astype(np.float64) - self.t_ref
        elif isinstance(data, pd.DataFrame):
            if "temp" in data.columns:
                x = data["temp"].to_numpy(dtype=np.float64) - self.t_ref
            elif "dT" in data.columns:
                x = data["dT"].to_numpy(dtype=np.float64)
            else:
                raise MissingInputError(
                    "drift model needs a temp or dT column, found "
                    f"{', '.join(map(str, data.columns)) or 'none'}"
                )
        else:
            x = np.asarray(data, dtype=np.float64).reshape(-1)
        if not np.isfinite(x).all():
            raise InputError(
                f"ΔT holds {int(np.count_nonzero(~np.isfinite(x)))} non-finite values; "
                "expected finite temperatures"
            )
        return x

    def predict(self, data) -> np.ndarray:
        """Predicted drift (n, 3) in deg/s for windows, samples, a RigLog or ΔT values."""
        dT = self.delta_t(data)
        W = np.asarray(self.coef)
        if self.kind == "poly":
            powers = dT[:, None] ** np.arange(W.shape[1])
            return powers @ W.T
        return self._kernels(dT) @ W.T

    def compensate(self, data) -> np.ndarray:
        """Compensated output (n, 3): the raw gyro columns minus the predicted drift."""
        if hasattr(data, "column") and hasattr(data, "batches"):
            raw = np.column_stack([data.column(c) for c in GYRO]).astype(np.float64)
        elif isinstance(data, pd.DataFrame) and set(GYRO) <= set(data.columns):
            raw = data[list(GYRO)].to_numpy(dtype=np.float64)
        else:
            raise MissingInputError("compensation needs the gyro_x, gyro_y, gyro_z columns")
        return raw - self.predict(data)

    def _kernels(self, dT: np.ndarray) -> np.ndarray:
        """Design matrix (n, 1 + N + K): bias neuron, direct links, Gaussian kernels (Eq 26)."""
        U = (_inputs(dT, self.inputs) - np.asarray(self.offset)) / np.asarray(self.scale)
        C = np.asarray(self.centres)
        d2 = (U * U).sum(axis=1)[:, None] + (C * C).sum(axis=1)[None, :] - 2.0 * U @ C.T
        phi = np.exp(-np.maximum(d2, 0.0) / (2.0 * np.asarray(self.widths) ** 2))
        return np.column_stack([np.ones(len(dT)), U, phi])

    # -- description and storage -------------------------------------------------------
    def parameter_names(self) -> list[str]:
        """Names of ``coef`` entries per axis: ``x.c0``.. (poly); ``x.w0``, ``x.a1``.., ``x.w1``.. (rbf)."""
        if self.kind == "poly":
            own = [f"c{k}" for k in range(len(self.coef[0]))]
        else:
            own = (
                ["w0"]
                + [f"a{i + 1}" for i in range(self.n_inputs)]
                + [f"w{j + 1}" for j in range(len(self.centres))]
            )
        return [f"{a}.{name}" for a in AXES for name in own]

    def summary(self) -> dict[str, Any]:
        """JSON-plain description: the model, its parameters by name, the fit quality."""
        names = self.parameter_names()
        values = np.asarray(self.coef).reshape(-1)
        errors = np.asarray(self.stderr).reshape(-1) if self.stderr else [None] * len(values)
        out = dict(
            kind=self.kind,
            inputs=self.inputs,
            t_ref=self.t_ref,
            n_train=self.n_train,
            dT_range=list(self.dT_range),
            parameters={
                n: dict(value=float(v), stderr=None if e is None else float(e))
                for n, v, e in zip(names, values, errors, strict=False)
            },
            residual_rms=dict(zip(AXES, map(float, self.residual_rms), strict=False)),
            noise=dict(zip(AXES, map(float, self.noise), strict=False)),
            units=dict(
                parameters="deg/s per °C^k" if self.kind == "poly" else "deg/s",
                residual_rms="deg/s",
                t_ref="°C",
            ),
        )
        if self.kind == "rbf":
            out["network"] = dict(kernels=len(self.centres), widths=list(self.widths), ridge=self.ridge)
        return out

    def to_dict(self) -> dict[str, Any]:
        d = {k: (_lists(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}
        return {"format": FORMAT, **d}

    @classmethod
    def from_dict(cls, d: dict) -> DriftModel:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            found = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise CalibrationFileError(f"drift model format must be {FORMAT!r}, found {found!r}")
        known = {f.name for f in fields(cls)}
        body = {k: v for k, v in d.items() if k != "format"}
        unknown = sorted(set(body) - known)
        if unknown:
            raise CalibrationFileError(f"drift model has unknown field {unknown[0]!r}")
        try:
            model = cls(**{k: _tuples(v) for k, v in body.items()})
        except TypeError as exc:
            raise CalibrationFileError(f"drift model is incomplete ({exc})") from None
        except ConfigError as exc:
            raise CalibrationFileError(str(exc)) from None
        W = np.asarray(model.coef, dtype=float)
        expected = model.n_inputs + 1 + (len(model.centres) if model.kind == "rbf" else 0)
        if W.shape != (3, expected) or not np.isfinite(W).all():
            raise CalibrationFileError(
                f"drift model coef must be 3 rows of {expected} finite numbers, found shape {W.shape}"
            )
        return model


def _lists(v):
    return [_lists(x) for x in v] if isinstance(v, tuple) else v


def _tuples(v):
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v


def _inputs(dT: np.ndarray, inputs: str) -> np.ndarray:
    return dT[:, None] if inputs == "dT" else np.column_stack([dT, dT * dT])


def _training_data(train: pd.DataFrame, t_ref: float | None):
    if not isinstance(train, pd.DataFrame):
        raise InputError(f"drift models fit sweep windows (a DataFrame), got {type(train).__name__}")
    missing = [c for c in TARGETS if c not in train.columns]
    if missing:
        raise MissingInputError(f"training windows lack {', '.join(missing)}; expected sweep_windows output")
    if t_ref is None:
        if {"temp", "dT"} <= set(train.columns) and len(train):
            t_ref = float(np.median(train["temp"].to_numpy() - train["dT"].to_numpy()))
        else:
            t_ref = train.attrs.get("t_ref")
        if t_ref is None:
            raise MissingInputError("training windows carry neither temp and dT columns nor a t_ref")
    t_ref = float(t_ref)
    y = train[list(TARGETS)].to_numpy(dtype=np.float64)
    w = train["n"].to_numpy(dtype=np.float64) if "n" in train.columns else np.ones(len(train))
    if "temp" in train.columns:
        dT = train["temp"].to_numpy(dtype=np.float64) - t_ref
    elif "dT" in train.columns:
        dT = train["dT"].to_numpy(dtype=np.float64)
    else:
        raise MissingInputError("training windows lack a temp or dT column")
    bad = ~(np.isfinite(y).all(axis=1) & np.isfinite(dT) & np.isfinite(w))
    if bad.any():
        raise InputError(f"training windows hold {int(bad.sum())} rows with non-finite values")
    if (w <= 0).any():
        raise InputError("training windows must each hold at least one sample (n > 0)")
    if {"std_x", "std_y", "std_z"} <= set(train.columns):
        s = train[["std_x", "std_y", "std_z"]].to_numpy(dtype=np.float64)
        noise = np.sqrt(np.mean(s * s / w[:, None], axis=0)) if len(s) else np.zeros(3)
    else:
        noise = np.zeros(3)
    return t_ref, dT, y, w, noise


def fit_drift(
    train_windows: pd.DataFrame,
    *,
    kind: str = "rbf",
    inputs: str = "dT,dT2",
    t_ref: float | None = None,
    centres: int = 12,
    width: float = 1.0,
    ridge: float = 1e-9,
) -> DriftModel:
    """Fit a drift model per axis to training windows (Section 3.2 steps 2-3).

    The target of each window is its error column (mean output minus the rig rate's
    expected output), its input ΔT counted from ``t_ref`` (default: the training sweep's
    own reference, from its ``temp`` and ``dT`` columns). Windows weigh by sample count.
    ``centres``, ``width`` and ``ridge`` set the RBF network (module docstring).
    Only the windows passed in are used: verification windows stay out of the fit.
    """
    if kind not in KINDS:
        raise ConfigError(f"drift model kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if inputs not in INPUTS:
        raise ConfigError(f"drift model inputs must be one of {', '.join(INPUTS)}, got {inputs!r}")
    t_ref, dT, y, w, noise = _training_data(train_windows, t_ref)
    m = len(dT)
    span = float(dT.max() - dT.min()) if m else 0.0
    if not span > 1e-6 * max(1.0, float(np.abs(dT).max(initial=0.0))):
        raise IdentifiabilityError(
            f"training ΔT spans {span:.3g} °C; a drift model needs a temperature change", parameters=("dT",)
        )
    if kind == "poly":
        return _fit_poly(dT, y, w, t_ref, inputs, noise)
    if isinstance(centres, bool) or not isinstance(centres, int) or centres < 2:
        raise ConfigError(f"rbf centres must be an integer >= 2, got {centres!r}")
    for name, value in (("width", width), ("ridge", ridge)):
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
            or value < 0
            or (name == "width" and value == 0)
        ):
            raise ConfigError(
                f"rbf {name} must be a {'positive' if name == 'width' else 'non-negative'} "
                f"number, got {value!r}"
            )
    return _fit_rbf(dT, y, w, t_ref, inputs, noise, centres, float(width), float(ridge))


def _fit_poly(dT, y, w, t_ref, inputs, noise) -> DriftModel:
    p = 2 if inputs == "dT" else 3
    m = len(dT)
    if m < p + 2:
        raise IdentifiabilityError(
            f"{m} training windows for {p} parameters per axis; expected at least {p + 2}",
            parameters=tuple(f"c{k}" for k in range(p)),
        )
    s = max(float(np.abs(dT).max()), 1.0)  # columns of order one for conditioning
    X = (dT[:, None] / s) ** np.arange(p)
    sw = np.sqrt(w)[:, None]
    A = X * sw
    beta, _, rank, sv = np.linalg.lstsq(A, y * sw, rcond=None)
    if rank < p or sv[-1] < 1e-10 * sv[0]:
        raise IdentifiabilityError(
            f"the ΔT powers are collinear over the training windows (rank {rank} of {p})",
            parameters=tuple(f"c{k}" for k in range(p)),
        )
    resid = y - X @ beta
    dof = m - p
    sigma2 = (w[:, None] * resid**2).sum(axis=0) / dof  # per-sample variance, per axis
    cov = np.linalg.inv(A.T @ A)
    unscale = s ** -np.arange(p, dtype=float)
    coef = beta.T * unscale
    stderr = np.sqrt(np.outer(sigma2, np.diag(cov))) * unscale
    rms = np.sqrt((w[:, None] * resid**2).sum(axis=0) / w.sum())
    return DriftModel(
        kind="poly",
        inputs=inputs,
        t_ref=t_ref,
        coef=_rows(coef),
        stderr=_rows(stderr),
        residual_rms=_floats(rms),
        noise=_floats(noise),
        n_train=int(m),
        dT_range=(float(dT.min()), float(dT.max())),
    )


def rbf_layout(dT: np.ndarray, inputs: str, k: int, width: float):
    """Centres, widths and input scaling of the network for training ΔT values: the rule of
    the module docstring. Returns (centres (k, N) scaled, widths (k,), offset, scale)."""
    X = _inputs(dT, inputs)
    offset = X.min(axis=0)
    scale = X.max(axis=0) - offset
    if (scale <= 0).any():
        raise IdentifiabilityError(
            "an RBF input does not vary over the training windows", parameters=tuple(inputs.split(","))
        )
    grid = np.linspace(dT.min(), dT.max(), k)
    C = (_inputs(grid, inputs) - offset) / scale
    gaps = np.linalg.norm(np.diff(C, axis=0), axis=1)
    neighbour = np.r_[gaps[0], (gaps[:-1] + gaps[1:]) / 2, gaps[-1]] if k > 2 else np.r_[gaps, gaps]
    return C, width * neighbour, offset, scale


def _fit_rbf(dT, y, w, t_ref, inputs, noise, k, width, ridge) -> DriftModel:
    m = len(dT)
    if m < k + 5:
        raise IdentifiabilityError(
            f"{m} training windows for an RBF network of {k} kernels; expected at least {k + 5}",
            parameters=("rbf",),
        )
    C, widths, offset, scale = rbf_layout(dT, inputs, k, width)
    tail = 1 + C.shape[1]
    shell = DriftModel(
        kind="rbf",
        inputs=inputs,
        t_ref=t_ref,
        coef=((0.0,) * (tail + k),) * 3,
        centres=_rows(C),
        widths=_floats(widths),
        offset=_floats(offset),
        scale=_floats(scale),
    )
    Phi = shell._kernels(dT)
    sw = np.sqrt(w)[:, None]
    A = Phi * sw
    lam = ridge * float(np.mean((A[:, tail:] ** 2).sum(axis=0)))
    penalty = np.zeros((k, tail + k))
    penalty[:, tail:] = math.sqrt(lam) * np.eye(k)
    W, *_ = np.linalg.lstsq(np.vstack([A, penalty]), np.vstack([y * sw, np.zeros((k, 3))]), rcond=None)
    resid = y - Phi @ W
    rms = np.sqrt((w[:, None] * resid**2).sum(axis=0) / w.sum())
    if not (np.isfinite(W).all() and np.isfinite(rms).all()):
        raise IdentifiabilityError(
            "the RBF weights are not finite; raise ridge or use fewer centres", parameters=("rbf",)
        )
    return DriftModel(
        kind="rbf",
        inputs=inputs,
        t_ref=t_ref,
        coef=_rows(W.T),
        centres=_rows(C),
        widths=_floats(widths),
        offset=_floats(offset),
        scale=_floats(scale),
        ridge=ridge,
        residual_rms=_floats(rms),
        noise=_floats(noise),
        n_train=int(m),
        dT_range=(float(dT.min()), float(dT.max())),
    )


def _rows(a) -> Rows:
    return tuple(tuple(float(x) for x in row) for row in np.asarray(a))


def _floats(a) -> tuple[float, ...]:
    return tuple(float(x) for x in np.asarray(a).reshape(-1))
