"""Calibration YAML parsing, scaling and the errors for bad files."""
import pytest
from vla_camera.camera_info import CalibrationError, load_calibration, parse_calibration, url_to_path

OST = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [500.0, 0.0, 320.5, 0.0, 510.0, 240.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.01, 0.001, 0.002, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [495.0, 0.0, 321.0, 0.0, 0.0, 505.0, 241.0, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_parse_standard_file(tmp_path):
    path = tmp_path / "ost.yaml"
    path.write_text(OST)
    for url in (str(path), f"file://{path}"):
        c = load_calibration(url)
        assert (c.width, c.height, c.camera_name) == (640, 480, "narrow_stereo")
        assert c.k[0] == 500.0 and c.k[5] == 240.5 and len(c.k) == 9
        assert c.distortion_model == "plumb_bob" and c.d == [-0.1, 0.01, 0.001, 0.002, 0.0]
        assert c.p[0] == 495.0 and len(c.p) == 12 and c.r[4] == 1.0


def test_projection_defaults_to_k_when_absent():
    text = OST.split("rectification_matrix")[0]
    c = parse_calibration(text)
    assert c.p == [500.0, 0.0, 320.5, 0.0, 0.0, 510.0, 240.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert c.r == [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]


def test_scaling_to_half_size():
    c = parse_calibration(OST).scaled_to(320, 240)
    assert (c.width, c.height) == (320, 240)
    assert c.k[0] == 250.0 and c.k[2] == 160.25 and c.k[4] == 255.0 and c.k[5] == 120.25 and c.k[8] == 1.0
    assert c.p[0] == 247.5 and c.p[6] == 120.5 and c.p[10] == 1.0
    assert c.d == [-0.1, 0.01, 0.001, 0.002, 0.0]  # distortion is size independent


def test_scaling_refuses_other_aspect_ratio():
    with pytest.raises(CalibrationError, match="aspect ratio"):
        parse_calibration(OST).scaled_to(1280, 720)


@pytest.mark.parametrize(
    "text, match",
    [
        ("image_width: [640\n", "not valid YAML"),
        ("- just\n- a list\n", "mapping"),
        (OST.replace("image_width: 640\n", ""), "image_width"),
        (OST.replace("image_height: 480", "image_height: tall"), "integers"),
        (OST.replace("rows: 3\n  cols: 3\n  data: [500.0", "rows: 2\n  cols: 3\n  data: [500.0"), "3x3"),
        (OST.replace("0.0, 0.0, 1.0]\ndistortion", "0.0, 1.0]\ndistortion"), "9 numbers"),
        (OST.replace("510.0", "abc"), "non-number"),
        (OST.replace("510.0", ".nan"), "NaN"),
        (OST.replace("500.0, 0.0, 320.5", "-500.0, 0.0, 320.5"), "focal"),
        (OST.replace("data: [-0.1, 0.01, 0.001, 0.002, 0.0]", "data: [-0.1, 0.01]"), "takes 5"),
        (OST.replace("camera_matrix:", "camera_matrix_typo:"), "camera_matrix"),
    ],
)
def test_bad_yaml_errors_name_the_problem(text, match):
    with pytest.raises(CalibrationError, match=match):
        parse_calibration(text, "cal.yaml")


def test_missing_file_and_unsupported_url(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read camera calibration"):
        load_calibration(str(tmp_path / "nope.yaml"))
    with pytest.raises(CalibrationError, match="only file://"):
        url_to_path("http://example.com/cal.yaml")
    with pytest.raises(CalibrationError, match="not installed"):
        url_to_path("package://no_such_package_xyz/cal.yaml")
