"""Two "hosts" on one machine for the multi-machine test: two network namespaces joined by a veth pair,
and the probe that runs on the robot side (`python test/two_hosts.py probe`).

Each namespace has only its loopback and its end of the veth, with an address in a private /24 that
exists nowhere else: traffic between them crosses the veth and nothing else, as between two PCs on a
switch. Creating them needs root (CAP_NET_ADMIN) and iproute2; `TwoHosts.create` raises
`NetnsUnavailableError` with the reason otherwise. `close` kills what still runs in them and deletes them.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import secrets
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DDS_SOURCE_DIR = REPO / "src" / "vla_bringup" / "config" / "dds"
IMAGE_BYTES = 640 * 480 * 3  # one rgb8 frame of the bridge's camera at the shipped size


class NetnsUnavailableError(RuntimeError):
    """Network namespaces cannot be made here; the message says why (the test skips with it)."""


@dataclass(frozen=True)
class Host:
    netns: str
    ifname: str
    address: str


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


def dds_config_dir() -> Path:
    """The shipped DDS files: installed (share/vla_bringup/config/dds) if they are, else the source."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("vla_bringup")) / "config" / "dds"
    except Exception:  # vla_bringup not installed: the source tree is the only copy
        installed = None
    return installed if installed is not None and installed.is_dir() else DDS_SOURCE_DIR


class TwoHosts:
    """The namespaces "robot" and "vision" (names made unique per run) and the veth between them."""

    def __init__(self) -> None:
        tag = secrets.token_hex(3)
        subnet = f"10.{200 + secrets.randbelow(50)}.{secrets.randbelow(256)}"
        self.robot = Host(f"vla-{tag}-robot", f"vr{tag}", f"{subnet}.1")
        self.vision = Host(f"vla-{tag}-vision", f"vv{tag}", f"{subnet}.2")
        self._made: list[str] = []

    def create(self) -> TwoHosts:
        if os.geteuid() != 0:
            raise NetnsUnavailableError("creating network namespaces needs root (CAP_NET_ADMIN)")
        if shutil.which("ip") is None:
            raise NetnsUnavailableError("iproute2's `ip` is not installed")
        r, v = self.robot, self.vision
        steps = [("netns", "add", r.netns), ("netns", "add", v.netns),
                 ("link", "add", r.ifname, "netns", r.netns, "type", "veth", "peer", "name", v.ifname,
                  "netns", v.netns)]
        for h in (r, v):
            steps += [("-n", h.netns, "addr", "add", f"{h.address}/24", "dev", h.ifname),
                      ("-n", h.netns, "link", "set", "lo", "up"),
                      ("-n", h.netns, "link", "set", h.ifname, "up")]
        for step in steps:
            res = _ip(*step)
            if res.returncode != 0:
                self.close()
                raise NetnsUnavailableError(f"`ip {' '.join(step)}` failed: {res.stderr.strip()}")
            if step[:2] == ("netns", "add"):
                self._made.append(step[2])
        self._wait_running()
        return self

    def _wait_running(self, timeout: float = 10.0) -> None:
        """Wait until both veth ends are operationally up (the kernel takes a moment after `link set
        up`): Fast DDS drops a whitelisted interface that is not running when a node starts, for good."""
        deadline = time.monotonic() + timeout
        while True:
            states = {h.ifname: self._operstate(h) for h in (self.robot, self.vision)}
            if all(s == "UP" for s in states.values()):
                return
            if time.monotonic() > deadline:
                self.close()
                raise NetnsUnavailableError(f"the veth pair did not come up within {timeout:g} s: {states}")
            time.sleep(0.05)

    def _operstate(self, host: Host) -> str:
        res = _ip("-n", host.netns, "-j", "link", "show", "dev", host.ifname)
        return json.loads(res.stdout)[0].get("operstate", "") if res.returncode == 0 else ""

    def peer(self, host: Host) -> Host:
        return self.vision if host is self.robot else self.robot

    def command(self, host: Host, argv: list[str]) -> list[str]:
        """`argv` run on `host` with the shipped two-PC DDS setup (config/dds/two_hosts.sh) sourced."""
        script = dds_config_dir() / "two_hosts.sh"
        setup = (f"export VLA_PEER={self.peer(host).address} VLA_DDS_INTERFACE={host.ifname} && "
                 '. "$0" && exec "$@"')
        return ["ip", "netns", "exec", host.netns, "bash", "-c", setup, str(script), *argv]

    def link_bytes(self, host: Host) -> dict[str, int]:
        """Bytes sent and received so far on `host`'s end of the veth."""
        res = _ip("-n", host.netns, "-s", "-j", "link", "show", "dev", host.ifname)
        stats = json.loads(res.stdout)[0]["stats64"]
        return {"tx": int(stats["tx"]["bytes"]), "rx": int(stats["rx"]["bytes"])}

    def pids(self, netns: str) -> list[int]:
        res = _ip("netns", "pids", netns)
        return [int(p) for p in res.stdout.split()] if res.returncode == 0 else []

    def close(self) -> None:
        """Kill every process left in our namespaces, then delete them (the veth goes with them)."""
        for netns in self._made:
            for pid in self.pids(netns):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        for netns in self._made:
            _ip("netns", "del", netns)
        self._made = []


