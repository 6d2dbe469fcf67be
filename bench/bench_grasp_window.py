"""The grasp window (issue 23): how far the hand may be from where the demonstrations grasp and the
pick-and-place still succeed. A learned 1-D latent puts the hand near, not at, the grasp point; this
prints how near it must be. MuJoCo through the safety filter, the scripted plan's path and hand
events, the object moved by (along, across) from where the plan grasps it: `along` the approach
(along the fingers' gap, + the hand stops short), `across` it (the fingers' closing axis).

    python bench/bench_grasp_window.py [--task soda_can/pick_place_west] [--along -1,0,1]
                                       [--across 0,0.5,1] (cm)
"""
from __future__ import annotations

import argparse
import itertools
import time

import numpy as np
from brief import parse
from vla_common.catalogue import default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.tasks import place_target, task_success
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter
from vla_sim.planner import plan_task, random_start_pose
from vla_sim.sim import PandaSim

DT = 0.002
OPEN = (0.08, 0.08, 20.0)     # width m, speed m/s, force N: as the demonstrator sends them
GRASP = (0.0, 0.08, 30.0)
PLANNED_AT = (0.50, -0.05)    # where the plan believes the object is (mid grasp region)


def run_plan(sim: PandaSim, plan, obj_class: str, settle: float = 0.5):
    """Execute the plan with its hand events; ((time, height gained) lists, the object's end pose)."""
    f = SafetyFilter(SafetyConfig(dt=DT))
    f.reset(sim.q_target)
    t0, done, lift = sim.time, set(), ([], [])
    z0 = next(o.z for o in sim.object_poses() if o.class_id == obj_class)
    for _ in range(int((plan.duration + settle) / DT)):
        t = sim.time - t0
        for i, (when, what) in enumerate(plan.hand_events):
            if when <= t and i not in done:
                done.add(i)
                sim.hand.command(*(OPEN if what == "open" else GRASP))
        cmd, _code, _text = f.filter(plan.command(t, sim.q), sim.q_target, sim.time)
        sim.set_velocity_command(cmd)
        sim.step(1)
        lift[0].append(t)
        lift[1].append(next(o.z for o in sim.object_poses() if o.class_id == obj_class) - z0)
    return lift, next(o for o in sim.object_poses() if o.class_id == obj_class)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="soda_can/pick_place_west")
    p.add_argument("--along", default="-1,0,1", help="cm, + the hand stops short of the object's centre")
    p.add_argument("--across", default="0,0.5,1", help="cm, across the approach")
    p.add_argument("--seed", type=int, default=7, help="start pose and plan parameters")
    a = parse(p, argv, along="0", across="0")
    cat = default_catalogue()
    spec = cat.task(a.task)
    kin = PandaKinematics()
    sim = PandaSim(render=False, physics_dt=DT)
    t_all = time.monotonic()
    ok_all = []
    try:
        for across, along in itertools.product([float(v) for v in a.across.split(",")],
                                               [float(v) for v in a.along.split(",")]):
            rng = np.random.default_rng(a.seed)
            planned = ObjectPose(spec.object_class, *PLANNED_AT, 0.0)
            # the planner's hand comes from the robot's side (-x) with the fingers closing along y
            actual = ObjectPose(spec.object_class, PLANNED_AT[0] + along / 100,
                                PLANNED_AT[1] + across / 100, 0.0)
            start = sim.reset(objects=[actual], q0=random_start_pose(rng))[0]
            plan = plan_task(kin, spec, planned, sim.q, rng, cat)
            lift, end = run_plan(sim, plan, spec.object_class)
            ok, _a, _b = task_success(spec, start, end, lift=lift)
            err = float("nan")
            if spec.kind == "pick_place":
                err = float(np.linalg.norm(np.array([end.x, end.y]) - place_target(spec, start)))
            ok_all.append(ok)
            print(f"hand {along:+.1f} cm short, {across:+.1f} cm across: {'ok  ' if ok else 'FAIL'} "
                  f"placement error {err * 100:5.1f} cm, highest lift {max(lift[1]) * 100:4.1f} cm",
                  flush=True)
    finally:
        sim.close()
    print(f"{a.task}: {sum(ok_all)} of {len(ok_all)} offsets succeed ({time.monotonic() - t_all:.0f} s wall)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
