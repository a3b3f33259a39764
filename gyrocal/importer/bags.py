"""ROS 2 bags (read with rosbags) and plain MCAP files (mcap with mcap_ros2's decoder).

A robot logs its IMU as ``sensor_msgs/msg/Imu`` messages and everything else (the IMU's
temperature, a turntable's rate) on topics of their own, at their own rates. The log needs
one row per IMU sample, so the other topics' values are *held*: each IMU sample gets the
last value stamped at or before it. Messages arrive in log (receive) order while the
header stamps may lag a little, so IMU samples wait until every held topic has been heard
at or past their stamp (or too many wait: then they go with what is known). Samples
before a held topic's first value are dropped, and counted.

Both libraries are imported here only, when a bag or MCAP file is converted.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ..io.errors import ConfigError, CorruptFileError, EmptyLogError, LogFormatError, first_line
from .mapping import ACCEL_UNITS, RATE_UNITS, Held, ImportMap, Scaled
from .sink import LogSink

IMU = "sensor_msgs/msg/Imu"
VALUE_FIELDS = {
    "sensor_msgs/msg/Temperature": "temperature",
    "std_msgs/msg/Float64": "data",
    "std_msgs/msg/Float32": "data",
}
BATCH = 1 << 16  # IMU samples per output batch
MAX_WAITING = 1 << 18  # IMU samples held back for a silent topic before they go anyway
_RAD = Scaled("rad/s", RATE_UNITS["rad/s"])
_MS2 = Scaled("m/s^2", ACCEL_UNITS["m/s^2"])


def msgtype(name: str) -> str:
    """ROS 2 type names as ``pkg/msg/Name`` (some MCAP writers leave out ``msg``)."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


class _Rosbag:
    """A rosbag2 directory (sqlite3 or MCAP storage) or a bare .db3 file."""

    def __init__(self, path: Path):
        import apsw
        from rosbags.rosbag2 import Reader, ReaderError
        from rosbags.serde import SerdeError
        from rosbags.typesys import TypesysError

        self.errors = (ReaderError, SerdeError, TypesysError, apsw.Error, struct.error)
        self.path = path
        try:
            self.reader = Reader(path)
            self.reader.open()
        except FileNotFoundError as exc:
            what = "no metadata.yaml" if "metadata" in str(exc) else first_line(exc)
            raise CorruptFileError(f"not a readable ROS 2 bag ({what})", source=path) from None
        except (*self.errors, OSError, ValueError, KeyError) as exc:
            raise CorruptFileError(f"not a readable ROS 2 bag ({first_line(exc)})", source=path) from None
        self.topics = {c.topic: msgtype(c.msgtype) for c in self.reader.connections}
        self.counts: dict[str, int] = {}
        for c in self.reader.connections:
            self.counts[c.topic] = self.counts.get(c.topic, 0) + c.msgcount

    def messages(self, topics) -> Iterator[tuple[str, int, object]]:
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.LATEST)
        connections = [c for c in self.reader.connections if c.topic in topics]
        self._register(store, connections)
        deserialize = store.deserialize_cdr
        for conn, log_ns, raw in self.reader.messages(connections=connections):
            yield conn.topic, log_ns, deserialize(raw, conn.msgtype)

    def _register(self, store, connections) -> None:
        """Types the bag defines but the ROS 2 type store lacks (a rig's own messages)."""
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        types: dict = {}
        for c in connections:
            if c.msgtype in store.types:
                continue
            if c.msgdef.format == MessageDefinitionFormat.MSG:
                types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
            elif c.msgdef.format == MessageDefinitionFormat.IDL:
                sep = "=" * 80 + "\n"
                for part in c.msgdef.data.split(sep):
                    if part.strip():
                        types.update(
                            get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part)
                        )
            else:
                raise LogFormatError(
                    f"topic {c.topic}: message type {c.msgtype} is not a "
                    "standard ROS 2 type and the bag holds no definition of it",
                    source=self.path,
                )
        if types:
            store.register(types)

    def close(self) -> None:
        self.reader.close()


