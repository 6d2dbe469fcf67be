"""Kinematic demonstrations straight from the task planner (no simulator, no bags): for tests,
benchmarks and quick experiments. Each is a ``vla_demo_recorder.dataset.Demo`` sampled at 10 Hz from
the plan's reference trajectory, with the goal object's detection where the simulated webcam would see
its centre (no image).
"""

from __future__ import annotations

import numpy as np
from vla_common.camera_model import SIM_WEBCAM
from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.detection import Detection
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import parse_task, task_layout
from vla_demo_recorder.dataset import Demo
from vla_sim.planner import plan_task, random_start_pose

IMAGE_SIZE = (640, 480)


def webcam_projection(image_size: tuple[int, int] = IMAGE_SIZE):
    """World point → pixel of the simulated webcam."""
    return SIM_WEBCAM.projector(*image_size)


def planner_demo(task: str, seed: int, kin=None, rate_hz: float = 10.0, catalogue: Catalogue | None = None):
    """(Demo, plan, goal ObjectPose) of one planned ``task`` episode; layout and start pose from ``seed``;
    the task, its object's shape and the class index from ``catalogue`` (default: vla_common's)."""
    kin = kin or PandaKinematics()
    catalogue = catalogue or default_catalogue()
    rng = np.random.default_rng(seed)
    spec = parse_task(task, catalogue)
    obj = task_layout(spec, rng, n_objects=1, catalogue=catalogue)[0]
    plan = plan_task(kin, spec, obj, random_start_pose(rng), rng, catalogue=catalogue)
    t = np.arange(0.0, plan.duration + 1e-9, 1.0 / rate_hz)
    q = np.array([plan.reference(ti)[0] for ti in t])
    cx, cy = webcam_projection()([obj.x, obj.y, 0.03])
    det = Detection(spec.object_class, 0.9, float(cx), float(cy), 30.0, 30.0,
                    class_index=catalogue.class_index(spec.object_class))
    demo = Demo(
        task=spec.name,
        object_class=spec.object_class,
        t=t,
        q=q,
        first_image=None,
        detection=det,
        image_size=IMAGE_SIZE,
        bag_path="",
    )
    return demo, plan, obj


def planner_demos(tasks, per_task: int, seed: int = 0, kin=None, catalogue: Catalogue | None = None) -> list:
    """``per_task`` demos of each task (distinct layouts), as Demo objects."""
    kin = kin or PandaKinematics()
    return [
        planner_demo(task, seed + 1000 * k + i, kin, catalogue=catalogue)[0]
        for k, task in enumerate(tasks)
        for i in range(per_task)
    ]
