"""Checks a real Panda makes that the simulated one makes too (MuJoCo model and data in, no state
of their own beyond what they precompute):

- `CollisionChecker`: is a joint configuration in collision with the robot itself or the table/floor?
  (MuJoCo only generates robot-table contacts, and never robot-robot ones: the robot's links do not
  collide with each other in the scene.) Pairs of links in the same rigid group (a link and what is
  fixed to it, e.g. link7, flange, hand) or in adjacent groups (joined by one joint, or the
  two fingers on the hand) always touch and are not checked, as MoveIt's "adjacent" pairs; the
  base stands on the table.
- `ReflexMonitor`: has the measured state gone past the robot's limits (what libfranka reports as a
  reflex)? Names as libfranka's `franka::Errors`: `joint_position_limits_violation`,
  `joint_velocity_violation`, `joint_reflex` (an external torque beyond the joint's torque limit:
  a collision the drive cannot hold).
"""
from __future__ import annotations

import itertools
from operator import gt, lt

import mujoco
import numpy as np

COLLISION_TOLERANCE = 1e-3   # m of penetration that counts as a collision (touching does not)
VELOCITY_TOLERANCE = 1e-6    # relative: the servo follows the filter's output to ~1e-12 in free motion
OUTWARD_SPEED = 1e-3         # rad/s: past a position limit, a reflex needs motion further out

POSITION_REFLEX = "joint_position_limits_violation"
VELOCITY_REFLEX = "joint_velocity_violation"
TORQUE_REFLEX = "joint_reflex"


def _rigid_group(model: mujoco.MjModel, body: int) -> int:
    """The body's nearest ancestor (or itself) that a joint moves; 0 (world) for fixed bodies."""
    while body != 0 and model.body_jntnum[body] == 0:
        body = model.body_parentid[body]
    return body


class CollisionChecker:
    """Robot-robot and robot-table/floor collisions of an arm configuration, on a scratch MjData
    (the simulation's state is not touched)."""

    def __init__(self, model: mujoco.MjModel, qpos_adr: np.ndarray, robot_prefix: str,
                 environment: tuple[str, ...]):
        self._model = model
        self._data = mujoco.MjData(model)
        self._qadr = np.asarray(qpos_adr)
        robot = [g for g in range(model.ngeom)
                 if model.body(model.geom_bodyid[g]).name.startswith(robot_prefix)]
        group = {g: _rigid_group(model, int(model.geom_bodyid[g])) for g in robot}

        def parent_group(a: int) -> int:
            return _rigid_group(model, int(model.body_parentid[a])) if a != 0 else 0

        def adjacent(a: int, b: int) -> bool:  # or both moved off the same link: the two fingers
            pa, pb = parent_group(a), parent_group(b)
            return a == b or pa == b or pb == a or (a != 0 and b != 0 and pa == pb)

        def label(g: int) -> str:
            return model.geom(g).name or model.body(model.geom_bodyid[g]).name

        self.pairs: list[tuple[int, int, str]] = [
            (a, b, f"{label(a)} with {label(b)}") for a, b in itertools.combinations(robot, 2)
            if not adjacent(group[a], group[b])]
        for name in environment:
            env = model.geom(name).id
            self.pairs += [(g, env, f"{label(g)} with {name}") for g in robot if group[g] != 0]

    def collisions(self, q: np.ndarray) -> list[str]:
        """The colliding pairs at arm configuration `q` ("panda_hand with table_top", ...)."""
        m, d = self._model, self._data
        d.qpos[self._qadr] = q
        mujoco.mj_kinematics(m, d)
        found: list[str] = []
        for a, b, text in self.pairs:
            if mujoco.mj_geomDistance(m, d, a, b, COLLISION_TOLERANCE, None) < -COLLISION_TOLERANCE:
                if text not in found:
                    found.append(text)
        return found


class ReflexMonitor:
    """The limit checks of the robot's reflexes on one state, joint by joint on Python floats (it runs
    every physics step). `check(q, dq, tau_ext)` returns the libfranka-like error text of the first
    violation, or None. Past a position limit only motion further out counts, so an arm recovered
    there can move back in."""

    def __init__(self, names: tuple[str, ...], q_min, q_max, dq_max, tau_max):
        self._names = names
        self._limits = [tuple(float(x[i]) for x in (q_min, q_max, dq_max, tau_max))
                        for i in range(len(names))]
        self._q_min = [float(x) for x in q_min]
        self._q_max = [float(x) for x in q_max]
        self._v_lim = [float(x) * (1 + VELOCITY_TOLERANCE) for x in dq_max]
        self._tau_max = [float(x) for x in tau_max]

    def check(self, q: list[float], dq: list[float], tau_ext: list[float]) -> str | None:
        if not (any(map(gt, map(abs, dq), self._v_lim)) or any(map(gt, q, self._q_max))
                or any(map(lt, q, self._q_min)) or any(map(gt, map(abs, tau_ext), self._tau_max))):
            return None                                     # the common case, checked in C
        for i, (lo, hi, vmax, tmax) in enumerate(self._limits):
            v = dq[i]
            if abs(v) > self._v_lim[i]:
                return f"{VELOCITY_REFLEX}: {self._names[i]} at {v:.4g} rad/s (limit {vmax:g})"
            if (q[i] > hi and v > OUTWARD_SPEED) or (q[i] < lo and v < -OUTWARD_SPEED):
                return f"{POSITION_REFLEX}: {self._names[i]} at {q[i]:.4g} rad (limits {lo:g}..{hi:g})"
            if abs(tau_ext[i]) > tmax:
                return (f"{TORQUE_REFLEX}: external torque {tau_ext[i]:.4g} Nm on {self._names[i]} "
                        f"(beyond its {tmax:g} Nm)")
        return None
