"""The simulated camera's worker: a request that comes while a frame renders is rendered next (the
newest of them), never dropped for being a little early, and never queued behind another."""
import threading

import numpy as np
from vla_sim.camera_worker import CameraWorker
from vla_sim.sim import PandaSim


def test_a_request_while_rendering_waits_and_the_newest_replaces_a_waiting_one():
    q = PandaSim(render=False).data.qpos.copy()
    delivered: list[int] = []
    first_in, let_go = threading.Event(), threading.Event()

    def on_frame(rgb: np.ndarray, stamp: int) -> None:
        delivered.append(stamp)
        if stamp == 1:           # hold the worker as a long render would
            first_in.set()
            let_go.wait(10.0)

    cam = CameraWorker(64, 48, 0.001, on_frame)
    try:
        assert cam.request(q, 1)
        assert first_in.wait(30.0)
        assert cam.request(q, 2)             # waits for the frame being rendered
        assert not cam.request(q, 3)         # replaces it: the newest state renders next
        let_go.set()
        assert cam.wait_idle(30.0)
        assert delivered == [1, 3] and cam.frames == 2 and cam.dropped == 1
    finally:
        let_go.set()
        cam.close()


def test_frames_render_at_background_priority():
    """The renderer yields the CPU to the physics loop and the operator's input (vla_common.priority)."""
    from vla_common.priority import BACKGROUND_NICE, MAX_NICE, thread_nice

    here = thread_nice()
    seen: list[int] = []
    cam = CameraWorker(64, 48, 0.001, lambda rgb, stamp: seen.append(thread_nice()))
    try:
        cam.request(PandaSim(render=False).data.qpos.copy(), 1)
        assert cam.wait_idle(30.0)
        assert seen == [min(MAX_NICE, here + BACKGROUND_NICE)]
        assert thread_nice() == here   # the caller's (the sim loop's) priority is untouched
    finally:
        cam.close()
