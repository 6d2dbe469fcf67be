"""The graph split over two machines, as docs/multi-machine.md sets it up, on two network namespaces.

robot namespace: panda_bridge (MuJoCo backend: physics, safety layer, rendered camera) + controller_node
(shipped latent model) + the probe (test/two_hosts.py) that holds the joystick.
vision namespace: detector_node, reading the bridge's camera across the link, detections back.
Every node is started as users start it: `vla run <pkg> <exe> --ros-args --params-file <shipped config>`
with the shipped DDS setup (config/dds/two_hosts.sh: Fast DDS profile, SUBNET discovery, static peer).

The arm must move on the stick, with the context latched from detections of the bridge's own frames
made on the other side, no command rejected, and the frames must have crossed the veth (its byte count
covers every frame detected: nothing went through shared memory behind the link's back).
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess

import pytest
import two_hosts
from require import missing
from two_hosts import IMAGE_BYTES, NetnsUnavailableError, TwoHosts
from vla_launch.launcher import ProcessSpec
from vla_launch.session import LaunchSession


@pytest.fixture
def hosts():
    pair = TwoHosts()
    try:
        pair.create()
    except NetnsUnavailableError as e:
        missing("NETNS", f"network namespaces unavailable: {e}")
    yield pair
    pair.close()


# conftest's LOCALHOST discovery would keep each side to itself; two_hosts.sh sets SUBNET and the static
# peer for every process. The domain stays this run's own.
NODE_ENV = {"PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0", "ROS_AUTOMATIC_DISCOVERY_RANGE": None}


def _session(specs: list[ProcessSpec], log_path) -> LaunchSession:
    """The processes supervised as `vla launch` does (own process groups, SIGINT then SIGTERM/SIGKILL
    after 10 s each, reverse order); one ending does not stop the others."""
    return LaunchSession.of_processes(specs, env=NODE_ENV, log_path=log_path, keep_going=True,
                                      sigterm_timeout=10.0, sigkill_timeout=10.0)


def _vla_run(pkg: str, exe: str, config: str, *params: str) -> list[str]:
    from ament_index_python.packages import get_package_share_directory
    from vla_launch.run import find_executable

    share = get_package_share_directory("vla_bringup")
    args = [word for kv in params for word in ("-p", kv)]
    return [find_executable("vla_launch", "vla"), "run", pkg, exe, "--ros-args",
            "--params-file", f"{share}/config/{config}", *args]


def test_namespaces_refused_without_root_say_why(monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    with pytest.raises(NetnsUnavailableError, match="needs root"):
        TwoHosts().create()


def test_namespaces_refused_without_iproute2_say_why(monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(NetnsUnavailableError, match="iproute2"):
        TwoHosts().create()


def test_a_half_made_pair_is_removed():
    pair = TwoHosts()
    # an interface name over the kernel's 15 characters: `ip link add` fails after both netns exist
    pair.vision = dataclasses.replace(pair.vision, ifname="x" * 16)
    try:
        pair.create()
    except NetnsUnavailableError as e:
        if "root" in str(e) or "iproute2" in str(e):
            pytest.skip(f"network namespaces unavailable: {e}")
        assert "ip link add" in str(e) or "netns add" in str(e)
    else:
        pair.close()
        pytest.fail("a 16-character interface name was accepted")
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert pair.robot.netns not in listed and pair.vision.netns not in listed


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(420)
def test_teleoperation_across_two_hosts(hosts, tmp_path):
    robot, vision = hosts.robot, hosts.vision
    before = hosts.link_bytes(robot)
    specs = [
        ProcessSpec("panda_bridge", hosts.command(robot, _vla_run(
            "vla_panda_bridge", "panda_bridge", "panda_bridge.yaml",
            # 5 frames/s of the shipped 640x480 (900 KiB each) keep a loaded 2-core machine responsive
            "camera_rate:=5.0", "state_rate:=100.0"))),
        ProcessSpec("controller_node", hosts.command(robot, _vla_run(
            "vla_latent_controller", "controller_node", "controller.yaml",
            "joy_timeout:=0.5"))),  # the probe's 50 Hz joystick may stall for a moment on a busy machine
        ProcessSpec("detector_node", hosts.command(vision, _vla_run(
            "vla_detector", "detector_node", "detector.yaml"))),
        ProcessSpec("probe", hosts.command(robot, [
            "python", two_hosts.__file__, "probe", "--timeout", "150", "--move", "0.05"])),
    ]
    with _session(specs, tmp_path / "logs" / "nodes.log") as procs:
        procs.wait("probe", 360)
        lines = [ln for ln in procs.output("probe") if ln.startswith("{")]
        assert lines, f"the probe printed no report\n{procs.describe()}"
        report = json.loads(lines[-1])
        after = hosts.link_bytes(robot)
        procs.stop()
        codes = procs.exit_codes()
    print(json.dumps(report), f"veth robot->vision {after['tx'] - before['tx']} B, "
          f"vision->robot {after['rx'] - before['rx']} B", codes)

    assert report["phase"] == "done", f"stopped at phase {report['phase']}: {report}\n{procs.describe()}"
    # detections of the bridge's frames, made across the link, came back; the controller used them
    assert report["matched"] >= 3
    assert report["latched"] and set(report["latched"]) <= set(report["classes"]), report
    assert report["moved"] >= 0.05
    safety = report["safety"]
    assert safety["commands_received"] > 0 and safety["commands_rejected"] == 0, safety
    assert not safety["estop_active"]
    # every frame the probe saw detected crossed the veth as UDP (not shared memory, which the two
    # namespaces could share on one machine): at least one full image per matched detection
    assert after["tx"] - before["tx"] >= report["matched"] * IMAGE_BYTES
    assert after["rx"] > before["rx"]
    # every node stops cleanly on SIGINT (run_node: exit code 0)
    assert codes == {"probe": 0, "detector_node": 0, "controller_node": 0, "panda_bridge": 0}, (
        f"{codes}\n{procs.describe()}")
