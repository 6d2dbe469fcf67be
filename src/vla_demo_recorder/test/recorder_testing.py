"""In-process rclpy helpers for the recorder tests: a private context, an executor, spin-until."""
from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor


class RosHarness:
    """A private rclpy context with one executor; nodes added with `add`."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return condition()

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, client, request, timeout: float = 20.0):
        assert client.wait_for_service(timeout_sec=timeout), f"service {client.srv_name} not available"
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"service {client.srv_name} timed out"
        return future.result()

    def shutdown(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.context)


# -- hand-made bags (rosbags' own CDR serializer; no ROS needed) ------------------------------------
_STORE = None


def typestore():
    """rosbags Jazzy type store plus our vla_interfaces types (from their installed .msg files)."""
    global _STORE
    if _STORE is None:
        from vla_demo_recorder.bag_writer import TypeRegistry

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
    import numpy as np

    ts = typestore()
    msg = ts.types["sensor_msgs/msg/JointState"](
        header=stamp(t_ns), name=list(names), position=np.asarray(positions, dtype=np.float64),
        velocity=np.zeros(0), effort=np.zeros(0))
    return ts.serialize_cdr(msg, "sensor_msgs/msg/JointState")


def image(t_ns: int, pixels, encoding: str = "rgb8", pad: int = 0) -> bytes:
    """An Image message; `pad` extra bytes per row exercise `step`."""
    import numpy as np

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
