"""ROS 2 node ``recorder``: records the suite's topics into a rosbag2 bag, for machines
without ``ros2 bag`` (SPEC §1 tools).

    recorder --ros-args -r __ns:=/fuel_valve -p output:=run1 [-p storage:=sqlite3]
             [-p overwrite:=true] [-p topics:="['resolver', 'demand']"] [-p use_sim_time:=true]

The bag is a rosbag2 directory (format version 9, MCAP storage by default) written with the
``rosbags`` library; every connection carries the Jazzy message definition and RIHS01 type
hash, so Jazzy's ``ros2 bag info`` / ``ros2 bag play`` and :mod:`.bag_io` read it.

Subscriptions are raw (the CDR bytes are written untouched: cheap and exact), RELIABLE,
KEEP_LAST ``DEPTH``; ``drive_enable`` is TRANSIENT_LOCAL like its publisher so a recorder
started late still gets the latched state.  Timestamps follow ``ros2 bag record`` (Jazzy):

* receive time (MCAP ``log_time``, the bag's timestamp) = the node's clock when the message
  is taken, ns: sim time with ``use_sim_time`` (0 until the first ``/clock``), else system
  time.  With sim time it never runs behind the newest ``/clock`` message already recorded
  (the node's time source and the recording subscription of ``/clock`` are two
  subscriptions of one topic, taken in either order);
* publish time (MCAP ``publish_time``) = the DDS source timestamp (publisher's system
  clock); MCAP ``sequence`` counts per topic from 1.  The sqlite3 storage has no publish
  time (rosbag2 neither).

MCAP channels also carry ``topic_type_hash`` metadata, as rosbag2's MCAP plugin writes it.

SIGINT and SIGTERM only set a flag, so a message being written is never interrupted; the
node then drains what is already queued, closes the writer (which writes metadata.yaml with
the message counts) and logs a summary.  A SIGKILL loses the bag's index and metadata.

The single-threaded executor is used: the events executor of this rclpy is faster per
message but cannot deliver the message info (source timestamp) to a callback.
"""
from __future__ import annotations

import importlib
import shutil
import signal
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..common import contract
from ..common.paramspec import Param, ParamSpec
from ..ros import interface as ri

#: per-topic queue of the subscriptions: a deep reliable queue absorbs bursts while a chunk
#: is being flushed to disk
DEPTH = 1000
BAG_VERSION = 9
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
STORAGES = ("mcap", "sqlite3")
#: the recorder node's parameters (all start-up only)
RECORDER_SPEC = ParamSpec("recorder", [
    Param("topics", list(contract.TOPIC_TYPES), "", "topics to record; relative names follow the node namespace; "
          "entries other than the suite's topics as 'name:pkg/msg/Type'. Default: every suite topic "
          "(+ /clock with use_sim_time)"),
    Param("output", "", "", "bag directory to create (default fuel_valve_<YYYYmmdd_HHMMSS> in the working "
          "directory)"),
    Param("overwrite", False, "", "replace an existing bag at output (never a non-bag directory)"),
    Param("storage", "mcap", "", "rosbag2 storage plugin", choices=STORAGES),
])
#: longest time spent, after a stop request, taking messages that are already queued, s
DRAIN_LIMIT_S = 0.5
#: the drain ends once no message arrived for this long, s
DRAIN_IDLE_S = 0.05


class RecorderError(Exception):
    """A configuration problem (bad parameter, output exists, unknown topic type)."""


@dataclass
class _Topic:
    name: str             # fully resolved
    msgtype: str          # e.g. std_msgs/msg/Float64
    connection: object = None
    count: int = 0


def default_output(now: float | None = None) -> str:
    """``fuel_valve_<YYYYmmdd_HHMMSS>`` (local time), relative to the working directory."""
    return time.strftime("fuel_valve_%Y%m%d_%H%M%S", time.localtime(now))