class _Mcap:
    """A plain MCAP file of ROS 2 (CDR, ros2msg schema) messages."""

    def __init__(self, path: Path):
        from mcap.exceptions import McapError
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        self.errors = (McapError, struct.error, EOFError)
        self.path = path
        try:
            self.file = open(path, "rb")  # noqa: SIM115 - held by the reader, closed by close()
        except OSError as exc:
            raise CorruptFileError(f"cannot read ({exc.strerror})", source=path) from None
        try:
            self.reader = make_reader(self.file, decoder_factories=[DecoderFactory()])
            summary = self.reader.get_summary()
            self.topics, self.counts = {}, {}
            if summary is not None:
                stats = summary.statistics.channel_message_counts if summary.statistics else {}
                for ch in summary.channels.values():
                    schema = summary.schemas.get(ch.schema_id)
                    self.topics[ch.topic] = msgtype(schema.name) if schema else ""
                    if ch.id in stats:
                        self.counts[ch.topic] = self.counts.get(ch.topic, 0) + stats[ch.id]
            else:  # no summary section (a recording cut short): one pass to list the topics
                for schema, ch, _ in self.reader.iter_messages(log_time_order=False):
                    self.topics[ch.topic] = msgtype(schema.name) if schema else ""
        except (*self.errors, OSError, ValueError) as exc:
            self.file.close()
            raise CorruptFileError(f"not a readable MCAP file ({first_line(exc)})", source=path) from None

    def messages(self, topics) -> Iterator[tuple[str, int, object]]:
        for _, channel, message, decoded in self.reader.iter_decoded_messages(
            topics=list(topics), log_time_order=True
        ):
            yield channel.topic, message.log_time, decoded

    def close(self) -> None:
        self.file.close()


