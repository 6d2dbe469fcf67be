"""The assistance's push alone (issue 34): on N random layouts of a push task, the controller's assistance
drives the simulated Panda in bare MuJoCo (no graph, no person: the person's command zero, the goal
inferred with full confidence, the object where it stands) from the ready pose through the push, and the
object's motion is scored. It measures the push itself (the hand's lean, the links' clearance), apart from
the decoder, the detector and the participant.

Prints per task and per tall-object tilt asked (`--tall-tilt`, default the assistance's TALL_TILT_DEG):
pushes done (the task's success at the push's end), objects toppled, and done as the study's
participant judges it (the direction when the object has gone the task's distance + 1 cm). Development
layouts: seeds from 900000 by default, none of the study's or the holds'.

    python bench/bench_assist_push.py [--tasks cereal_box/push_south] [--n 200] [--first-seed 900000]
                                      [--tall-tilt 34,45]
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np
import vla_latent_controller.assistance as assistance
from brief import parse
from vla_common.catalogue import default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import task_layout, task_success
from vla_sim.sim import PandaSim

RATE = 20.0         # Hz, the controller's
LIMIT_S = 30.0      # a trial's limit in the study
AFTER_S = 1.0       # s the arm holds at the push's end before the object is scored
TOPPLED_BELOW = 0.6  # an object whose centre fell below this share of its standing height lies toppled


@dataclass
class Push:
    done: bool          # the task's success at the end
    toppled: bool
    judged: bool        # the task's success where the participant stops (the distance + 1 cm gone)


def push_once(sim: PandaSim, kin: PandaKinematics, task, shape, seed: int) -> Push:
    """One push from the ready pose on the layout of `seed` (the task's object alone, `shape` its spec)."""
    sim.reset(objects=task_layout(task, np.random.default_rng(seed), n_objects=1))
    start = sim.object_poses()[0]
    a = assistance.Assistance(kinematics=kin)
    a.level, a.tasks = "high", {task.object_class: [task]}
    xy, tcp = np.array([start.x, start.y]), kin.tcp_state(sim.q)[0]
    seen = assistance.Seen(task.object_class, xy, xy.copy(), (0.0, 0.0), (1.0, 1.0), (640, 480), tcp)
    poses = assistance._poses(task, shape, xy, tcp)
    goal = assistance.Goal(seen, task, poses, evidence=assistance.EVIDENCE_MAX)
    a.objects, a.goals = [seen], [goal]
    steps, t, judged, done_t = int(round(1.0 / RATE / sim.physics_dt)), 0.0, None, None
    while t < LIMIT_S and (done_t is None or t < done_t + AFTER_S):
        sim.set_velocity_command(a.command(sim.q, 1.0, np.zeros(7), t))
        sim.step(steps)
        t += 1.0 / RATE
        done_t = t if goal.done and done_t is None else done_t
        now = sim.object_poses()[0]
        moved = (now.x - start.x) * task.direction_vector[0] + (now.y - start.y) * task.direction_vector[1]
        if judged is None and moved >= task.distance + 0.01:
            judged = task_success(task, start, now)[0]
    end = sim.object_poses()[0]
    return Push(task_success(task, start, end)[0], end.z < TOPPLED_BELOW * start.z, bool(judged))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="cereal_box/push_south", help="comma-separated push tasks")
    p.add_argument("--n", type=int, default=200, help="layouts per task")
    p.add_argument("--first-seed", type=int, default=900000)
    p.add_argument("--tall-tilt", default="", help="comma-separated leans (deg) for tall objects' pushes "
                   "to compare in one run (default: the assistance's TALL_TILT_DEG)")
    a = parse(p, argv, n=2)
    tilts = [float(x) for x in a.tall_tilt.split(",") if x.strip()] or [assistance.TALL_TILT_DEG]
    cat, kin, sim = default_catalogue(), PandaKinematics(), PandaSim(render=False)
    shipped = assistance.TALL_TILT_DEG
    try:
        for name in a.tasks.split(","):
            task = cat.task(name.strip())
            for tilt in tilts:
                assistance.TALL_TILT_DEG = tilt
                rows = [push_once(sim, kin, task, cat.spec(task.object_class), a.first_seed + i)
                        for i in range(a.n)]
                print(f"{task.name:28s} tall tilt {tilt:4.1f} deg  layouts {a.n:4d}  done "
                      f"{sum(r.done for r in rows):4d}  toppled {sum(r.toppled for r in rows):4d}  "
                      f"done as judged {sum(r.judged for r in rows):4d}", flush=True)
    finally:
        assistance.TALL_TILT_DEG = shipped
        sim.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
