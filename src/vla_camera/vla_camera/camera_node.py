"""ROS 2 camera node: publishes frames of a device, video file or image folder with CameraInfo.

Thin wrapper around :mod:`vla_camera.source` and :mod:`vla_camera.camera_info`: a timer at ``fps``
reads one frame per tick (no busy loop), stamps it and publishes ``camera/image_raw`` and
``camera/camera_info`` with the same header. A missing or vanished device is retried with backoff and
reported on ``~/status``; the end of a file either loops, idles (default) or exits 0 (``exit_on_end``).
"""
from __future__ import annotations

import time

from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import SetBool
from vla_common.ros.diagnostics import Diagnostics
from vla_common.ros.node_main import ConfigError, run_node
from vla_common.ros.parameters import Param, ParameterTable
from vla_common.ros.qos import IMAGE_QOS

from vla_camera.camera_info import Calibration, CalibrationError, load_calibration
from vla_camera.source import (
    PIXEL_FORMATS,
    Backoff,
    FrameSource,
    SourceError,
    SourceKind,
    SourceState,
    parse_source,
)
from vla_interfaces.msg import CameraStatus

_STATE_CODES = {
    SourceState.STREAMING: CameraStatus.STREAMING,
    SourceState.PAUSED: CameraStatus.PAUSED,
    SourceState.RECONNECTING: CameraStatus.RECONNECTING,
    SourceState.ENDED: CameraStatus.ENDED,
}
_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}
WARN_PERIOD_S = 5.0


def _not_empty(value: str) -> str | None:
    return None if value else "must not be empty"


# All read-only: a new source, size or rate means a new capture; restart the node to change them.
PARAMS = ParameterTable([
    Param("source", "0", "Device index, /dev/videoN, a video file, an image file, or a folder/glob of "
          "images"),
    Param("loop", False, "Restart a video file or image list at its end instead of stopping"),
    Param("width", 0, "Output width in pixels (0 = native); frames are resized to it", range=(0, 8192)),
    Param("height", 0, "Output height in pixels (0 = native)", range=(0, 8192)),
    Param("fps", 30.0, "Publish rate in Hz (timer period); also requested from a device", range=(0.1, 240.0)),
    Param("pixel_format", "rgb8", "Output encoding", choices=PIXEL_FORMATS),
    Param("frame_id", "camera_optical_frame", "header.frame_id of images and camera info", check=_not_empty),
    Param("camera_info_url", "", "Calibration YAML: file:///path, package://pkg/path or a path; "
          "empty = uncalibrated"),
    Param("exit_on_end", False, "At the end of a non-looping file/folder: exit 0 (true) or idle"),
    Param("reconnect_initial_s", 0.25, "First retry delay for a missing device (doubles each time)",
          range=(0.01, 60.0)),
    Param("reconnect_max_s", 8.0, "Longest retry delay for a missing device", range=(0.01, 600.0)),
])


def check_parameters(p: dict) -> None:
    """The rules between parameters (each alone is checked by the table); ConfigError names them."""
    if (p["width"] == 0) != (p["height"] == 0):
        raise ConfigError("parameters 'width' and 'height' must both be 0 (native size) or both be set")
    if p["reconnect_initial_s"] > p["reconnect_max_s"]:
        raise ConfigError("parameter 'reconnect_initial_s' must not exceed 'reconnect_max_s'")


