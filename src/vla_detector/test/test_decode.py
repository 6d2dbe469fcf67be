"""Output decoding and NMS, on small ONNX graphs built here that emit known YOLOv5 / YOLOv8 outputs."""

import json

import numpy as np
import pytest
from detector_fake_models import make_model
from vla_detector.decode import DecodeError, infer_layout, letterbox, nms, postprocess
from vla_detector.inference import Detector, ModelError

# Known objects in model-input pixels (64x64 input): (cx, cy, w, h, class, score).
OBJECTS = [(20.0, 20.0, 10.0, 12.0, 0, 0.9), (44.0, 40.0, 16.0, 8.0, 2, 0.8)]
NC = 3


def candidate_rows():
    """Per candidate (cx, cy, w, h, class scores...): the objects, a weaker duplicate of the first (NMS
    must drop it), a different-class box on top of the first (kept: NMS is per class), one under the
    score threshold, and background."""
    rows = []
    for cx, cy, w, h, c, s in OBJECTS:
        sc = np.zeros(NC)
        sc[c] = s
        rows.append([cx, cy, w, h, *sc])
    rows.append([21.0, 20.5, 10.0, 12.0, 0.7, 0.0, 0.0])  # duplicate of object 0
    rows.append([20.0, 20.0, 10.0, 12.0, 0.0, 0.6, 0.0])  # class 1 on the same spot
    rows.append([50.0, 10.0, 8.0, 8.0, 0.0, 0.0, 0.1])  # below 0.3
    rows += [[5.0, 5.0, 4.0, 4.0, 0.01, 0.01, 0.01]] * 5
    return np.array(rows, dtype=np.float32)


def yolov8_output():
    return candidate_rows().T[None]  # [1, 4 + nc, N]


def yolov5_output():
    rows = candidate_rows()
    # YOLOv5: objectness x class probability = score; split the score as obj = 1, prob = score, except
    # for the first object where obj = 0.95 and prob = 0.9 / 0.95.
    obj = np.ones((len(rows), 1), np.float32)
    probs = rows[:, 4:].copy()
    obj[0] = 0.95
    probs[0] /= 0.95
    return np.concatenate([rows[:, :4], obj, probs], axis=1)[None]  # [1, N, 5 + nc]


def check_objects(dets):
    assert [d.class_index for d in dets] == [0, 2, 1]  # best first; class-1 box on object 0 kept
    for d, (cx, cy, w, h, c, s) in zip(dets[:2], OBJECTS):
        assert d.class_index == c
        assert d.score == pytest.approx(s, abs=1e-5)
        assert (d.cx, d.cy, d.width, d.height) == pytest.approx((cx, cy, w, h), abs=1e-4)


@pytest.mark.parametrize("layout,output", [("yolov8", yolov8_output()), ("yolov5", yolov5_output())])
def test_ultralytics_layouts_decode_known_boxes(tmp_path, layout, output):
    names = {0: "a", 1: "b", 2: "c"}
    path = make_model(
        tmp_path / f"{layout}.onnx", output, metadata={"names": repr(names), "imgsz": "[64, 64]"}
    )
    det = Detector(path, score_threshold=0.3, iou_threshold=0.25)
    assert det.layout == layout
    assert det.classes == ["a", "b", "c"]
    assert det.input_size == (64, 64)
    dets = det.detect(np.zeros((64, 64, 3), np.uint8))
    check_objects(dets)
    assert [d.class_id for d in dets] == ["a", "c", "b"]


def test_letterboxed_image_maps_boxes_back(tmp_path):
    path = make_model(tmp_path / "m.onnx", yolov8_output())
    det = Detector(path)
    # 128x96 image -> scale 0.5 -> 64x48, padded by 8 rows at the top and bottom.
    dets = det.detect(np.zeros((96, 128, 3), np.uint8))
    d = dets[0]
    assert (d.cx, d.cy, d.width, d.height) == pytest.approx((40.0, (20.0 - 8) * 2, 20.0, 24.0), abs=1e-4)
    assert det.classes == ["class0", "class1", "class2"]  # no names anywhere: generic ones


