"""The simulated camera's renderer: frames of requested states, rendered in a thread of its own.

Rendering (10-30 ms a frame on a CPU) runs on a second PandaSim in a worker thread — its own GL
context and its own MjData, fed a copy of the physics state's qpos — so the sim loop keeps its
period while a frame renders. Frames are stamped with the simulated time of that state.

Mesa's llvmpipe renders in the calling thread (LP_NUM_THREADS=0 unless the environment sets it): its
default, one rasteriser thread per core, costs the same CPU per frame but has to get every one of
those threads onto a core; on a loaded 2-core machine that took a frame's wall time from 15-18 ms
to 100-130 ms at the 90th percentile (bench: 640x480, load 13), and the camera dropped the frames
requested meanwhile.

The worker runs at background priority (vla_common.priority): a frame may wait, the 1 kHz physics
and the operator's input do not wait for a frame.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import numpy as np
from vla_common.catalogue import Catalogue
from vla_common.priority import run_in_background

from vla_sim.sim import PandaSim


class CameraWorker:
    """Renders requested states in a background thread and hands each frame to `on_frame(rgb, stamp)`.

    request() never blocks (real-time pacing wins). A request that comes while a frame renders waits
    in one slot and is rendered right after it; a newer request replaces a waiting one (counted in
    ``dropped``): the newest state is rendered next, never a backlog. (A request used to be dropped
    whenever a frame was rendering: a frame that rendered a little late cost the next one too.)
    wait_idle() lets an as-fast-as-possible loop wait instead, so no frame is dropped there.
    """

    def __init__(
        self,
        width: int,
        height: int,
        physics_dt: float,
        on_frame: Callable[[np.ndarray, float], None],
        on_error: Callable[[str], None] | None = None,
        catalogue: Catalogue | None = None,
    ):
        os.environ.setdefault("LP_NUM_THREADS", "0")   # before the first GL context (module docstring)
        self._sim = PandaSim(camera_width=width, camera_height=height, render=True, physics_dt=physics_dt,
                             catalogue=catalogue)
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
        """Render this state next; False when it replaced a request still waiting."""
        with self._cond:
            replaced = self._job is not None
            self.dropped += replaced
            self._job = (qpos, stamp)
            self._cond.notify()
            return not replaced

    def wait_idle(self, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy and self._job is None, timeout)

    def close(self, timeout: float = 2.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout)

    def _run(self) -> None:
        run_in_background()
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
