"""Reading a log ahead while the process starts.

A command that reads a log spends its first second importing what it runs (pandas, scipy,
gyrocal's stages); imports hold the GIL, Arrow's Parquet decoding does not. So the command
line starts decoding the log on a thread before those imports (:func:`start`), and the
reader (:func:`gyrocal.io.log.record_batches`) takes the batches from here (:func:`take`)
instead of reading the file again. The batches are the ones the reader would have read
itself (same reader, batch size and buffer), so results are the same to the bit. At most
``DEPTH`` batches wait; past that the thread waits for the reader, so memory stays bounded.

Light on purpose: imports only pyarrow.parquet (and pyarrow.compute, whose functions the
decoder uses), so that reading starts at once.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path

# The columns a log is read for (gyrocal.io.log.REQUIRED and the segmentation's optional ones):
# what a file holds of them is decoded ahead; a reader asking for a column outside them
# reads the file itself.
COLUMNS = ("t", "gyro_x", "gyro_y", "gyro_z", "temp", "ref_rate", "mount", "accel_x", "accel_y", "accel_z")
BATCH_ROWS = 1 << 17
BUFFER_BYTES = 1 << 20  # each column chunk is read through a buffer this size
DEPTH = 24  # batches waiting: about 250 MB of ten float64 columns at most

_END = object()
_pending: dict[str, ReadAhead] = {}
_lock = threading.Lock()


class ReadAhead:
    def __init__(self, path: Path):
        self.path = path
        self.columns: tuple[str, ...] | None = None  # set once the footer is read
        self.opened = threading.Event()
        self.batches: queue.Queue = queue.Queue(maxsize=DEPTH)
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name="read-ahead", daemon=True)

    def _run(self) -> None:
        try:
            # Arrow's compute functions (a cast the decoder makes) are registered when
            # pyarrow.compute is first imported: importing it here, under the import lock,
            # makes sure they are before this thread decodes, whatever the main thread is
            # importing meanwhile ("No function registered with name: cast" otherwise, now
            # and then).
            import pyarrow.compute  # noqa: F401
            import pyarrow.parquet as pq

            reader = pq.ParquetFile(self.path, pre_buffer=False, buffer_size=BUFFER_BYTES)
            names = set(reader.schema_arrow.names)
            self.columns = tuple(c for c in COLUMNS if c in names)
        except Exception:  # noqa: BLE001 - the reader opens the file itself and says why
            self.columns = ()
            self.opened.set()
            return
        self.opened.set()
        try:
            for batch in reader.iter_batches(
                batch_size=BATCH_ROWS, columns=list(self.columns), use_threads=True
            ):
                if not self._put(batch):
                    return
            self._put(_END)
        except Exception as exc:  # noqa: BLE001 - raised where the reader takes the batches
            self._put(exc)

    def _put(self, item) -> bool:
        """Queue ``item``, waiting for room unless stopped (False once stopped)."""
        while not self.stopped.is_set():
            try:
                self.batches.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def stream(self, columns):
        while (item := self.batches.get()) is not _END:
            if isinstance(item, Exception):
                raise item
            yield item.select(list(columns))


def start(path) -> None:
    """Begin decoding the log file at ``path`` on a thread (a directory is not read ahead)."""
    path = Path(path)
    if not path.is_file():
        return
    ahead = ReadAhead(path)
    with _lock:
        _pending[str(path.resolve())] = ahead
    ahead.thread.start()


def take(path, columns, batch_rows: int, buffer_bytes: int):
    """The batches of ``columns`` of the file at ``path`` read ahead, as an iterator, or
    None when it was not read ahead (or not as asked). Each file's read-ahead is taken once."""
    with _lock:
        if not _pending:
            return None
        ahead = _pending.pop(str(Path(path).resolve()), None)
    if ahead is None:
        return None
    if batch_rows != BATCH_ROWS or buffer_bytes != BUFFER_BYTES:
        ahead.stopped.set()
        return None
    ahead.opened.wait()
    if not ahead.columns or not set(columns) <= set(ahead.columns):
        ahead.stopped.set()  # its batches are of no use: free the thread and their memory
        return None
    return ahead.stream(columns)
