"""The simulated Panda as a bridge backend (plain Python, no ROS): PandaSim stepped in fixed physics
increments by the bridge, plus a camera worker that renders frames in its own thread.

Rendering (10-30 ms a frame on a CPU) runs on a second PandaSim in a worker thread — its own GL
context and its own MjData, fed a copy of the physics state's qpos — so the sim loop keeps its
period while a frame renders. Frames are stamped with the simulated time of that state.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from vla_panda_bridge.backend import JointSample
from vla_panda_bridge.objects import ObjectPose
from vla_panda_bridge.sim import PandaSim


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


class CameraWorker:
    """Renders requested states in a background thread and hands each frame to `on_frame(rgb, stamp)`.

    request() never blocks: if the previous frame is still rendering the request is dropped and
    counted (real-time pacing wins). wait_idle() lets an as-fast-as-possible loop wait instead, so no
    frame is dropped there.
    """

    def __init__(
        self,
        width: int,
        height: int,
        physics_dt: float,
        on_frame: Callable[[np.ndarray, float], None],
        on_error: Callable[[str], None] | None = None,
    ):
        self._sim = PandaSim(camera_width=width, camera_height=height, render=True, physics_dt=physics_dt)
        self.intrinsics = self._sim.camera_intrinsics()
        self.frame_id = self._sim.camera_frame_id
        self.size = (width, height)
        self._on_frame = on_frame
        self._on_error = on_error
        self._cond = threading.Condition()
        self._job: tuple[np.ndarray, float] | None = None
        self._busy = False
        self._stop = False
        self.frames = 0
        self.dropped = 0
        self.render_seconds = 0.0
        self._thread = threading.Thread(target=self._run, name="camera_worker", daemon=True)
        self._thread.start()

    def request(self, qpos: np.ndarray, stamp: float) -> bool:
        with self._cond:
            if self._busy or self._job is not None:
                self.dropped += 1
                return False
            self._job = (qpos, stamp)
            self._cond.notify()
            return True

    def wait_idle(self, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy and self._job is None, timeout)

    def close(self, timeout: float = 2.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout)

    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    self._cond.wait_for(lambda: self._stop or self._job is not None)
                    if self._stop:
                        return
                    qpos, stamp = self._job
                    self._job = None
                    self._busy = True
                try:
                    t0 = time.perf_counter()
                    self._sim.data.qpos[:] = qpos
                    rgb = self._sim.render()
                    self.render_seconds += time.perf_counter() - t0
                    self.frames += 1
                    self._on_frame(rgb, stamp)
                except Exception as exc:  # a failed frame must not kill the worker; report it
                    if self._on_error is not None:
                        self._on_error(f"camera frame failed: {exc}")
                finally:
                    with self._cond:
                        self._busy = False
                        self._cond.notify_all()
        finally:
            self._sim.close()  # the GL context belongs to this thread
