"""One rosbag2 bag (folder with metadata.yaml version 9 + an MCAP file) per episode.

Written with rosbags' rosbag2 Writer (storage MCAP): it produces the `ros2msg` schemas, `cdr` channels,
`offered_qos_profiles` channel metadata, type hashes and metadata.yaml exactly as rosbag2 does. We add
what a demonstration recorder needs on top:

- a time-based flush: the pending MCAP chunk is closed and written (and fsynced) at least every
  `flush_period_s`, so a killed writer leaves only complete chunks behind (see recover.py);
- an interim metadata.yaml written at open (and on every new topic) that already holds the episode
  metadata and topic list, so a crashed episode keeps its task and types;
- episode metadata (task, object class, index, start/end time, outcome, note) in metadata.yaml
  `custom_data` and, through rosbags, in the MCAP `rosbag2` metadata record;
- clear errors: an unwritable output folder raises BagError, a full disk raises BagWriteError and
  leaves the file with every chunk flushed so far.

Messages arrive already CDR-serialized (raw subscriptions / rclpy.serialization); nothing here
serializes by hand. No rclpy import: this module is used by the node, the tests and the tools.
"""
from __future__ import annotations

import errno
import os
import time
from dataclasses import asdict, dataclass, field, fields
from io import StringIO
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from ruamel.yaml import YAML

ROSBAG2_VERSION = 9
EPISODE_PREFIX = "episode."
OUTCOMES = ("recording", "kept", "discarded", "failed", "interrupted", "recovered")


class BagError(RuntimeError):
    """The bag cannot be created or used (bad folder, existing path, unknown type)."""


class BagExistsError(BagError):
    """The bag's folder exists already (another recorder may have just created it)."""


class BagWriteError(BagError):
    """Writing failed mid-episode (e.g. disk full); everything flushed before stays readable."""


def normalize_type(msgtype: str) -> str:
    """`sensor_msgs/JointState` or `sensor_msgs/msg/JointState` -> `sensor_msgs/msg/JointState`."""
    parts = msgtype.strip().split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise BagError(f"malformed message type {msgtype!r}; expected 'pkg/msg/Type'")
    return "/".join(parts)


def object_class_of(task: str) -> str:
    """`bread/push_east` or `bread:push_east` -> `bread`."""
    return task.replace(":", "/").split("/", 1)[0].strip()


@dataclass
class EpisodeInfo:
    """Episode metadata stored in the bag (metadata.yaml custom_data, keys prefixed `episode.`)."""

    task: str
    object_class: str = ""
    index: int = 0
    start_time_ns: int = 0
    end_time_ns: int = 0
    outcome: str = "recording"
    note: str = ""
    error: str = ""
    messages_dropped: int = 0
    extra: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.object_class:
            self.object_class = object_class_of(self.task)

    def to_custom_data(self) -> dict[str, str]:
        data = {EPISODE_PREFIX + k: str(v) for k, v in asdict(self).items() if k != "extra"}
        data.update({EPISODE_PREFIX + k: str(v) for k, v in self.extra.items()})
        return data

    @classmethod
    def from_custom_data(cls, custom: dict[str, str] | None) -> EpisodeInfo | None:
        """Parse custom_data; None when the bag has no episode metadata (other writers)."""
        if not custom or EPISODE_PREFIX + "task" not in custom:
            return None
        own = {k[len(EPISODE_PREFIX):]: v for k, v in custom.items() if k.startswith(EPISODE_PREFIX)}
        kwargs: dict = {}
        for f in fields(cls):
            if f.name == "extra" or f.name not in own:
                continue
            value = own.pop(f.name)
            kwargs[f.name] = int(value) if f.type in ("int", int) else value
        return cls(**kwargs, extra=own)