def topic_list(topics: list[str], use_sim_time: bool, is_default: bool) -> list[tuple[str, str]]:
    """``[(name, type)]`` for the ``topics`` parameter.

    An entry is ``name`` (a suite topic, matched on its last path component, or ``/clock``)
    or ``name:pkg/msg/Type`` for anything else.  ``/clock`` is added to the default list
    when ``use_sim_time`` is true.
    """
    out = []
    for entry in topics:
        name, _, msgtype = entry.strip().partition(":")
        name = name.strip()
        if not name:
            raise RecorderError(f"empty topic name in topics entry {entry!r}")
        if not msgtype:
            base = name.rstrip("/").rsplit("/", 1)[-1]
            if name in contract.TOPIC_TYPES:
                msgtype = contract.TOPIC_TYPES[name]
            elif name.rstrip("/") == contract.CLOCK:
                msgtype = CLOCK_TYPE
            elif base in contract.TOPIC_TYPES:
                msgtype = contract.TOPIC_TYPES[base]
            elif "/" + base in contract.TOPIC_TYPES:          # e.g. /ns/diagnostics
                msgtype = contract.TOPIC_TYPES["/" + base]
            else:
                raise RecorderError(f"unknown type of topic {name!r}: not a fuel_valve topic, write it as "
                                    f"'{name}:pkg/msg/Type'")
        out.append((name, msgtype.strip()))
    if use_sim_time and is_default and all(n != contract.CLOCK for n, _ in out):
        out.append((contract.CLOCK, CLOCK_TYPE))
    return out


def message_class(msgtype: str):
    """The rclpy message class of ``pkg/msg/Type``."""
    try:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise RecorderError(f"message type {msgtype!r} is not installed") from None


def subscription_qos(name: str) -> QoSProfile:
    """RELIABLE, KEEP_LAST DEPTH; TRANSIENT_LOCAL only where the suite's publisher is latched."""
    base = name.rstrip("/").rsplit("/", 1)[-1]
    durability = ri.qos_for(base).durability if base in contract.TOPIC_TYPES else DurabilityPolicy.VOLATILE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=durability)


def to_bag_qos(profile):
    """rclpy QoSProfile -> rosbags ``Qos`` (for the bag's offered_qos_profiles)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)

    def enum(target, value):
        try:
            return target[value.name]
        except (KeyError, AttributeError):
            return target.UNKNOWN

    def dur(d):
        ns = int(d.nanoseconds)
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)
    return Qos(enum(QosHistory, profile.history), int(profile.depth), enum(QosReliability, profile.reliability),
               enum(QosDurability, profile.durability), dur(profile.deadline), dur(profile.lifespan),
               enum(QosLiveliness, profile.liveliness), dur(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def prepare_output(path: Path, overwrite: bool) -> None:
    """Make room for a new bag at ``path``; refuse to replace anything that is not a bag."""
    if not path.exists() and not path.is_symlink():
        return
    if not overwrite:
        raise RecorderError(f"output {str(path)!r} exists already; choose another path or set overwrite:=true")
    if path.is_dir() and not path.is_symlink():
        entries = list(path.iterdir())
        is_bag = (path / "metadata.yaml").exists() or any(p.suffix in (".mcap", ".db3") for p in entries)
        if entries and not is_bag:
            raise RecorderError(f"output {str(path)!r} is a non-empty directory that is not a bag; "
                                "refusing to delete it")
        shutil.rmtree(path)
    else:
        path.unlink()


def bag_writer(path: Path, storage: str):
    """A rosbags ``Writer`` for ``path`` (rosbag2 version 9) whose MCAP storage also writes the
    publish time, a per-topic sequence number and the channel's ``topic_type_hash``.

    rosbags' own MCAP writer sets publish_time = log_time and sequence = 0; the subclass below
    changes only those fields of the message record (layout of the MCAP specification) and
    adds one channel metadata entry.  Should rosbags' internals ever change, the plain writer
    is used instead (publish time = receive time, still a valid bag).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    if storage == "mcap":
        try:
            return _PublishTimeWriter(path, version=BAG_VERSION, storage_plugin=plugin)
        except NameError:
            pass
    return Writer(path, version=BAG_VERSION, storage_plugin=plugin)


