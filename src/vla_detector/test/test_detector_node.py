"""detector_node in-process with the shipped model on rendered scenes, and as an installed executable."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rclpy
from detector_fake_models import make_model
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import ReliabilityPolicy
from require import missing
from sensor_msgs.msg import Image
from std_srvs.srv import SetBool
from vla_common.ros.context import end_context
from vla_common.ros.node_main import ConfigError
from vla_common.ros.qos import IMAGE_QOS, SENSOR_QOS
from vla_common.ros.testing import RosHarness
from vla_detector.detector_node import DetectorNode
from vla_launch.run import RunError, find_executable

from vla_interfaces.msg import DetectionArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def scene():
    """A rendered scene with one soda can and one cereal box, at 320x240 and 640x480."""
    from vla_sim.sim import PandaSim  # MuJoCo: heavy, only for this fixture

    sim = PandaSim(320, 240)
    sim.reset(objects=[("soda_can", 0.45, 0.10, 0.0), ("cereal_box", 0.60, -0.15, 0.4)])
    small = sim.render()
    centre = sim.project(np.array([[0.45, 0.10, 0.061]]))[0]
    sim.set_camera_size(640, 480)
    large = sim.render()
    sim.close()
    return small, large, centre


def image_msg(rgb, encoding="rgb8", frame="camera_optical_frame", stamp=(12, 345)):
    img = rgb
    if encoding == "bgr8":
        img = rgb[..., ::-1]
    elif encoding == "mono8":
        img = rgb.mean(axis=2).astype(np.uint8)[..., None]
    img = np.ascontiguousarray(img)
    m = Image(
        height=img.shape[0],
        width=img.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=img.shape[1] * img.shape[2],
    )
    m.header.frame_id = frame
    m.header.stamp.sec, m.header.stamp.nanosec = stamp
    m.data = img.tobytes()
    return m


class Harness(RosHarness):
    """The node and a peer that publishes images and records detections and overlays."""

    def __init__(self, **params):
        super().__init__()
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = self.add(DetectorNode(context=self.context, parameter_overrides=overrides))
        self.peer = self.add(rclpy.create_node("detector_test_peer", context=self.context))
        self.dets, self.overlays = [], []
        self.peer.create_subscription(DetectionArray, "detections", self.dets.append, 10)
        self.peer.create_subscription(Image, "detections/image", self.overlays.append, IMAGE_QOS)
        self.pub = self.peer.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
        assert self.spin_until(
            lambda: self.pub.get_subscription_count() >= 1 and self.node.pub.get_subscription_count() >= 1
        )

    def send(self, msg, expect=True, timeout=10.0):
        n = len(self.dets)
        self.pub.publish(msg)
        if expect:
            assert self.spin_until(lambda: len(self.dets) > n, timeout), "no detections published"
            return self.dets[-1]
        self.spin_until(lambda: len(self.dets) > n, 1.0)
        assert len(self.dets) == n, "published although it should not have"
        return None

    def set_enable(self, value):
        client = self.peer.create_client(SetBool, "detector_node/enable")
        return self.call(client, SetBool.Request(data=value))


@pytest.fixture
def harness(request):
    h = Harness(**getattr(request, "param", {}))
    yield h
    h.shutdown()


def classes_of(out):
    return [d.class_id for d in out.detections]


def test_detects_rendered_scene_with_right_classes(harness, scene):
    small, large, centre = scene
    out = harness.send(image_msg(small))
    assert sorted(classes_of(out)) == ["cereal_box", "soda_can"]
    assert out.header.frame_id == "camera_optical_frame"
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (12, 345)
    assert (out.image_width, out.image_height) == (320, 240)
    can = next(d for d in out.detections if d.class_id == "soda_can")
    assert can.class_index == 1 and can.score > 0.5
    assert np.hypot(can.center_x - centre[0], can.center_y - centre[1]) < 4.0
    # a 640x480 bgr8 frame: converted, resized by the detector, boxes in 640x480 pixels
    out = harness.send(image_msg(large, "bgr8"))
    assert sorted(classes_of(out)) == ["cereal_box", "soda_can"]
    assert out.image_width == 640
    can2 = next(d for d in out.detections if d.class_id == "soda_can")
    assert np.hypot(can2.center_x - 2 * centre[0] - 0.5, can2.center_y - 2 * centre[1] - 0.5) < 8.0


def test_bad_images_skipped_node_keeps_running(harness, scene):
    small = scene[0]
    bad = image_msg(small)
    bad.encoding = "jpeg"
    harness.send(bad, expect=False)
    short = image_msg(small)
    short.data = short.data[:100]
    harness.send(short, expect=False)
    assert harness.node.skipped == 2
    harness.send(image_msg(small, "mono8"))  # converted, not skipped
    assert harness.node.skipped == 2
    assert sorted(classes_of(harness.send(image_msg(small)))) == ["cereal_box", "soda_can"]


def test_enable_service_and_class_filter(harness, scene):
    small = scene[0]
    assert harness.set_enable(False).success
    harness.send(image_msg(small), expect=False)
    harness.set_enable(True)
    assert len(harness.send(image_msg(small)).detections) == 2
    harness.node.set_parameters([Parameter("classes", value=["soda_can"])])
    assert classes_of(harness.send(image_msg(small))) == ["soda_can"]
    res = harness.node.set_parameters([Parameter("classes", value=["unicorn"])])
    assert not res[0].successful and "unknown class" in res[0].reason
    harness.node.set_parameters([Parameter("score_threshold", value=0.999999)])
    assert harness.send(image_msg(small)).detections == []


@pytest.mark.parametrize("harness", [{"publish_overlay": True, "max_detections": 1}], indirect=True)
def test_overlay_and_max_detections(harness, scene):
    out = harness.send(image_msg(scene[0]))
    assert len(out.detections) == 1
    assert harness.spin_until(lambda: harness.overlays)
    ov = harness.overlays[-1]
    assert (ov.width, ov.height, ov.encoding) == (320, 240, "rgb8")
    assert bytes(ov.data) != image_msg(scene[0]).data.tobytes()  # boxes drawn


def run_exe(*ros_args, timeout=60):
    try:
        exe = find_executable("vla_detector", "detector_node")
    except RunError as err:
        missing("SETUP", f"detector_node: {err} (run make setup)")
    return subprocess.run(
        [exe, "--ros-args", *ros_args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=os.environ.copy(),
    )


@pytest.mark.parametrize(
    "content,message", [(None, "not found"), (b"garbage" * 20, "not a valid ONNX model")]
)
def test_missing_or_corrupt_model_exits_1(tmp_path, content, message):
    path = tmp_path / "model.onnx"
    if content is not None:
        path.write_bytes(content)
    r = run_exe("-p", f"model_path:={path}")
    assert r.returncode == 1, r.stderr
    assert message in r.stderr and str(path) in r.stderr


def test_refused_parameters_exit_2(tmp_path):
    r = run_exe("-p", f"model_path:={spam_detector(tmp_path)}")
    assert r.returncode == 2 and "['bread', 'spam']" in r.stderr and "'cereal_box']" in r.stderr
    r = run_exe("-p", "classes:=[unicorn]")
    assert r.returncode == 2 and "parameter 'classes'" in r.stderr and "unknown class names" in r.stderr
    r = run_exe("-p", "score_threshold:=1.5")
    assert r.returncode == 2 and "score_threshold" in r.stderr


def test_parameters_applied_or_refused_at_run_time(harness, scene):
    node = harness.node
    assert node.set_parameters([Parameter("max_detections", value=1)])[0].successful
    assert node.detector.max_detections == 1
    assert len(harness.send(image_msg(scene[0])).detections) == 1
    for name, value in (("num_threads", 4), ("model_path", "/tmp/other.onnx"), ("publish_overlay", True)):
        res = node.set_parameters([Parameter(name, value=value)])[0]
        assert not res.successful, name  # read-only: refused, not silently ignored
    assert node.get_parameter("num_threads").value == 2
    res = node.set_parameters([Parameter("iou_threshold", value=float("nan"))])[0]
    assert not res.successful and node.detector.iou_threshold == 0.25


def test_bringup_parameter_file_loads():
    params = ROOT / "src/vla_bringup/config/detector.yaml"
    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", str(params)])
    try:
        node = DetectorNode(context=ctx)
        assert node.get_parameter("score_threshold").value == 0.3
        assert node.detector.class_filter is None  # classes: [""] = every class
        node.destroy_node()
    finally:
        end_context(ctx)


def test_enable_service_sets_the_parameter(harness, scene):
    """~/enable and the enable parameter are one state: the service goes through the parameter."""
    resp = harness.set_enable(False)
    assert resp.success and resp.message == "detection disabled"
    assert harness.node.get_parameter("enable").value is False
    harness.send(image_msg(scene[0]), expect=False)
    harness.node.set_parameters([Parameter("enable", value=True)])
    assert harness.set_enable(True).message == "detection enabled"
    assert len(harness.send(image_msg(scene[0])).detections) == 2


def test_image_subscription_is_reliable_by_default(harness):
    """A best-effort subscription lost ~40 % of 640x480 frames between processes; reliable, matching
    the camera's and the bridge's reliable publishers, loses none (bench/bench_detector.py)."""
    infos = harness.peer.get_subscriptions_info_by_topic("/camera/image_raw")
    mine = [i for i in infos if i.node_name == "detector_node"]
    assert [i.qos_profile.reliability for i in mine] == [ReliabilityPolicy.RELIABLE]


@pytest.mark.parametrize("harness", [{"image_reliability": "best_effort", "image_queue": 2}], indirect=True)
def test_best_effort_camera_with_image_reliability_best_effort(harness, scene):
    infos = harness.peer.get_subscriptions_info_by_topic("/camera/image_raw")
    assert [i.qos_profile.reliability for i in infos if i.node_name == "detector_node"] == [
        ReliabilityPolicy.BEST_EFFORT]
    assert harness.node.sub.qos_profile.depth == 2  # the graph does not report depths
    best_effort = harness.peer.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
    assert harness.spin_until(lambda: best_effort.get_subscription_count() >= 1)
    n = len(harness.dets)
    best_effort.publish(image_msg(scene[0]))
    assert harness.spin_until(lambda: len(harness.dets) > n)


LAB_CATALOGUE = """extends: default
objects:
  spam:
    shape: box
    size: [0.10, 0.06, 0.08]
    rgba: [0.80, 0.08, 0.10, 1.0]
    mass: 0.34
    friction: 0.5
    tasks: [push_south]
