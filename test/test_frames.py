"""Every frame id our nodes stamp belongs to one TF tree (the Panda URDF's links plus the camera, whose
pose is data), the camera's static transform is the pose the simulator renders from, and the URDF is
on /robot_description for a subscriber that comes late (transient local)."""
from pathlib import Path

import numpy as np
import rclpy
from std_msgs.msg import String
from vla_camera.camera_node import PARAMS as CAMERA_PARAMS
from vla_common.camera_model import CAMERA_FRAME_ID, SIM_WEBCAM, look_at_rotation
from vla_common.frames import BASE_FRAME, camera_transform, tree_frames
from vla_common.kinematics import panda_urdf_path
from vla_common.robot import ROBOTS
from vla_common.ros.description import QOS, TOPIC, publish_robot_description
from vla_common.ros.testing import RosHarness

from vla_latent_controller import controller_node

ROOT = Path(__file__).resolve().parents[1]
POSE = ROOT / "src" / "vla_bringup" / "config" / "camera_pose.yaml"


def rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_camera_pose_is_data_and_matches_the_rendered_camera():
    t = camera_transform(POSE)
    assert (t.parent, t.child) == (BASE_FRAME, CAMERA_FRAME_ID)
    assert t == camera_transform(None)  # the shipped file is the simulated webcam
    want = look_at_rotation(SIM_WEBCAM.position, SIM_WEBCAM.look_at)
    np.testing.assert_allclose(rotation(t.quat_xyzw), want, atol=1e-9)
    args = t.static_transform_publisher_args()
    assert args[args.index("--frame-id") + 1] == BASE_FRAME


def test_every_published_frame_id_belongs_to_the_tree():
    frames = tree_frames(Path(panda_urdf_path()).read_text(), camera_transform(POSE))
    published = {
        "bridge ee_pose, joint_states (Panda)": ROBOTS["panda"].base_frame,
        "controller status": controller_node.BASE_FRAME,
        "camera images (default frame_id)": CAMERA_PARAMS.params["frame_id"].default,
        "simulated camera": CAMERA_FRAME_ID,
    }
    outside = {k: v for k, v in published.items() if v not in frames}
    assert not outside, f"frame ids no transform defines: {outside}"
    assert "world" not in frames


def test_robot_description_reaches_a_late_subscriber():
    h = RosHarness()
    try:
        node = h.add(rclpy.create_node("describer", context=h.context))
        publish_robot_description(node)
        got = []
        late = h.add(rclpy.create_node("late", context=h.context))
        late.create_subscription(String, TOPIC, got.append, QOS)
        assert h.spin_until(lambda: got), "no /robot_description for a late transient-local subscriber"
        assert "<robot" in got[0].data and 'name="panda_link0"' in got[0].data
    finally:
        h.shutdown()
