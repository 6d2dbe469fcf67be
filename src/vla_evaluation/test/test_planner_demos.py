"""Planner demonstrations of a lab catalogue's task, and of the default ones (no simulator)."""

from pathlib import Path

import numpy as np
from vla_common.catalogue import load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_evaluation.planner_demos import planner_demo, planner_demos

SPAM = Path(__file__).resolve().parents[3] / "test" / "data" / "spam_catalogue.yaml"


def test_a_catalogue_task_gets_its_class_index_and_a_plan():
    kin = PandaKinematics()
    demo, plan, obj = planner_demo("spam/push_south_east", 3, kin, catalogue=load_catalogue(SPAM))
    assert demo.task == "spam/push_south_east" and obj.class_id == "spam"
    assert demo.detection.class_index == 5 and demo.q.shape[1] == 7 and len(demo.q) > 20
    assert np.allclose(demo.q[0], plan.reference(0.0)[0])


def test_default_tasks_are_reproducible():
    kin = PandaKinematics()
    a = planner_demos(["bread/push_east"], per_task=2, seed=4, kin=kin)
    b = planner_demos(["bread/push_east"], per_task=2, seed=4, kin=kin)
    assert [d.detection.class_index for d in a] == [0, 0]
    assert all(np.array_equal(x.q, y.q) for x, y in zip(a, b)) and not np.array_equal(a[0].q, a[1].q)
