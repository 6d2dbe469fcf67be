"""Detector speed: latency per frame of the shipped ONNX model at 320x240 and 640x480 input images
(target <= 15 ms at 320x240 on 2 cores, well inside a 30 Hz frame), and frames per second end to
end from `camera/image_raw` to `detections` through the installed detector_node (a separate process).

Per-frame latency is `Detector.detect` (letterbox/resize + ONNX Runtime + NMS) on rendered scenes;
the network alone is shown beside it. End to end: (1) closed loop, the next image is published when
the previous frame's detections arrive: sustained throughput and per-frame latency (publish ->
detections received); (2) open loop at the camera's 30 Hz: frames delivered per second.

    source scripts/env.sh && python bench/bench_detector.py [--frames 300] [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from vla_detector.inference import Detector, default_model_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXE = ROOT / "install" / "vla_detector" / "lib" / "vla_detector" / "detector_node"
LOST_AFTER_S = 0.3  # closed loop: a frame without detections by then counts as lost
LAYOUT = [("bread", 0.45, 0.2, 0.3), ("soda_can", 0.6, 0.0, 0.0), ("cereal_box", 0.5, -0.25, 1.0)]


def scenes(width: int, height: int, n: int = 8) -> list[np.ndarray]:
    from vla_sim.sim import PandaSim

    sim = PandaSim(width, height)
    out = []
    for i in range(n):
        sim.reset(seed=100 + i) if i else sim.reset(objects=LAYOUT)
        out.append(sim.render())
    sim.close()
    return out


def stats(ms: np.ndarray) -> str:
    return f"median {np.median(ms):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms  mean {ms.mean():6.2f} ms"


def bench_latency(det: Detector, images: list[np.ndarray], frames: int) -> tuple[np.ndarray, np.ndarray]:
    from vla_detector.decode import letterbox, to_input_tensor

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


def bench_node(images: list[np.ndarray], seconds: float, rate_hz: float | None) -> dict:
    """Start detector_node, publish images (closed loop if rate_hz is None), measure detections."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    from vla_interfaces.msg import DetectionArray

    proc = subprocess.Popen([str(EXE)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("bench_detector_peer", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got: list[tuple[float, float]] = []  # (receive time, latency)

    def on_det(msg: DetectionArray) -> None:
        now = time.time()
        sent = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        got.append((now, now - sent))

    node.create_subscription(DetectionArray, "detections", on_det, 50)
    pub = node.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
    msgs = []
    for im in images:
        m = Image(height=im.shape[0], width=im.shape[1], encoding="rgb8", step=im.shape[1] * 3)
        m.header.frame_id = "camera_optical_frame"
        m.data = im.tobytes()
        msgs.append(m)
    try:
        end = time.monotonic() + 30.0
        while time.monotonic() < end and (
            pub.get_subscription_count() < 1 or node.count_publishers("detections") < 1
        ):
            ex.spin_once(timeout_sec=0.05)
        if proc.poll() is not None:
            raise RuntimeError(f"detector_node exited: {proc.stderr.read()}")

        def publish(i: int) -> None:
            m = msgs[i % len(msgs)]
            t = time.time()
            m.header.stamp.sec, m.header.stamp.nanosec = int(t), int((t % 1) * 1e9)
            pub.publish(m)

        # warm-up: until the first detections arrive
        end = time.monotonic() + 20.0
        while not got and time.monotonic() < end:
            publish(0)
            ex.spin_once(timeout_sec=0.2)
        got.clear()
        sent = 0
        t_start = time.monotonic()
        if rate_hz is None:
            while time.monotonic() - t_start < seconds:
                n = len(got)
                publish(sent)
                sent += 1
                t_pub = time.monotonic()
                while len(got) == n and time.monotonic() - t_pub < LOST_AFTER_S:
                    ex.spin_once(timeout_sec=0.001)
        else:
            period = 1.0 / rate_hz
            next_t = t_start
            while time.monotonic() - t_start < seconds:
                if time.monotonic() >= next_t:
                    publish(sent)
                    sent += 1
                    next_t += period
                ex.spin_once(timeout_sec=max(0.0, min(0.002, next_t - time.monotonic())))
            elapsed = time.monotonic() - t_start
            drain = time.monotonic() + 0.5  # frames still in flight count; the rate is over the sending time
            while time.monotonic() < drain:
                ex.spin_once(timeout_sec=0.01)
        if rate_hz is None:
            elapsed = time.monotonic() - t_start
    finally:
        node.destroy_node()
        ex.shutdown()
        rclpy.shutdown(context=ctx)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
    lat = np.array([g[1] for g in got]) * 1e3 if got else np.full(1, np.nan)
    return {"sent": sent, "received": len(got), "fps": len(got) / elapsed, "latency_ms": lat}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(default_model_path()))
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-node", action="store_true", help="skip the end-to-end node measurement")
    a = ap.parse_args()
    det = Detector(a.model, num_threads=a.threads)
    w, h = det.input_size
    print(f"model {a.model}: input {w}x{h}, {len(det.classes)} classes, ONNX Runtime {a.threads} threads; "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print("torch imported at run time:", "torch" in sys.modules)
    imgs = {}
    for size in ((320, 240), (640, 480)):
        imgs[size] = scenes(*size)
        full, net = bench_latency(det, imgs[size], a.frames)
        print(f"detect() {size[0]}x{size[1]}: {stats(full)}   network only: {stats(net)}")
    if a.no_node:
        return 0
    profile = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")
    print(f"DDS: {os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp (default)')}, "
          f"Fast DDS profile: {profile or 'none (default transports)'}")
    if not EXE.exists():
        print(f"{EXE} missing: run make setup for the end-to-end figures")
        return 1
    lossy = False
    for size in ((320, 240), (640, 480)):
        r = bench_node(imgs[size], a.seconds, None)
        lossy |= r["received"] < r["sent"]
        print(f"node end to end {size[0]}x{size[1]}, closed loop: {r['fps']:.1f} frames/s sustained, "
              f"latency {stats(r['latency_ms'])} ({r['received']}/{r['sent']} frames)")
        r = bench_node(imgs[size], a.seconds, 30.0)
        print(f"node end to end {size[0]}x{size[1]}, camera at 30 Hz: {r['fps']:.1f} frames/s delivered, "
              f"latency {stats(r['latency_ms'])} ({r['received']}/{r['sent']} frames)")
    if lossy and not profile:
        print("frames were lost: best-effort images over ~512 KB overflow Fast DDS's default shared-memory "
              "segment; see the vla_detector README (FASTRTPS_DEFAULT_PROFILES_FILE with a larger segment)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
