"""ROS 2 node ``recorder``: records the suite's topics into a rosbag2 bag, for machines
without ``ros2 bag`` (SPEC §1 tools).

    recorder --ros-args -r __ns:=/fuel_valve -p output:=run1 [-p storage:=sqlite3]
             [-p overwrite:=true] [-p topics:="['resolver', 'demand']"] [-p use_sim_time:=true]

The bag is a rosbag2 directory (format version 9, MCAP storage by default) written with the
``rosbags`` library; every connection carries the Jazzy message definition and RIHS01 type
hash, so Jazzy's ``ros2 bag info`` / ``ros2 bag play`` and :mod:`.bag_io` read it.

Hot path (measured in benchmarks/ros_loop.py --record): subscriptions are raw, so the CDR
bytes are never deserialised, only stamped and queued; a writer thread hands them to rosbags'
public ``Writer.write`` (what rosbag2's own recorder does).  The queue is bounded
(:class:`BagWriterThread`): a message that does not fit is dropped *and counted*; the summary
logged at the end lists per topic the messages written and any dropped.  The executor is the
suite's (:mod:`fuel_valve_control.ros.node_runner`, rclpy's events executor).

Subscriptions are KEEP_LAST ``DEPTH`` and adapt to the publishers, as ``ros2 bag record``'s
adaptive QoS does (:func:`adapted_qos`): RELIABLE unless a publisher offers BEST_EFFORT (a
supervisor publishing the demand or Δp best-effort, which the controller hears since h24u: a
reliable subscription would match none of its samples and the bag would lack the demand);
``drive_enable`` is TRANSIENT_LOCAL like its publisher so a recorder started late still gets
the latched state, VOLATILE once a volatile publisher appears.  The publishers are read at
start and every ``QOS_RECHECK_S``; a subscription that no longer matches them all is re-made
with the weaker profile (only ever weaker, never back: no churn, no replayed latched samples),
logged; that topic then misses what is published during the new subscription's discovery
(tens of ms), once.  No message is lost to
start-up or to a stalled recorder when the suite's nodes know a recorder is in the run
(``recorded_topics``, set by the launcher and the launch file): they publish once it has
matched and keep deep writer histories for its re-sends (``interface.RecorderGate``,
``interface.RECORDED_WRITER_DEPTH``).  metadata.yaml carries,
per topic, the message count written and the QoS profiles its publishers offered (as
``ros2 bag record`` stores them, so ``ros2 bag play`` offers the same), and ``ros_distro:
jazzy``.  Timestamps follow ``ros2 bag record`` (Jazzy): the receive time (MCAP
``log_time``, the bag's timestamp) is the node's clock when the message is taken, ns: sim
time with ``use_sim_time`` (0 until the first ``/clock``; never behind the newest ``/clock``
message already recorded, as the node's time source and the recording subscription are two
subscriptions of one topic, taken in either order), else system time.

Not written, because rosbags' public writer API has no argument for them: the MCAP publish
time (the DDS source timestamp; rosbags writes the receive time) and the per-channel
sequence number (rosbags writes 0).  The events executor cannot hand the message info to a
callback either.  Readers that need the send time use the header stamps.

SIGINT and SIGTERM only set a flag, so a message being written is never interrupted; the
node then drains what is already queued, closes the writer (which writes metadata.yaml with
the message counts) and logs a summary.  A SIGKILL loses the bag's index and metadata, so the
stop is bounded: the drain and the writing of the queue's backlog end ``STOP_BUDGET_S`` after
the stop request, well inside ``ros2 launch``'s 5 s between its SIGINT and SIGTERM (and
SIGKILL 5 s later).  On a starved CPU (a loaded 2-core machine gave the recorder ~5 % of a
core) the backlog can outlast it: what is still queued then is dropped and counted per topic
in the summary ("N DROPPED"), never silently -- a closed bag with a counted loss instead of a
bag killed without its index.
"""
from __future__ import annotations

import importlib
import math
import shutil
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..common import contract
from ..common.paramspec import Param, ParamSpec
from ..ros import interface as ri
from ..ros import node_runner