def test_sidecar_names_threshold_and_filter(tmp_path):
    path = make_model(tmp_path / "m.onnx", yolov8_output())
    (tmp_path / "m.json").write_text(json.dumps({"classes": ["x", "y", "z"], "layout": "yolov8"}))
    det = Detector(path, score_threshold=0.85, classes=["x", "z"])
    dets = det.detect(np.zeros((64, 64, 3), np.uint8))
    assert [(d.class_id, round(d.score, 3)) for d in dets] == [("x", 0.9)]
    det.score_threshold = 0.3
    assert [d.class_id for d in det.detect(np.zeros((64, 64, 3), np.uint8))] == ["x", "z"]
    with pytest.raises(ValueError, match="unknown class names"):
        det.set_class_filter(["nope"])
    det.max_detections = 1
    assert len(det.detect(np.zeros((64, 64, 3), np.uint8))) == 1


def test_postprocess_direct_and_nms_modes():
    boxes, scores, cls = postprocess(yolov8_output(), "yolov8", 0.3, 0.25, 100)
    assert list(cls) == [0, 2, 1]
    boxes, scores, cls = postprocess(yolov8_output(), "yolov8", 0.3, 0.25, 100, agnostic=True)
    assert list(cls) == [0, 2]  # the class-1 box on object 0 is suppressed class-agnostically
    b = np.array([[10, 10, 10, 10], [11, 10, 10, 10], [40, 40, 10, 10]], float)
    assert list(nms(b, np.array([0.5, 0.9, 0.4]), np.zeros(3, int), 0.5, 10)) == [1, 2]
    assert list(nms(np.zeros((0, 4)), np.zeros(0), np.zeros(0, int), 0.5, 10)) == []


def test_layout_inference_and_errors():
    assert infer_layout((1, 84, 8400)) == ("yolov8", 80)
    assert infer_layout((1, 25200, 85)) == ("yolov5", 80)
    assert infer_layout((1, 7, 9), num_classes=3) == ("yolov8", 3)
    assert infer_layout((1, 9, 8), num_classes=3) == ("yolov5", 3)
    with pytest.raises(DecodeError, match="fits neither"):
        infer_layout((1, 10, 100), num_classes=3)
    with pytest.raises(DecodeError, match=r"not \[1, a, b\]"):
        infer_layout((2, 10, 100))
    with pytest.raises(DecodeError, match="unknown output layout"):
        postprocess(yolov8_output(), "yolov9")


def test_letterbox_geometry():
    img = np.full((100, 200, 3), 7, np.uint8)
    out, lb = letterbox(img, 64, 64)
    assert out.shape == (64, 64, 3)
    assert lb.scale == pytest.approx(0.32) and lb.pad_x == 0 and lb.pad_y == 16
    assert out[0, 0, 0] == 114 and out[32, 32, 0] == 7
    same, lb2 = letterbox(img, 200, 100)
    assert same is img and lb2.scale == 1.0


def test_bad_models_fail_clearly(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        Detector(tmp_path / "missing.onnx")
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(b"this is not a protobuf" * 10)
    with pytest.raises(ModelError, match="not a valid ONNX model"):
        Detector(corrupt)
    path = make_model(tmp_path / "m.onnx", yolov8_output())
    (tmp_path / "m.json").write_text("{ not json")
    with pytest.raises(ModelError, match="unreadable model sidecar"):
        Detector(path)
    (tmp_path / "m.json").write_text(json.dumps({"classes": ["only", "two"]}))
    with pytest.raises(ModelError, match="fits neither"):
        Detector(path)
    (tmp_path / "m.json").write_text(json.dumps({"layout": "ssd"}))
    with pytest.raises(ModelError, match="unknown layout"):
        Detector(path)
    bad_shape = make_model(tmp_path / "b.onnx", np.zeros((1, 2, 3), np.float32))
    with pytest.raises(ModelError, match="too few channels"):
        Detector(bad_shape)


def test_detect_rejects_non_rgb(tmp_path):
    det = Detector(make_model(tmp_path / "m.onnx", yolov8_output()))
    with pytest.raises(ValueError, match="uint8 RGB"):
        det.detect(np.zeros((64, 64), np.uint8))