# --- the probe: runs on the robot side, drives the joystick and reports what it saw -----------------

def probe(timeout: float, move: float, stick: float) -> dict:
    """Wait for detections of the bridge's own frames (made on the vision side), then hold the stick
    at `stick` until the arm has moved `move` rad (norm over the 7 joints), then release it."""
    import numpy as np
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data as sensor
    from sensor_msgs.msg import CameraInfo, JointState, Joy
    from vla_common.ros.convert import ns_from_stamp
    from vla_common.ros.testing import RosHarness

    from vla_interfaces.msg import ControllerStatus, DetectionArray, SafetyStatus

    h = RosHarness(other_processes=True)
    node = h.add(Node("two_hosts_probe", context=h.context))
    seen = {"info": set(), "dets": 0, "matched": 0, "classes": set(), "q": None, "ctrl": None,
            "safety": None, "latched": set()}

    def on_dets(m: DetectionArray) -> None:
        seen["dets"] += 1
        if m.detections and ns_from_stamp(m.header.stamp) in seen["info"]:
            seen["matched"] += 1
            seen["classes"].add(m.detections[0].class_id)

    def on_ctrl(m: ControllerStatus) -> None:
        seen["ctrl"] = m
        if m.code == ControllerStatus.ACTIVE and m.latched_class:
            seen["latched"].add(m.latched_class)

    node.create_subscription(CameraInfo, "camera/camera_info",
                             lambda m: seen["info"].add(ns_from_stamp(m.header.stamp)), sensor)
    node.create_subscription(DetectionArray, "detections", on_dets, sensor)
    node.create_subscription(JointState, "joint_states",
                             lambda m: seen.update(q=np.array(m.position, dtype=float)), sensor)
    node.create_subscription(ControllerStatus, "controller_node/status", on_ctrl, sensor)
    node.create_subscription(SafetyStatus, "panda_bridge/status", lambda m: seen.update(safety=m), sensor)
    joy_pub = node.create_publisher(Joy, "joy", 10)
    axis = [0.0]

    def publish_joy() -> None:
        msg = Joy(axes=[axis[0]], buttons=[0])
        msg.header.stamp = node.get_clock().now().to_msg()
        joy_pub.publish(msg)

    report = {"phase": "detections"}
    try:
        if h.spin_until(lambda: seen["matched"] >= 3 and seen["q"] is not None and seen["ctrl"] is not None,
                        timeout):
            report["phase"] = "move"
            node.create_timer(0.02, publish_joy)      # the stick at neutral first (it arms the controller)
            h.spin_until(lambda: seen["ctrl"].code == ControllerStatus.ZERO_DEADBAND, timeout)
            q0 = seen["q"].copy()
            axis[0] = stick

            def moved() -> float:
                return float(np.linalg.norm(seen["q"] - q0))

            if h.spin_until(lambda: moved() >= move, timeout):
                report["phase"] = "done"
            axis[0] = 0.0
            h.spin_for(1.0)  # the released stick: zero commands, then the bridge's status catches up
            report["moved"] = moved()
        s, c = seen["safety"], seen["ctrl"]
        report.update(
            camera_infos=len(seen["info"]), detections=seen["dets"], matched=seen["matched"],
            classes=sorted(seen["classes"]), latched=sorted(seen["latched"]),
            controller=None if c is None else {"code": int(c.code), "reason": c.reason},
            safety=None if s is None else {
                "commands_received": int(s.commands_received), "commands_rejected": int(s.commands_rejected),
                "estop_active": bool(s.estop_active), "last_intervention": int(s.last_intervention)})
    finally:
        h.shutdown()
    return report


# --- a measurement: camera-size images from one host to the other, per DDS setup ---------------------

def image_pub(rate: float, seconds: float) -> dict:
    """Publish 640x480 rgb8 images (reliable, keep-last 5, as the bridge's camera) for `seconds` after
    the first subscriber matched; the count published."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from vla_common.ros.testing import RosHarness

    h = RosHarness(other_processes=True)
    node = h.add(Node("image_pub", context=h.context))
    pub = node.create_publisher(Image, "image", QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    msg = Image(height=480, width=640, encoding="rgb8", step=640 * 3, data=bytes(IMAGE_BYTES))
    sent = [0]

    def tick() -> None:
        if pub.get_subscription_count() > 0:
            msg.header.frame_id = str(sent[0])
            pub.publish(msg)
            sent[0] += 1

    try:
        timer = node.create_timer(1.0 / rate, tick)
        matched = h.spin_until(lambda: sent[0] > 0, 60.0)
        h.spin_until(lambda: sent[0] >= rate * seconds, seconds * 10)
        timer.cancel()
        h.spin_for(2.0)  # reliable: let the last ones be repaired before leaving the graph
    finally:
        h.shutdown()
    return {"matched": matched, "published": sent[0]}


def image_sub(reliable: bool, quiet: float = 3.0, timeout: float = 120.0) -> dict:
    """Count the images received until none came for `quiet` s (after the first) or `timeout`."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from vla_common.ros.testing import RosHarness

    h = RosHarness(other_processes=True)
    node = h.add(Node("image_sub", context=h.context))
    rel = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
    got = {"n": 0, "last": None}

    def on_image(m) -> None:
        got["n"] += 1
        got["last"] = time.monotonic()

    try:
        node.create_subscription(Image, "image", on_image, QoSProfile(depth=5, reliability=rel))
        h.spin_until(lambda: got["last"] is not None and time.monotonic() - got["last"] > quiet, timeout)
    finally:
        h.shutdown()
    return {"received": got["n"]}


