"""Run by test_vision_msgs.py in an environment where a vision_msgs built from its definition is
importable: the detector publishes vision_msgs/Detection2DArray beside ours, and the controller takes
one as its detections."""
import sys
import tempfile
from pathlib import Path

import numpy as np
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from vision_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose
from vla_common.detection import Detection
from vla_common.ros import vision
from vla_common.ros.testing import RosHarness
from vla_detector.detector_node import DetectorNode
from vla_latent_controller.controller_node import ControllerNode
from vla_latent_controller.testing import write_random_model


def round_trip() -> None:
    assert vision.AVAILABLE
    d = Detection("bread", 0.9, 100.5, 80.0, 40.0, 30.0, class_index=1)
    msg = vision.to_detection2d_array([d], Image().header)
    assert msg.detections[0].results[0].hypothesis.class_id == "bread"
    assert vision.from_detection2d_array(msg, ["soda_can", "bread"]) == [d]


def detector_publishes(h: RosHarness) -> None:
    node = h.add(DetectorNode(context=h.context))
    peer = h.add(rclpy.create_node("vision_peer", context=h.context))
    got: list = []
    peer.create_subscription(Detection2DArray, "detections_2d", got.append, 10)
    pub = peer.create_publisher(Image, "camera/image_raw", 10)
    assert h.spin_until(lambda: pub.get_subscription_count() and node.pub_2d.get_subscription_count())
    img = Image(height=240, width=320, encoding="rgb8", step=960, data=bytes(320 * 240 * 3))
    img.header.frame_id = "camera_optical_frame"
    pub.publish(img)
    assert h.spin_until(lambda: got), "no vision_msgs/Detection2DArray from the detector"
    assert got[0].header.frame_id == "camera_optical_frame"


def controller_accepts(h: RosHarness, model_dir: Path) -> None:
    node = h.add(ControllerNode(context=h.context,
                                parameter_overrides=[Parameter("model_path", value=str(model_dir))]))
    peer = h.add(rclpy.create_node("vision_feed", context=h.context))
    info = peer.create_publisher(CameraInfo, "camera/camera_info", 10)
    dets = peer.create_publisher(Detection2DArray, "detections_2d", 10)
    assert h.spin_until(lambda: info.get_subscription_count() and dets.get_subscription_count())
    info.publish(CameraInfo(width=640, height=480, k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 1]))
    assert h.spin_until(lambda: node._image_size == (640, 480))
    m = Detection2D()
    hyp = ObjectHypothesisWithPose()
    hyp.hypothesis.class_id, hyp.hypothesis.score = "bread", 0.8
    m.results = [hyp]
    m.bbox.center.position.x, m.bbox.center.position.y = 320.0, 200.0
    m.bbox.size_x, m.bbox.size_y = 50.0, 40.0
    dets.publish(Detection2DArray(detections=[m]))
    assert h.spin_until(lambda: node.core._dets), "the controller ignored a vision_msgs detection"
    got = node.core._dets[0]
    assert (got.class_id, got.cx, got.cy) == ("bread", 320.0, 200.0) and node.core._dets_size == (640, 480)
    assert np.isfinite(got.score)


def main() -> int:
    round_trip()
    with tempfile.TemporaryDirectory() as tmp:
        model = write_random_model(Path(tmp) / "m")
        for check in (detector_publishes, lambda h: controller_accepts(h, model)):
            h = RosHarness()
            try:
                check(h)
            finally:
                h.shutdown()
    print("vision_msgs paths ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
