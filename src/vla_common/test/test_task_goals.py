"""Task goal poses (vla_common.task_goals) and the camera's inverse projection the assistance uses."""
import math

import numpy as np
import pytest
from vla_common.camera_model import SIM_WEBCAM
from vla_common.catalogue import default_catalogue
from vla_common.task_goals import DOWN, GRASP, OPEN, task_goal_poses

CAT = default_catalogue()


def poses(task, xy, tcp=None):
    spec = CAT.task(task)
    return task_goal_poses(spec, CAT.spec(spec.object_class), xy, tcp)


def test_a_push_hovers_behind_the_object_comes_down_and_pushes_the_task_distance():
    hover, pre, end = poses("soda_can/push_south", (0.5, 0.1))
    assert [p.name for p in (hover, pre, end)] == ["hover", "pre_push", "push_end"]
    assert hover.position[:2] == pytest.approx(pre.position[:2])
    assert pre.position[0] > 0.5 + 0.033 and pre.position[1] == pytest.approx(0.1)   # north of the can
    assert pre.position[2] == pytest.approx(0.025) and hover.position[2] >= 0.18
    travel = end.position - pre.position
    assert travel[1] == pytest.approx(0.0) and -travel[0] > CAT.task("soda_can/push_south").distance
    for p in (hover, pre, end):
        assert p.rotation @ p.rotation.T == pytest.approx(np.eye(3)) and p.speed > 0 and not p.hand


def test_a_circle_goes_round_the_object_from_where_the_hand_is():
    ring = poses("cereal_box/circle", (0.5, 0.0), tcp=(0.5, 0.5, 0.4))
    centre = np.array([0.5, 0.0])
    r = [np.linalg.norm(p.position[:2] - centre) for p in ring]
    assert max(r) == pytest.approx(min(r)) and min(r) > CAT.spec("cereal_box").footprint_radius
    assert ring[0].position[1] > 0.1 and ring[0].position[0] == pytest.approx(0.5)   # on the hand's side
    angles = np.unwrap([math.atan2(p.position[1], p.position[0] - 0.5) for p in ring])
    assert np.all(np.diff(angles) > 0) and angles[-1] - angles[0] >= math.radians(330)


def test_a_pick_and_place_closes_the_hand_at_the_object_and_opens_it_at_the_target():
    ps = poses("glass_bottle/pick_place_west", (0.5, -0.1))
    assert [p.name for p in ps] == ["hover", "grasp", "carry", "place", "retreat"]
    assert [p.hand for p in ps] == [OPEN, GRASP, "", OPEN, ""]     # open above it, close on it, ...
    assert ps[1].position[:2] == pytest.approx((0.5, -0.1))
    assert ps[3].position[:2] == pytest.approx((0.5, 0.05))        # 15 cm west
    assert all(np.array_equal(p.rotation, DOWN) for p in ps)


def test_unproject_inverts_the_projection_on_a_plane():
    project, unproject = SIM_WEBCAM.projector(640, 480), SIM_WEBCAM.unprojector(640, 480)
    for point in ([0.5, 0.1, 0.04], [0.35, -0.25, 0.135], [0.62, 0.3, 0.0]):
        assert unproject(project(point), point[2]) == pytest.approx(point, abs=1e-9)
    assert unproject((320.0, -5000.0), 0.0) is None          # a ray above the horizon meets no table