def _last_json(text: str) -> dict:
    lines = [ln for ln in text.splitlines() if ln.startswith("{")]
    return json.loads(lines[-1]) if lines else {}


SETUPS = ("static peer only", "LARGE_DATA", "two_hosts.sh")


def _side_command(pair: TwoHosts, host: Host, setup: str, argv: list[str]) -> list[str]:
    """`argv` on `host` under one DDS setup: the shipped script, or the ROS variables alone
    (optionally with Fast DDS's LARGE_DATA builtin transports: TCP for data, UDP for discovery)."""
    if setup == "two_hosts.sh":
        return pair.command(host, argv)
    extra = [f"ROS_STATIC_PEERS={pair.peer(host).address}", "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET"]
    if setup == "LARGE_DATA":
        extra.append("FASTDDS_BUILTIN_TRANSPORTS=LARGE_DATA")
    return ["ip", "netns", "exec", host.netns, "env", "-u", "FASTRTPS_DEFAULT_PROFILES_FILE", *extra, *argv]


def bench_images(rate: float, seconds: float) -> list[dict]:
    """Images robot -> vision under each DDS setup and subscriber reliability; one row each."""
    pair = TwoHosts().create()
    env = {k: v for k, v in os.environ.items() if k != "FASTDDS_BUILTIN_TRANSPORTS"}
    env["PYTHONUNBUFFERED"] = "1"
    me = [sys.executable, __file__]
    rows = []
    try:
        for setup in SETUPS:
            for reliable in (False, True):
                before = pair.link_bytes(pair.robot)["tx"]
                sub_args = ["image-sub"] + (["--reliable"] if reliable else [])
                pub_args = ["image-pub", "--rate", str(rate), "--seconds", str(seconds)]
                sub, pub = (subprocess.Popen(_side_command(pair, host, setup, me + args), env=env, text=True,
                                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
                            for host, args in ((pair.vision, sub_args), (pair.robot, pub_args)))
                sent = _last_json(pub.communicate(timeout=300)[0]).get("published", 0)
                got = _last_json(sub.communicate(timeout=300)[0]).get("received", 0)
                rows.append({"setup": setup, "subscriber": "reliable" if reliable else "best effort",
                             "published": sent, "received": got,
                             "lost_pct": round(100.0 * (1 - got / sent), 1) if sent else None,
                             "link_MB": round((pair.link_bytes(pair.robot)["tx"] - before) / 1e6, 1)})
                print(json.dumps(rows[-1]), flush=True)
    finally:
        pair.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    pr = sub.add_parser("probe", help="run on the robot side: detections in, joystick out; prints JSON")
    pr.add_argument("--timeout", type=float, default=120.0, help="s to wait for each phase")
    pr.add_argument("--move", type=float, default=0.05, help="rad the arm must move")
    pr.add_argument("--stick", type=float, default=1.0, help="joystick axis 0 while moving")
    ip = sub.add_parser("image-pub", help="(inside a namespace) publish camera-size images")
    ip.add_argument("--rate", type=float, default=30.0)
    ip.add_argument("--seconds", type=float, default=10.0)
    isub = sub.add_parser("image-sub", help="(inside a namespace) count the images received")
    isub.add_argument("--reliable", action="store_true")
    bi = sub.add_parser("bench-images", help="as root: images across the link under each DDS setup")
    bi.add_argument("--rate", type=float, default=30.0, help="Hz (the shipped camera_rate is 30)")
    bi.add_argument("--seconds", type=float, default=10.0)
    ns = p.parse_args(argv)
    if ns.command == "probe":
        report = probe(ns.timeout, ns.move, ns.stick)
        print(json.dumps(report), flush=True)
        return 0 if report["phase"] == "done" and math.isfinite(report.get("moved", math.nan)) else 1
    if ns.command == "image-pub":
        print(json.dumps(image_pub(ns.rate, ns.seconds)), flush=True)
    elif ns.command == "image-sub":
        print(json.dumps(image_sub(ns.reliable)), flush=True)
    else:
        bench_images(ns.rate, ns.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