def make_qos(reliability: str = "reliable", durability: str = "volatile", depth: int = 10,
             history: str = "keep_last") -> Qos:
    """A rosbags QoS profile from plain names (what a publisher offered)."""
    zero = QosTime(0, 0)
    return Qos(QosHistory[history.upper()], int(depth), QosReliability[reliability.upper()],
               QosDurability[durability.upper()], zero, zero, QosLiveliness.AUTOMATIC, zero, False)


class TypeRegistry:
    """Message definitions (`ros2msg` text with dependencies) and RIHS01 hashes by type name.

    Standard types come from rosbags' Jazzy type store; others (our vla_interfaces, anything else
    installed) are parsed from their installed `share/<pkg>/msg/<Type>.msg` files found via the
    ament index, dependencies included.
    """

    def __init__(self) -> None:
        self._store = get_typestore(Stores.ROS2_JAZZY)

    def _msg_file(self, msgtype: str) -> Path:
        pkg, _, name = msgtype.split("/")
        try:
            path = Path(get_package_share_directory(pkg)) / "msg" / f"{name}.msg"
        except PackageNotFoundError as err:
            raise BagError(f"unknown message type {msgtype}: package {pkg!r} is not installed") from err
        if not path.is_file():
            raise BagError(f"unknown message type {msgtype}: {path} does not exist")
        return path

    def _ensure(self, msgtype: str, seen: set[str]) -> None:
        if msgtype in self._store.fielddefs or msgtype in seen:
            return
        seen.add(msgtype)
        types = get_types_from_msg(self._msg_file(msgtype).read_text(), msgtype)
        for _name, (_consts, flds) in types.items():
            for _fname, desc in flds:
                for nested in _nested_types(desc):
                    self._ensure(nested, seen)
        self._store.register(types)

    def definition(self, msgtype: str) -> tuple[str, str]:
        """(msgdef, rihs01) of a type, loading its definition if needed."""
        msgtype = normalize_type(msgtype)
        self._ensure(msgtype, set())
        msgdef, _ = self._store.generate_msgdef(msgtype, ros_version=2)
        return msgdef, self._store.hash_rihs01(msgtype)


def _nested_types(desc) -> list[str]:
    """Type names referenced by a rosbags field description (NAME, or SEQUENCE/ARRAY of NAME)."""
    kind, detail = desc
    if kind.name == "NAME":
        return [detail]
    if kind.name in ("ARRAY", "SEQUENCE"):
        return _nested_types(detail[0])
    return []


class _FlushingMcapStorage(McapWriter):
    """rosbags' MCAP storage plus `flush()`: close the pending chunk, write it out, fsync."""

    def flush(self, fsync: bool = True) -> None:
        if self.chunk.msgs:
            self.close_chunk()
        self.bio.flush()
        if fsync:
            os.fsync(self.bio.fileno())

    def abort(self) -> None:
        """Drop the pending chunk; keep the complete chunks already on disk."""
        try:
            self.bio.close()
        except OSError:
            pass


class _Rosbag2Writer(Writer):
    STORAGE_PLUGINS = {StoragePlugin.MCAP: _FlushingMcapStorage}