#: per-topic queue of the subscriptions, messages: a starved recorder process finds what arrived
#: meanwhile still queued (5 s of a 1 kHz topic; deeper than the suite's writers keep for it,
#: interface.RECORDED_WRITER_DEPTH, so a re-sent sample is never pushed out here)
DEPTH = 5000
BAG_VERSION = 9
#: the distribution whose message definitions and type hashes the bag carries (the rosbags
#: typestore used below is Jazzy's; rosbag2 writes its distro into metadata.yaml)
ROS_DISTRO = "jazzy"
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
#: the bag reaches the disk at least this often, s: the sqlite3 transaction is committed and the
#: MCAP chunk being filled is closed and flushed (:func:`flush_storage`), so a SIGKILL loses at
#: most this much and ``recorder --reindex`` recovers the rest
FLUSH_INTERVAL_S = 0.25
#: longest time spent, after a stop request, taking messages that are already queued, s
DRAIN_LIMIT_S = 0.5
#: the drain ends once no message arrived for this long, s
DRAIN_IDLE_S = 0.05
#: longest time from a stop request (SIGINT/SIGTERM) to closing the bag, s: the drain and the
#: writing of the queued backlog share it; what is still queued then is dropped and counted.
#: ros2 launch escalates to SIGTERM 5 s after its SIGINT and to SIGKILL 5 s later; closing the
#: bag, tearing down and exiting need the rest
STOP_BUDGET_S = 2.0
#: how often the publishers of every recorded topic are re-read to adapt the subscriptions'
#: QoS, s (a best-effort publisher that appears is recorded from at most this much later)
QOS_RECHECK_S = 0.5


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


