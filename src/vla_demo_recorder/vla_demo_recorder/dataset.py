"""Demonstration bags -> demonstrations (joint trajectory + context), plain Python, no rclpy.

Reads rosbag2 bags from any writer (our recorder, `ros2 bag record`, rosbags, Foxglove): MCAP with
the mcap library and its mcap-ros2 decoder, sqlite3 (.db3) with rosbags, each decoding messages from
the definitions stored in the bag, so extra topics are simply ignored, optional topics (camera,
detections) may be missing, and joint order is resolved by name. Joint states are resampled to
10 Hz; the episode's context is its first camera frame (any encoding `vla_common.image_convert`
reads, or compressed) and its first detection (top score, the episode's object preferred). A bag
without a usable context is reported with the reason and skipped, never silently used.

Training pairs are made from these demonstrations by `vla_latent_training.pairs`.
"""
from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML
from vla_common.detection import Detection, best
from vla_common.image_convert import UnsupportedImageError, to_rgb
from vla_common.objects import OBJECT_CLASSES
from vla_common.robot import DQ_MAX, HAND, JOINT_NAMES

from vla_demo_recorder.bag_files import DATA_SUFFIXES, bag_file, has_footer, storage_of
from vla_demo_recorder.bag_writer import BagError, EpisodeInfo, object_class_of, read_metadata_yaml

RATE_HZ = 10.0
JOINT_STATE_TYPES = ("sensor_msgs/msg/JointState",)
FINGER_JOINTS = HAND.finger_joints
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
DETECTION_TYPES = ("vla_interfaces/msg/DetectionArray", "vision_msgs/msg/Detection2DArray")
USABLE_OUTCOMES = ("kept",)
# Demonstrations that may end before the task did: used only when asked (include_incomplete).
INCOMPLETE_OUTCOMES = {
    "recovered": "the file was cut short and `recover` kept its complete chunks, so the demonstration "
                 "may end early",
    "interrupted": "the recorder shut down during the episode",
}
# A camera frame stamped this long before the episode start was queued before it: never the context.
STALE_FRAME_S = 1.0
# Joint-state checks: a longer silence means lost messages (resampling would invent a straight line),
# a faster move than this share of the Panda's velocity limit is a jump (e.g. a scene reset).
MAX_STATE_GAP_S = 0.5
MAX_SPEED_SHARE = 1.5


class DemoError(ValueError):
    """A bag that cannot serve as a demonstration; the message says why."""


@dataclass
class Demo:
    task: str
    object_class: str
    t: np.ndarray                 # (T,) seconds from the first joint state, 10 Hz
    q: np.ndarray                 # (T, 7) joint positions in JOINT_NAMES order
    first_image: np.ndarray | None  # (H, W, 3) uint8 RGB
    detection: Detection | None   # box in pixels of an image of image_size
    image_size: tuple[int, int] | None  # (w, h)
    bag_path: str
    image_error: str = ""         # why first_image is None, when a camera topic was there
    outcome: str = ""             # the episode's outcome ("kept", "recovered", ...); "": no episode metadata
    # the hand: the gap between the fingers (m) on the same 10 Hz grid (NaN where joint_states had no
    # finger joints), and the grasp events from gripper/status: (t s, state code, what it holds), one
    # per change of state
    hand: np.ndarray | None = None
    grasp_events: list[tuple[float, int, str]] = field(default_factory=list)


# -- message decoding --------------------------------------------------------------------------
def _stamp_ns(msg) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def image_to_rgb(msg, schema: str) -> np.ndarray:
    """sensor_msgs Image/CompressedImage -> (H, W, 3) uint8 RGB; DemoError when it cannot be read."""
    if schema.endswith("CompressedImage"):
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DemoError(f"cannot decode compressed image (format {msg.format!r})")
        return np.ascontiguousarray(bgr[:, :, ::-1])
    try:
        return to_rgb(msg.encoding, int(msg.width), int(msg.height), int(msg.step), bytes(msg.data),
                      bool(getattr(msg, "is_bigendian", False)))
    except UnsupportedImageError as err:
        raise DemoError(f"camera image: {err}") from err


def _class_index(class_id: str, given: int | None) -> int:
    if given is not None and given >= 0:
        return int(given)
    return OBJECT_CLASSES.index(class_id) if class_id in OBJECT_CLASSES else -1


