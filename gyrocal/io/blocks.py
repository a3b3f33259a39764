"""Fixed-size sample blocks: the one pass over a log's samples that segmentation makes.

A block is ``size`` consecutive samples counted from the log's first row across batch
boundaries (a block straddling two batches is assembled from both ends; a tail shorter than
a block is ignored). Later stages work on per-block means and variances only, so the
samples are touched once, batch by batch, while Arrow decodes the next batch; a hold is a
run of whole blocks, so its statistics are exact sums of block statistics.

The reductions are the compiled kernels of :mod:`gyrocal.io.blockstats` (one read per sample),
or their numpy fallback. Both centre each block on its first sample before squaring, so the
variance stays exact to well below the noise even at 400 deg/s. Optional columns
(accelerometer) may hold NaN: their block means are taken over the finite samples.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .blockstats import LIB, block_mean, block_moments
from .log import ACCEL, GYRO, RigLog


class BlockAccumulator:
    """Consumes batches (``push``) and fills per-block statistics (``result``).

    Result keys: ``t_first``, ``t_last`` (s); ``ref`` mean and ``ref_span`` (deg/s);
    ``temp`` mean; ``gyro`` mean (k, 3) and ``gyro_var`` (k, 3, float32) sample variance;
    ``accel`` mean (k, 3) over the finite samples when the log has it; ``mount_first``/
    ``mount_last`` codes when it has a mount column; ``gyro_max``/``gyro_min`` (3,) over
    every sample. Outputs are allocated once for ``blocks`` blocks.
    """

    def __init__(self, size: int, names: tuple[str, ...], blocks: int):
        self.size = size
        self.accel = ACCEL if all(c in names for c in ACCEL) else ()
        self.mount = "mount" in names
        self.names = ("t", "ref_rate", "temp", *GYRO, *self.accel) + (("mount",) if self.mount else ())
        self._work = [np.empty(0, dtype=np.float32)]
        self._carry: dict[str, np.ndarray] | None = None
        self.filled = 0
        self.out = {k: np.empty(blocks) for k in ("t_first", "t_last", "ref", "ref_span", "temp")}
        self.out["gyro"] = np.empty((blocks, 3))
        self.out["gyro_var"] = np.empty((blocks, 3), dtype=np.float32)
        if self.accel:
            self.out["accel"] = np.empty((blocks, 3))
        if self.mount:
            self.out["mount_first"] = np.empty(blocks, dtype=np.int8)
            self.out["mount_last"] = np.empty(blocks, dtype=np.int8)
        self.extremes = np.tile([np.inf, -np.inf], (3, 1))  # per axis [min, max]

    def push(self, batch: dict[str, np.ndarray]) -> None:
        size, names = self.size, self.names
        n = len(batch["t"])
        for a, c in enumerate(GYRO):  # the log's output extremes, for saturation checks
            self.extremes[a] = (
                min(self.extremes[a, 0], batch[c].min()),
                max(self.extremes[a, 1], batch[c].max()),
            )
        start = 0
        if self._carry is not None:
            need = size - len(self._carry["t"])
            if n < need:
                self._carry = {k: np.concatenate((self._carry[k], batch[k])) for k in names}
                return
            self._reduce(
                {k: np.concatenate((self._carry[k], batch[k][:need])).reshape(1, size) for k in names}
            )
            start = need
        whole = (n - start) // size
        if whole:
            stop = start + whole * size
            self._reduce({k: batch[k][start:stop].reshape(whole, size) for k in names})
            start = stop
        self._carry = {k: batch[k][start:] for k in names} if start < n else None

    def _reduce(self, view: dict[str, np.ndarray]) -> None:
        out = self.out
        k = len(view["t"])
        sl = slice(self.filled, self.filled + k)
        self.filled += k
        out["t_first"][sl] = view["t"][:, 0]
        out["t_last"][sl] = view["t"][:, -1]
        # The reference is piecewise constant: its mean, and a spread that sees ramps
        # (first against last sample) and bumps (mean against the ends' midpoint).
        ref = view["ref_rate"]
        block_mean(ref, out["ref"][sl])
        first, last = ref[:, 0], ref[:, -1]
        out["ref_span"][sl] = np.maximum(
            np.abs(last - first), 2.0 * np.abs(out["ref"][sl] - (first + last) / 2)
        )
        block_mean(view["temp"], out["temp"][sl])
        for a, c in enumerate(GYRO):
            block_moments(view[c], out["gyro"][sl, a], out["gyro_var"][sl, a], self._work)
        for a, c in enumerate(self.accel):  # optional column: a gap in it is not an error
            block_mean(view[c], out["accel"][sl, a], finite_only=True)
        if self.mount:
            out["mount_first"][sl] = view["mount"][:, 0]
            out["mount_last"][sl] = view["mount"][:, -1]

    def result(self) -> dict[str, np.ndarray]:
        if not self.filled:
            return {}
        out = {k: v[: self.filled] for k, v in self.out.items()}
        out["gyro_min"], out["gyro_max"] = self.extremes[:, 0].copy(), self.extremes[:, 1].copy()
        return out


FIRST_ROWS = 20001  # the sample interval is the median step of the first rows


def _size(t: np.ndarray, block_s: float) -> tuple[int, float]:
    dt = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
    return (max(4, int(round(block_s / dt))) if dt > 0 else 4), dt


class BlockSink:
    """Block statistics made while a log is read (``read_log(sink=...)``): the first rows
    are held until they give the sample interval, then every batch is reduced as it comes,
    so the samples need not stay in memory. ``result()`` is what :func:`block_statistics`
    returns for the same log and block length."""

    def __init__(self, block_s: float):
        self.block_s = block_s
        self.names: tuple[str, ...] = ()
        self.rows_bound = 0
        self._held: list[dict[str, np.ndarray]] = []
        self._acc: BlockAccumulator | None = None
        self.size, self.dt = 4, float("nan")

    def open(self, names: tuple[str, ...], rows_bound: int) -> None:
        """The columns the batches hold, and at most how many rows they hold in all."""
        self.names, self.rows_bound = names, rows_bound

    def push(self, batch: dict[str, np.ndarray]) -> None:
        if self._acc is not None:
            self._acc.push(batch)
            return
        self._held.append(batch)
        if sum(len(b["t"]) for b in self._held) >= FIRST_ROWS:
            self._start()

    def _start(self) -> None:
        t = np.concatenate([b["t"] for b in self._held])[:FIRST_ROWS]
        self.size, self.dt = _size(t, self.block_s)
        self._acc = BlockAccumulator(self.size, self.names, self.rows_bound // self.size)
        for batch in self._held:
            self._acc.push(batch)
        self._held = []

    def result(self) -> tuple[dict[str, np.ndarray], int, float]:
        if self._acc is None:
            if not self._held:
                return {}, self.size, self.dt
            self._start()
        return self._acc.result(), self.size, self.dt


def block_statistics(
    log: RigLog, block_s: float, *, workers: int | None = None
) -> tuple[dict[str, np.ndarray], int, float]:
    """Per-block statistics of a whole log: (statistics, block size, sample interval).

    Made while the log was read when it was read with a :class:`BlockSink` of this block
    length. Otherwise, for a log in memory, the rows are split at a block boundary into one
    part per worker thread (the compiled kernels release the GIL, so the parts are reduced
    in parallel, then joined in order); a log not in memory is read again, batch by batch.
    """
    if block_s in log.blocks:
        return log.blocks[block_s]
    size, dt = _size(log.rows("t", 0, min(len(log), FIRST_ROWS)), block_s)
    n_blocks = len(log) // size
    if not log.in_memory:
        acc = BlockAccumulator(size, log.names, n_blocks)
        for batch in log.scan():
            acc.push(batch)
        return acc.result(), size, dt
    if workers is None:
        workers = min(2, os.cpu_count() or 1) if LIB is not None and n_blocks >= 20_000 else 1
    bounds = [round(i * n_blocks / workers) * size for i in range(workers + 1)]
    parts = [_rows(log.batches, lo, hi) for lo, hi in zip(bounds, bounds[1:], strict=False) if hi > lo]

    def reduce(batches):
        acc = BlockAccumulator(size, log.names, sum(len(b["t"]) for b in batches) // size)
        for batch in batches:
            acc.push(batch)
        return acc.result()

    if len(parts) > 1:
        with ThreadPoolExecutor(len(parts)) as pool:
            results = [r for r in pool.map(reduce, parts) if r]
    else:
        results = [r for r in map(reduce, parts) if r]
    if len(results) < 2:
        return (results[0] if results else {}), size, dt
    out = {
        k: np.concatenate([r[k] for r in results]) for k in results[0] if k not in ("gyro_max", "gyro_min")
    }
    out["gyro_max"] = np.max([r["gyro_max"] for r in results], axis=0)
    out["gyro_min"] = np.min([r["gyro_min"] for r in results], axis=0)
    return out, size, dt


def _rows(batches, lo: int, hi: int) -> list[dict[str, np.ndarray]]:
    """Views of rows lo:hi across batches."""
    out, offset = [], 0
    for batch in batches:
        n = len(batch["t"])
        a, z = max(lo - offset, 0), min(hi - offset, n)
        if a < z:
            out.append({k: v[a:z] for k, v in batch.items()})
        offset += n
    return out
