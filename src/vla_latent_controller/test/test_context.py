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