def _detections(msg, schema: str) -> list[Detection]:
    """All detections of a vla_interfaces/DetectionArray or vision_msgs/Detection2DArray."""
    if schema.startswith("vla_interfaces"):
        return [Detection(d.class_id, float(d.score), float(d.center_x), float(d.center_y),
                          float(d.size_x), float(d.size_y), _class_index(d.class_id, d.class_index))
                for d in msg.detections]
    out = []  # vision_msgs/Detection2DArray: one Detection per hypothesis
    for d in msg.detections:
        c = d.bbox.center.position
        for hyp in d.results:
            h = hyp.hypothesis
            out.append(Detection(h.class_id, float(h.score), float(c.x), float(c.y), float(d.bbox.size_x),
                                 float(d.bbox.size_y), _class_index(h.class_id, None)))
    return out


def top_detection(msg, schema: str, prefer_class: str | None = None) -> Detection | None:
    """The highest-score detection of a detection array, or None when empty. With `prefer_class`
    (the episode's object) the best detection of that class wins when there is one: the context of
    a demonstration is the object it manipulates, even when another object scores higher."""
    return best(_detections(msg, schema), prefer_class)


# -- bag reading -------------------------------------------------------------------------------
GRIPPER_STATUS_TYPES = ("vla_interfaces/msg/GripperStatus",)
_WANTED_TYPES = JOINT_STATE_TYPES + IMAGE_TYPES + DETECTION_TYPES + GRIPPER_STATUS_TYPES
_READ_ERRORS = (McapError, OSError, ValueError, KeyError, EOFError, AnyReaderError, sqlite3.Error)


def _episode_of(bag_dir: Path, reader) -> EpisodeInfo | None:
    try:
        return EpisodeInfo.from_custom_data(read_metadata_yaml(bag_dir).get("custom_data"))
    except BagError:
        pass
    for record in reader.iter_metadata():  # a bare .mcap: rosbag2's serialized metadata record
        if record.name == "rosbag2" and "serialized_metadata" in record.metadata:
            try:
                meta = YAML(typ="safe").load(record.metadata["serialized_metadata"])
                return EpisodeInfo.from_custom_data(meta.get("custom_data"))
            except Exception:  # garbled metadata from another writer: read it as a bag without any
                return None
    return None


@contextmanager
def _mcap_bag(mcap: Path) -> Iterator[tuple[EpisodeInfo | None, Iterator[tuple[str, int, object]]]]:
    """(episode metadata, messages as (schema name, log time ns, decoded message)) of an MCAP file."""
    with mcap.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        episode = _episode_of(mcap.parent, reader)
        summary = reader.get_summary()
        wanted = None if summary is None else [
            c.topic for c in summary.channels.values() if summary.schemas[c.schema_id].name in _WANTED_TYPES]
        yield episode, ((schema.name, message.log_time, msg)
                        for schema, _channel, message, msg in reader.iter_decoded_messages(topics=wanted))


