"""detector_node: camera images in, vla_interfaces/DetectionArray out (ONNX Runtime, no torch).

Thin ROS wrapper around `vla_detector.inference.Detector`; see the package README for topics,
parameters and services. Every run-time change, the ~/enable service included, goes through the
parameter table, so a parameter always reads what the node does.
"""

from __future__ import annotations

import time

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_policy_name_from_kind
from sensor_msgs.msg import Image
from std_srvs.srv import SetBool
from vla_common.catalogue import Catalogue, CatalogueError, load_catalogue
from vla_common.detection import Detection
from vla_common.image_convert import UnsupportedImageError, draw_detections, to_rgb
from vla_common.priority import run_in_background
from vla_common.ros import vision
from vla_common.ros.convert import detection_array
from vla_common.ros.diagnostics import Diagnostics
from vla_common.ros.node_main import ConfigError, StartupError, run_node
from vla_common.ros.parameters import Param, ParameterTable
from vla_common.ros.qos import IMAGE_DEPTH, IMAGE_QOS, RELIABILITIES, image_qos

from vla_detector.inference import Detector, ModelError, default_model_path
from vla_interfaces.msg import DetectionArray

WARN_PERIOD_S = 5.0

PARAMS = ParameterTable([
    Param("catalogue", "", "YAML file of the object classes ('': the default catalogue, "
          "vla_common/data/catalogue.yaml); every class the node publishes must be in it"),
    Param("model_path", "", "ONNX detector (ours with its .json sidecar, or an Ultralytics YOLOv5/YOLOv8 "
          "export); empty: the shipped model share/vla_detector/models/detector.onnx"),
    Param("score_threshold", 0.3, "minimum detection score", range=(0.0, 1.0), dynamic=True),
    Param("iou_threshold", 0.25, "NMS IoU threshold (per class)", range=(0.0, 1.0), dynamic=True),
    Param("max_detections", 20, "most detections per image, best first", range=(1, 1000), dynamic=True),
    Param("classes", [], "publish only these class names; empty or [''] for all", dynamic=True,
          array="string_array"),
    Param("enable", True, "run detection; the ~/enable service sets this parameter", dynamic=True),
    Param("publish_overlay", False, "also publish detections/image (rgb8 with boxes) for viewing"),
    Param("num_threads", 2, "ONNX Runtime intra-op threads", range=(1, 64)),
    Param("image_reliability", "reliable", "camera/image_raw subscription: reliable (every frame; the "
          "camera must publish reliable) or best_effort (for a best-effort camera driver)",
          choices=tuple(RELIABILITIES)),
    Param("image_queue", IMAGE_DEPTH, "camera/image_raw frames held while detection runs: they ride out a "
          "stall (1 s at 30 Hz); a model slower than the camera lags by as many frames, use 1-2 for it",
          range=(1, 100)),
])


def class_names(value) -> list[str]:
    """The `classes` parameter without its empty entries ([""] is how YAML spells an empty list)."""
    return [c for c in (value or []) if c]


class DetectorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("detector_node", **kwargs)
        p = PARAMS.declare(self, self._on_change)
        path = p["model_path"] or str(default_model_path())
        self.catalogue, self.detector = self._load(p, path)
        self.enabled = bool(p["enable"])

        self.pub = self.create_publisher(DetectionArray, "detections", QoSProfile(depth=10))
        self.pub_2d = (self.create_publisher(vision.Detection2DArray, "detections" + vision.TOPIC_SUFFIX,
                                             QoSProfile(depth=10)) if vision.AVAILABLE else None)
        self.overlay_pub = (
            self.create_publisher(Image, "detections/image", IMAGE_QOS) if p["publish_overlay"] else None
        )
        events = SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible_qos)
        self.sub = self.create_subscription(Image, "camera/image_raw", self._on_image,
                                            image_qos(p["image_reliability"], p["image_queue"]),
                                            event_callbacks=events)
        self.srv = self.create_service(SetBool, "~/enable", self._on_enable)
        self.diagnostics = Diagnostics(self)
        self.frames = 0
        self.skipped = 0
        self.last_latency_ms = float("nan")
        w, h = self.detector.input_size
        self.get_logger().info(
            f"model {path}: {len(self.detector.classes)} classes {self.detector.classes}, input {w}x{h}, "
            f"layout {self.detector.layout}; detecting on camera/image_raw ({p['image_reliability']}) "
            "-> detections"
        )

    def _load(self, p: dict, path: str) -> tuple[Catalogue, Detector]:
        """The catalogue and the model; ConfigError for a refused parameter, StartupError for a model
        that does not load."""
        try:
            catalogue = load_catalogue(p["catalogue"])
        except CatalogueError as exc:
            raise ConfigError(f"parameter 'catalogue': {exc}") from exc
        try:
            detector = Detector(path, score_threshold=p["score_threshold"], iou_threshold=p["iou_threshold"],
                                max_detections=p["max_detections"], num_threads=p["num_threads"])
        except (ModelError, ValueError) as exc:
            raise StartupError(str(exc)) from exc
        self.catalogue, self.detector = catalogue, detector
        reason = self._set_classes(class_names(p["classes"]))
        if reason:
            raise ConfigError(reason)
        missing = [c for c in catalogue.classes if c not in detector.classes]
        if missing:
            self.get_logger().warning(f"catalogue classes {missing} are not among the model's classes "
                                      f"{detector.classes}: they are never detected")
        return catalogue, detector

    def _on_change(self, name: str, value) -> str | None:
        """Apply one accepted run-time change, or return why it is refused."""
        if name == "classes":
            return self._set_classes(class_names(value))
        elif name == "score_threshold":
            self.detector.score_threshold = float(value)
        elif name == "iou_threshold":
            self.detector.iou_threshold = float(value)
        elif name == "max_detections":
            self.detector.max_detections = int(value)
        elif name == "enable":
            self.enabled = bool(value)
        return None

    def _set_classes(self, names: list[str]) -> str | None:
        """Publish only `names` (all when empty): classes of the model, and of the catalogue, so that the
        controller can place them. Else the reason, naming the lists; the filter stays as it was."""
        previous = self.detector.class_filter
        try:
            self.detector.set_class_filter(names or None)
        except ValueError as exc:
            return f"parameter 'classes': {exc}"
        what = f"detector model {self.detector.model_path}"
        if names:
            what += f" ('classes' filter {names})"
        try:
            self.catalogue.check_classes(names or self.detector.classes, what)
        except CatalogueError as exc:
            self.detector.class_filter = previous
            return f"{exc}; give a 'catalogue' that defines them or leave them out of 'classes'"
        return None

    def _on_enable(self, req: SetBool.Request, resp: SetBool.Response) -> SetBool.Response:
        """The service sets the `enable` parameter: one path (`_on_change`) applies both."""
        result = self.set_parameters([Parameter("enable", value=bool(req.data))])[0]
        resp.success = result.successful
        resp.message = result.reason or ("detection enabled" if self.enabled else "detection disabled")
        return resp

    def _on_incompatible_qos(self, event) -> None:
        policy = qos_policy_name_from_kind(event.last_policy_kind)
        self.get_logger().warning(
            f"camera/image_raw: a publisher offers an incompatible {policy} QoS and this subscription "
            "receives nothing from it; for a best-effort camera set image_reliability:=best_effort",
            throttle_duration_sec=WARN_PERIOD_S)

    def _on_image(self, msg: Image) -> None:
        if not self.enabled:
            return
        try:
            rgb = to_rgb(msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian))
        except UnsupportedImageError as exc:
            self.skipped += 1
            self.get_logger().warning(f"skipping image: {exc}", throttle_duration_sec=WARN_PERIOD_S)
            return
        t0 = time.perf_counter()
        try:
            dets = self.detector.detect(rgb)
        except Exception as exc:  # never let one bad frame kill the node
            self.skipped += 1
            self.get_logger().warning(f"detection failed on a {msg.width}x{msg.height} image: {exc}",
                                      throttle_duration_sec=WARN_PERIOD_S)
            return
        self.last_latency_ms = (time.perf_counter() - t0) * 1e3
        self.pub.publish(detection_array(dets, msg.header, (msg.width, msg.height)))
        if self.pub_2d is not None:
            self.pub_2d.publish(vision.to_detection2d_array(dets, msg.header))
        self.frames += 1
        self.diagnostics.update("ok", f"{len(dets)} detections", frames=self.frames, skipped=self.skipped,
                                latency_ms=self.last_latency_ms)
        if self.overlay_pub is not None:
            self.overlay_pub.publish(self._overlay(rgb, dets, msg.header))

    @staticmethod
    def _overlay(rgb, dets: list[Detection], header) -> Image:
        vis = draw_detections(rgb, dets)
        im = Image(header=header, height=vis.shape[0], width=vis.shape[1], encoding="rgb8", is_bigendian=0,
                   step=vis.shape[1] * 3)
        im.data = vis.tobytes()
        return im


def main(args: list[str] | None = None) -> int:
    # Detection is perception, not control: the whole process (its executor, the pools its imports
    # started, and ONNX Runtime's and DDS's threads, which inherit it) yields the CPU to the operator's
    # input and the arm's loop (vla_common.priority).
    run_in_background(process=True)
    return run_node(DetectorNode, "detector_node", args)


if __name__ == "__main__":
    raise SystemExit(main())