class CameraNode(Node):
    def __init__(self, *, capture_opener=None, **node_kwargs):
        super().__init__("camera_node", **node_kwargs)
        p = PARAMS.declare(self)
        check_parameters(p)
        self._calibration = self._load_calibration(p)
        self._params = p
        self._frame_id = p["frame_id"]
        self._encoding = p["pixel_format"]
        try:
            spec = parse_source(p["source"])
            self.source = FrameSource(
                spec,
                pixel_format=p["pixel_format"],
                width=p["width"],
                height=p["height"],
                fps=p["fps"],
                loop=p["loop"],
                backoff=Backoff(p["reconnect_initial_s"], p["reconnect_max_s"]),
                capture_opener=capture_opener,
            )
        except SourceError as exc:
            raise ConfigError(f"parameter 'source': {exc}") from exc
        self.frames_published = 0
        self.finished = False  # set when the source ended and exit_on_end is true: run_node returns 0
        self._info_cache: dict[tuple[int, int], CameraInfo] = {}
        self._last_state: SourceState | None = None
        self._message = ""

        # Reliable keep-last 30: matched by reliable and by best-effort (SensorDataQoS) subscribers alike.
        self._image_pub = self.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
        self._info_pub = self.create_publisher(CameraInfo, "camera/camera_info", IMAGE_QOS)
        self._status_pub = self.create_publisher(CameraStatus, "~/status", 10)
        self.diagnostics = Diagnostics(self)
        self.create_service(SetBool, "~/set_capture", self._on_set_capture)
        self._timer = self.create_timer(1.0 / p["fps"], self._tick)
        self._wake_timer = None  # one-shot timer for the next reconnect attempt
        self.create_timer(1.0, self._publish_status)
        calib = f"calibration {p['camera_info_url']}" if self._calibration else "uncalibrated"
        size = "native size" if p["width"] == 0 else f"{p['width']}x{p['height']}"
        self.get_logger().info(
            f"{spec.describe()} -> camera/image_raw at {p['fps']:g} Hz, {self._encoding}, {size}, "
            f"frame '{self._frame_id}', {calib}, loop={p['loop']}"
        )
        self._publish_status()

    @staticmethod
    def _load_calibration(p: dict) -> Calibration | None:
        """The calibration file, refused now if it cannot fit the configured output size."""
        if not p["camera_info_url"]:
            return None
        try:
            calibration = load_calibration(p["camera_info_url"])
            if p["width"] > 0:
                calibration.scaled_to(p["width"], p["height"])
        except CalibrationError as exc:
            raise ConfigError(f"parameter 'camera_info_url': {exc}") from exc
        return calibration

    # -- publishing --------------------------------------------------------------------------------
    def _tick(self) -> None:
        result = self.source.read(time.monotonic())
        if result.frame is not None:
            self._publish_frame(result.frame)
            if result.message:
                self.get_logger().warn(result.message, throttle_duration_sec=WARN_PERIOD_S)
        state = result.state
        self._message = result.message
        if state != self._last_state:
            self._on_state_change(state, result.message)
        if state is SourceState.RECONNECTING:
            self.get_logger().warn(
                f"camera {self._params['source']}: {result.message}", throttle_duration_sec=WARN_PERIOD_S
            )
            self._sleep_until_retry()

    def _sleep_until_retry(self) -> None:
        """Stop the frame timer until the next reconnect attempt: no wake-ups at fps while it is away."""
        delay = max(0.01, self.source.backoff.next_time - time.monotonic())
        self._timer.cancel()
        self._cancel_wake()
        self._wake_timer = self.create_timer(delay, self._wake)

    def _wake(self) -> None:
        self._cancel_wake()
        if not self.source.paused and self.source.state is not SourceState.ENDED:
            self._timer.reset()
            self._tick()  # attempt now rather than one frame period later

    def _cancel_wake(self) -> None:
        if self._wake_timer is not None:
            self.destroy_timer(self._wake_timer)
            self._wake_timer = None

    def _on_state_change(self, state: SourceState, message: str) -> None:
        previous, self._last_state = self._last_state, state
        if state is SourceState.STREAMING and previous is SourceState.RECONNECTING:
            self.get_logger().info(f"camera {self._params['source']} streaming")
        if state is SourceState.ENDED:
            self._timer.cancel()
            what = "exiting" if self._params["exit_on_end"] else "idling (set_capture true restarts it)"
            self.get_logger().info(f"{message}; {self.frames_published} frames published; {what}")
            if self._params["exit_on_end"]:
                self.finished = True
        self._publish_status()

    def _publish_frame(self, frame) -> None:
        h, w = frame.shape[:2]
        stamp = self.get_clock().now().to_msg()
        img = Image()
        img.header.stamp = stamp
        img.header.frame_id = self._frame_id
        img.height, img.width = h, w
        img.encoding = self._encoding
        img.is_bigendian = 0
        img.step = w * _CHANNELS[self._encoding]
        img.data = frame.tobytes()
        info = self._camera_info(w, h)
        info.header.stamp = stamp
        self._image_pub.publish(img)
        self._info_pub.publish(info)
        self.frames_published += 1

    def _camera_info(self, width: int, height: int) -> CameraInfo:
        info = self._info_cache.get((width, height))
        if info is not None:
            return info
        info = CameraInfo()
        info.header.frame_id = self._frame_id
        info.width, info.height = width, height
        if self._calibration is not None:
            try:
                c = self._calibration.scaled_to(width, height)
                info.distortion_model = c.distortion_model
                info.d = c.d
                info.k = c.k
                info.r = c.r
                info.p = c.p
            except CalibrationError as exc:
                self.get_logger().error(f"{exc}; publishing camera_info without intrinsics")
        self._info_cache[(width, height)] = info
        return info

    def _publish_status(self) -> None:
        msg = CameraStatus()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self._frame_id
        msg.state = _STATE_CODES[self.source.current_state]
        msg.source = str(self._params["source"])
        msg.frames_published = self.frames_published
        msg.reconnect_attempts = self.source.backoff.attempts
        msg.message = self._message
        self._status_pub.publish(msg)
        ok = msg.state in (CameraStatus.STREAMING, CameraStatus.PAUSED)
        self.diagnostics.update("ok" if ok else "warn", msg.message or "",
                                state=self.source.current_state, frames_published=msg.frames_published,
                                reconnect_attempts=msg.reconnect_attempts)

    # -- services ----------------------------------------------------------------------------------
    def _on_set_capture(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        if request.data:
            ended = self.source.state is SourceState.ENDED and self.source.spec.kind is not SourceKind.DEVICE
            if ended:
                self.source.restart()
            self.source.resume()
            self._message = "restarted from the first frame" if ended else "capture resumed"
            if self._timer.is_canceled():
                self._timer.reset()
        else:
            self.source.pause()
            self._timer.cancel()  # no wake-ups while paused
            self._cancel_wake()
            self._message = "capture paused"
        self._last_state = self.source.current_state
        response.success = True
        response.message = self._message
        self.get_logger().info(self._message)
        self._publish_status()
        return response

    def destroy_node(self):
        self.source.close()
        return super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(CameraNode, "camera_node", args)


if __name__ == "__main__":
    raise SystemExit(main())
