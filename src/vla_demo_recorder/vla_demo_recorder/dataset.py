"""Demonstration bags -> demonstrations (joint trajectory + context), plain Python, no rclpy.

Reads rosbag2 MCAP bags from any writer (our recorder, `ros2 bag record`, rosbags, Foxglove): the
mcap library with the mcap-ros2 decoder decodes every message from the schema stored in the file, so
extra topics are simply ignored, optional topics (camera, detections) may be missing, and joint order
is resolved by name. Joint states are resampled to 10 Hz; the episode's context is its first camera
frame (rgb8/bgr8/rgba8/bgra8/mono8 or compressed) and its first detection (top score). A bag without
a usable context is reported with the reason and skipped, never silently used.

Training pairs are made from these demonstrations by `vla_latent_training.pairs`.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from ruamel.yaml import YAML

from vla_demo_recorder.bag_writer import BagError, EpisodeInfo, read_metadata_yaml
from vla_demo_recorder.recover import find_mcap, has_footer

try:
    from vla_common.robot import DQ_MAX, JOINT_NAMES
except ImportError:  # pragma: no cover - the workspace always has it
    JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))
    DQ_MAX = None  # no limit table: the jump check is skipped

RATE_HZ = 10.0
JOINT_STATE_TYPES = ("sensor_msgs/msg/JointState",)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
DETECTION_TYPES = ("vla_interfaces/msg/DetectionArray", "vision_msgs/msg/Detection2DArray")
USABLE_OUTCOMES = ("kept",)
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
    detection: dict | None        # class_id, class_index, score, cx, cy, width, height (pixels)
    image_size: tuple[int, int] | None  # (w, h)
    bag_path: str
    image_error: str = ""         # why first_image is None, when a camera topic was there


# -- message decoding --------------------------------------------------------------------------
def _stamp_ns(msg) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def image_to_rgb(msg, schema: str) -> np.ndarray:
    """sensor_msgs Image/CompressedImage -> (H, W, 3) uint8 RGB; DemoError for other encodings."""
    if schema.endswith("CompressedImage"):
        import cv2

        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DemoError(f"cannot decode compressed image (format {msg.format!r})")
        return np.ascontiguousarray(bgr[:, :, ::-1])
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
    enc = msg.encoding.lower()
    if enc not in channels:
        raise DemoError(f"unsupported image encoding {msg.encoding!r} (rgb8, bgr8, rgba8, bgra8, mono8)")
    h, w, c = int(msg.height), int(msg.width), channels[enc]
    step = int(msg.step) or w * c
    raw = np.frombuffer(bytes(msg.data), np.uint8)
    if h == 0 or w == 0 or step < w * c or raw.size < step * h:
        raise DemoError(f"malformed image: {w}x{h} {enc}, step {step}, {raw.size} bytes")
    img = raw[: step * h].reshape(h, step)[:, : w * c].reshape(h, w, c)
    if enc == "mono8":
        img = np.repeat(img, 3, axis=2)
    elif enc.startswith("bgr"):
        img = img[:, :, 2::-1]
    else:
        img = img[:, :, :3]
    return np.ascontiguousarray(img)


def _class_index(class_id: str, given: int | None) -> int:
    if given is not None and given >= 0:
        return int(given)
    try:
        from vla_common.objects import OBJECT_CLASSES
    except ImportError:
        return -1
    return OBJECT_CLASSES.index(class_id) if class_id in OBJECT_CLASSES else -1


def _detections(msg, schema: str) -> list[dict]:
    """All detections of a vla_interfaces/DetectionArray or vision_msgs/Detection2DArray as dicts."""
    out = []
    if schema.startswith("vla_interfaces"):
        for d in msg.detections:
            out.append({"class_id": d.class_id, "class_index": _class_index(d.class_id, d.class_index),
                        "score": float(d.score), "cx": float(d.center_x), "cy": float(d.center_y),
                        "width": float(d.size_x), "height": float(d.size_y)})
    else:  # vision_msgs/Detection2DArray
        for d in msg.detections:
            c = d.bbox.center.position
            for hyp in d.results:
                h = hyp.hypothesis
                out.append({"class_id": h.class_id, "class_index": _class_index(h.class_id, None),
                            "score": float(h.score), "cx": float(c.x), "cy": float(c.y),
                            "width": float(d.bbox.size_x), "height": float(d.bbox.size_y)})
    return out


def top_detection(msg, schema: str, prefer_class: str | None = None) -> dict | None:
    """The highest-score detection of a detection array, or None when empty. With `prefer_class`
    (the episode's object) the best detection of that class wins when there is one: the context of
    a demonstration is the object it manipulates, even when another object scores higher."""
    dets = _detections(msg, schema)
    preferred = [d for d in dets if prefer_class and d["class_id"] == prefer_class]
    return max(preferred or dets, key=lambda d: d["score"], default=None)


# -- bag reading -------------------------------------------------------------------------------
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
            except Exception:
                return None
    return None


def resample(t: np.ndarray, q: np.ndarray, rate_hz: float = RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of q(t) onto a uniform grid starting at t[0]."""
    grid = np.arange(0.0, t[-1] - t[0] + 1e-9, 1.0 / rate_hz)
    return grid, np.stack([np.interp(grid + t[0], t, q[:, j]) for j in range(q.shape[1])], axis=1)


def load_demo(path: str | Path, task: str | None = None, *, joint_names: Sequence[str] = JOINT_NAMES,
              rate_hz: float = RATE_HZ, context_window_s: float = 2.0,
              include_incomplete: bool = False) -> Demo:
    """Read one demonstration bag (folder or .mcap). Raises DemoError with a clear reason.

    `task` is used when the bag carries no episode metadata (bags from other writers); the context
    (first image / detection) must arrive within `context_window_s` of the first joint state.
    """
    path = Path(path)
    try:
        mcap = find_mcap(path)
    except BagError as err:
        raise DemoError(str(err)) from err
    if not has_footer(mcap):
        raise DemoError(f"incomplete MCAP file (writer killed?); run `vla_demo_recorder recover {path}`")
    names = list(joint_names)
    js_t: list[int] = []
    js_log: list[int] = []
    js_q: list[np.ndarray] = []
    image = image_err = image_size = None
    image_t = det_t = None
    detection = None
    try:
        with mcap.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            episode = _episode_of(mcap.parent, reader)
            if episode is not None and episode.outcome not in USABLE_OUTCOMES and not (
                    include_incomplete and episode.outcome in ("interrupted", "recovered")):
                raise DemoError(f"episode outcome is {episode.outcome!r}"
                                + (f" ({episode.error})" if episode.error else ""))
            prefer = episode.object_class if episode is not None else \
                (task.replace(":", "/").split("/")[0] if task else None)
            stale_before = episode.start_time_ns - int(STALE_FRAME_S * 1e9) \
                if episode is not None and episode.start_time_ns else 0
            summary = reader.get_summary()
            wanted = None if summary is None else [
                c.topic for c in summary.channels.values()
                if summary.schemas[c.schema_id].name in JOINT_STATE_TYPES + IMAGE_TYPES + DETECTION_TYPES]
            for schema, _channel, message, msg in reader.iter_decoded_messages(topics=wanted):
                if schema.name in JOINT_STATE_TYPES:
                    index = {n: i for i, n in enumerate(msg.name)}
                    if not all(n in index for n in names) or len(msg.position) < len(msg.name):
                        continue  # e.g. a gripper-only JointState
                    js_q.append(np.array([msg.position[index[n]] for n in names], dtype=np.float64))
                    js_t.append(_stamp_ns(msg))
                    js_log.append(message.log_time)
                elif schema.name in IMAGE_TYPES and image is None and image_err is None:
                    if stale_before and 0 < _stamp_ns(msg) < stale_before:
                        continue  # queued before the episode started: not this episode's scene
                    try:
                        image = image_to_rgb(msg, schema.name)
                        image_size = (image.shape[1], image.shape[0])
                        image_t = message.log_time
                    except DemoError as err:
                        image_err = str(err)
                elif schema.name in DETECTION_TYPES and detection is None:
                    detection = top_detection(msg, schema.name, prefer_class=prefer)
                    if detection is not None:
                        det_t = message.log_time
                        w, h = getattr(msg, "image_width", 0), getattr(msg, "image_height", 0)
                        if w and h:
                            detection["image_size"] = (int(w), int(h))
    except DemoError:
        raise
    except (McapError, OSError, ValueError, KeyError, EOFError) as err:
        raise DemoError(f"cannot read {mcap}: {type(err).__name__}: {err}") from err

    task = (episode.task if episode is not None else None) or task
    if not task:
        raise DemoError("bag has no episode metadata and no task was given")
    if len(js_q) < 2:
        raise DemoError(f"fewer than 2 joint_states messages with {names[0]}..{names[-1]}")
    stamps = np.array(js_t if all(js_t) else js_log, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps, q = stamps[order], np.stack(js_q)[order]
    keep = np.concatenate([[True], np.diff(stamps) > 0])
    stamps, q = stamps[keep], q[keep]
    if episode is not None:
        stamps, q = _within_episode(stamps, q, episode.start_time_ns)
    t_s = (stamps - stamps[0]) / 1e9
    if len(t_s) < 2:
        raise DemoError("joint_states have no time span")
    grid, q10 = resample(t_s, q, rate_hz)
    start_log = min(js_log)
    if image is not None and (image_t - start_log) / 1e9 > context_window_s:
        image_err = f"first camera frame arrives {(image_t - start_log) / 1e9:.1f} s after the start"
        image = image_size = None
    if detection is not None and (det_t - start_log) / 1e9 > context_window_s:
        detection = None
    if detection is not None:
        det_size = detection.pop("image_size", None)
        image_size = image_size or det_size
    object_class = episode.object_class if episode is not None else task.replace(":", "/").split("/")[0]
    return Demo(task=task, object_class=object_class, t=grid, q=q10, first_image=image,
                detection=detection, image_size=image_size, bag_path=str(mcap.parent),
                image_error=image_err or "")


def _within_episode(stamps: np.ndarray, q: np.ndarray, start_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint states stamped inside the episode, checked for lost messages and jumps.

    States stamped before the start were queued before it (a recorder behind a faster-than-real-time
    simulation receives the previous episode's last states after a reset) and are dropped. The
    bounds apply only when the stamps and the recorder's clock agree (the stamps straddle the start),
    so bags whose writer used another clock are read unchanged. DemoError when states are missing
    (a gap) or jump faster than the arm can move. (A lost tail cannot be told from an early stop:
    `vla_demo_recorder generate` stops only once the recorder has recorded the plan's end.)
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
    if DQ_MAX is None:
        return stamps, q
    steps = np.abs(np.diff(q, axis=0))
    ratio = steps / np.maximum(dt, 1e-6)[:, None] / (MAX_SPEED_SHARE * np.asarray(DQ_MAX)[: q.shape[1]])
    k = int(np.argmax(ratio.max(axis=1)))
    step = steps[k].max()
    if ratio[k].max() > 1.0 and step > 0.01:
        raise DemoError(f"joint positions jump by {step:.2f} rad in {dt[k] * 1e3:.0f} ms at "
                        f"{(stamps[k] - stamps[0]) / 1e9:.1f} s (a scene reset inside the episode?)")
    return stamps, q


def _bag_paths(paths_or_dir: str | Path | Iterable[str | Path]) -> list[Path]:
    items = [paths_or_dir] if isinstance(paths_or_dir, (str, Path)) else list(paths_or_dir)
    out: list[Path] = []
    for item in map(Path, items):
        if item.is_dir() and not (item / "metadata.yaml").exists() and not list(item.glob("*.mcap")):
            out.extend(sorted(p for p in item.iterdir()
                              if p.is_dir() and ((p / "metadata.yaml").exists() or list(p.glob("*.mcap")))))
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
