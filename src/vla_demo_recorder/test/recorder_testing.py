"""Hand-made bags for the recorder tests (rosbags' own CDR serializer; no ROS needed)."""
from __future__ import annotations

import numpy as np
from vla_demo_recorder.bag_writer import TypeRegistry

_STORE = None


def typestore():
    """rosbags Jazzy type store plus our vla_interfaces types (from their installed .msg files)."""
    global _STORE
    if _STORE is None:
        reg = TypeRegistry()
        reg.definition("vla_interfaces/msg/DetectionArray")
        _STORE = reg._store
    return _STORE


def stamp(t_ns: int):
    ts = typestore()
    return ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
        frame_id="base")


def joint_state(t_ns: int, names, positions) -> bytes:
    ts = typestore()
    msg = ts.types["sensor_msgs/msg/JointState"](
        header=stamp(t_ns), name=list(names), position=np.asarray(positions, dtype=np.float64),
        velocity=np.zeros(0), effort=np.zeros(0))
    return ts.serialize_cdr(msg, "sensor_msgs/msg/JointState")


def image(t_ns: int, pixels, encoding: str = "rgb8", pad: int = 0) -> bytes:
    """An Image message; `pad` extra bytes per row exercise `step`."""
    ts = typestore()
    h, w = pixels.shape[:2]
    rows = pixels.reshape(h, -1)
    data = np.concatenate([rows, np.zeros((h, pad), np.uint8)], axis=1).ravel()
    msg = ts.types["sensor_msgs/msg/Image"](header=stamp(t_ns), height=h, width=w, encoding=encoding,
                                            is_bigendian=0, step=rows.shape[1] + pad, data=data)
    return ts.serialize_cdr(msg, "sensor_msgs/msg/Image")


def detections(t_ns: int, dets, width=640, height=480) -> bytes:
    """dets: list of (class_id, class_index, score, cx, cy, w, h)."""
    ts = typestore()
    det = ts.types["vla_interfaces/msg/Detection"]
    msg = ts.types["vla_interfaces/msg/DetectionArray"](
        header=stamp(t_ns), image_width=width, image_height=height,
        detections=[det(class_id=c, class_index=i, score=s, center_x=x, center_y=y, size_x=w, size_y=h)
                    for c, i, s, x, y, w, h in dets])
    return ts.serialize_cdr(msg, "vla_interfaces/msg/DetectionArray")


def string(text: str) -> bytes:
    ts = typestore()
    return ts.serialize_cdr(ts.types["std_msgs/msg/String"](data=text), "std_msgs/msg/String")
