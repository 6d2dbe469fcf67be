"""detector_node: camera images in, vla_interfaces/DetectionArray out (ONNX Runtime, no torch).

Thin ROS wrapper around `vla_detector.inference.Detector`; see the package README for topics,
parameters and services.
"""

from __future__ import annotations

import sys
import time

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_srvs.srv import SetBool
from vla_common.image_convert import UnsupportedImageError, draw_detections, to_rgb

from vla_detector.inference import Detector, ModelError, default_model_path
from vla_interfaces.msg import Detection as DetectionMsg
from vla_interfaces.msg import DetectionArray

WARN_PERIOD_S = 5.0


def _unit_range() -> FloatingPointRange:
    return FloatingPointRange(from_value=0.0, to_value=1.0, step=0.0)


class DetectorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("detector_node", **kwargs)
        self.declare_parameter(
            "model_path",
            "",
            ParameterDescriptor(
                description="ONNX detector (ours with its .json sidecar, or an Ultralytics YOLOv5/YOLOv8 "
                "export); "
                "empty: the shipped model share/vla_detector/models/detector.onnx",
                read_only=True,
            ),
        )
        self.declare_parameter(
            "score_threshold",
            0.3,
            ParameterDescriptor(description="minimum detection score", floating_point_range=[_unit_range()]),
        )
        self.declare_parameter(
            "iou_threshold",
            0.25,
            ParameterDescriptor(
                description="NMS IoU threshold (per class)", floating_point_range=[_unit_range()]
            ),
        )
        self.declare_parameter(
            "max_detections",
            20,
            ParameterDescriptor(
                description="most detections per image, best first",
                integer_range=[IntegerRange(from_value=1, to_value=1000, step=1)],
            ),
        )
        self.declare_parameter(
            "classes",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY,
                description="publish only these class names; unset, empty or [''] for all",
            ),
        )
        self.declare_parameter(
            "enable",
            True,
            ParameterDescriptor(description="run detection; also switched by the ~/enable service"),
        )
        self.declare_parameter(
            "publish_overlay",
            False,
            ParameterDescriptor(
                description="also publish detections/image (rgb8 with boxes) for viewing", read_only=True
            ),
        )
        self.declare_parameter(
            "num_threads",
            2,
            ParameterDescriptor(
                description="ONNX Runtime intra-op threads",
                read_only=True,
                integer_range=[IntegerRange(from_value=1, to_value=64, step=1)],
            ),
        )

        path = self.get_parameter("model_path").value or str(default_model_path())
        try:
            classes = [c for c in (self.get_parameter("classes").value or []) if c]
        except ParameterUninitializedException:  # declared by type only: no filter
            classes = []
        self.detector = Detector(
            path,
            score_threshold=self.get_parameter("score_threshold").value,
            iou_threshold=self.get_parameter("iou_threshold").value,
            max_detections=self.get_parameter("max_detections").value,
            classes=classes or None,
            num_threads=self.get_parameter("num_threads").value,
        )  # ModelError / ValueError propagate to main(): a clear message and a non-zero exit
        self.enabled = bool(self.get_parameter("enable").value)
        self.add_on_set_parameters_callback(self._on_params)

        self.pub = self.create_publisher(DetectionArray, "detections", 10)
        self.overlay_pub = (
            self.create_publisher(Image, "detections/image", qos_profile_sensor_data)
            if self.get_parameter("publish_overlay").value
            else None
        )
        self.sub = self.create_subscription(
            Image, "camera/image_raw", self._on_image, qos_profile_sensor_data
        )
        self.srv = self.create_service(SetBool, "~/enable", self._on_enable)
        self.frames = 0
        self.skipped = 0
        self.last_latency_ms = float("nan")
        self._last_warn: dict[str, float] = {}
        w, h = self.detector.input_size
        self.get_logger().info(
            f"model {path}: {len(self.detector.classes)} classes {self.detector.classes}, input {w}x{h}, "
            f"layout {self.detector.layout}; detecting on camera/image_raw -> detections"
        )

    # ------------------------------------------------------------------ callbacks
    def _warn_throttled(self, key: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn.get(key, -1e9) >= WARN_PERIOD_S:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def _on_params(self, params) -> SetParametersResult:
        for p in params:
            if p.name == "classes":
                try:
                    self.detector.set_class_filter([c for c in (p.value or []) if c] or None)
                except ValueError as e:
                    return SetParametersResult(successful=False, reason=str(e))
            elif p.name == "score_threshold":
                self.detector.score_threshold = float(p.value)
            elif p.name == "iou_threshold":
                self.detector.iou_threshold = float(p.value)
            elif p.name == "max_detections":
                self.detector.max_detections = int(p.value)
            elif p.name == "enable":
                self.enabled = bool(p.value)
        return SetParametersResult(successful=True)

    def _on_enable(self, req: SetBool.Request, resp: SetBool.Response) -> SetBool.Response:
        self.enabled = bool(req.data)
        resp.success = True
        resp.message = "detection enabled" if self.enabled else "detection disabled"
        return resp

    def _on_image(self, msg: Image) -> None:
        if not self.enabled:
            return
        try:
            rgb = to_rgb(msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian))
        except UnsupportedImageError as e:
            self.skipped += 1
            self._warn_throttled("image", f"skipping image: {e}")
            return
        t0 = time.perf_counter()
        try:
            dets = self.detector.detect(rgb)
        except Exception as e:  # never let one bad frame kill the node
            self.skipped += 1
            self._warn_throttled("detect", f"detection failed on a {msg.width}x{msg.height} image: {e}")
            return
        self.last_latency_ms = (time.perf_counter() - t0) * 1e3
        out = DetectionArray()
        out.header = msg.header
        out.image_width = int(msg.width)
        out.image_height = int(msg.height)
        for d in dets:
            out.detections.append(
                DetectionMsg(
                    class_id=d.class_id,
                    class_index=d.class_index,
                    score=d.score,
                    center_x=d.cx,
                    center_y=d.cy,
                    size_x=d.w,
                    size_y=d.h,
                )
            )
        self.pub.publish(out)
        self.frames += 1
        if self.overlay_pub is not None:
            vis = draw_detections(rgb, dets)
            im = Image(
                header=msg.header,
                height=vis.shape[0],
                width=vis.shape[1],
                encoding="rgb8",
                is_bigendian=0,
                step=vis.shape[1] * 3,
            )
            im.data = vis.tobytes()
            self.overlay_pub.publish(im)


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = DetectorNode()
        rclpy.spin(node)
    except (ModelError, ValueError) as e:
        print(f"[detector_node] fatal: {e}", file=sys.stderr, flush=True)
        code = 1
    except KeyboardInterrupt:
        pass
    except rclpy.executors.ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
