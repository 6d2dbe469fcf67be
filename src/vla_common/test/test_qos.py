"""The image and sensor QoS profiles, and when the large-image Fast DDS profile is applied."""

import xml.etree.ElementTree as ET

import pytest
from rclpy.qos import ReliabilityPolicy
from vla_common.ros.qos import (
    IMAGE_QOS,
    LARGE_IMAGE_PROFILE,
    PROFILE_VARIABLE,
    SENSOR_QOS,
    image_qos,
    use_large_image_transport,
)


def test_images_reliable_sensors_best_effort():
    assert IMAGE_QOS.reliability == ReliabilityPolicy.RELIABLE and IMAGE_QOS.depth == 30
    assert SENSOR_QOS.reliability == ReliabilityPolicy.BEST_EFFORT
    assert image_qos("reliable") == IMAGE_QOS
    assert image_qos("best_effort", 2).reliability == ReliabilityPolicy.BEST_EFFORT
    assert image_qos("best_effort", 2).depth == 2
    with pytest.raises(ValueError, match="best_effort"):
        image_qos("sometimes")


def test_profile_applied_only_where_nothing_else_is_chosen():
    env = {}
    assert use_large_image_transport(env) == str(LARGE_IMAGE_PROFILE)
    assert env[PROFILE_VARIABLE] == str(LARGE_IMAGE_PROFILE)
    assert use_large_image_transport(env) is None  # already set: left as it is
    for chosen in ({PROFILE_VARIABLE: "/etc/mine.xml"}, {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"},
                   {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}):
        env = dict(chosen)
        assert use_large_image_transport(env) is None and env == chosen
    env = {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    assert use_large_image_transport(env) and PROFILE_VARIABLE in env


def test_profile_file_holds_a_large_shared_memory_segment():
    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(LARGE_IMAGE_PROFILE).getroot()
    sizes = [int(e.text) for e in root.iterfind(".//f:segment_size", ns)]
    assert sizes and min(sizes) >= 10 * 640 * 480 * 3  # 640x480 rgb8 frames in flight to a slow reader
    assert root.find(".//f:participant[@is_default_profile='true']", ns) is not None