try:
    from io import BytesIO

    from rosbags.rosbag2 import StoragePlugin as _StoragePlugin
    from rosbags.rosbag2 import Writer as _Writer
    from rosbags.rosbag2.storage_mcap import Channel as _Channel
    from rosbags.rosbag2.storage_mcap import McapWriter as _McapWriter
    from rosbags.rosbag2.storage_mcap import write_channel as _write_channel
    from rosbags.rosbag2.storage_mcap import write_record as _write_record
    from rosbags.rosbag2.storage_mcap import write_string as _write_string
    from rosbags.rosbag2.storage_mcap import write_uint16 as _write_uint16
    from rosbags.rosbag2.storage_mcap import write_uint32 as _write_uint32
    from rosbags.rosbag2.storage_mcap import write_uint64 as _write_uint64

    class _McapStorage(_McapWriter):
        """rosbags' MCAP storage with publish time, sequence and topic_type_hash."""

        #: (publish_time, sequence) of the message being written, set by the Writer
        pending: tuple[int, int] | None = None

        def add_connection(self, connection, offered_qos_profiles: str) -> None:
            metadata = BytesIO()
            _write_string(metadata, "offered_qos_profiles")
            _write_string(metadata, offered_qos_profiles)
            _write_string(metadata, "topic_type_hash")
            _write_string(metadata, connection.digest)
            self.channels.append(_Channel(connection.id, connection.msgtype, connection.topic,
                                         connection.ext.serialization_format, metadata.getvalue()))
            self.channel_stats[connection.id] = 0
            _write_channel(self.chunk.bio, self.channels[-1], self.schemas)

        def write(self, connection, timestamp: int, data) -> None:
            publish, sequence = self.pending if self.pending is not None else (timestamp, 0)
            self.pending = None
            self.message_start_time = min(timestamp, self.message_start_time)
            self.message_end_time = max(timestamp, self.message_end_time)
            self.channel_stats[connection.id] += 1
            chunk = self.chunk
            chunk.message_start_time = min(timestamp, chunk.message_start_time)
            chunk.message_end_time = max(timestamp, chunk.message_end_time)
            chunk.msgs[connection.id].append((timestamp, chunk.bio.tell()))
            rec = BytesIO()
            _write_uint16(rec, connection.id)
            _write_uint32(rec, sequence & 0xFFFFFFFF)
            _write_uint64(rec, timestamp)           # log_time
            _write_uint64(rec, publish)             # publish_time
            rec.write(data)
            _write_record(chunk.bio, 0x05, rec)
            if chunk.bio.tell() > 2**20:
                self.close_chunk()

    class _PublishTimeWriter(_Writer):
        STORAGE_PLUGINS = {**_Writer.STORAGE_PLUGINS, _StoragePlugin.MCAP: _McapStorage}

        def write_message(self, connection, log_time: int, data, publish_time: int, sequence: int) -> None:
            if isinstance(self.storage, _McapStorage):
                self.storage.pending = (publish_time, sequence)
            self.write(connection, log_time, data)
except ImportError:                                     # pragma: no cover - other rosbags versions
    pass


