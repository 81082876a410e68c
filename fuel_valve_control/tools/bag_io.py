"""Read a rosbag2 bag (MCAP or sqlite3; from ``recorder`` or ``ros2 bag record``) into numpy
arrays per topic, with the ``rosbags`` library (no ROS install needed).

    bag = read_bag("run1")                 # the bag directory (or its .mcap / .db3 file)
    js = bag.find("joint_states")          # namespace-agnostic lookup
    js.stamp_s, js["valve_shaft.position"]

Per message type the numeric content becomes named columns of a :class:`TopicData`:

* ``std_msgs/Float64`` / ``Bool`` / ``UInt8``: ``data``;
* ``sensor_msgs/JointState``: ``<joint>.position|velocity|effort`` (NaN where absent) and the
  header stamp;
* ``std_msgs/Float64MultiArray``: one column per layout label (the suite's labelled
  telemetry; unlabelled entries are ``0``, ``1``, ...);
* ``rosgraph_msgs/Clock``: ``clock`` [s] (also used as the stamp);
* ``diagnostic_msgs/DiagnosticArray``: no columns; the newest key/values of every status
  name are kept in :attr:`Bag.diagnostics`.

Times: ``log_ns`` is the bag's receive time, ``stamp_ns`` the header stamp where the type has
one.  :class:`BagError` (with a readable message) for anything that is not a readable bag.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class BagError(Exception):
    """The input is not a readable bag, or lacks what was asked for."""


@dataclass
class TopicData:
    topic: str
    msgtype: str
    log_ns: np.ndarray                              # int64, receive time
    stamp_ns: np.ndarray | None = None              # int64, header stamp (None: type has no header)
    columns: dict = field(default_factory=dict)     # name -> float array, one value per message

    def __len__(self) -> int:
        return len(self.log_ns)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    @property
    def log_s(self) -> np.ndarray:
        return self.log_ns.astype(np.float64) * 1e-9

    @property
    def stamp_s(self) -> np.ndarray | None:
        return None if self.stamp_ns is None else self.stamp_ns.astype(np.float64) * 1e-9


@dataclass
class Bag:
    path: Path
    storage: str                                    # mcap | sqlite3
    topics: dict                                    # full topic name -> TopicData
    counts: dict                                    # full topic name -> messages in the bag
    types: dict                                     # full topic name -> message type
    diagnostics: dict = field(default_factory=dict)  # status name -> {key: value} (newest)
    custom_data: dict = field(default_factory=dict)
    texts: dict = field(default_factory=dict)        # full topic name -> [std_msgs/String data, ...]

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def find(self, name: str) -> TopicData | None:
        """The topic called ``name`` (full name, or its last component: ``joint_states``
        matches ``/fuel_valve/joint_states``).  Several namespaces: the one with most messages."""
        if name in self.topics:
            return self.topics[name]
        base = name.strip("/").rsplit("/", 1)[-1]
        hits = [t for n, t in self.topics.items() if n.rstrip("/").rsplit("/", 1)[-1] == base]
        return max(hits, key=len) if hits else None


def bag_directory(path: str | Path) -> Path:
    """The bag directory for ``path`` (a bag directory, or a storage file inside one)."""
    p = Path(path).expanduser()
    if not p.exists():
        raise BagError(f"{str(path)!r} does not exist")
    if p.is_file():
        if p.suffix in (".mcap", ".db3") and (p.parent / "metadata.yaml").is_file():
            return p.parent
        raise BagError(f"{str(path)!r} is not a rosbag2 bag (expected a bag directory with metadata.yaml)")
    if not (p / "metadata.yaml").is_file():
        files = [q.name for q in p.iterdir() if q.suffix in (".mcap", ".db3")]
        hint = (f" (it holds {', '.join(files)} but no metadata.yaml: an unfinished recording? "
                f"'recorder --reindex {p}' rebuilds it)") if files else ""
        raise BagError(f"{str(path)!r} is not a rosbag2 bag: no metadata.yaml{hint}")
    return p


def read_bag(path: str | Path, topics: list[str] | None = None) -> Bag:
    """Read every message (or those of ``topics``, full names or last components) of a bag."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    directory = bag_directory(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    raw: dict[str, list] = {}
    try:
        with AnyReader([directory], default_typestore=typestore) as reader:
            storage = _storage_of(directory)
            custom = dict(getattr(getattr(reader.readers[0], "metadata", None), "custom", None) or {})
            counts: dict[str, int] = {}
            types: dict[str, str] = {}
            for conn in reader.connections:
                counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
                types[conn.topic] = conn.msgtype
            wanted = list(reader.connections)
            if topics is not None:
                bases = {t.strip("/").rsplit("/", 1)[-1] for t in topics}
                wanted = [c for c in wanted if c.topic in topics or c.topic.rstrip("/").rsplit("/", 1)[-1] in bases]
            diagnostics: dict[str, dict] = {}
            texts: dict[str, list] = {}
            for conn, log_ns, data in (reader.messages(connections=wanted) if wanted else ()):
                msg = reader.deserialize(data, conn.msgtype)
                if conn.msgtype == "diagnostic_msgs/msg/DiagnosticArray":
                    for st in msg.status:
                        diagnostics[st.name] = {kv.key: kv.value for kv in st.values}
                        diagnostics[st.name]["_message"] = st.message
                    continue
                if conn.msgtype == "std_msgs/msg/String":
                    texts.setdefault(conn.topic, []).append(msg.data)
                    continue
                raw.setdefault(conn.topic, []).append((log_ns, conn.msgtype, msg))
    except AnyReaderError as exc:
        raise BagError(f"cannot read bag {str(directory)!r}: {exc}") from None
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - corrupt storage files raise many types
        raise BagError(f"cannot read bag {str(directory)!r}: {type(exc).__name__}: {exc}") from None
    out = {name: _columns(name, items) for name, items in raw.items()}
    return Bag(directory, storage, out, counts, types, diagnostics, custom, texts)