@contextmanager
def _rosbag2_bag(file: Path) -> Iterator[tuple[EpisodeInfo | None, Iterator[tuple[str, int, object]]]]:
    """The same for a sqlite3 (.db3) bag, read with rosbags: types from the bag's own message
    definitions, else rosbags' Jazzy type store."""
    try:
        episode = EpisodeInfo.from_custom_data(read_metadata_yaml(file.parent).get("custom_data"))
        source = file.parent
    except BagError:
        episode, source = None, file
    with AnyReader([source], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        wanted = [c for c in reader.connections if c.msgtype in _WANTED_TYPES]
        yield episode, ((c.msgtype, t, reader.deserialize(raw, c.msgtype))
                        for c, t, raw in reader.messages(connections=wanted))


@dataclass
class _Scan:
    """What a demonstration needs from a bag's messages, gathered in one pass."""

    names: list[str]
    prefer: str | None = None     # the episode's object: its detection wins
    stale_before: int = 0         # frames stamped before this (ns) belong to an earlier scene
    js_t: list[int] = field(default_factory=list)
    js_log: list[int] = field(default_factory=list)
    js_q: list[np.ndarray] = field(default_factory=list)
    js_hand: list[float] = field(default_factory=list)
    grasp: list[tuple[int, int, str]] = field(default_factory=list)   # (stamp ns, state, holding)
    image: np.ndarray | None = None
    image_err: str = ""
    image_t: int = 0              # its log time (ns) ...
    image_stamp: int = 0          # ... and its header's stamp (0: none)
    detection: Detection | None = None
    det_t: int = 0
    det_stamp: int = 0
    det_size: tuple[int, int] | None = None

    def add(self, schema: str, log_time: int, msg) -> None:
        if schema in JOINT_STATE_TYPES:
            self._joint_state(log_time, msg)
        elif schema in IMAGE_TYPES and self.image is None and not self.image_err:
            self._image(schema, log_time, msg)
        elif schema in DETECTION_TYPES and self.detection is None:
            self._detection(schema, log_time, msg)
        elif schema in GRIPPER_STATUS_TYPES and (not self.grasp or self.grasp[-1][1] != msg.state):
            self.grasp.append((_stamp_ns(msg) or log_time, int(msg.state), str(msg.holding)))

    def _joint_state(self, log_time: int, msg) -> None:
        index = {n: i for i, n in enumerate(msg.name)}
        if not all(n in index for n in self.names) or len(msg.position) < len(msg.name):
            return  # e.g. a gripper-only JointState
        self.js_q.append(np.array([msg.position[index[n]] for n in self.names], dtype=np.float64))
        fingers = [index.get(n) for n in FINGER_JOINTS]
        self.js_hand.append(sum(msg.position[i] for i in fingers) if None not in fingers else np.nan)
        self.js_t.append(_stamp_ns(msg))
        self.js_log.append(log_time)

    def _image(self, schema: str, log_time: int, msg) -> None:
        if self.stale_before and 0 < _stamp_ns(msg) < self.stale_before:
            return  # queued before the episode started: not this episode's scene
        try:
            self.image = image_to_rgb(msg, schema)
            self.image_t, self.image_stamp = log_time, _stamp_ns(msg)
        except DemoError as err:
            self.image_err = str(err)

    def _detection(self, schema: str, log_time: int, msg) -> None:
        self.detection = top_detection(msg, schema, prefer_class=self.prefer)
        if self.detection is not None:
            self.det_t, self.det_stamp = log_time, _stamp_ns(msg)
            w, h = getattr(msg, "image_width", 0), getattr(msg, "image_height", 0)
            self.det_size = (int(w), int(h)) if w and h else None


def _after_start(scan: _Scan, stamp: int, log_time: int) -> float:
    """Seconds from the first joint state to a context message: by the headers' stamps where both have
    one (the time of the scene it shows; in a lockstep recording, simulated time), else by the bag's
    log times. Log times are when the recorder got round to a message: generated at real-time factor 0
    beside two busy loops, a detection of the frame at the start came later than the window by them,
    and the bag was refused while another run's was kept (test_generate.py in a clean clone)."""
    if stamp > 0 and all(scan.js_t):
        return (stamp - min(scan.js_t)) / 1e9
    return (log_time - min(scan.js_log)) / 1e9


def resample(t: np.ndarray, q: np.ndarray, rate_hz: float = RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of q(t) onto a uniform grid starting at t[0]."""
    grid = np.arange(0.0, t[-1] - t[0] + 1e-9, 1.0 / rate_hz)
    return grid, np.stack([np.interp(grid + t[0], t, q[:, j]) for j in range(q.shape[1])], axis=1)


def load_demo(path: str | Path, task: str | None = None, *, joint_names: Sequence[str] = JOINT_NAMES,
              rate_hz: float = RATE_HZ, context_window_s: float = 2.0,
              include_incomplete: bool = False) -> Demo:
    """Read one demonstration bag (folder, .mcap or .db3 file; MCAP or sqlite3 storage). Raises
    DemoError with a clear reason.

    `task` is used when the bag carries no episode metadata (bags from other writers) or its task is
    empty (another writer's bag after `recover`); the context (first image / detection) must arrive
    within `context_window_s` of the first joint state. Only `kept` episodes (and bags without
    episode metadata) load; with `include_incomplete` also `recovered` and `interrupted` ones, which
    may end before the task did.
    """
    path = Path(path)
    file, open_bag = _opener(path)
    try:
        with open_bag(file) as (episode, messages):
            _check_outcome(episode, include_incomplete)
            scan = _Scan(list(joint_names))
            if episode is not None:
                scan.stale_before = max(0, episode.start_time_ns - int(STALE_FRAME_S * 1e9)) \
                    if episode.start_time_ns else 0
            scan.prefer = (episode.object_class if episode is not None else "") or \
                (object_class_of(task) if task else None)
            for schema, log_time, msg in messages:
                scan.add(schema, log_time, msg)
    except DemoError:
        raise
    except _READ_ERRORS as err:
        raise DemoError(f"cannot read {file}: {type(err).__name__}: {err}") from err
    task = (episode.task if episode is not None else None) or (task or "").strip().replace(":", "/")
    if not task:
        raise DemoError("bag has no episode metadata and no task was given")
    return _demo_of(scan, episode, task, str(file.parent), rate_hz, context_window_s)


def _opener(path: Path):
    """(data file, reader for its storage); DemoError saying what the file is when it is unusable."""
    try:
        file = bag_file(path)
        kind = storage_of(file)
    except (BagError, OSError) as err:
        raise DemoError(str(err)) from err
    if kind == "sqlite3":
        return file, _rosbag2_bag
    if kind != "mcap":
        raise DemoError(f"{file} is neither an MCAP nor a sqlite3 rosbag2 file")
    if not has_footer(file):
        raise DemoError(f"incomplete MCAP file (writer killed?); run `vla_demo_recorder recover {path}`")
    return file, _mcap_bag


def _check_outcome(episode: EpisodeInfo | None, include_incomplete: bool) -> None:
    if episode is None or episode.outcome in USABLE_OUTCOMES:
        return
    if include_incomplete and episode.outcome in INCOMPLETE_OUTCOMES:
        return
    reason = f" ({episode.error})" if episode.error else ""
    if episode.outcome in INCOMPLETE_OUTCOMES:
        why = INCOMPLETE_OUTCOMES[episode.outcome]
        raise DemoError(f"episode outcome is {episode.outcome!r}{reason}: {why}; left out "
                        "(include_incomplete, --include-incomplete, uses it)")
    raise DemoError(f"episode outcome is {episode.outcome!r}{reason}")


def _demo_of(scan: _Scan, episode: EpisodeInfo | None, task: str, bag_path: str, rate_hz: float,
             context_window_s: float) -> Demo:
    """The 10 Hz trajectory and the context that arrived near its start."""
    names = scan.names
    if len(scan.js_q) < 2:
        raise DemoError(f"fewer than 2 joint_states messages with {names[0]}..{names[-1]}")
    stamps = np.array(scan.js_t if all(scan.js_t) else scan.js_log, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    hand_column = np.array(scan.js_hand, dtype=np.float64)[:, None]
    stamps, q = stamps[order], np.hstack([np.stack(scan.js_q), hand_column])[order]
    keep = np.concatenate([[True], np.diff(stamps) > 0])
    stamps, q = stamps[keep], q[keep]
    if episode is not None:
        stamps, q = _within_episode(stamps, q, episode.start_time_ns)
    t_s = (stamps - stamps[0]) / 1e9
    if len(t_s) < 2:
        raise DemoError("joint_states have no time span")
    grid, q10 = resample(t_s, q, rate_hz)
    q10, hand = q10[:, :-1], q10[:, -1]
    t_first = int(stamps[0])
    events = [((ns - t_first) / 1e9, state, holding) for ns, state, holding in scan.grasp if ns >= t_first]
    image, image_err = scan.image, scan.image_err
    image_late = _after_start(scan, scan.image_stamp, scan.image_t) if image is not None else 0.0
    if image_late > context_window_s:
        image_err = f"first camera frame arrives {image_late:.1f} s after the start"
        image = None
    detection = scan.detection
    if detection is not None and _after_start(scan, scan.det_stamp, scan.det_t) > context_window_s:
        detection = None
    image_size = (image.shape[1], image.shape[0]) if image is not None else None
    if detection is not None:
        image_size = image_size or scan.det_size
    object_class = episode.object_class if episode is not None else object_class_of(task)
    return Demo(task=task, object_class=object_class, t=grid, q=q10, first_image=image,
                detection=detection, image_size=image_size, bag_path=bag_path, image_error=image_err,
                outcome=episode.outcome if episode is not None else "",
                hand=None if np.all(np.isnan(hand)) else hand, grasp_events=events)


def _within_episode(stamps: np.ndarray, q: np.ndarray, start_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint states stamped inside the episode, checked for lost messages and jumps.

    States stamped before the start were queued before it (a recorder behind a faster-than-real-time
    simulation receives the previous episode's last states after a reset) and are dropped. The
    bounds apply only when the stamps and the recorder's clock agree (the stamps straddle the start),
    so bags whose writer used another clock are read unchanged. DemoError when states are missing
    (a gap) or jump faster than the arm can move. (A lost tail cannot be told from an early stop:
    `vla_evaluation generate` stops only once the recorder has recorded the plan's end.)
    """
    same_clock = bool(start_ns) and stamps[0] - 60e9 < start_ns <= stamps[-1]
    if same_clock:
        inside = stamps >= start_ns
        stamps, q = stamps[inside], q[inside]
    if len(stamps) < 2:
        raise DemoError("fewer than 2 joint_states messages inside the episode")
    dt = np.diff(stamps) / 1e9
    i = int(np.argmax(dt))
    if dt[i] > MAX_STATE_GAP_S:
        at = (stamps[i] - stamps[0]) / 1e9
        raise DemoError(f"joint_states are missing for {dt[i]:.2f} s at {at:.1f} s into the episode "
                        "(messages lost while recording)")
    arm = q[:, :min(q.shape[1], len(DQ_MAX))]          # (a last column may be the hand's gap)
    steps = np.abs(np.diff(arm, axis=0))
    ratio = steps / np.maximum(dt, 1e-6)[:, None] / (MAX_SPEED_SHARE * np.asarray(DQ_MAX)[: arm.shape[1]])
    k = int(np.argmax(ratio.max(axis=1)))
    step = steps[k].max()
    if ratio[k].max() > 1.0 and step > 0.01:
        raise DemoError(f"joint positions jump by {step:.2f} rad in {dt[k] * 1e3:.0f} ms at "
                        f"{(stamps[k] - stamps[0]) / 1e9:.1f} s (a scene reset inside the episode?)")
    return stamps, q


def _is_bag_dir(path: Path) -> bool:
    return (path / "metadata.yaml").exists() or any(p.suffix in DATA_SUFFIXES for p in path.iterdir())


def _bag_paths(paths_or_dir: str | Path | Iterable[str | Path]) -> list[Path]:
    items = [paths_or_dir] if isinstance(paths_or_dir, (str, Path)) else list(paths_or_dir)
    out: list[Path] = []
    for item in map(Path, items):
        if item.is_dir() and not _is_bag_dir(item):
            out.extend(sorted(p for p in item.iterdir() if p.is_dir() and _is_bag_dir(p)))
        else:
            out.append(item)
    return out


def load_demos(paths_or_dir, require: str | None = None,
               **kwargs) -> tuple[list[Demo], list[tuple[str, str]]]:
    """Load every bag (a folder of bags, bag folders or .mcap files).

    require: "image" (first camera frame needed), "detection" (a detection needed) or None (either
    one). Returns (demos, skipped) with skipped = [(path, reason)]; nothing unusable is kept silently.
    """
    if require not in (None, "image", "detection"):
        raise ValueError(f"require must be 'image', 'detection' or None, got {require!r}")
    demos: list[Demo] = []
    skipped: list[tuple[str, str]] = []
    for path in _bag_paths(paths_or_dir):
        try:
            demo = load_demo(path, **kwargs)
        except DemoError as err:
            skipped.append((str(path), str(err)))
            continue
        image_reason = demo.image_error or "no camera frame"
        if require == "image" and demo.first_image is None:
            skipped.append((str(path), f"no usable context image: {image_reason}"))
        elif require == "detection" and demo.detection is None:
            skipped.append((str(path), "no usable context: no detection near the start of the episode"))
        elif require is None and demo.first_image is None and demo.detection is None:
            skipped.append((str(path), f"no usable context frame: {image_reason}, no detection"))
        else:
            demos.append(demo)
    return demos, skipped
