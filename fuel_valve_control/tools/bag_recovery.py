"""Recover a bag whose recorder was killed (SIGKILL, power loss): ``recorder --reindex <bag>``.

A recorder that never reached its clean close leaves a bag directory without
``metadata.yaml`` (written at close), and, in MCAP storage, a file without its summary and
footer; rosbags (and ``ros2 bag``) refuse both.  What reached the disk is still there: the
recorder commits the sqlite3 transaction and closes an MCAP chunk every
:data:`~.recorder.FLUSH_INTERVAL_S` (see :mod:`.recorder`).  :func:`reindex` rebuilds:

* MCAP: the file is scanned record by record (inside chunks too: schemas, channels, messages);
  a torn record at the end (the write the kill interrupted) is cut off, and a footer without
  summary is appended (MCAP readers then scan the file, as rosbags does); nothing before the
  torn record is changed;
* sqlite3: the committed rows are what the database holds (sqlite rolls an interrupted
  transaction back on open); topics, types, QoS and hashes come from its ``topics`` table;
* both: ``metadata.yaml`` (rosbag2 version 9, as rosbags' writer lays it out) with the
  message count per topic, start time and duration from the messages found, types, the
  offered QoS profiles the recorder stored per connection and the type hashes.

ROS-free (no rclpy): stdlib, PyYAML and rosbags' Jazzy typestore for type hashes MCAP does
not store.
"""
from __future__ import annotations

import sqlite3
import struct
from dataclasses import dataclass, field
from pathlib import Path

import yaml

MCAP_MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F
BAG_VERSION = 9


class RecoveryError(Exception):
    """The directory holds nothing this module can recover."""


@dataclass
class _Topic:
    name: str
    msgtype: str
    serialization_format: str = "cdr"
    qos: list = field(default_factory=list)
    type_hash: str = ""
    count: int = 0


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    return buf[pos + 4:pos + 4 + n].decode(), pos + 4 + n


def _records(buf: bytes, pos: int, end: int):
    """(opcode, body, end offset) of every complete record in ``buf[pos:end]``; stops at a torn one."""
    while pos + 9 <= end:
        op, length = buf[pos], struct.unpack_from("<Q", buf, pos + 1)[0]
        if pos + 9 + length > end:
            return
        yield op, buf[pos + 9:pos + 9 + length], pos + 9 + length
        pos += 9 + length


def scan_mcap(path: Path) -> tuple[dict, int, int, int, bool]:
    """``({channel id: _Topic}, first ns, last ns, end of the last complete record, has footer)``."""
    data = path.read_bytes()
    if data[:8] != MCAP_MAGIC:
        raise RecoveryError(f"{path} is not an MCAP file")
    schemas: dict[int, str] = {}
    topics: dict[int, _Topic] = {}
    first, last = None, None
    good_end, footer = 8, False

    def handle(op, body):
        nonlocal first, last
        if op == OP_SCHEMA:
            (sid,) = struct.unpack_from("<H", body, 0)
            schemas[sid], _ = _string(body, 2)
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, pos = _string(body, 4)
            encoding, pos = _string(body, pos)
            (map_len,) = struct.unpack_from("<I", body, pos)
            pos, end, meta = pos + 4, pos + 4 + map_len, {}
            while pos < end:
                key, pos = _string(body, pos)
                meta[key], pos = _string(body, pos)
            qos = yaml.safe_load(meta.get("offered_qos_profiles") or "[]") or []
            topics[cid] = _Topic(topic, schemas.get(sid, ""), encoding, qos if isinstance(qos, list) else [])
        elif op == OP_MESSAGE:
            cid, _seq, log_ns = struct.unpack_from("<HIQ", body, 0)
            if cid in topics:
                topics[cid].count += 1
                first = log_ns if first is None else min(first, log_ns)
                last = log_ns if last is None else max(last, log_ns)

    for op, body, end in _records(data, 8, len(data)):
        if op == OP_CHUNK:
            clen = struct.unpack_from("<I", body, 28)[0]
            compression = body[32:32 + clen].decode()
            if compression:
                raise RecoveryError(f"{path}: compressed chunks ({compression}) are not supported")
            (size,) = struct.unpack_from("<Q", body, 32 + clen)
            inner = body[40 + clen:40 + clen + size]
            for op2, body2, _ in _records(inner, 0, len(inner)):
                handle(op2, body2)
        elif op == OP_FOOTER:
            footer = True
            good_end = end
            break
        else:
            handle(op, body)
        good_end = end
    return topics, first or 0, last or 0, good_end, footer


