"""vision_msgs/Detection2DArray paths, with a vision_msgs interface package built here (colcon, rosidl)
from its documented definition (ros-perception/vision_msgs 4.x, the Jazzy release): vision_msgs has no
PyPI wheel, so this is how the optional path gets exercised on this machine. Without it (the usual
case here) the nodes must still start: that is every other node test."""
from pathlib import Path

import interface_package
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

# The message definitions of vision_msgs 4.x (ros-perception/vision_msgs, ROS 2 branch), as used here.
MSGS = {
    "Point2D": "float64 x\nfloat64 y\n",
    "Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "ObjectHypothesis": "string class_id\nfloat64 score\n",
    "ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    "Detection2D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox2D bbox\n"
                   "string id\n",
    "Detection2DArray": "std_msgs/Header header\nDetection2D[] detections\n",
}


@pytest.fixture(scope="module")
def vision_msgs_install() -> Path:
    return interface_package.build("vision_msgs", "4.1.1", {f"msg/{n}.msg": t for n, t in MSGS.items()},
                                   ["std_msgs", "geometry_msgs"])


@pytest.mark.timeout(1800)
def test_detector_publishes_and_controller_accepts_detection2d_array(vision_msgs_install):
    interface_package.run_check(vision_msgs_install, "vision_msgs_check.py", "vision_msgs paths ok")


def test_without_vision_msgs_the_module_says_so():
    from vla_common.ros import vision

    assert vision.AVAILABLE in (True, False)
    if not vision.AVAILABLE:
        assert vision.Detection2DArray is None
