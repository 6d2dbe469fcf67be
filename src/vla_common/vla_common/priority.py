"""Thread priority by role: perception and display work yields the CPU to input and control.

On the 2-core machine the graph alone keeps the cores busy at times (the simulated camera's renderer,
the detector, the live view's JPEG encoder, a browser drawing the frames). A key press then waits
behind that work at every hop from the page to the arm (the station's web thread, the controller),
and so does the 1 kHz loop. The bulk threads therefore lower their own priority (a higher nice value)
when they start: they still get the CPU the input and control threads leave, and always at least
their fair share against other background work, but a woken input or control thread runs first.

Lowering one's own priority needs no privilege. On Linux the nice value belongs to the thread (and
threads it starts inherit it), so this touches only the calling thread; elsewhere it is left alone.
"""
from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

BACKGROUND_NICE = 10   # added to the caller's nice value: weight ~1/9 of a nice-0 thread under contention
MAX_NICE = 19


def thread_nice() -> int:
    """The calling thread's nice value (Linux); the process's elsewhere."""
    return os.getpriority(os.PRIO_PROCESS, _this_thread())


def run_in_background(delta: int = BACKGROUND_NICE, process: bool = False) -> str | None:
    """Lower the calling thread's priority by ``delta`` nice steps (capped at 19); threads it starts
    afterwards inherit it. ``process``: every thread of this process instead (the pools that imports
    started too). Returns why not, or None."""
    if not sys.platform.startswith("linux"):
        return f"thread priorities are per process on {sys.platform}: left as they are"
    tids = [int(t.name) for t in Path("/proc/self/task").iterdir()] if process else [_this_thread()]
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, min(MAX_NICE, os.getpriority(os.PRIO_PROCESS, tid) + delta))
        except ProcessLookupError:
            pass   # a thread that ended meanwhile
        except OSError as e:
            return f"could not lower this thread's priority: {e.strerror}"
    return None


def _this_thread() -> int:
    return threading.get_native_id() if sys.platform.startswith("linux") else 0