"""


def spam_detector(tmp_path):
    """A stand-in detector whose sidecar lists bread and spam (spam is not in the default catalogue)."""
    rows = np.array([[20.0, 20.0, 10.0, 12.0, 0.9, 0.0], [44.0, 40.0, 16.0, 8.0, 0.0, 0.8]], np.float32)
    path = make_model(tmp_path / "spam.onnx", rows.T[None])
    (tmp_path / "spam.json").write_text(json.dumps({"classes": ["bread", "spam"], "layout": "yolov8"}))
    return path


def start(tmp_path, **params):
    h = RosHarness()
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    try:
        return h, h.add(DetectorNode(context=h.context, parameter_overrides=overrides))
    except Exception:
        h.shutdown()
        raise


def test_model_classes_outside_the_catalogue_refused_naming_both_lists(tmp_path):
    with pytest.raises(ConfigError) as err:
        start(tmp_path, model_path=str(spam_detector(tmp_path)))
    text = str(err.value)
    assert "['bread', 'spam']" in text  # the detector's classes
    assert "['bread', 'soda_can', 'milk_carton', 'glass_bottle', 'cereal_box']" in text  # the catalogue's
    assert "catalogue.yaml" in text and "spam.onnx" in text and "['spam'] unknown" in text


def test_a_lab_catalogue_or_a_class_filter_admits_the_model(tmp_path):
    lab = tmp_path / "lab.yaml"
    lab.write_text(LAB_CATALOGUE)
    h, node = start(tmp_path, model_path=str(spam_detector(tmp_path)), catalogue=str(lab))
    assert node.detector.classes == ["bread", "spam"]
    h.shutdown()
    h, node = start(tmp_path, model_path=str(spam_detector(tmp_path)), classes=["bread"])
    try:  # publishing only bread: spam's absence from the catalogue does not matter ...
        res = node.set_parameters([Parameter("classes", value=["spam"])])[0]
        assert not res.successful and "['spam'] unknown" in res.reason  # ... until spam is published
        assert node.detector.class_filter == {0}
    finally:
        h.shutdown()


def test_unreadable_catalogue_refused(tmp_path):
    with pytest.raises(ConfigError, match="parameter 'catalogue'"):
        start(tmp_path, catalogue=str(tmp_path / "missing.yaml"))