def adapted_qos(current: QoSProfile, offered) -> QoSProfile:
    """The subscription profile that matches every offered publisher profile (``offered``:
    rclpy QoSProfiles, from ``get_publishers_info_by_topic``), starting from ``current``:
    BEST_EFFORT if any publisher is best-effort, VOLATILE if any is volatile (a reliable or
    transient-local request does not match a weaker offer), else ``current`` unchanged --
    rosbag2's adaptive QoS, restricted to weakening so a subscription is re-made at most twice."""
    reliability, durability = current.reliability, current.durability
    offered = list(offered)
    if any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in offered):
        reliability = ReliabilityPolicy.BEST_EFFORT
    if any(p.durability == DurabilityPolicy.VOLATILE for p in offered):
        durability = DurabilityPolicy.VOLATILE
    if reliability == current.reliability and durability == current.durability:
        return current
    return QoSProfile(history=current.history, depth=current.depth, reliability=reliability,
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
    """A rosbags ``Writer`` (public API) for a rosbag2 version-9 bag at ``path``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer(path, version=BAG_VERSION, storage_plugin=plugin)


def set_ros_distro(metadata: Path, distro: str = ROS_DISTRO) -> None:
    """Write the real distribution into a closed bag's ``metadata.yaml`` (rosbags writes
    ``ros_distro: rosbags`` and has no setting for it; the copy of the metadata inside an MCAP
    file keeps rosbags' value: rosbag2 reads metadata.yaml)."""
    text = metadata.read_text()
    fixed = text.replace("ros_distro: rosbags\n", f"ros_distro: {distro}\n")
    if fixed != text:
        tmp = metadata.with_suffix(".yaml.tmp")
        tmp.write_text(fixed)
        tmp.replace(metadata)


def flush_storage(writer) -> bool:
    """Put what ``writer`` (an open rosbags ``Writer``) has written so far on the disk: commit
    the sqlite3 transaction, or close the MCAP chunk being filled and flush the file.

    rosbags' public API has no flush or commit (its sqlite3 storage commits once, at close; its
    MCAP storage closes a chunk per MiB): this reaches into the writer's storage object
    (``Writer.storage``: the sqlite3 ``conn`` / the MCAP ``chunk``, ``close_chunk()`` and ``bio``
    of rosbags 0.10-0.11).  Returns False, changing nothing, when those are not there (another
    rosbags version): the bag is then only complete after a clean close, as before."""
    storage = getattr(writer, "storage", None)
    conn = getattr(storage, "conn", None)
    if conn is not None and hasattr(conn, "commit"):
        conn.commit()
        return True
    chunk, bio = getattr(storage, "chunk", None), getattr(storage, "bio", None)
    if chunk is not None and bio is not None and hasattr(storage, "close_chunk"):
        if chunk.bio.tell():
            storage.close_chunk()
        bio.flush()
        return True
    return False


class BagWriterThread:
    """Writes ``(topic, receive time, CDR bytes)`` items to the bag on its own thread.

    The executor's callbacks only append to a bounded queue (a deque: append and popleft are
    atomic, no lock), so taking messages from DDS never waits for the disk; the thread wakes
    every ``POLL_S`` and writes everything queued.  A full queue drops the new message and
    counts it (``dropped``): memory stays bounded and a loss is reported, never silent.
    The rosbags writer lives entirely on this thread (opened, written and closed there: its
    sqlite3 storage refuses use from another thread).
    """

    #: queue bound, messages (about 20 s of the suite's traffic at 1 kHz)
    MAX_QUEUE = 100_000
    #: the thread's wake-up period, s
    POLL_S = 0.005

    def __init__(self, open_writer, connect, topics):
        """``open_writer()`` -> an open rosbags Writer; ``connect(writer, topic)`` -> its
        connection; ``topics``: every recorded topic (a connection each, even if empty)."""
        import collections
        import threading
        self._open, self._connect, self._topics = open_writer, connect, topics
        self._queue = collections.deque()
        self.dropped: dict[str, int] = {}
        self._deadline: float | None = None      # time.monotonic() the final write stops at
        self.error: BaseException | None = None
        self._ready, self._stop = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._run, name="bag-writer", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self.error is not None:
            raise self.error

    def put(self, topic, stamp: int, data: bytes) -> None:
        """Queue one message (executor thread)."""
        if len(self._queue) >= self.MAX_QUEUE:
            self.dropped[topic.name] = self.dropped.get(topic.name, 0) + 1
            return
        self._queue.append((topic, stamp, data))

    def _run(self) -> None:
        try:
            writer = self._open()
        except BaseException as exc:          # noqa: BLE001 - handed to the constructor's caller
            self.error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            flushed = time.monotonic()
            while not self._stop.wait(self.POLL_S):
                self._write_queued(writer)
                if time.monotonic() - flushed >= FLUSH_INTERVAL_S:
                    flushed = time.monotonic()
                    if not flush_storage(writer):
                        flushed = float("inf")       # not supported by this rosbags: stop trying
            self._write_queued(writer, math.inf if self._deadline is None else self._deadline)
            self._drop_queued()
            for topic in self._topics:
                if topic.connection is None:   # subscribed but nothing arrived: still listed, count 0
                    topic.connection = self._connect(writer, topic)
            writer.close()
        except BaseException as exc:          # noqa: BLE001 - reported by close()
            self.error = exc

    def _write_queued(self, writer, deadline: float | None = None) -> None:
        """Write the queue out.  A pass of the running loop (``deadline`` None) yields to a
        stop request; the final pass writes until ``deadline`` (``time.monotonic()``)."""
        queue, write = self._queue, writer.write
        n = 0
        while queue:
            n += 1
            if n % 64 == 0 and (self._stop.is_set() if deadline is None else time.monotonic() > deadline):
                return
            topic, stamp, data = queue.popleft()
            if topic.connection is None:
                topic.connection = self._connect(writer, topic)
            write(topic.connection, stamp, data)
            topic.count += 1

    def _drop_queued(self) -> None:
        """Count what is still queued as dropped (the final write ran out of time)."""
        while self._queue:
            topic = self._queue.popleft()[0]
            self.dropped[topic.name] = self.dropped.get(topic.name, 0) + 1

    def close(self, deadline: float | None = None) -> None:
        """Write what is queued (until ``deadline``, ``time.monotonic()``; the rest is dropped
        and counted) and close the bag (metadata.yaml); raises what the thread hit."""
        self._deadline = deadline
        self._stop.set()
        self._thread.join()
        if self.error is not None:
            raise self.error


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
        def open_writer():
            writer = bag_writer(self.path, storage)
            writer.open()
            return writer
        try:
            self._bag = BagWriterThread(open_writer, self._connect, list(self._topics.values()))
        except (WriterError, OSError) as exc:
            raise RecorderError(f"cannot create bag {str(self.path)!r}: {exc}") from None
        self._clock = self.get_clock()
        self._floor_ns = 0            # newest /clock value recorded (sim time only)
        self._use_sim_time = use_sim_time
        self.storage = storage
        self.received = 0             # messages taken from DDS (written + dropped + queued)
        self.dropped: dict[str, int] = {}

        #: topic name -> (subscription, its QoS profile)
        self._subs: dict[str, tuple[object, QoSProfile]] = {}
        for topic in self._topics.values():
            qos = adapted_qos(subscription_qos(topic.name), self._offered(topic.name))
            self._subs[topic.name] = (self._subscribe(topic, qos), qos)
            self._check_hash(topic, self._subs[topic.name][0])
        self.get_logger().info(f"recording {len(self._topics)} topics to {self.path} ({storage}): "
                               + ", ".join(sorted(self._topics)))
        for name, (_, qos) in sorted(self._subs.items()):
            if qos != subscription_qos(name):
                self._log_adapted(name, qos)
        self._qos_timer = self.create_timer(QOS_RECHECK_S, self._adapt_qos)

    def _subscribe(self, topic: _Topic, qos: QoSProfile):
        return self.create_subscription(message_class(topic.msgtype), topic.name, partial(self._on_message, topic),
                                        qos, raw=True,
                                        event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))

    def _offered(self, name: str) -> list:
        """The QoS profiles the topic's publishers offer (our graph view; [] if the query fails)."""
        try:
            return [info.qos_profile for info in self.get_publishers_info_by_topic(name)]
        except Exception:  # the graph query is best effort: keep the current subscription
            return []

    def _log_adapted(self, name: str, qos: QoSProfile) -> None:
        self.get_logger().info(f"{name}: a publisher offers {qos.reliability.name.lower()} / "
                               f"{qos.durability.name.lower()}: recording with that QoS (adaptive, as ros2 bag record)")

    def _adapt_qos(self) -> None:
        """Timer: re-make every subscription that no longer matches all the topic's publishers."""
        if self._bag is None:
            return
        for topic in self._topics.values():
            sub, qos = self._subs[topic.name]
            new = adapted_qos(qos, self._offered(topic.name))
            if new is qos:
                continue
            # the old one goes first: kept while the new one is discovered, both would record
            # the same samples (duplicates in the bag); a gap of one discovery, once, instead
            self.destroy_subscription(sub)
            self._subs[topic.name] = (self._subscribe(topic, new), new)
            self._log_adapted(topic.name, new)

    @property
    def total(self) -> int:
        """Messages written so far."""
        return sum(t.count for t in self._topics.values())

    def _on_message(self, topic: _Topic, data: bytes) -> None:
        """Executor thread: stamp the CDR bytes with the receive time and queue them."""
        bag = self._bag
        if bag is None:                                    # closed: a late callback
            return
        self.received += 1
        if not self._use_sim_time:
            bag.put(topic, time.time_ns(), data)           # the node's clock = system time
            return
        stamp = self._clock.now().nanoseconds
        if topic.msgtype == CLOCK_TYPE and len(data) >= 12:    # /clock, or a valve's remapped clock
            # CDR: 4-byte encapsulation header, then int32 sec, uint32 nanosec
            order = "little" if data[1] == 1 else "big"
            sec = int.from_bytes(data[4:8], order, signed=True)
            self._floor_ns = max(self._floor_ns, sec * 1_000_000_000 + int.from_bytes(data[8:12], order))
        bag.put(topic, max(stamp, self._floor_ns), data)

    def _connect(self, writer, topic: _Topic):
        """Add the bag connection with the offered QoS of the topic's publishers (which ``ros2
        bag play`` reuses, e.g. TRANSIENT_LOCAL for ``drive_enable``): done at the first
        message, when the publishers are known."""
        try:
            qos = [to_bag_qos(info.qos_profile) for info in self.get_publishers_info_by_topic(topic.name)]
        except Exception:  # the graph query is best effort; a connection without QoS is still valid
            qos = []
        return writer.add_connection(topic.name, topic.msgtype, typestore=self._typestore,
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

    def finish(self, deadline: float | None = None) -> dict[str, int]:
        """Write what is queued (until ``deadline``, ``time.monotonic()``: the rest is dropped
        and counted), close the bag (metadata.yaml with the message counts and ``ros_distro``)
        and log the summary, dropped messages included; idempotent.
        Returns ``{topic: messages written}``."""
        if self._bag is not None:
            bag, self._bag = self._bag, None
            bag.close(deadline)
            self.dropped = bag.dropped
            set_ros_distro(self.path / "metadata.yaml")
            counts = {t.name: t.count for t in self._topics.values()}
            width = max(len(n) for n in counts)
            lines = "\n".join(f"  {n:<{width}} {c}" + (f" ({self.dropped[n]} DROPPED)" if n in self.dropped else "")
                              for n, c in sorted(counts.items()))
            self.get_logger().info(f"bag {self.path} closed: {sum(counts.values())} messages, "
                                   f"{sum(self.dropped.values())} dropped\n{lines}")
        return {t.name: t.count for t in self._topics.values()}


def reindex_main(argv: list[str]) -> int:
    """``recorder --reindex <bag dir> [--force]``: rebuild a killed recording's metadata.yaml
    (:mod:`.bag_recovery`).  Exit codes: 0 rebuilt, 2 nothing recoverable (printed)."""
    import argparse
    import json
    from .bag_recovery import RecoveryError, reindex
    parser = argparse.ArgumentParser(prog="recorder --reindex", description="rebuild metadata.yaml (and an MCAP "
                                     "footer) of a bag whose recorder was killed")
    parser.add_argument("bag", help="bag directory holding one .mcap or .db3 file")
    parser.add_argument("--force", action="store_true", help="rebuild even if metadata.yaml exists")
    ns = parser.parse_args(argv)
    try:
        summary = reindex(ns.bag, force=ns.force)
    except RecoveryError as exc:
        print(f"recorder --reindex: {exc}", file=sys.stderr)
        return 2
    print(f"reindexed {summary['file']}: {summary['message_count']} messages in {len(summary['topics'])} topics"
          + (f", {summary['repaired_bytes_cut']} bytes of a torn last record cut" if summary["repaired_bytes_cut"]
             else ""))
    print(json.dumps(summary))
    return 0


def main(args=None) -> int:
    """Record until SIGINT / SIGTERM.  Exit codes: 0 ok, 1 bag could not be finalised,
    2 configuration error (printed on stderr).  Ends the process (``os._exit``) once the bag
    is closed and the node torn down.  ``recorder --reindex <bag>``: see :func:`reindex_main`."""
    argv = list(sys.argv[1:] if args is None else args[1:])
    if argv[:1] == ["--reindex"]:
        return reindex_main(argv[1:])
    import rclpy
    from rclpy.executors import ExternalShutdownException

    stop: list[int] = []
    # only a flag (as for every node, see node_runner): the spin loop sees it within one spin
    # timeout, then the queued messages are taken before anything is shut down
    node_runner.quiet_signals(stop.append)
    if not node_runner.init_or_explain(args):
        return 2
    node = executor = stopped_at = None
    code = 0
    try:
        try:
            node = Recorder()
        except (RecorderError, OSError) as exc:
            print(f"recorder: {exc}", file=sys.stderr, flush=True)
            return 2
        executor = node_runner.make_executor()
        executor.add_node(node)
        try:
            node_runner.spin(executor, until=lambda: bool(stop), timeout_s=0.05)
            stopped_at = time.monotonic()
            # take what is already queued in the subscriptions before closing
            # (until none arrived for DRAIN_IDLE_S; at most DRAIN_LIMIT_S if publishers go on)
            now = stopped_at
            deadline, idle_since, last = now + DRAIN_LIMIT_S, now, node.received
            while rclpy.ok() and now < deadline and now - idle_since < DRAIN_IDLE_S:
                executor.spin_once(timeout_sec=DRAIN_IDLE_S / 5)
                now = time.monotonic()
                if node.received != last:
                    idle_since, last = now, node.received
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        try:
            node.finish((stopped_at or time.monotonic()) + STOP_BUDGET_S)
        except Exception as exc:  # disk full, permissions: say so, do not hide it
            print(f"recorder: could not finalise bag {node.path}: {exc}", file=sys.stderr, flush=True)
            code = 1
    finally:
        node_runner.tear_down(node, executor, code)     # past its budget it ends with this code (h36r)
    node_runner.end_process(code)       # the bag is closed: no interpreter finalization (node_runner)


if __name__ == "__main__":
    sys.exit(main())