def _repair_mcap(path: Path, good_end: int) -> None:
    """Cut a torn trailing record and append a data-end record and a footer without summary."""
    with open(path, "r+b") as fh:
        fh.truncate(good_end)
        fh.seek(good_end)
        fh.write(bytes([OP_DATA_END]) + struct.pack("<QI", 4, 0))
        fh.write(bytes([OP_FOOTER]) + struct.pack("<QQQI", 20, 0, 0, 0))
        fh.write(MCAP_MAGIC)


def scan_sqlite3(path: Path) -> tuple[dict, int, int]:
    """``({topic id: _Topic}, first ns, last ns)`` of the committed rows."""
    try:
        conn = sqlite3.connect(str(path))           # read-write: a hot journal is rolled back
        try:
            rows = conn.execute("SELECT id, name, type, serialization_format, offered_qos_profiles, "
                                "type_description_hash FROM topics").fetchall()
            counts = dict(conn.execute("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id").fetchall())
            first, last = conn.execute("SELECT MIN(timestamp), MAX(timestamp) FROM messages").fetchone()
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise RecoveryError(f"{path}: {exc}") from None
    topics = {}
    for tid, name, msgtype, fmt, qos, digest in rows:
        parsed = yaml.safe_load(qos or "[]") or []
        topics[tid] = _Topic(name, msgtype, fmt, parsed if isinstance(parsed, list) else [], digest or "",
                             counts.get(tid, 0))
    return topics, first or 0, last or 0


def _type_hash(msgtype: str) -> str:
    try:
        from rosbags.typesys import Stores, get_typestore
        return get_typestore(Stores.ROS2_JAZZY).hash_rihs01(msgtype)
    except Exception:                      # noqa: BLE001 - a type outside the typestore: no hash
        return ""


def metadata(storage: str, file_name: str, topics: list[_Topic], first: int, last: int) -> dict:
    """rosbag2 version-9 metadata (the layout rosbags' writer uses)."""
    count = sum(t.count for t in topics)
    duration = max(0, last - first) if count else 0
    start = first if count else 0
    return {"rosbag2_bagfile_information": {
        "version": BAG_VERSION, "storage_identifier": storage, "relative_file_paths": [file_name],
        "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msgtype, "serialization_format": t.serialization_format,
                                "offered_qos_profiles": t.qos,
                                "type_description_hash": t.type_hash or _type_hash(t.msgtype)},
             "message_count": t.count} for t in topics],
        "compression_format": "", "compression_mode": "",
        "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": count}],
        "custom_data": {"recovered_by": "fuel_valve recorder --reindex"},
        "ros_distro": "jazzy"}}


def reindex(path: str | Path, force: bool = False) -> dict:
    """Rebuild ``metadata.yaml`` (and an MCAP file's footer) of the bag directory ``path``.
    Refuses a bag that already has ``metadata.yaml`` unless ``force``.  Returns a summary:
    ``{"storage", "file", "message_count", "topics": {name: count}, "repaired_bytes_cut"}``."""
    directory = Path(path).expanduser()
    if not directory.is_dir():
        raise RecoveryError(f"{str(path)!r} is not a directory")
    meta_path = directory / "metadata.yaml"
    if meta_path.exists() and not force:
        raise RecoveryError(f"{meta_path} exists: the bag was closed cleanly (use --force to rebuild it anyway)")
    files = sorted(directory.glob("*.mcap")) + sorted(directory.glob("*.db3"))
    if len(files) != 1:
        raise RecoveryError(f"{directory}: expected one .mcap or .db3 file, found {[f.name for f in files]}")
    storage_file = files[0]
    cut = 0
    if storage_file.suffix == ".mcap":
        storage = "mcap"
        found, first, last, good_end, has_footer = scan_mcap(storage_file)
        if not has_footer:
            cut = storage_file.stat().st_size - good_end
            _repair_mcap(storage_file, good_end)
    else:
        storage = "sqlite3"
        found, first, last = scan_sqlite3(storage_file)
    topics = list(found.values())
    text = yaml.safe_dump(metadata(storage, storage_file.name, topics, first, last), sort_keys=False)
    tmp = meta_path.with_suffix(".yaml.tmp")
    tmp.write_text(text)
    tmp.replace(meta_path)
    return {"storage": storage, "file": str(storage_file), "message_count": sum(t.count for t in topics),
            "topics": {t.name: t.count for t in topics}, "repaired_bytes_cut": cut}
