"""The shared camera model (vla_common) is the camera the MuJoCo scene renders with."""
import numpy as np
from vla_common.camera_model import SIM_WEBCAM
from vla_sim.sim import PandaSim


def test_camera_model_projection_matches_the_simulated_camera():
    sim = PandaSim(render=False)
    pts = np.array([[0.5, 0.1, 0.0], [0.3, -0.2, 0.2], [0.6, 0.25, 0.05]])
    project = SIM_WEBCAM.projector(*sim.camera_size)
    ours = np.array([project(p) for p in pts])
    np.testing.assert_allclose(ours, sim.project(pts), atol=1e-6)
    assert sim.camera_intrinsics() == SIM_WEBCAM.intrinsics(*sim.camera_size)