class _Stream:
    """One held topic: values not yet passed by the IMU, and the last one that was."""

    def __init__(self, name: str, held: Held, kind: str):
        self.name, self.topic, self.scale = name, held.topic, held.scale
        path = held.field or VALUE_FIELDS.get(kind)
        self.field = path
        self.get = operator.attrgetter(path)
        self.stamps: list[int] = []
        self.values: list[float] = []
        self.carry: tuple[int, float] | None = None
        self.seen: int | None = None  # the newest stamp heard
        self.header: bool | None = None  # whether its messages carry a header stamp
        self.dropped = 0

    def add(self, stamp: int, value: float) -> None:
        self.stamps.append(stamp)
        self.values.append(value)
        if self.seen is None or stamp > self.seen:
            self.seen = stamp

    def take(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The value held at each stamp of ``t`` (sorted), and where one exists."""
        stamps = np.array(self.stamps, dtype=np.int64)
        values = np.array(self.values, dtype=np.float64)
        if self.carry is not None:
            stamps = np.concatenate(([self.carry[0]], stamps))
            values = np.concatenate(([self.carry[1]], values))
        if not len(stamps):
            return np.full(len(t), np.nan), np.zeros(len(t), dtype=bool)
        order = np.argsort(stamps, kind="stable")  # equal stamps: the later message wins
        stamps, values = stamps[order], values[order]
        index = np.searchsorted(stamps, t, side="right") - 1
        known = index >= 0
        held = values[np.maximum(index, 0)]
        passed = int(np.searchsorted(stamps, t[-1], side="right"))
        if passed:
            self.carry = (int(stamps[passed - 1]), float(values[passed - 1]))
        self.stamps, self.values = stamps[passed:].tolist(), values[passed:].tolist()
        return self.scale.apply(held), known


def convert(path: Path, spec: ImportMap, make_sink, map_name: str):
    """Stream the bag's IMU samples into a sink from ``make_sink(locate, hint)``; returns
    (sink, IMU samples read, provenance extras, what was mapped, notes)."""
    source = _Rosbag(path) if spec.format == "ros2" else _Mcap(path)
    try:
        imu = _imu_topic(source, spec, path, map_name)
        streams = [
            _Stream(name, held, _check_held(source, held, name, path))
            for name, held in (("temp", spec.temperature), ("ref_rate", spec.ref_topic))
            if held is not None
        ]
        hint = (
            " (header stamps not filled in? map time: {source: log} to use the log time)"
            if spec.time_source == "header"
            else ""
        )
        sink = make_sink(lambda row: f"message {row + 1} on {imu}", hint)
        state = _Convert(sink, streams, spec.time_source == "header")
        try:
            for topic, log_ns, msg in source.messages({imu, *(s.topic for s in streams)}):
                if topic == imu:
                    state.imu(msg, log_ns)
                for s in streams:
                    if s.topic == topic:
                        state.held(s, msg, log_ns, path)
            state.flush(force=True)
        except source.errors as exc:
            raise CorruptFileError(f"a message cannot be read ({first_line(exc)})", source=path) from None
    finally:
        source.close()
    if state.count == 0:
        raise EmptyLogError(f"topic {imu} holds no messages", source=path)
    notes = []
    for s in streams:
        if s.dropped:
            notes.append(
                f"{s.dropped} IMU sample{'s' if s.dropped != 1 else ''} before the "
                f"first {s.name} message on {s.topic} dropped"
            )
    if sink.rows == 0:
        missing = [s.topic for s in streams if s.carry is None]
        raise EmptyLogError(
            f"all {state.count} IMU samples come before the first message on "
            f"{', '.join(missing) or 'the held topics'} (if their stamps are on "
            "another clock, map time: {source: log})",
            source=path,
        )
    extra = {
        "imu_topic": imu,
        "time_source": spec.time_source,
        "time_origin_ns": state.origin,
        "time_origin": _iso(state.origin),
    }
    mapped = [f"gyro{' and accel' if state.accel else ''} from {imu}"]
    mapped += [f"{s.name} from {s.topic}" + (f".{s.field}" if s.field else "") for s in streams]
    return sink, state.count, extra, mapped, notes


class _Convert:
    """IMU samples collected message by message, converted and written a batch at a time."""

    def __init__(self, sink: LogSink, streams: list[_Stream], header: bool):
        self.sink, self.streams, self.header = sink, streams, header
        self.rows: list[tuple] = []  # (stamp, gx, gy, gz, ax, ay, az) waiting
        self.first_row = 0  # IMU ordinal of rows[0]
        self.count = 0
        self.accel: bool | None = None
        self.origin: int | None = None
        self.due = BATCH

    def imu(self, msg, log_ns: int) -> None:
        if self.accel is None:  # REP 145: covariance[0] = -1 means "no such data"
            self.accel = float(msg.linear_acceleration_covariance[0]) != -1.0
        w, a = msg.angular_velocity, msg.linear_acceleration
        self.rows.append((self._stamp(msg) if self.header else log_ns, w.x, w.y, w.z, a.x, a.y, a.z))
        self.count += 1
        if len(self.rows) >= self.due:
            self.flush()

    def held(self, s: _Stream, msg, log_ns: int, path: Path) -> None:
        if s.header is None:
            s.header = self.header and hasattr(msg, "header")
            self._check_value(s, msg, path)
        s.add(self._stamp(msg) if s.header else log_ns, float(s.get(msg)))

    @staticmethod
    def _stamp(msg) -> int:
        stamp = msg.header.stamp
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    @staticmethod
    def _check_value(s: _Stream, msg, path: Path) -> None:
        kind = getattr(msg, "__msgtype__", type(msg).__name__)
        try:
            value = s.get(msg)
        except AttributeError:
            raise ConfigError(f"topic {s.topic}: {kind} has no field {s.field}", source=path) from None
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise ConfigError(
                f"topic {s.topic}: field {s.field} of {kind} is not a number "
                "(give a field path to one, such as vector.z)",
                source=path,
            )

    def flush(self, force: bool = False) -> None:
        """Write the waiting samples every held topic has been heard past (all: ``force``)."""
        if not self.rows:
            return
        data = np.array(self.rows, dtype=np.float64)
        stamps = np.array([r[0] for r in self.rows], dtype=np.int64)  # exact, unlike float64
        ready = len(stamps)
        if not force and len(stamps) < MAX_WAITING and self.streams:
            heard = [s.seen for s in self.streams]
            ready = 0 if None in heard else int(np.searchsorted(stamps, min(heard), side="right"))
        if ready:
            self._write(stamps[:ready], data[:ready])
            del self.rows[:ready]
            self.first_row += ready
        self.due = len(self.rows) + BATCH

    def _write(self, stamps: np.ndarray, data: np.ndarray) -> None:
        rows = np.arange(self.first_row, self.first_row + len(stamps), dtype=np.int64)
        keep = np.ones(len(stamps), dtype=bool)
        held = {}
        for s in self.streams:
            held[s.name], known = s.take(stamps)
            s.dropped += int(np.count_nonzero(~known & keep))
            keep &= known
        if not keep.all():
            stamps, data, rows = stamps[keep], data[keep], rows[keep]
            held = {k: v[keep] for k, v in held.items()}
        if not len(stamps):
            return
        if self.origin is None:
            self.origin = int(stamps[0])
        batch = {"t": (stamps - self.origin) / 1e9}
        for i, axis in enumerate("xyz"):
            batch[f"gyro_{axis}"] = _RAD.apply(data[:, 1 + i])
        batch.update(held)
        if self.accel:
            for i, axis in enumerate("xyz"):
                batch[f"accel_{axis}"] = _MS2.apply(data[:, 4 + i])
        self.sink.write(batch, rows)


def _imu_topic(source, spec: ImportMap, path: Path, map_name: str) -> str:
    listing = ", ".join(f"{t} ({k})" for t, k in sorted(source.topics.items())) or "none"
    if spec.imu_topic is not None:
        if spec.imu_topic not in source.topics:
            raise LogFormatError(
                f"topic {spec.imu_topic} (topics.imu in {map_name}) is not in "
                f"the file; its topics: {listing}",
                source=path,
            )
        kind = source.topics[spec.imu_topic]
        if kind != IMU:
            raise LogFormatError(
                f"topic {spec.imu_topic} carries {kind or 'no schema'}, expected {IMU}", source=path
            )
        return spec.imu_topic
    imus = sorted(t for t, k in source.topics.items() if k == IMU)
    if len(imus) == 1:
        return imus[0]
    if not imus:
        raise LogFormatError(f"no {IMU} topic in the file; its topics: {listing}", source=path)
    raise LogFormatError(
        f"{len(imus)} {IMU} topics ({', '.join(imus)}): name one as topics.imu in the map", source=path
    )


def _check_held(source, held: Held, name: str, path: Path) -> str:
    if held.topic not in source.topics:
        listing = ", ".join(f"{t} ({k})" for t, k in sorted(source.topics.items())) or "none"
        raise LogFormatError(
            f"topic {held.topic} ({name}) is not in the file; its topics: {listing}", source=path
        )
    kind = source.topics[held.topic]
    if held.field is None and kind not in VALUE_FIELDS:
        expected = "sensor_msgs/msg/Temperature" if name == "temp" else "std_msgs/msg/Float64"
        raise LogFormatError(
            f"topic {held.topic} carries {kind or 'no schema'}, expected "
            f"{expected} or std_msgs Float64/Float32 (or give field: to read "
            "one of its fields)",
            source=path,
        )
    if source.counts.get(held.topic) == 0:
        raise EmptyLogError(f"topic {held.topic} ({name}) holds no messages", source=path)
    return kind


def _iso(ns: int | None) -> str | None:
    if ns is None:
        return None
    seconds, rest = divmod(ns, 1_000_000_000)
    return datetime.fromtimestamp(seconds, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{rest:09d}Z"
