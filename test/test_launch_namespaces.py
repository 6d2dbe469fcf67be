"""Parameter files apply under namespaces and renamed nodes (the shipped files are keyed `/**`).

A launch file started with `vla launch` puts a detector, renamed, in a pushed namespace with a test
copy of config/detector.yaml (score_threshold 0.6), and a second one in another namespace with the
shipped file. Each node reports, through its parameter service, the value of its file. With files
keyed by node name (`detector_node:`) neither would, and this test fails.
"""
from __future__ import annotations

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from launch_process import LaunchProcess
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node
from vla_common.ros.testing import RosHarness

pytestmark = [pytest.mark.slow, pytest.mark.ros]


def shipped_detector_config() -> str:
    return f"{get_package_share_directory('vla_bringup')}/config/detector.yaml"


def test_parameter_files_reach_namespaced_and_renamed_nodes(tmp_path):
    with open(shipped_detector_config()) as f:
        config = yaml.safe_load(f)
    shipped = config["/**"]["ros__parameters"]["score_threshold"]
    config["/**"]["ros__parameters"]["score_threshold"] = 0.6
    copy = tmp_path / "detector.yaml"
    copy.write_text(yaml.safe_dump(config))
    launch = tmp_path / "namespaced.launch.yaml"
    launch.write_text(f"""launch:
  - group:
    - push_ros_namespace: {{namespace: robot1}}
    - node: {{pkg: vla_detector, exec: detector_node, name: front_detector, param: [{{from: "{copy}"}}]}}
  - node:
      pkg: vla_detector
      exec: detector_node
      namespace: robot2
      param: [{{from: "{shipped_detector_config()}"}}]
""")
    h = RosHarness(other_processes=True)
    try:
        with LaunchProcess(str(launch), log_path=tmp_path / "launch.log") as run:
            node = h.add(Node("test_parameters", context=h.context))
            for name, want in (("/robot1/front_detector", 0.6), ("/robot2/detector_node", shipped)):
                cli = node.create_client(GetParameters, f"{name}/get_parameters")
                assert h.discovered_by(node, name, 90.0), (name, run.text()[-2000:])
                res = h.call(cli, GetParameters.Request(names=["score_threshold"]), timeout=90.0)
                assert res.values[0].double_value == pytest.approx(want), (name, run.text()[-2000:])
            assert run.stop() == 0, run.text()[-2000:]
    finally:
        h.shutdown()
