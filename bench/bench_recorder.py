"""Recorder throughput: joint_states at 1 kHz + 640x480 rgb8 images at 30 Hz into one episode.

Starts the installed recorder in its own process, publishes from this process (reliable QoS,
as the bridge and camera do), then compares published with written counts (metadata.yaml) and
prints MB/s, the publish-rate actually achieved and the recorder's CPU use.

    python bench/bench_recorder.py [--seconds 60] [--js-rate 1000] [--image-rate 30]
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from brief import parse
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger
from vla_common.ros.domain import isolate
from vla_demo_recorder.bag_writer import read_metadata_yaml
from vla_launch.run import RunError, find_executable

from vla_interfaces.srv import StartEpisode


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--js-rate", type=float, default=1000.0)
    ap.add_argument("--image-rate", type=float, default=30.0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--keep", action="store_true", help="keep the bag")
    args = parse(ap, seconds=3.0)

    isolate()  # read by rclpy.init and the child
    try:
        exe = find_executable("vla_demo_recorder", "recorder")
    except RunError as err:
        print(f"recorder: {err}: run `make setup`", file=sys.stderr)
        return 1
    out = Path(tempfile.mkdtemp(prefix="bench_recorder_"))
    proc = subprocess.Popen([str(exe), "--ros-args", "-r", "__node:=bench_recorder",
                             "-p", f"output_dir:={out}", "-p", "topics:=[joint_states, camera/image_raw]",
                             "--log-level", "warn"])
    rclpy.init()
    node = Node("bench_publisher")
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    js_pub = node.create_publisher(JointState, "joint_states", reliable)
    img_pub = node.create_publisher(Image, "camera/image_raw",
                                    QoSProfile(depth=60, reliability=ReliabilityPolicy.RELIABLE))
    start_cli = node.create_client(StartEpisode, "/bench_recorder/start_episode")
    stop_cli = node.create_client(Trigger, "/bench_recorder/stop_episode")

    def call(cli, req, timeout=60.0):
        assert cli.wait_for_service(timeout_sec=30), "recorder services not up"
        fut = cli.call_async(req)
        ex.spin_until_future_complete(fut, timeout_sec=timeout)
        return fut.result()

    try:
        deadline = time.monotonic() + 30
        while (js_pub.get_subscription_count() == 0 or img_pub.get_subscription_count() == 0) \
                and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        res = call(start_cli, StartEpisode.Request(task="bread/push_east", note="bench"))
        assert res.success, res.message
        js = JointState(name=[f"panda_joint{i}" for i in range(1, 8)], position=[0.0] * 7,
                        velocity=[0.0] * 7, effort=[0.0] * 7)
        img = Image(height=args.height, width=args.width, encoding="rgb8", step=args.width * 3,
                    data=np.random.default_rng(0).integers(0, 255, args.height * args.width * 3,
                                                           dtype=np.uint8).tobytes())
        img.header.frame_id = "camera_optical_frame"
        published = {"js": 0, "img": 0}
        lateness: list[float] = []
        stop = threading.Event()

        def publish_loop() -> None:
            """Deadline-scheduled publishing: catches up after a late wake-up, so rates are exact."""
            t0 = time.monotonic()
            next_js = next_img = 0
            while not stop.is_set():
                now = time.monotonic() - t0
                if now >= args.seconds:
                    break
                while next_js / args.js_rate <= now:
                    js.header.stamp = node.get_clock().now().to_msg()
                    js.position[0] = float(next_js)
                    js_pub.publish(js)
                    next_js += 1
                while next_img / args.image_rate <= now:
                    lateness.append(now - next_img / args.image_rate)
                    img.header.stamp = node.get_clock().now().to_msg()
                    img_pub.publish(img)
                    next_img += 1
                published["js"], published["img"] = next_js, next_img
                time.sleep(max(0.0, min((next_js / args.js_rate), next_img / args.image_rate)
                               - (time.monotonic() - t0)))

        cpu0, w0 = cpu_seconds(proc.pid), time.monotonic()
        thread = threading.Thread(target=publish_loop)
        thread.start()
        while thread.is_alive():
            ex.spin_once(timeout_sec=0.1)
        elapsed = time.monotonic() - w0
        ex.spin_once(timeout_sec=0.0)
        time.sleep(2.0)  # let the recorder drain its queues
        cpu = cpu_seconds(proc.pid) - cpu0
        t_stop = time.monotonic()
        res = call(stop_cli, Trigger.Request())
        stop_s = time.monotonic() - t_stop
        assert res.success, res.message
        bag = Path(res.message.rsplit(" in ", 1)[1])
        meta = read_metadata_yaml(bag)
        written = {t["topic_metadata"]["name"]: t["message_count"]
                   for t in meta["topics_with_message_count"]}
        w_js, w_img = written.get("/joint_states", 0), written.get("/camera/image_raw", 0)
        size = sum(p.stat().st_size for p in bag.iterdir())
        mb_s = size / 1e6 / elapsed
        lat = np.array(lateness) * 1e3
        print(f"recorder benchmark: {args.seconds:.0f} s, joint_states {args.js_rate:.0f} Hz + "
              f"{args.width}x{args.height} rgb8 {args.image_rate:.0f} Hz (2-core shared CPU)")
        print(f"  joint_states   published {published['js']:>7}  written {w_js:>7}  "
              f"dropped {published['js'] - w_js}")
        print(f"  camera images  published {published['img']:>7}  written {w_img:>7}  "
              f"dropped {published['img'] - w_img}")
        print(f"  achieved rates: joint_states {published['js'] / elapsed:.0f} Hz, "
              f"images {published['img'] / elapsed:.1f} Hz")
        print(f"  bag {size / 1e6:.1f} MB in {elapsed:.1f} s = {mb_s:.1f} MB/s written; "
              f"recorder CPU {100 * cpu / (elapsed + 2.0):.0f} % of one core; stop took {stop_s:.2f} s")
        print(f"  image publish lateness: median {np.median(lat):.2f} ms, "
              f"p99 {np.percentile(lat, 99):.2f} ms")
        ok = w_js == published["js"] and w_img == published["img"]
        print("  ZERO DROPS" if ok else "  DROPS DETECTED")
        return 0 if ok else 2
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
        node.destroy_node()
        rclpy.shutdown()
        if not args.keep:
            shutil.rmtree(out, ignore_errors=True)
        else:
            print(f"  kept {out}")


if __name__ == "__main__":
    sys.exit(main())