class Recorder(Node):
    """Writes every message of the configured topics to the bag; :meth:`finish` closes it."""

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        from rosbags.rosbag2 import WriterError
        from rosbags.typesys import Stores, get_typestore

        default_topics = RECORDER_SPEC.params["topics"].default
        ri.declare_spec(self, RECORDER_SPEC)

        storage = self.get_parameter("storage").value
        if storage not in STORAGES:
            raise RecorderError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
        topics = list(self.get_parameter("topics").value)
        use_sim_time = bool(self.get_parameter("use_sim_time").value)
        wanted = topic_list(topics, use_sim_time, topics == default_topics)
        if not wanted:
            raise RecorderError("topics is empty: nothing to record")

        typestore = get_typestore(Stores.ROS2_JAZZY)
        self._topics: dict[str, _Topic] = {}
        for name, msgtype in wanted:
            try:
                resolved = self.resolve_topic_name(name)
            except Exception as exc:  # rclpy raises several types for invalid names
                raise RecorderError(f"invalid topic name {name!r}: {exc}") from None
            if resolved in self._topics:
                if self._topics[resolved].msgtype != msgtype:
                    raise RecorderError(f"topic {resolved} listed with two types")
                continue
            try:
                typestore.get_msgdef(msgtype)
            except Exception:
                raise RecorderError(f"message type {msgtype!r} is not in the rosbags Jazzy typestore") from None
            message_class(msgtype)
            self._topics[resolved] = _Topic(resolved, msgtype)

        self.path = Path(self.get_parameter("output").value or default_output()).expanduser()
        prepare_output(self.path, bool(self.get_parameter("overwrite").value))
        self._typestore = typestore
        self._writer = bag_writer(self.path, storage)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise RecorderError(f"cannot create bag {str(self.path)!r}: {exc}") from None
        self._write_message = getattr(self._writer, "write_message", None)
        self._clock = self.get_clock()
        self._floor_ns = 0            # newest /clock value recorded (sim time only)
        self._use_sim_time = use_sim_time
        self.storage = storage

        # /clock first: within one executor wait, entities are taken in creation order
        for topic in sorted(self._topics.values(), key=lambda tp: tp.name != contract.CLOCK):
            sub = self.create_subscription(message_class(topic.msgtype), topic.name, partial(self._on_message, topic),
                                           subscription_qos(topic.name), raw=True)
            self._check_hash(topic, sub)
        self.get_logger().info(f"recording {len(self._topics)} topics to {self.path} ({storage}): "
                               + ", ".join(sorted(self._topics)))

    @property
    def total(self) -> int:
        """Messages written so far."""
        return sum(t.count for t in self._topics.values())

    def _on_message(self, topic: _Topic, data: bytes, info) -> None:
        if self._writer is None:
            return
        stamp = self._clock.now().nanoseconds
        if self._use_sim_time:
            if topic.name == contract.CLOCK and len(data) >= 12:
                # CDR: 4-byte encapsulation header, then int32 sec, uint32 nanosec
                sec = int.from_bytes(data[4:8], "little" if data[1] == 1 else "big", signed=True)
                nsec = int.from_bytes(data[8:12], "little" if data[1] == 1 else "big")
                self._floor_ns = max(self._floor_ns, sec * 1_000_000_000 + nsec)
            stamp = max(stamp, self._floor_ns)
        if topic.connection is None:
            topic.connection = self._connect(topic)
        topic.count += 1
        if self._write_message is not None:
            sent = info.get("source_timestamp") if isinstance(info, dict) else None
            self._write_message(topic.connection, stamp, data, int(sent) if sent else stamp, topic.count)
        else:
            self._writer.write(topic.connection, stamp, data)

    def _connect(self, topic: _Topic):
        """Add the bag connection; done at the first message so the publishers' offered QoS
        (which ``ros2 bag play`` reuses, e.g. for the latched ``drive_enable``) is known."""
        try:
            qos = [to_bag_qos(info.qos_profile) for info in self.get_publishers_info_by_topic(topic.name)]
        except Exception:  # the graph query is best effort; a connection without QoS is still valid
            qos = []
        return self._writer.add_connection(topic.name, topic.msgtype, typestore=self._typestore,
                                           offered_qos_profiles=qos)

    def _check_hash(self, topic: _Topic, sub) -> None:
        """Warn when the middleware's type hash differs from the typestore's: the stored
        definition would not describe the recorded bytes."""
        try:
            ours = [i for i in self.get_subscriptions_info_by_topic(topic.name) if i.node_name == self.get_name()]
            expected = self._typestore.hash_rihs01(topic.msgtype)
            if ours and str(ours[0].topic_type_hash) != expected:
                self.get_logger().warn(f"{topic.name}: type hash {ours[0].topic_type_hash} differs from "
                                       f"the Jazzy typestore's {expected}")
        except Exception:
            pass

    def finish(self) -> dict[str, int]:
        """Close the bag (metadata.yaml with message counts) and log the summary; idempotent.
        Returns ``{topic: messages}``."""
        counts = {t.name: t.count for t in self._topics.values()}
        if self._writer is None:
            return counts
        writer, self._writer = self._writer, None
        for topic in self._topics.values():
            if topic.connection is None:   # subscribed but nothing arrived: still listed, count 0
                topic.connection = writer.add_connection(topic.name, topic.msgtype, typestore=self._typestore)
        writer.close()
        width = max(len(n) for n in counts)
        lines = "\n".join(f"  {n:<{width}} {c}" for n, c in sorted(counts.items()))
        self.get_logger().info(f"bag {self.path} closed: {sum(counts.values())} messages\n{lines}")
        return counts


def main(args=None) -> int:
    """Record until SIGINT / SIGTERM.  Exit codes: 0 ok, 1 bag could not be finalised,
    2 configuration error (printed on stderr)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    stop: list[int] = []

    def request_stop(signum, frame):
        # only a flag: raising here could interrupt a write and corrupt the chunk being built
        stop.append(signum)
    signal.signal(signal.SIGINT, request_stop)
    signal.signal(signal.SIGTERM, request_stop)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    try:
        try:
            node = Recorder()
        except (RecorderError, OSError) as exc:
            print(f"recorder: {exc}", file=sys.stderr, flush=True)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            # spin_once with a timeout, not spin(): the flag is checked even when no data flows
            while not stop and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
            # take what is already queued in the subscriptions before closing
            # (until none arrived for DRAIN_IDLE_S; at most DRAIN_LIMIT_S if publishers go on)
            now = time.monotonic()
            deadline, idle_since, last = now + DRAIN_LIMIT_S, now, node.total
            while rclpy.ok() and now < deadline and now - idle_since < DRAIN_IDLE_S:
                executor.spin_once(timeout_sec=DRAIN_IDLE_S / 5)
                now = time.monotonic()
                if node.total != last:
                    idle_since, last = now, node.total
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        try:
            node.finish()
        except Exception as exc:  # disk full, permissions: say so, do not hide it
            print(f"recorder: could not finalise bag {node.path}: {exc}", file=sys.stderr, flush=True)
            code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
