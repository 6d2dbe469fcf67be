"""Thread priority by role: perception and display work yields the CPU to input and control.

On the 2-core machine the graph alone keeps the cores busy at times (the simulated camera's renderer,
the detector, the live view's JPEG encoder, a browser drawing the frames). A key press then waits
behind that work at every hop from the page to the arm (the station's web thread, the controller),
and so does the 1 kHz loop. The bulk threads therefore lower their own priority (a higher nice value)
when they start: they still get the CPU the input and control threads leave, and always at least
their fair share against other background work, but a woken input or control thread runs first.

Lowering one's own priority needs no privilege. On Linux the nice value belongs to the thread (and
threads it starts inherit it), so this touches only the calling thread; elsewhere it is left alone.

A nice value is not enough for the input and control side: on the 2-core machine with the simulated
graph busy, a thread that sleeps 5 ms at nice 0 or -5 woke up to 100-176 ms late (115-168 times over
8 ms in 40 s; the same thread at SCHED_FIFO: at most 1.3 ms), and the key press waited for it at every
hop. So the nodes on the person's path (station, joystick, controller, bridge) can run their threads
at a modest SCHED_FIFO priority (`run_realtime`, the `thread_priority` parameter, as ros2_control's
controller manager does; off by default, `thread_priority:=10` in teleop.launch.yaml), where the system
allows it: root, CAP_SYS_NICE or an rtprio limit (the `realtime` group that libfranka's setup creates).
Their threads sleep between events, and the kernel keeps 5 % of each second for the others
(sched_rt_runtime_us). Elsewhere they run as before, with one line that says why.
"""
from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

BACKGROUND_NICE = 10   # added to the caller's nice value: weight ~1/9 of a nice-0 thread under contention
MAX_NICE = 19
# SCHED_FIFO priority the input and control nodes' threads are given where a launch asks for it
# (`thread_priority:=10`): above every normal thread, below the kernel's interrupt threads (50) and a
# libfranka loop given its own `loop_priority`
INPUT_PRIORITY = 10
MAX_PRIORITY = 98


def thread_nice() -> int:
    """The calling thread's nice value (Linux); the process's elsewhere."""
    return os.getpriority(os.PRIO_PROCESS, _this_thread())


def run_in_background(delta: int = BACKGROUND_NICE, process: bool = False) -> str | None:
    """Lower the calling thread's priority by ``delta`` nice steps (capped at 19); threads it starts
    afterwards inherit it. ``process``: every thread of this process instead (the pools that imports
    started too). Returns why not, or None."""
    if not sys.platform.startswith("linux"):
        return f"thread priorities are per process on {sys.platform}: left as they are"
    tids = _threads() if process else [_this_thread()]
    for tid in tids:
        try:
            _normal_policy(tid)   # a thread started by a real-time one: background is never real time
            os.setpriority(os.PRIO_PROCESS, tid, min(MAX_NICE, os.getpriority(os.PRIO_PROCESS, tid) + delta))
        except ProcessLookupError:
            pass   # a thread that ended meanwhile
        except OSError as e:
            return f"could not lower this thread's priority: {e.strerror}"
    return None


def _this_thread() -> int:
    return threading.get_native_id() if sys.platform.startswith("linux") else 0


def run_realtime(priority: int) -> str | None:
    """Every thread of this process that is not in the background (no higher nice value than the
    main thread's) to SCHED_FIFO `priority` (0: leave them as they are). Threads they start later,
    and child processes, begin at normal priority (SCHED_RESET_ON_FORK): a bulk worker or a
    subprocess is never real time by inheritance. A process started niced (nice > 0: a batch run,
    an evaluation beside other work) was asked to yield, and is left as it is. Returns why not (not
    Linux, not permitted), or None."""
    if priority <= 0 or not sys.platform.startswith("linux"):
        return None if priority <= 0 else f"real-time threads are Linux's: normal priority on {sys.platform}"
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    if base > 0:
        return None
    policy = os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
    for tid in _threads():
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) <= base:
                os.sched_setscheduler(tid, policy, os.sched_param(min(priority, MAX_PRIORITY)))
        except ProcessLookupError:
            pass   # a thread that ended meanwhile
        except OSError as e:
            return (f"SCHED_FIFO {priority} was refused ({e.strerror}): it needs root, CAP_SYS_NICE or "
                    "an rtprio limit (ulimit -r); the threads run at normal priority")
    return None


def thread_policy() -> int:
    """The calling thread's scheduling policy (os.SCHED_OTHER, os.SCHED_FIFO, ...), without flags."""
    return os.sched_getscheduler(_this_thread()) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)


def _normal_policy(tid: int) -> None:
    if os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK != os.SCHED_OTHER:
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


def _threads() -> list[int]:
    return [int(t.name) for t in Path("/proc/self/task").iterdir()]
