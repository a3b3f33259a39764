"""Fixed-size sample blocks: the one pass over a log's samples that segmentation makes.

A block is ``size`` consecutive samples counted from the log's first row across batch
boundaries (a block straddling two batches is assembled from both ends; a tail shorter than
a block is ignored). Later stages work on per-block means and variances only, so the
samples are touched once, batch by batch, while Arrow decodes the next batch; a hold is a
run of whole blocks, so its statistics are exact sums of block statistics.

Precision: values are centred on each block's first sample before squaring and summing in
float32, which stays exact to well below the noise even at 400 deg/s; block means add the
float64 first sample back. Optional columns (accelerometer) may hold NaN: their block means
are taken over the finite samples.
"""

from __future__ import annotations

import numpy as np

from .io import ACCEL, GYRO, RigLog


class BlockAccumulator:
    """Consumes batches (``push``) and fills per-block statistics (``result``).

    Result keys: ``t_first``, ``t_last`` (s); ``ref`` mean and ``ref_span`` (deg/s);
    ``temp`` mean; ``gyro`` mean (k, 3) float64 and ``gyro_var`` (k, 3) sample variance;
    ``accel`` mean (k, 3) when the log has it; ``mount_first``/``mount_last`` codes when it
    has a mount column; and ``gyro_max``/``gyro_min`` (3,) over every sample. Outputs are
    allocated once for ``blocks`` blocks and filled in place.
    """

    def __init__(self, size: int, names: tuple[str, ...], blocks: int):
        self.size = size
        self.accel = ACCEL if all(c in names for c in ACCEL) else ()
        self.mount = "mount" in names
        self.names = ("t", "ref_rate", "temp", *GYRO, *self.accel) + (("mount",) if self.mount else ())
        self._ones = np.ones(size, dtype=np.float32)
        self._ones64 = np.ones(size)
        self._work = np.empty(0, dtype=np.float32)
        self._carry: dict[str, np.ndarray] | None = None
        self.filled = 0
        self.out = {k: np.empty(blocks) for k in ("t_first", "t_last", "ref", "ref_span")}
        self.out["temp"] = np.empty(blocks, dtype=np.float32)
        self.out["gyro"] = np.empty((blocks, 3))
        self.out["gyro_var"] = np.empty((blocks, 3), dtype=np.float32)
        if self.accel:
            self.out["accel"] = np.empty((blocks, 3), dtype=np.float32)
        if self.mount:
            self.out["mount_first"] = np.empty(blocks, dtype=np.int8)
            self.out["mount_last"] = np.empty(blocks, dtype=np.int8)
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

    def _moments(self, v: np.ndarray, mean_out: np.ndarray, var_out: np.ndarray) -> None:
        """Row means (float64) and sample variances (float32) of a (k, size) view."""
        size = self.size
        if self._work.size < v.size:
            self._work = np.empty(v.size, dtype=np.float32)
        d = self._work[: v.size].reshape(v.shape)  # reused: no page faults per batch
        first = v[:, :1]
        np.subtract(v, first, out=d, casting="same_kind")
        s = d @ self._ones
        np.square(d, out=d)
        q = d @ self._ones
        var_out[:] = np.maximum(q - s * s / size, 0.0) / (size - 1)
        mean_out[:] = first[:, 0] + s / size

    def _reduce(self, view: dict[str, np.ndarray]) -> None:
        size, out = self.size, self.out
        k = len(view["t"])
        sl = slice(self.filled, self.filled + k)
        self.filled += k
        out["t_first"][sl] = view["t"][:, 0]
        out["t_last"][sl] = view["t"][:, -1]
        # The reference is piecewise constant: its mean, and a spread that sees ramps
        # (first against last sample) and bumps (mean against the ends' midpoint).
        ref = view["ref_rate"]
        mean = (ref.astype(np.float64, copy=False) @ self._ones64) / size
        first, last = ref[:, 0], ref[:, -1]
        out["ref"][sl] = mean
        out["ref_span"][sl] = np.maximum(np.abs(last - first), 2.0 * np.abs(mean - (first + last) / 2))
        out["temp"][sl] = (view["temp"].astype(np.float32, copy=False) @ self._ones) / size
        for a, c in enumerate(GYRO):
            self._moments(view[c], out["gyro"][sl, a], out["gyro_var"][sl, a])
        for a, c in enumerate(self.accel):
            v = view[c].astype(np.float32, copy=False)
            sums = v @ self._ones
            if np.isnan(sums).any():  # optional column with gaps: mean of what is there
                finite = np.isfinite(v)
                with np.errstate(invalid="ignore"):
                    sums = np.where(finite, v, 0.0) @ self._ones / (finite @ self._ones)
                out["accel"][sl, a] = sums
            else:
                out["accel"][sl, a] = sums / size
        if self.mount:
            out["mount_first"][sl] = view["mount"][:, 0]
            out["mount_last"][sl] = view["mount"][:, -1]

    def result(self) -> dict[str, np.ndarray]:
        if not self.filled:
            return {}
        out = {k: v[: self.filled] for k, v in self.out.items()}
        out["gyro_max"], out["gyro_min"] = self.gyro_max, self.gyro_min
        return out


def block_statistics(log: RigLog, block_s: float) -> tuple[dict[str, np.ndarray], int, float]:
    """Per-block statistics of a whole log: (statistics, block size, sample interval)."""
    t = log.rows("t", 0, min(len(log), 20001))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
    size = max(4, int(round(block_s / dt))) if dt > 0 else 4
    acc = BlockAccumulator(size, log.names, len(log) // size)
    for batch in log.batches:
        acc.push(batch)
    return acc.result(), size, dt
