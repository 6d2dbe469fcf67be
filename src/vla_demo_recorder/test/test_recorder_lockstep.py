"""The recorder in lockstep (vla_demo_recorder.lockstep): the stamp read from the serialized message,
and the episode's window by stamp (a detection of a frame before the start is left out)."""
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image, JointState, Joy
from std_msgs.msg import Float64MultiArray
from vla_demo_recorder.lockstep import StampWindow, has_header, header_stamp_ns

from vla_interfaces.msg import DetectionArray, GripperStatus


def _stamped(cls, sec: int, nanosec: int):
    msg = cls()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return serialize_message(msg)


def test_the_header_stamp_is_read_from_the_serialized_message():
    for cls in (JointState, Image, CameraInfo, DetectionArray, GripperStatus, Joy):
        assert has_header(cls), cls
        assert header_stamp_ns(_stamped(cls, 12, 345_000_000)) == 12_345_000_000
    assert not has_header(Float64MultiArray)


def test_the_window_keeps_what_is_stamped_after_the_start():
    window = StampWindow()
    assert window.keeps(_stamped(DetectionArray, 1, 0))          # no episode yet: no window
    window.open(2_200_000_000)
    assert not window.keeps(_stamped(DetectionArray, 2, 0))      # a frame before the start
    assert not window.keeps(_stamped(JointState, 2, 200_000_000))   # the held step itself
    assert window.keeps(_stamped(JointState, 2, 220_000_000))
