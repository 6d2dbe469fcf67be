"""`vla_detector_training capture`: frames published on camera/image_raw (by a publisher in the same
process) become a YOLO dataset skeleton with a contact sheet."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image
from vla_common.objects import OBJECT_CLASSES
from vla_common.ros.node_main import ConfigError
from vla_common.ros.qos import IMAGE_QOS
from vla_detector_training.capture import CaptureSession, contact_sheet
from vla_detector_training.capture_node import CaptureNode
from vla_detector_training.cli import build_parser
from vla_detector_training.dataset import load_data_config, load_split

W, H = 64, 48

pytestmark = pytest.mark.ros


def frame_msg(i: int, encoding: str = "rgb8") -> Image:
    rgb = np.full((H, W, 3), (10 * i) % 250, np.uint8)
    rgb[:, : W // 2, 0] = 255  # the left half red in RGB
    data = rgb if encoding == "rgb8" else rgb[..., ::-1]
    return Image(height=H, width=W, encoding=encoding, step=W * 3, data=data.tobytes())


def start(ros, tmp_path, **params):
    values = {"out": str(tmp_path / "data"), "count": 3, "every": 0.0, **params}
    node = ros.add(CaptureNode(parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
                               context=ros.context))
    camera = ros.add(Node("camera", context=ros.context))
    pub = camera.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    return node, pub


def test_frames_become_a_dataset_skeleton_with_a_contact_sheet(ros, tmp_path):
    node, pub = start(ros, tmp_path)
    sent = 0

    def publish_until_done():
        nonlocal sent
        if not node.finished:
            pub.publish(frame_msg(sent, "bgr8" if sent % 2 else "rgb8"))
            sent += 1
        return node.finished

    assert ros.spin_until(publish_until_done, timeout=20.0)
    root = tmp_path / "data"
    cfg = load_data_config(root)
    assert cfg.names == list(OBJECT_CLASSES) and list(cfg.splits) == ["train"]
    frames = sorted((root / "images" / "train").iterdir())
    assert [p.name for p in frames] == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    for p in frames:  # saved as RGB whatever the encoding: the left half is red
        bgr = cv2.imread(str(p))
        assert bgr.shape == (H, W, 3) and bgr[0, 0, 2] == 255
    assert list((root / "labels" / "train").iterdir()) == []  # for the labelling tool
    sheet = cv2.imread(str(node.sheet))
    assert node.sheet == root / "contact_sheet.png" and sheet.shape == (120, 3 * 160, 3)
    assert [len(s.boxes) for s in load_split(cfg, "train")] == [0, 0, 0]  # usable as it is


def test_a_second_session_adds_frames_and_every_spaces_them(ros, tmp_path):
    session = CaptureSession(tmp_path / "data", 2, 0.0, OBJECT_CLASSES)
    session.offer(np.zeros((H, W, 3), np.uint8), 0.0)
    node, pub = start(ros, tmp_path, count=2, every=3600.0)
    for i in range(4):
        pub.publish(frame_msg(i))
    ros.spin_until(lambda: len(node.session.saved) == 1, timeout=10.0)
    ros.spin_for(0.5)
    assert len(node.session.saved) == 1 and not node.finished  # the next is due in an hour
    assert node.session.saved[0].name == "frame_000001.png"  # after the first session's frame
    node.on_shutdown()  # interrupted: the sheet of what was saved
    assert node.sheet.is_file()


@pytest.mark.parametrize("params,message", [
    ({"count": 0}, "count"),
    ({"out": " "}, "must name the dataset folder"),
    ({"split": "holdout"}, "must be one of"),
    ({"catalogue": "/nonexistent.yaml"}, "nonexistent"),
])
def test_bad_parameters_are_refused(ros, tmp_path, params, message):
    values = {"out": str(tmp_path / "d"), **params}
    with pytest.raises(ConfigError, match=message):
        CaptureNode(parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
                    context=ros.context)


def test_contact_sheet_tiles_in_rows_of_six():
    sheet = contact_sheet([np.zeros((H, W, 3), np.uint8)] * 7, [f"frame_{i:06d}" for i in range(7)])
    assert sheet.shape == (2 * 120, 6 * 160, 3)


def test_cli_flags_and_a_refusal_exit_code(tmp_path):
    a = build_parser().parse_args(["capture", "--out", "d", "--count", "5", "--every", "0.5", "--ros-args",
                                   "-r", "camera/image_raw:=/webcam/image_raw"])
    assert (a.out, a.count, a.every) == ("d", 5, 0.5)
    assert a.ros_args == ["-r", "camera/image_raw:=/webcam/image_raw"]
    r = subprocess.run([sys.executable, "-m", "vla_detector_training.cli", "capture", "--out",
                        str(tmp_path / "d"), "--count", "0"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "count" in r.stderr
