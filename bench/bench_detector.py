"""Detector speed and camera-image transport, printed as figures.

1. `Detector.detect` latency per frame (letterbox + ONNX Runtime + NMS) of the shipped model on
   rendered 320x240 and 640x480 scenes, the network alone beside it (target <= 15 ms at 320x240).
2. Image transport between two processes: 640x480 rgb8 at 30 Hz from a publisher with the camera
   node's QoS to a subscriber, for the old setting (best-effort SensorDataQoS subscriber, Fast DDS's
   default transports, keep-last 5), each fix alone, and the shipped default (reliable, the large-image
   shared-memory profile, keep-last 30): frames received of those published, latency median and p99.
3. The same through the installed detector_node at 30 Hz (frames published -> detections received),
   old and new QoS in the same run.
4. Closed loop through detector_node (next frame when the detections arrive): sustained frames/s.

Every ROS participant runs in its own child process (this script with --role), because Fast DDS reads
its transport settings once per process.

    source scripts/env.sh && python bench/bench_detector.py [--frames 300] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from brief import parse
from sensor_msgs.msg import Image
from vla_common.ros.domain import isolate
from vla_common.ros.qos import IMAGE_DEPTH, image_qos, use_large_image_transport
from vla_detector.decode import letterbox, to_input_tensor
from vla_detector.inference import Detector, default_model_path
from vla_launch.run import RunError, find_executable

from vla_interfaces.msg import DetectionArray

TRANSPORT_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
                       "FASTDDS_BUILTIN_TRANSPORTS")
WARMUP_FRAME = "warmup"  # frame_id of frames that are not counted (discovery, ONNX Runtime's first runs)
WARMUP_S = 1.5
LOST_AFTER_S = 0.3  # closed loop: a frame without detections by then counts as lost
isolate()  # this run's ROS domain (kept from ROS_DOMAIN_ID if set), inherited by its children
LAYOUT = [("bread", 0.45, 0.2, 0.3), ("soda_can", 0.6, 0.0, 0.0), ("cereal_box", 0.5, -0.25, 1.0)]


@dataclass(frozen=True)
class Setting:
    name: str
    subscriber: str  # "reliable" | "best_effort"
    profile: bool  # the publisher applies use_large_image_transport()
    depth: int = 5  # keep-last depth of publisher and subscriber (the old camera, bridge and detector: 5)


OLD = Setting("old: best effort, default Fast DDS, depth 5", "best_effort", False)
NEW = Setting(f"new (shipped): reliable, profile, depth {IMAGE_DEPTH}", "reliable", True, IMAGE_DEPTH)
TRANSPORT_SETTINGS = [
    OLD,
    Setting("best effort, large-image profile, depth 5", "best_effort", True),
    Setting("reliable, default Fast DDS, depth 5", "reliable", False),
    Setting("reliable, large-image profile, depth 5", "reliable", True),
    NEW,
]


# ---------------------------------------------------------------------------------------- figures
def stats(ms: np.ndarray) -> str:
    if ms.size == 0:
        return "median    n/a        p99    n/a   "
    return f"median {np.median(ms):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms"


def received(r: dict) -> str:
    pct = 100.0 * r["received"] / max(1, r["sent"])
    return f"{r['received']:4d}/{r['sent']:4d} = {pct:5.1f} %"


def machine() -> str:
    model = "unknown CPU"
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                     if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{model}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"


# ---------------------------------------------------------------------------------------- latency
def scenes(width: int, height: int, n: int = 8) -> list[np.ndarray]:
    os.environ.setdefault("MUJOCO_GL", "egl")
    from vla_sim.sim import PandaSim  # MuJoCo: heavy, only to render the benchmark's scenes

    sim = PandaSim(width, height)
    out = []
    for i in range(n):
        sim.reset(seed=100 + i) if i else sim.reset(objects=LAYOUT)
        out.append(sim.render())
    sim.close()
    return out


def bench_latency(det: Detector, images: list[np.ndarray], frames: int) -> tuple[np.ndarray, np.ndarray]:
    for im in images[:3]:
        det.detect(im)  # warm-up
    full, net = [], []
    for i in range(frames):
        im = images[i % len(images)]
        t0 = time.perf_counter()
        det.detect(im)
        full.append(time.perf_counter() - t0)
        x = to_input_tensor(letterbox(im, *det.input_size)[0])
        t0 = time.perf_counter()
        det.session.run(None, {det.input_name: x})
        net.append(time.perf_counter() - t0)
    return np.array(full) * 1e3, np.array(net) * 1e3


# ---------------------------------------------------------------------------------------- children
def _image_messages(frames_file: str) -> list[Image]:
    frames = np.load(frames_file, allow_pickle=False)
    msgs = []
    for im in frames:
        m = Image(height=im.shape[0], width=im.shape[1], encoding="rgb8", step=im.shape[1] * 3)
        m.data = im.tobytes()
        msgs.append(m)
    return msgs


def _stamp(m: Image, frame_id: str) -> None:
    t = time.time_ns()
    m.header.stamp.sec, m.header.stamp.nanosec = t // 1_000_000_000, t % 1_000_000_000
    m.header.frame_id = frame_id


def _age_ms(header) -> float:
    return (time.time_ns() - (header.stamp.sec * 1_000_000_000 + header.stamp.nanosec)) / 1e6


def _prepare_transport(profile: bool) -> None:
    for name in TRANSPORT_VARIABLES:
        os.environ.pop(name, None)
    if profile:
        use_large_image_transport()


def role_camera(a: argparse.Namespace) -> None:
    """Publish frames at a fixed rate with the camera node's QoS: warm-up frames, then counted ones."""
    _prepare_transport(a.profile)
    rclpy.init()
    node = rclpy.create_node("bench_camera")
    pub = node.create_publisher(Image, "camera/image_raw", image_qos("reliable", a.depth))
    msgs = _image_messages(a.frames)
    end = time.monotonic() + 30.0
    while pub.get_subscription_count() < 1 and time.monotonic() < end:
        time.sleep(0.01)
    sent = 0
    for phase, seconds in ((WARMUP_FRAME, WARMUP_S), ("camera_optical_frame", a.seconds)):
        t0, n = time.monotonic(), 0
        while time.monotonic() - t0 < seconds:
            m = msgs[n % len(msgs)]
            _stamp(m, phase)
            pub.publish(m)
            n += 1
            time.sleep(max(0.0, t0 + n / a.rate - time.monotonic()))
        sent = n
    time.sleep(0.5)  # let the last frames leave before the participant goes
    print(json.dumps({"sent": sent}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def role_listen(a: argparse.Namespace) -> None:
    """Count counted frames (images or detections) until stdin closes; print count and latencies."""
    rclpy.init()
    node = rclpy.create_node("bench_listener")
    ages: list[float] = []

    def on_msg(msg) -> None:
        if msg.header.frame_id != WARMUP_FRAME:
            ages.append(_age_ms(msg.header))

    if a.topic == "detections":
        node.create_subscription(DetectionArray, "detections", on_msg, 100)
    else:
        node.create_subscription(Image, "camera/image_raw", on_msg, image_qos(a.reliability, a.depth))
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    print("ready", flush=True)
    while not stop.is_set():
        rclpy.spin_once(node, timeout_sec=0.01)
    print(json.dumps({"received": len(ages), "latency_ms": ages}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def role_loop(a: argparse.Namespace) -> None:
    """Closed loop: publish the next frame when the previous frame's detections arrived."""
    _prepare_transport(a.profile)
    rclpy.init()
    node = rclpy.create_node("bench_loop")
    got: list[float] = []  # latency of each counted frame; NaN for a warm-up frame

    def on_detections(msg: DetectionArray) -> None:
        got.append(float("nan") if msg.header.frame_id == WARMUP_FRAME else _age_ms(msg.header))

    node.create_subscription(DetectionArray, "detections", on_detections, 10)
    pub = node.create_publisher(Image, "camera/image_raw", image_qos("reliable", a.depth))
    msgs = _image_messages(a.frames)
    end = time.monotonic() + 30.0
    while (pub.get_subscription_count() < 1 or node.count_publishers("detections") < 1) \
            and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    while not got and time.monotonic() < end:  # warm-up: until the first detections arrive
        _stamp(msgs[0], WARMUP_FRAME)
        pub.publish(msgs[0])
        rclpy.spin_once(node, timeout_sec=0.2)
    rclpy.spin_once(node, timeout_sec=0.5)
    got.clear()
    sent, t0 = 0, time.monotonic()
    while time.monotonic() - t0 < a.seconds:
        n = len(got)
        _stamp(msgs[sent % len(msgs)], "camera_optical_frame")
        pub.publish(msgs[sent % len(msgs)])
        sent += 1
        t_pub = time.monotonic()
        while len(got) == n and time.monotonic() - t_pub < LOST_AFTER_S:
            rclpy.spin_once(node, timeout_sec=0.001)
    elapsed = time.monotonic() - t0
    lat = [g for g in got if np.isfinite(g)]
    print(json.dumps({"sent": sent, "received": len(lat), "elapsed": elapsed, "latency_ms": lat}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


# ---------------------------------------------------------------------------------------- parent
def _child_env() -> dict[str, str]:
    """This run's children: the transport each setting chooses, and this run's ROS domain (`isolate`
    above) so that other graphs on the machine neither add frames nor load."""
    return {k: v for k, v in os.environ.items() if k not in TRANSPORT_VARIABLES}


def _script(*args: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *args]


def _last_json(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def _start_detector(setting: Setting) -> subprocess.Popen:
    exe = find_executable("vla_detector", "detector_node")
    return subprocess.Popen([exe, "--ros-args", "-p", f"image_reliability:={setting.subscriber}",
                             "-p", f"image_queue:={setting.depth}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=_child_env())


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def open_loop(frames: str, setting: Setting, seconds: float, rate: float, through_detector: bool) -> dict:
    """Publisher process -> (detector_node ->) listener process; frames sent and received."""
    topic = "detections" if through_detector else "image"
    listener = subprocess.Popen(
        _script("--role", "listen", "--topic", topic, "--reliability", setting.subscriber,
                "--depth", str(setting.depth)),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=_child_env())
    detector = _start_detector(setting) if through_detector else None
    try:
        if listener.stdout.readline().strip() != "ready":
            raise RuntimeError("the listener did not start")
        camera = subprocess.run(
            _script("--role", "camera", "--frames", frames, "--seconds", str(seconds), "--rate", str(rate),
                    "--depth", str(setting.depth), *(["--profile"] if setting.profile else [])),
            capture_output=True, text=True, env=_child_env(), timeout=seconds + 90)
        if camera.returncode != 0:
            raise RuntimeError(f"the publisher failed: {camera.stderr[-2000:]}")
        time.sleep(1.0)  # frames in flight and detections of the last frames
        out, _ = listener.communicate("", timeout=30)
    finally:
        if detector is not None:
            _stop(detector)
        if listener.poll() is None:
            listener.kill()
    r = _last_json(out)
    return {"sent": _last_json(camera.stdout)["sent"], "received": r["received"],
            "latency_ms": np.array(r["latency_ms"])}


def closed_loop(frames: str, seconds: float) -> dict:
    detector = _start_detector(NEW)
    try:
        args = ("--role", "loop", "--frames", frames, "--seconds", str(seconds), "--depth", str(NEW.depth),
                "--profile")
        loop = subprocess.run(_script(*args), capture_output=True, text=True, env=_child_env(),
                              timeout=seconds + 90)
    finally:
        _stop(detector)
    if loop.returncode != 0:
        raise RuntimeError(f"the closed loop failed: {loop.stderr[-2000:]}")
    r = _last_json(loop.stdout)
    r["latency_ms"] = np.array(r["latency_ms"])
    r["fps"] = r["received"] / r["elapsed"]
    return r


def main_bench(a: argparse.Namespace) -> int:
    det = Detector(a.model, num_threads=a.threads)
    w, h = det.input_size
    print(f"{machine()}\nmodel {a.model}: input {w}x{h}, {len(det.classes)} classes, "
          f"ONNX Runtime {a.threads} threads; torch imported: {'torch' in sys.modules}")
    imgs = {}
    for size in ((320, 240), (640, 480)):
        imgs[size] = scenes(*size)
        full, net = bench_latency(det, imgs[size], a.frames)
        print(f"detect() {size[0]}x{size[1]}: {stats(full)}   network only: {stats(net)}")
    if a.no_node:
        return 0
    try:
        find_executable("vla_detector", "detector_node")
    except RunError as err:
        print(f"detector_node: {err}: run make setup for the end-to-end figures")
        return 1
    with tempfile.TemporaryDirectory(prefix="bench_detector_") as tmp:
        files = {}
        for size, frames in imgs.items():
            files[size] = str(Path(tmp) / f"frames_{size[0]}x{size[1]}.npy")
            np.save(files[size], np.stack(frames), allow_pickle=False)
        big = files[(640, 480)]
        print(f"\nimage transport, 640x480 rgb8 at {a.rate:g} Hz for {a.seconds:g} s, publisher (reliable, "
              "as the camera node) and subscriber in two processes:")
        for setting in TRANSPORT_SETTINGS:
            r = open_loop(big, setting, a.seconds, a.rate, through_detector=False)
            print(f"  {setting.name:45s} {received(r)}  latency {stats(r['latency_ms'])}")
        print(f"\ndetector_node, 640x480 rgb8 at {a.rate:g} Hz: frames published -> detections received")
        for setting in (OLD, NEW):
            r = open_loop(big, setting, a.seconds, a.rate, through_detector=True)
            print(f"  {setting.name:45s} {received(r)}  latency {stats(r['latency_ms'])}")
        print("\ndetector_node, closed loop (next frame when the detections arrive), shipped default:")
        for size in ((320, 240), (640, 480)):
            r = closed_loop(files[size], a.seconds)
            print(f"  {size[0]}x{size[1]}: {r['fps']:5.1f} frames/s, {received(r)}, "
                  f"latency {stats(r['latency_ms'])}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(default_model_path()))
    ap.add_argument("--frames", default="300", help="latency: frames; --role camera/loop: the .npy file")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-node", action="store_true", help="only the detect() latency")
    ap.add_argument("--role", choices=("camera", "listen", "loop"), help=argparse.SUPPRESS)
    ap.add_argument("--topic", default="image", help=argparse.SUPPRESS)
    ap.add_argument("--reliability", default="reliable", help=argparse.SUPPRESS)
    ap.add_argument("--profile", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--depth", type=int, default=IMAGE_DEPTH, help=argparse.SUPPRESS)
    a = parse(ap, frames="20", seconds=1.0)
    if a.role is not None:
        {"camera": role_camera, "listen": role_listen, "loop": role_loop}[a.role](a)
        return 0
    a.frames = int(a.frames)
    return main_bench(a)


if __name__ == "__main__":
    sys.exit(main())