def _metadata_dict(mcap_name: str, topics: list[dict], custom: dict[str, str],
                   start_ns: int, end_ns: int, total: int) -> dict:
    """rosbag2 metadata.yaml (version 9) contents, the same keys rosbags and rosbag2 write."""
    duration = max(0, end_ns - start_ns) if total else 0
    start = start_ns if total else 0
    return {"rosbag2_bagfile_information": {
        "version": ROSBAG2_VERSION,
        "storage_identifier": "mcap",
        "relative_file_paths": [mcap_name],
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total,
        "topics_with_message_count": topics,
        "compression_format": "",
        "compression_mode": "",
        "files": [{"path": mcap_name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": total}],
        "custom_data": dict(custom) or None,
        "ros_distro": "rosbags",
    }}


def write_metadata_yaml(path: Path, metadata: dict) -> None:
    """Atomically replace `path/metadata.yaml`."""
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    text = StringIO()
    yaml.dump(metadata, text)
    tmp = path / "metadata.yaml.tmp"
    tmp.write_text(text.getvalue(), "utf8")
    tmp.replace(path / "metadata.yaml")


def read_metadata_yaml(path: Path) -> dict:
    """The `rosbag2_bagfile_information` mapping of a bag folder (BagError if absent/garbled)."""
    file = Path(path) / "metadata.yaml"
    try:
        data = YAML(typ="safe").load(file.read_text())
        return data["rosbag2_bagfile_information"]
    except FileNotFoundError as err:
        raise BagError(f"{file} does not exist") from err
    except Exception as err:
        raise BagError(f"{file} is not rosbag2 metadata: {err}") from err


class BagWriter:
    """Writes one episode's bag. Not thread-safe: use it from one thread (the node's writer thread).

    `open()` raises BagError (folder not creatable/writable, path exists); `write()`/`flush()` raise
    BagWriteError on I/O errors (disk full), after which the writer is closed for good.
    """

    def __init__(self, path: str | Path, episode: EpisodeInfo | None = None, *,
                 flush_period_s: float = 1.0, fsync: bool = True,
                 registry: TypeRegistry | None = None) -> None:
        if not 0.0 < flush_period_s <= 1.0:
            raise BagError(f"flush_period_s must be in (0, 1] s, got {flush_period_s}")
        self.path = Path(path).expanduser().absolute()
        self.episode = episode
        self.flush_period_s = flush_period_s
        self.fsync = fsync
        self.registry = registry or TypeRegistry()
        self._writer: _Rosbag2Writer | None = None
        self._connections: dict[str, object] = {}
        self._topic_meta: dict[str, dict] = {}
        self.counts: dict[str, int] = {}
        self.message_count = 0
        self.bytes_written = 0
        self.first_ns = 0
        self.last_ns = 0
        self._last_flush = time.monotonic()
        self._unflushed = 0
        self.error = ""
        self.closed = False

    # -- lifecycle -----------------------------------------------------------------------------
    def open(self) -> BagWriter:
        parent = self.path.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise BagError(f"cannot create output folder {parent}: {err.strerror or err}") from err
        if not parent.is_dir():
            raise BagError(f"output folder {parent} is not a directory")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise BagError(f"output folder {parent} is not writable")
        exists = BagExistsError(f"{self.path} exists already; episode folders are never overwritten")
        if self.path.exists():
            raise exists
        try:  # the folder is created by one mkdir: of two writers racing for a name, one gets it
            writer = _Rosbag2Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
            writer.open()
        except (OSError, WriterError) as err:
            if isinstance(err, FileExistsError) or (isinstance(err, WriterError) and "exists" in str(err)):
                raise exists from err
            raise BagError(f"cannot create bag {self.path}: {_reason(err)}") from err
        self._writer = writer
        try:
            self._write_interim_metadata()
        except OSError as err:
            self._fail(err)
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.closed:
            return
        if exc_type is None:
            self.close()
        else:
            self.abort(f"{exc_type.__name__}: {exc}")

    @property
    def mcap_path(self) -> Path:
        return self.path / f"{self.path.name}.mcap"

    # -- topics and messages ---------------------------------------------------------------------
    def has_topic(self, topic: str) -> bool:
        return topic in self._connections

    def add_topic(self, topic: str, msgtype: str, qos: list[Qos] | tuple[Qos, ...] = (),
                  definition: tuple[str, str] | None = None) -> None:
        """Register a topic. Its type is resolved by name (BagError when unknown) unless
        `definition` = (msgdef, rihs01) is given (recovery copies them from the old file)."""
        writer = self._require_open()
        if topic in self._connections:
            return
        msgtype = normalize_type(msgtype)
        msgdef, rihs01 = definition or self.registry.definition(msgtype)
        conn = writer.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01,
                                     offered_qos_profiles=list(qos))
        self._connections[topic] = conn
        self.counts[topic] = 0
        self._topic_meta[topic] = {"name": topic, "type": msgtype, "serialization_format": "cdr",
                                   "offered_qos_profiles": dump_qos_v9(list(qos)),
                                   "type_description_hash": rihs01}
        try:
            self._write_interim_metadata()
        except OSError as err:
            self._fail(err)

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Append one CDR-serialized message (receive time `timestamp_ns`)."""
        writer = self._require_open()
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f"topic {topic!r} was not added to {self.path}")
        try:
            writer.write(conn, int(timestamp_ns), data)
        except OSError as err:
            self._fail(err)
        if not self.message_count:
            self.first_ns = timestamp_ns
        self.first_ns = min(self.first_ns, timestamp_ns)
        self.last_ns = max(self.last_ns, timestamp_ns)
        self.message_count += 1
        self.counts[topic] += 1
        self.bytes_written += len(data)
        self._unflushed += 1
        self.maybe_flush()

    def maybe_flush(self) -> bool:
        """Flush if the last flush is older than `flush_period_s`; True if it flushed."""
        if self._writer is None or not self._unflushed:
            return False
        if time.monotonic() - self._last_flush < self.flush_period_s:
            return False
        self.flush()
        return True

    def flush(self) -> None:
        """Write the pending chunk as a complete MCAP chunk and fsync it."""
        writer = self._require_open()
        try:
            writer.storage.flush(self.fsync)
        except OSError as err:
            self._fail(err)
        self._unflushed = 0
        self._last_flush = time.monotonic()

    def close(self, outcome: str = "kept", end_time_ns: int | None = None, error: str = "") -> Path:
        """Finish the MCAP (summary, footer) and write the final metadata.yaml."""
        writer = self._require_open()
        if outcome not in OUTCOMES:
            raise BagError(f"unknown outcome {outcome!r}; one of {OUTCOMES}")
        if self.episode is not None:
            self.episode.outcome = outcome
            self.episode.end_time_ns = int(end_time_ns if end_time_ns is not None else time.time_ns())
            self.episode.error = error or self.episode.error
            for key, value in self.episode.to_custom_data().items():
                writer.set_custom_data(key, value)
        try:
            writer.close()
        except OSError as err:
            self._fail(err)
        self._writer = None
        self.closed = True
        return self.path

    def abort(self, error: str = "") -> None:
        """Stop without a footer (e.g. after an I/O error); flushed chunks stay recoverable."""
        self.error = error or self.error
        writer, self._writer = self._writer, None
        self.closed = True
        if writer is None:  # never opened (or already closed): the folder is not ours to touch
            return
        writer.abort()
        if self.episode is not None and self.error:
            self.episode.outcome, self.episode.error = "failed", self.error
            try:  # best effort: the disk may be full; recover.py regenerates it anyway
                self._write_interim_metadata()
            except OSError:
                pass

    # -- helpers -------------------------------------------------------------------------------
    def _require_open(self) -> _Rosbag2Writer:
        if self._writer is None:
            raise BagError(f"bag {self.path} is not open" + (f" ({self.error})" if self.error else ""))
        return self._writer

    def _fail(self, err: OSError) -> None:
        if err.errno == errno.ENOSPC:
            message = (f"disk full while writing {self.path}; the chunks flushed before are kept "
                       f"(`vla_demo_recorder recover` makes them readable once there is space)")
        else:
            message = f"I/O error while writing {self.path}: {_reason(err)}"
        self.abort(message)
        raise BagWriteError(message) from err

    def _write_interim_metadata(self) -> None:
        custom = self.episode.to_custom_data() if self.episode else {}
        topics = [{"topic_metadata": meta, "message_count": 0} for meta in self._topic_meta.values()]
        write_metadata_yaml(self.path, _metadata_dict(self.mcap_path.name, topics, custom, 0, 0, 0))


def _reason(err: BaseException) -> str:
    if isinstance(err, OSError) and err.strerror:
        return f"{err.strerror} ({err.filename or ''})".replace(" ()", "")
    return str(err)
