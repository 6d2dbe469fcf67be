import numpy as np
import pytest
from vla_common.detection import Detection
from vla_latent_controller.context import (
    ContextError,
    context_dim,
    detector_context,
    preprocess_image,
    select_detection,
)
from vla_latent_controller.testing import CLASSES


def test_detector_context_is_one_hot_and_normalised_centre():
    c = detector_context(Detection("milk_carton", 0.9, 320.0, 120.0), (640, 480), CLASSES)
    assert c.shape == (context_dim("detector", len(CLASSES)),)
    np.testing.assert_array_equal(c[:5], [0, 0, 1, 0, 0])
    np.testing.assert_allclose(c[5:], [0.5, 0.25])


def test_unknown_class_and_bad_size_raise_clear_errors():
    with pytest.raises(ContextError, match="not one of the model's classes"):
        detector_context(Detection("teapot", 0.9, 1, 1), (640, 480), CLASSES)
    with pytest.raises(ContextError, match="image size"):
        detector_context(Detection("bread", 0.9, 1, 1), (0, 480), CLASSES)


def test_select_detection_policies():
    dets = [Detection("bread", 0.5, 100, 100), Detection("soda_can", 0.9, 500, 400),
            Detection("teapot", 0.99, 0, 0)]
    assert select_detection(dets, "highest_score", CLASSES).class_id == "soda_can"
    assert select_detection(dets, "nearest_to_ee", CLASSES, ee_pixel=(90, 90)).class_id == "bread"
    assert select_detection(dets, "nearest_to_ee", CLASSES, ee_pixel=None).class_id == "soda_can"
    assert select_detection(dets, "bread", CLASSES).class_id == "bread"
    assert select_detection(dets, "cereal_box", CLASSES) is None
    assert select_detection([Detection("bread", float("nan"), 1, 1)], "highest_score", CLASSES) is None


def test_preprocess_image_shape_and_range():
    img = np.zeros((480, 640, 3), np.uint8)
    img[:, 320:] = 255
    x = preprocess_image(img)
    assert x.shape == (3, 48, 64) and x.dtype == np.float32
    assert x[:, :, :32].max() == 0.0 and x[:, :, 32:].min() == 1.0
    with pytest.raises(ContextError):
        preprocess_image(np.zeros((10, 10)))


@pytest.mark.parametrize("cx, cy", [(1e6, -1e6), (-50.0, 240.0), (320.0, 480 * 1.03), (float("inf"), 1.0)])
def test_a_detection_outside_the_image_is_no_context(cx, cy):
    """Issue 20 item 8: (1e6, -1e6) or -50 px in a 640x480 image were latched and drove the arm."""
    det = Detection("bread", 0.9, cx, cy)
    with pytest.raises(ContextError, match="outside the 640x480 image|not finite"):
        detector_context(det, (640, 480), CLASSES)
    assert select_detection([det], "highest_score", CLASSES, image_size=(640, 480)) is None


def test_the_border_margin_and_a_valid_detection_beside_a_bad_one():
    for cx, cy in ((-12.0, 0.0), (652.0, 489.0), (0.0, 480.0)):  # within 2 % of the image size
        detector_context(Detection("bread", 0.9, cx, cy), (640, 480), CLASSES)
    dets = [Detection("soda_can", 0.99, 1e6, -1e6), Detection("bread", 0.5, 100, 100)]
    assert select_detection(dets, "highest_score", CLASSES, image_size=(640, 480)).class_id == "bread"
    with pytest.raises(ContextError, match="image size must be 1..16384 px a side, got 100000x480"):
        detector_context(Detection("bread", 0.9, 5e4, 1), (100_000, 480), CLASSES)
