"""The live view through the node, a peer's camera topic and a page's socket (issue 32, item 8): an
empty and a corrupt image leave the view running, and a stopped camera shows as a stale view in the
state the pages get (``view_stale``, ``view_age_s``; the page's words are the page's own)."""
import numpy as np
import pytest
from rclpy.node import Node
from sensor_msgs.msg import Image
from vla_common.ros.qos import IMAGE_QOS

pytestmark = pytest.mark.ros


class Camera(Node):
    """A DDS peer on camera/image_raw: good frames at 20 Hz while ``on``; ``bad`` images go first."""

    def __init__(self, context):
        super().__init__("test_view_camera", context=context)
        self.pub = self.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
        self.on, self.bad, self.sent = True, [], 0
        self.create_timer(0.05, self._tick)

    def _tick(self):
        if self.bad:
            self.pub.publish(self.bad.pop(0))
        elif self.on:
            img = np.full((48, 64, 3), self.sent % 200, np.uint8)
            self.pub.publish(Image(height=48, width=64, encoding="rgb8", step=64 * 3, data=img.tobytes()))
            self.sent += 1


def test_bad_images_leave_the_view_running_and_a_stopped_camera_is_stale(station_node, page_class):
    node = station_node()
    h = station_node.harness
    cam = h.add(Camera(h.context))
    page = page_class(node.address)
    try:
        def state(p):
            s = p.last("state")
            return s or {}
        assert h.spin_until(lambda: page.jpegs >= 3 and state(page).get("view_stale") is False, 30.0), \
            page.got[-3:]
        n = page.jpegs
        cam.bad = [Image(height=0, width=0, encoding="rgb8"),                        # empty
                   Image(height=48, width=64, encoding="rgb8", step=192, data=b"\x01" * 99),   # corrupt
                   Image(height=48, width=64, encoding="32FC1", step=256, data=b"\0" * 256 * 48)]
        assert h.spin_until(lambda: not cam.bad and page.jpegs >= n + 5, 30.0)     # frames after them
        assert node.frames.refused == 3 and node.frames.alive()
        assert not state(page)["view_stale"]
        cam.on = False                                                             # the camera stops
        assert h.spin_until(lambda: state(page).get("view_stale") is True, 30.0)
        first = next(m for m in page.of("state") if m.get("view_stale") and m["view_age_s"] is not None)
        assert first["view_age_s"] >= 1.0
        cam.on = True
        assert h.spin_until(lambda: state(page).get("view_stale") is False, 30.0)
    finally:
        page.close()


@pytest.mark.parametrize("stop_on_stale_view", [True, False])
def test_a_stale_view_stops_the_arm_only_with_the_caregivers_setting(station_node, page_class, tmp_path,
                                                                      stop_on_stale_view):
    """stop_on_stale_view (off by default): a stale view holds motion (zero, inputs refused) and, once
    the view is back, motion needs a neutral input first. Off: the view only says it is stale."""
    import json
    import time

    from sensor_msgs.msg import Joy

    (tmp_path / "settings.json").write_text(json.dumps({"stop_on_stale_view": stop_on_stale_view}))
    node = station_node()
    h = station_node.harness
    cam = h.add(Camera(h.context))
    joys = []
    h.add(Node("test_view_joy", context=h.context)).create_subscription(Joy, "joy", joys.append, 100)
    page = page_class(node.address)
    seq = [0]

    def send(axis: float) -> None:
        seq[0] += 1
        page.send({"type": "input", "seq": seq[0], "t": time.monotonic() * 1000.0, "axis": axis})

    def state(key):
        return (page.last("state") or {}).get(key)
    try:
        assert h.spin_until(lambda: state("view_stale") is False and page.of("hello"), 30.0)
        send(0.0)
        send(0.5)
        assert h.spin_until(lambda: any(j.axes[0] == 0.5 for j in joys), 30.0)     # it moves
        send(0.0)                                  # let go (this page sends no heartbeat: at rest)
        cam.on = False
        assert h.spin_until(lambda: state("view_stale") is True, 30.0)
        n = len(page.of("refused"))
        send(0.5)
        if not stop_on_stale_view:
            assert h.spin_until(lambda: joys[-1].axes[0] == 0.5, 30.0) and not state("motion_held")
            assert len(page.of("refused")) == n
            return
        assert h.spin_until(lambda: len(page.of("refused")) > n, 30.0)
        assert "live view stopped" in page.last("refused")["reason"] and state("motion_held")
        assert h.spin_until(lambda: joys[-1].axes[0] == 0.0, 30.0)                  # stopped
        cam.on = True
        assert h.spin_until(lambda: state("view_stale") is False and state("motion_held") == "", 30.0)
        n = len(page.of("refused"))
        send(0.5)                                                    # held through the stop: refused
        assert h.spin_until(lambda: len(page.of("refused")) > n, 30.0)
        assert "neutral input first" in page.last("refused")["reason"]
        send(0.0)
        send(0.5)
        k = len(joys)
        assert h.spin_until(lambda: any(j.axes[0] == 0.5 for j in joys[k:]), 30.0)   # moves again
    finally:
        page.close()


def test_what_a_dds_peer_publishes_reaches_the_page_as_json_it_can_parse_and_bounded(station_node,
                                                                                      page_class):
    """Any peer may publish detections and status: a NaN or an infinity in them used to reach the page
    as NaN/Infinity, which JSON.parse refuses (the page dropped that state or frame); every detection
    went with every frame to every page."""
    from vla_interfaces.msg import ControllerStatus, Detection, DetectionArray

    node = station_node()
    h = station_node.harness
    cam = h.add(Camera(h.context))
    peer = h.add(Node("test_view_peer", context=h.context))
    dets = peer.create_publisher(DetectionArray, "detections", 10)
    ctrl = peer.create_publisher(ControllerStatus, f"{node.p['controller']}/status", 10)
    page = page_class(node.address)
    try:
        assert h.spin_until(lambda: page.jpegs >= 2, 30.0)
        nan, inf = float("nan"), float("inf")
        many = DetectionArray(image_width=64, image_height=48, detections=[
            Detection(class_id="x" * 100, score=nan, center_x=inf, center_y=1.0, size_x=2.0, size_y=3.0)
            for _ in range(500)])
        status = ControllerStatus(code=1, latched_x=nan, latched_y=-inf, reason="r" * 5000)

        def sent() -> bool:
            dets.publish(many)
            ctrl.publish(status)
            frames = page.of("frame")
            state = page.last("state") or {}
            return bool(frames and frames[-1]["boxes"] and state.get("controller"))
        assert h.spin_until(sent, 30.0)
        frame, state = page.of("frame")[-1], page.last("state")
        assert page.invalid == 0 and cam.sent > 0
        assert len(frame["boxes"]) == 32 and len(frame["boxes"][0]["class_id"]) == 64
        assert frame["boxes"][0]["score"] is None and frame["boxes"][0]["cx"] is None
        assert state["controller"]["latched_x"] is None and len(state["controller"]["reason"]) == 300
    finally:
        page.close()
