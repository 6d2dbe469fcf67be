"""Every frame id our nodes stamp belongs to one TF tree (the Panda URDF's links plus the camera, whose
pose is data), the camera's static transform is the pose the simulator renders from, and the URDF is
on /robot_description for a subscriber that comes late (transient local)."""
import ast
from pathlib import Path

import numpy as np
import pytest
import rclpy
from std_msgs.msg import String
from vla_camera.camera_node import PARAMS as CAMERA_PARAMS
from vla_common.camera_model import CAMERA_FRAME_ID, SIM_WEBCAM, look_at_rotation
from vla_common.frames import BASE_FRAME, camera_transform, tree_frames
from vla_common.kinematics import panda_urdf_path
from vla_common.robot import ROBOTS
from vla_common.ros.description import QOS, TOPIC, publish_robot_description
from vla_common.ros.testing import RosHarness
from vla_joystick.joy_node import PARAMETERS as JOY_PARAMS
from vla_launch.launch_file import load_launch_file
from vla_launch.substitutions import SubstitutionContext

from vla_latent_controller import controller_node

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "src" / "vla_bringup" / "launch"


def shipped_camera_args() -> list[str]:
    """The camera's pose as data: static_transform_publisher's arguments as tf.launch.yaml makes them."""
    plan = load_launch_file(str(LAUNCH / "tf.launch.yaml"), {}, SubstitutionContext())   # the install's
    return next(p.args for p in plan.processes if p.executable == "static_transform_publisher")


def rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_camera_pose_is_data_and_matches_the_rendered_camera():
    t = camera_transform(shipped_camera_args())
    assert (t.parent, t.child) == (BASE_FRAME, CAMERA_FRAME_ID)
    assert t.child == camera_transform(None).child  # the shipped pose is the simulated webcam's
    np.testing.assert_allclose(t.xyz, camera_transform(None).xyz, atol=1e-6)
    np.testing.assert_allclose(t.quat_xyzw, camera_transform(None).quat_xyzw, atol=1e-8)
    want = look_at_rotation(SIM_WEBCAM.position, SIM_WEBCAM.look_at)
    np.testing.assert_allclose(rotation(t.quat_xyzw), want, atol=1e-8)
    args = t.static_transform_publisher_args()
    assert args[args.index("--frame-id") + 1] == BASE_FRAME


def _stamped_frame(path: Path) -> str:
    """The frame_id a node's source assigns to its Joy header (one assignment, a string literal)."""
    lines = [ln for ln in path.read_text().splitlines() if "msg.header.frame_id = " in ln]
    assert len(lines) == 1, lines
    return ast.literal_eval(lines[0].split("=", 1)[1].split("#")[0].strip())


def test_every_published_frame_id_belongs_to_the_tree():
    frames = tree_frames(Path(panda_urdf_path()).read_text(), camera_transform(shipped_camera_args()))
    published = {
        "bridge ee_pose, joint_states (Panda)": ROBOTS["panda"].base_frame,
        "controller status": controller_node.BASE_FRAME,
        "camera images (default frame_id)": CAMERA_PARAMS.params["frame_id"].default,
        "simulated camera": CAMERA_FRAME_ID,
    }
    outside = {k: v for k, v in published.items() if v not in frames}
    assert not outside, f"frame ids no transform defines: {outside}"
    # Messages without geometry (Joy from the joystick, the station, the simulated user) name no frame.
    joy_frames = {"joy_node": JOY_PARAMS.params["frame_id"].default,
                  "operator station": _stamped_frame(ROOT / "src/vla_operator/vla_operator/station_node.py"),
                  "sim teleoperator": _stamped_frame(
                      ROOT / "src/vla_evaluation/vla_evaluation/sim_teleoperator_node.py")}
    assert set(joy_frames.values()) == {""}, joy_frames
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


def test_a_bad_camera_pose_is_refused():
    good = shipped_camera_args()
    for bad in (good[:-2], good[:1] + ["nan"] + good[2:], good[:7] + ["2.0"] + good[8:],
                good + ["--yaw", "1"]):
        with pytest.raises(ValueError):
            camera_transform(bad)


@pytest.mark.parametrize("launch", ["teleop", "record"])
def test_use_tf_starts_robot_state_publisher_with_the_urdf_and_the_camera_transform(launch, tmp_path):
    """On a full install use_tf:=true adds robot_state_publisher (the URDF by $(file-content)) and
    static_transform_publisher with the camera's pose; the plan is checked here (neither is
    installable on this machine)."""
    urdf = tmp_path / "urdf" / "panda.urdf"
    urdf.parent.mkdir()
    urdf.write_text(Path(panda_urdf_path()).read_text())
    (tmp_path / "launch").symlink_to(LAUNCH)
    (tmp_path / "config").symlink_to(ROOT / "src" / "vla_bringup" / "config")
    ctx = SubstitutionContext(find_share=lambda pkg: str(tmp_path) if pkg == "vla_bringup" else "/x")
    path = str(LAUNCH / f"{launch}.launch.yaml")
    plain = {p.executable for p in load_launch_file(path, {}, ctx).processes}
    assert not plain & {"robot_state_publisher", "static_transform_publisher"}
    procs = {p.executable: p for p in load_launch_file(path, {"use_tf": "true"}, ctx).processes}
    rsp, tf = procs["robot_state_publisher"], procs["static_transform_publisher"]
    assert (rsp.pkg, tf.pkg) == ("robot_state_publisher", "tf2_ros")
    values = {k: v for d in rsp.params for k, v in getattr(d, "values", {}).items()}
    assert values["robot_description"] == urdf.read_text()
    assert tf.args == shipped_camera_args()
    plan = load_launch_file(path, {"use_tf": "true", "camera_x": "1.0"}, ctx)
    tf = next(p for p in plan.processes if p.executable == "static_transform_publisher")
    assert camera_transform(tf.args).xyz[0] == 1.0
