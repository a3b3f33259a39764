"""Fixed-size sample blocks: the one pass over a log's samples that segmentation makes.

A block is ``size`` consecutive samples counted from the log's first row across batch
boundaries (a block straddling two batches is assembled from both ends; a tail shorter than
a block is ignored). Later stages work on per-block means and variances only, so the
samples are touched once, batch by batch, while Arrow decodes the next batch; a hold is a
run of whole blocks, so its statistics are exact sums of block statistics.

Precision: float32 columns are centred on each block's first sample before squaring, so
float32 arithmetic stays exact to well below the noise even at 400 deg/s; float64 columns
need no centring. Block means are float64.
"""

from __future__ import annotations

import numpy as np

from .io import ACCEL, GYRO, RigLog


class BlockAccumulator:
    """Consumes batches (``push``) and returns per-block statistics (``result``).

    Result keys: ``t_first``, ``t_last`` (s); ``ref`` mean and ``ref_span`` (deg/s, the
    span of a linear ramp with the block's variance);
    ``temp`` mean; ``gyro`` mean
    (k, 3) float64 and ``gyro_var`` (k, 3) sample variance; ``accel`` mean (k, 3) when the
    log has it; ``mount_first``/``mount_last`` codes when it has a mount column; and
    ``gyro_max``/``gyro_min`` (3,) over every sample.
    """

    def __init__(self, size: int, names: tuple[str, ...]):
        self.size = size
        self.accel = ACCEL if all(c in names for c in ACCEL) else ()
        self.mount = "mount" in names
        self.names = ("t", "ref_rate", "temp", *GYRO, *self.accel) + (("mount",) if self.mount else ())
        self._ones = np.ones(size, dtype=np.float32)
        self._ones64 = np.ones(size)
        self._work = np.empty(0, dtype=np.float32)
        self._carry: dict[str, np.ndarray] | None = None
        self._parts: dict[str, list[np.ndarray]] = {}
        self.gyro_max = np.full(3, -np.inf)
        self.gyro_min = np.full(3, np.inf)

    def push(self, batch: dict[str, np.ndarray]) -> None:
        size, names = self.size, self.names
        n = len(batch["t"])
        for a, c in enumerate(GYRO):
            self.gyro_max[a] = max(self.gyro_max[a], batch[c].max())
            self.gyro_min[a] = min(self.gyro_min[a], batch[c].min())
        start = 0
        if self._carry is not None:
            need = size - len(self._carry["t"])
            if n < need:
                self._carry = {k: np.concatenate((self._carry[k], batch[k])) for k in names}
                return
            self._reduce({k: np.concatenate((self._carry[k], batch[k][:need])).reshape(1, size)
                          for k in names})
            start = need
        whole = (n - start) // size
        if whole:
            stop = start + whole * size
            self._reduce({k: batch[k][start:stop].reshape(whole, size) for k in names})
            start = stop
        self._carry = {k: batch[k][start:] for k in names} if start < n else None

    def _put(self, key: str, value: np.ndarray) -> None:
        self._parts.setdefault(key, []).append(value)

    def _moments(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (float64) and sample variance (float32) of each row of a (k, size) view."""
        size = self.size
        if v.dtype == np.float64:
            # float64 holds x² of any rate exactly enough: no centring, no temporary.
            s = v @ self._ones64
            q = np.einsum("ij,ij->i", v, v)
            var = np.maximum(q - s * s / size, 0.0) / (size - 1)
            return s / size, var.astype(np.float32)
        if self._work.size < v.size:
            self._work = np.empty(v.size, dtype=np.float32)
        d = self._work[: v.size].reshape(v.shape)  # reused: no page faults per batch
        first = v[:, :1]
        np.subtract(v, first, out=d, casting="same_kind")
        s = d @ self._ones
        np.square(d, out=d)
        q = d @ self._ones
        var = np.maximum(q - s * s / size, 0.0) / (size - 1)
        return first[:, 0] + s.astype(np.float64) / size, var

    def _reduce(self, view: dict[str, np.ndarray]) -> None:
        put, size = self._put, self.size
        put("t_first", view["t"][:, 0].copy())
        put("t_last", view["t"][:, -1].copy())
        mean, var = self._moments(view["ref_rate"])
        put("ref", mean)
        put("ref_span", np.sqrt(12.0 * var))  # the span of a ramp with this variance
        put("temp", (view["temp"].astype(np.float32, copy=False) @ self._ones) / size)
        for c in GYRO:
            mean, var = self._moments(view[c])
            put(c, mean)
            put(c + "_var", var)
        for c in self.accel:
            put(c, (view[c].astype(np.float32, copy=False) @ self._ones) / size)
        if self.mount:
            put("mount_first", view["mount"][:, 0].copy())
            put("mount_last", view["mount"][:, -1].copy())

    def result(self) -> dict[str, np.ndarray]:
        if not self._parts:
            return {}
        cat = {k: np.concatenate(v) for k, v in self._parts.items()}
        out = {k: v for k, v in cat.items() if not k.startswith(("gyro_", "accel_"))}
        out["gyro"] = np.column_stack([cat[c] for c in GYRO])
        out["gyro_var"] = np.column_stack([cat[c + "_var"] for c in GYRO])
        if self.accel:
            out["accel"] = np.column_stack([cat[c] for c in self.accel])
        out["gyro_max"], out["gyro_min"] = self.gyro_max, self.gyro_min
        return out


def block_statistics(log: RigLog, block_s: float) -> tuple[dict[str, np.ndarray], int, float]:
    """Per-block statistics of a whole log: (statistics, block size, sample interval)."""
    t = log.rows("t", 0, min(len(log), 20001))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
    size = max(4, int(round(block_s / dt))) if dt > 0 else 4
    acc = BlockAccumulator(size, log.names)
    for batch in log.batches:
        acc.push(batch)
    return acc.result(), size, dt