def _storage_of(directory: Path) -> str:
    if any(directory.glob("*.mcap")):
        return "mcap"
    if any(directory.glob("*.db3")):
        return "sqlite3"
    return "unknown"


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _columns(topic: str, items: list) -> TopicData:
    msgtype = items[0][1]
    log_ns = np.array([i[0] for i in items], dtype=np.int64)
    msgs = [i[2] for i in items]
    data = TopicData(topic, msgtype, log_ns)
    n = len(msgs)
    if msgtype in ("std_msgs/msg/Float64", "std_msgs/msg/Float32", "std_msgs/msg/Bool", "std_msgs/msg/UInt8"):
        data.columns["data"] = np.array([float(m.data) for m in msgs])
    elif msgtype == "rosgraph_msgs/msg/Clock":
        data.stamp_ns = np.array([_stamp_ns(m.clock) for m in msgs], dtype=np.int64)
        data.columns["clock"] = data.stamp_ns * 1e-9
    elif msgtype == "sensor_msgs/msg/JointState":
        data.stamp_ns = np.array([_stamp_ns(m.header.stamp) for m in msgs], dtype=np.int64)
        cols: dict[str, np.ndarray] = {}
        for k, m in enumerate(msgs):
            for fname in ("position", "velocity", "effort"):
                values = getattr(m, fname)
                if len(values) != len(m.name):
                    continue
                for joint, v in zip(m.name, values):
                    key = f"{joint}.{fname}"
                    if key not in cols:
                        cols[key] = np.full(n, math.nan)
                    cols[key][k] = float(v)
        data.columns.update(cols)
    elif msgtype in ("std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray"):
        cols = {}
        for k, m in enumerate(msgs):
            values = np.asarray(m.data, dtype=float)
            labels = [d.label for d in m.layout.dim]
            if len(labels) != len(values) or len(set(labels)) != len(labels) or not all(labels):
                labels = [str(i) for i in range(len(values))]
            for label, v in zip(labels, values):
                if label not in cols:
                    cols[label] = np.full(n, math.nan)
                cols[label][k] = v
        data.columns.update(cols)
    elif hasattr(msgs[0], "header") and hasattr(msgs[0].header, "stamp"):
        data.stamp_ns = np.array([_stamp_ns(m.header.stamp) for m in msgs], dtype=np.int64)
    return data
