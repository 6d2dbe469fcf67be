"""vision_msgs/Detection2DArray beside our DetectionArray, where vision_msgs is installed (every full
Jazzy desktop install has it; the PyPI wheels here do not): so yolo_ros or any vision_msgs detector can
feed the controller, and RViz/Foxglove show our detections. Optional: without vision_msgs,
`AVAILABLE` is False and nodes skip the vision_msgs topic. Our type stays for what vision_msgs lacks
(the image size and the class index).

Mapping (vision_msgs 4.x): one ObjectHypothesisWithPose per Detection2D (class_id, score),
bbox.center.position.(x, y) the box centre and bbox.size_x/size_y its size, in pixels; the header is
the image's, on the array and on each detection.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from vla_common.detection import Detection

try:
    from vision_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose
    AVAILABLE = True
except ImportError:  # vision_msgs not installed: the vision_msgs topics are left out
    Detection2D = Detection2DArray = ObjectHypothesisWithPose = None
    AVAILABLE = False

TOPIC_SUFFIX = "_2d"  # `detections` (ours) and `detections_2d` (vision_msgs/Detection2DArray)


def to_detection2d_array(detections: Iterable[Detection], header) -> Detection2DArray:
    """vision_msgs/Detection2DArray of one image; the header is the image's."""
    out = Detection2DArray(header=header)
    for d in detections:
        m = Detection2D(header=header)
        h = ObjectHypothesisWithPose()
        h.hypothesis.class_id, h.hypothesis.score = d.class_id, float(d.score)
        m.results = [h]
        m.bbox.center.position.x, m.bbox.center.position.y = float(d.cx), float(d.cy)
        m.bbox.size_x, m.bbox.size_y = float(d.width), float(d.height)
        out.detections.append(m)
    return out


def from_detection2d_array(msg, classes: Sequence[str] = ()) -> list[Detection]:
    """Our detections from a Detection2DArray: the best hypothesis of each Detection2D (one without a
    hypothesis is skipped); class_index is the class's place in `classes`, -1 when not there."""
    out = []
    for m in msg.detections:
        if not m.results:
            continue
        best = max(m.results, key=lambda r: r.hypothesis.score).hypothesis
        index = classes.index(best.class_id) if best.class_id in classes else -1
        out.append(Detection(class_id=best.class_id, score=float(best.score),
                             cx=float(m.bbox.center.position.x), cy=float(m.bbox.center.position.y),
                             width=float(m.bbox.size_x), height=float(m.bbox.size_y), class_index=index))
    return out
