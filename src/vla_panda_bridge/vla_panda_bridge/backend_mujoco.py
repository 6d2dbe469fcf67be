"""The simulated Panda as a bridge backend (plain Python, no ROS): PandaSim stepped in fixed physics
increments by the bridge. Its camera is rendered by vla_sim.camera_worker in a thread of its own."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from vla_common.objects import ObjectPose
from vla_sim.sim import PandaSim

from vla_panda_bridge.backend import JointSample


class MujocoBackend:
    """PandaSim behind the Backend protocol. The bridge calls write() then step() once per control
    period (physics_dt), so the safety filter's period is the physics step."""

    kind = "mujoco"

    def __init__(self, physics_dt: float, seed: int = 0, q0: Sequence[float] | None = None):
        self.sim = PandaSim(render=False, physics_dt=physics_dt)
        self.physics_dt = self.sim.physics_dt
        self.layout: list[ObjectPose] = self.sim.reset(seed=seed, q0=q0)

    def read(self) -> JointSample:
        sim = self.sim
        return JointSample(sim.q, sim.dq, sim.effort, sim.time, reference=sim.q_target)

    def write(self, dq: np.ndarray) -> None:
        self.sim.set_velocity_command(dq)

    def step(self, n: int = 1) -> None:
        self.sim.step(n)

    def reset(self, seed: int | None = None, objects=None, q0=None) -> list[ObjectPose]:
        """PandaSim.reset: ValueError (scene unchanged) on an unknown class or malformed layout."""
        self.layout = self.sim.reset(seed=seed, objects=objects, q0=q0)
        return self.layout

    def object_poses(self) -> list[ObjectPose]:
        return self.sim.object_poses()

    def qpos(self) -> np.ndarray:
        return self.sim.data.qpos.copy()

    def close(self) -> None:
        self.sim.set_velocity_command(np.zeros(7))
