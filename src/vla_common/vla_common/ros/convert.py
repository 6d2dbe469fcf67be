"""Message converters: plain values and vla_common types to and from ROS messages, in one place."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose

from vla_common.detection import Detection
from vla_interfaces.msg import Detection as DetectionMsg
from vla_interfaces.msg import DetectionArray, SceneObject
from vla_interfaces.srv import ResetScene


def stamp_from_ns(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def ns_from_stamp(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def quat_wxyz_from_matrix(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> unit quaternion (w, x, y, z) (Shepperd's method)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def pose_msg(position, rot: np.ndarray | None = None, quat_wxyz=None) -> Pose:
    """geometry_msgs/Pose from a position and a rotation matrix or a (w, x, y, z) quaternion."""
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    w, x, y, z = quat_wxyz if quat_wxyz is not None else quat_wxyz_from_matrix(rot)
    pose.orientation.w, pose.orientation.x = float(w), float(x)
    pose.orientation.y, pose.orientation.z = float(y), float(z)
    return pose


def detection_to_msg(d: Detection) -> DetectionMsg:
    return DetectionMsg(class_id=d.class_id, class_index=int(d.class_index), score=float(d.score),
                        center_x=float(d.cx), center_y=float(d.cy), size_x=float(d.width),
                        size_y=float(d.height))


def detection_from_msg(m: DetectionMsg) -> Detection:
    return Detection(class_id=m.class_id, score=float(m.score), cx=float(m.center_x), cy=float(m.center_y),
                     width=float(m.size_x), height=float(m.size_y), class_index=int(m.class_index))


def detection_array(detections: Iterable[Detection], header, image_size: tuple[int, int]) -> DetectionArray:
    """vla_interfaces/DetectionArray of one image; the header is the image's (stamp and frame)."""
    msg = DetectionArray(header=header, image_width=int(image_size[0]), image_height=int(image_size[1]))
    msg.detections = [detection_to_msg(d) for d in detections]
    return msg


def detections_from_array(msg: DetectionArray) -> tuple[list[Detection], tuple[int, int]]:
    return [detection_from_msg(d) for d in msg.detections], (int(msg.image_width), int(msg.image_height))


def reset_request(objects: Iterable, positions: Sequence[float]) -> ResetScene.Request:
    """A ~/reset request for this layout (objects with class_id, x, y, yaw, such as ObjectPose) and
    these initial joint positions, not a seeded random one."""
    req = ResetScene.Request(use_seed=False)
    req.objects = [SceneObject(class_id=o.class_id, x=float(o.x), y=float(o.y), yaw=float(o.yaw))
                   for o in objects]
    req.initial_positions = [float(v) for v in positions]
    return req
