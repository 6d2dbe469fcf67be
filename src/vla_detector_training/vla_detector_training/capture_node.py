"""The capture node: frames of `camera/image_raw` saved into a YOLO dataset skeleton for labelling
(`capture.CaptureSession`), a progress line per frame, a contact sheet at the end. It finishes
(exit 0) once `count` frames are saved; on SIGINT it stops within 2 s and writes the contact sheet of
what it saved. Run by `vla_detector_training capture` (vla_common.ros.node_main.run_node)."""

from __future__ import annotations

from rclpy.node import Node
from sensor_msgs.msg import Image
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.image_convert import UnsupportedImageError, to_rgb
from vla_common.ros.node_main import ConfigError
from vla_common.ros.parameters import Param, ParameterTable
from vla_common.ros.qos import RELIABILITIES, image_qos

from vla_detector_training.capture import CaptureSession
from vla_detector_training.dataset import SPLITS, DatasetError

WARN_PERIOD_S = 5.0


def _not_empty(value: str) -> str | None:
    return None if value.strip() else "must name the dataset folder"


PARAMS = ParameterTable([
    Param("out", "", "Dataset folder (created; a folder with frames is added to)", check=_not_empty),
    Param("count", 20, "Frames to save; the node finishes after the last", range=(1, 1_000_000)),
    Param("every", 1.0, "Seconds (of the node's clock) between saved frames; 0: every frame",
          range=(0.0, 86_400.0)),
    Param("split", "train", "Split the frames go to", choices=SPLITS),
    Param("catalogue", "", "Catalogue YAML naming the classes of data.yaml (empty: vla_common's default)"),
    Param("image_reliability", "reliable", "camera/image_raw subscription QoS (best_effort for a "
          "best-effort camera driver)", choices=tuple(RELIABILITIES)),
])


class CaptureNode(Node):
    def __init__(self, **kwargs):
        super().__init__("capture", **kwargs)
        p = PARAMS.declare(self)  # every parameter is read-only: a session is fixed at its start
        try:
            classes = load_catalogue(p["catalogue"] or None).classes
            self.session = CaptureSession(p["out"], p["count"], p["every"], classes, p["split"])
        except (CatalogueError, DatasetError, OSError) as exc:
            raise ConfigError(str(exc)) from exc
        self.finished = False
        self.sheet = None
        self.create_subscription(Image, "camera/image_raw", self._on_image, image_qos(p["image_reliability"]))
        self.get_logger().info(
            f"saving {p['count']} frames of camera/image_raw, {p['every']} s apart, into "
            f"{self.session.images} (classes {list(classes)})")

    def _on_image(self, msg: Image) -> None:
        if self.finished:
            return
        try:
            rgb = to_rgb(msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian))
        except UnsupportedImageError as exc:
            self.get_logger().warning(f"skipping image: {exc}", throttle_duration_sec=WARN_PERIOD_S)
            return
        path = self.session.offer(rgb, self.get_clock().now().nanoseconds * 1e-9)
        if path is None:
            return
        n, total = len(self.session.saved), self.session.count
        self.get_logger().info(f"[{n}/{total}] {path.name} ({msg.width}x{msg.height}, {msg.encoding})")
        if self.session.done:
            self._finish()

    def _finish(self) -> None:
        self.sheet = self.session.write_contact_sheet()
        self.finished = True
        if self.sheet is not None:
            self.get_logger().info(f"saved {len(self.session.saved)} frames; contact sheet {self.sheet}; "
                                   f"label them into {self.session.out / 'labels' / self.session.split}")

    def on_shutdown(self) -> None:
        """Interrupted: the contact sheet of the frames saved so far."""
        if not self.finished:
            self._finish()
