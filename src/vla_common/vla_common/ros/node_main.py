"""`run_node`: the one main of every node of the project.

- SIGINT and SIGTERM set a flag; the executor spins in short slices (`SPIN_SLICE_S`) so the flag is
  seen within that time even when every timer runs on a simulated clock that does not advance
  (`use_sim_time` without /clock): the node stops within 2 s of a signal, always.
- Before the context goes down the node's `on_shutdown()` runs (a zero command, acknowledged): with
  rclpy's own signal handling the context would already be invalid.
- Fast DDS gets the large-image transport profile (`qos.use_large_image_transport`) before
  rclpy.init, unless the environment chooses transports itself: whole camera frames go through
  shared memory, for every node alike.
- Shutdown is bounded, in two parts:
  - `on_shutdown` (the zero command) gets `SHUTDOWN_GRACE_S`, or the node's `shutdown_timeout_s`
    where its work needs longer (the recorder closes an episode's bag); one that has not returned by
    then is a failure: a C-level watchdog (faulthandler, it needs no Python lock) prints where each
    thread is and ends the process with exit code 1.
  - The teardown (destroy_node, rclpy shutdown, the DDS participant's deletion, said to the other
    participants) gets what is left of `STOP_S` since the signal (at least `TEARDOWN_MIN_S`: at rest
    about 1.7 s, after a long brake less), and then the process ends (`os._exit`) with its exit code: the
    node's duty is done, and Python's own finalization is skipped. That finalization ran after the
    watchdog was cancelled, unbounded: in 4 of 8 Ctrl-Cs of the teleop graph at load 12 it took
    2.0-2.9 s of the stop, and once it crashed the bridge (exit code -11, no Python frame); and a
    teardown starved at load 38 ran past the old 3 s watchdog in rclpy's logging shutdown (exit code
    1, issue 32). A teardown that runs past its bound (Fast DDS 2.14 can busy-wait in participant
    deletion when several nodes leave at once, eProsima/Fast-DDS #6513) has its threads' stacks
    printed, and the process ends all the same with its code: a native timer calls `_exit`
    (glibc's `timer_create` with SIGEV_THREAD: no GIL, no Python lock needed).
- The executor is rclpy's `EventsExecutor` (C++, rclpy.experimental): the default
  `SingleThreadedExecutor` rebuilt its wait set in Python for every callback, 44 % of the controller's
  samples (py-spy). In the whole teleop graph with the operator station, loaded machine (load 23-33,
  3 runs each, alternated, `bench/bench_operator.py`), the simulation kept x0.68-0.78 of real time
  against x0.37-0.45, the camera gave the station 20-23 frames/s against 10-13, key press ->
  joint_velocity_cmd median 4.8-6.3 ms against 13-34 ms; the controller used 10.5 % of a core against
  19-21 %. Its timers follow /clock with use_sim_time.
- Once the node is built, its `thread_priority` parameter, where it declares one, puts its threads
  at that SCHED_FIFO priority (`vla_common.priority.run_realtime`: the nodes on the operator's path).
- The command line is remembered for the parameter table, which tells a file section meant for this
  node from a shared one (`parameter_sources`).
- Exit codes: 0 after a signal or when the node sets `finished`; 2 for a refused parameter
  (`ConfigError`, or a command line or parameter file rcl cannot read: one line on stderr); 1 for any
  other failure at startup or in a callback (its message on stderr, no traceback for a startup
  error). A second signal during cleanup is ignored.
"""

from __future__ import annotations

import ctypes
import faulthandler
import gc
import os
import re
import signal
import sys
import time
import traceback
from collections.abc import Callable
from typing import Protocol

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from vla_common.priority import run_realtime
from vla_common.ros.context import destroy_node
from vla_common.ros.parameter_sources import remember
from vla_common.ros.qos import use_large_image_transport

SPIN_SLICE_S = 0.1
SHUTDOWN_GRACE_S = 3.0
STOP_S = 1.9           # a node stops within 2 s of a signal (the project's rule)
TEARDOWN_MIN_S = 0.3   # the teardown's bound when on_shutdown took most of STOP_S


class ConfigError(ValueError):
    """A parameter value (or a file it names) that the node refuses at startup: exit code 2."""


class StartupError(RuntimeError):
    """The node cannot start for another reason (a model that does not load, a device): exit code 1."""


class Stoppable(Protocol):
    # Optional: seconds on_shutdown may take (default SHUTDOWN_GRACE_S); destroy_node then gets its own.
    shutdown_timeout_s: float

    def on_shutdown(self) -> None:
        """Command zero (and wait for it to be acknowledged) while the context is still valid."""


class _Signals:
    """SIGINT/SIGTERM -> a flag (the first one), then ignored while cleaning up."""

    def __init__(self) -> None:
        self.received: int | None = None
        self.at: float | None = None   # monotonic s of the first signal
        self._previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def _on_signal(self, signum, frame) -> None:
        if self.received is None:
            self.received, self.at = signum, time.monotonic()

    def ignore(self) -> None:
        for s in self._previous:
            signal.signal(s, signal.SIG_IGN)


def spin_until_stopped(node: Node, executor, stop: Callable[[], bool]) -> None:
    """Spin in slices until `stop()` or the node's `finished` attribute is true, or the context ends."""
    while not stop() and not getattr(node, "finished", False) and executor.context.ok():
        executor.spin_once(timeout_sec=SPIN_SLICE_S)


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None) -> int:
    """Create the node with `make_node()`, spin it until a signal, shut it down, and end the process
    with the exit code (it returns only when rcl refuses the command line: 2)."""
    use_large_image_transport()
    argv = list(sys.argv if args is None else args)
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except _rclpy.RCLError as exc:  # a -p value or a parameter file rcl cannot read: say which, exit 2
        print(f"{name}: {rcl_argument_error(str(exc))}", file=sys.stderr)
        return 2
    remember(rclpy.utilities.get_default_context(), argv)  # which section gave which parameter
    signals = _Signals()
    node: Node | None = None
    executor: EventsExecutor | None = None
    code = 0
    try:
        node = make_node()
        executor = EventsExecutor()
        executor.add_node(node)
        _run_realtime(node)   # with the executor's own threads
        spin_until_stopped(node, executor, lambda: signals.received is not None)
        code = int(getattr(node, "exit_code", 0))
    except ConfigError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        code = 2
    except StartupError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # a failing callback: say what failed, exit non-zero so a launch notices
        traceback.print_exc()
        code = 1
    finally:
        signals.ignore()
        began = signals.at if signals.at is not None else time.monotonic()
        _shutdown(node, name)
    held = [node, executor]
    node = executor = None
    _end_process(held, name, code, max(TEARDOWN_MIN_S, began + STOP_S - time.monotonic()))
    return code  # not reached


def rcl_argument_error(text: str) -> str:
    """rcl's refusal of the command line in one line, without its source locations; with a hint where
    it read a bare y, no, on ... as a boolean inside a list of strings."""
    text = re.sub(r",? at /\S+:\d+", "", text).removeprefix("failed to initialize rcl: ").strip()
    if "Value type 'bool'" in text or "should be of same type" in text:
        text += (" (rcl reads a bare y, n, yes, no, on, off, true or false as a boolean: quote such "
                 "strings in a list, ['x', 'y'])")
    return text


def _run_realtime(node: Node) -> None:
    """The node's `thread_priority` (a parameter of the nodes on the operator's path) for its threads,
    now that they are all started: its background threads (nice > 0) are left as they are. Not in a
    lockstep simulation: it owns time and runs as fast as the CPU allows, with no person waiting on
    it; real time there would only take the cores from everything else."""
    if node.has_parameter("lockstep") and node.get_parameter("lockstep").value:
        return
    if node.has_parameter("thread_priority"):
        why = run_realtime(int(node.get_parameter("thread_priority").value))
        if why:
            node.get_logger().warning(why)


def _watchdog(seconds: float) -> None:
    """(Re)arm the watchdog: in `seconds`, print every thread's stack and exit 1."""
    faulthandler.dump_traceback_later(seconds, exit=True)


def _shutdown(node: Node | None, name: str) -> None:
    """The node's on_shutdown (its zero command), bounded: a hang ends the process with exit code 1."""
    try:
        on_shutdown = getattr(node, "on_shutdown", None)
        if on_shutdown is not None and rclpy.ok():
            _watchdog(max(SHUTDOWN_GRACE_S, float(getattr(node, "shutdown_timeout_s", 0.0))))
            on_shutdown()
    except Exception as exc:  # the context may already be gone: nothing more can be sent
        print(f"{name}: during shutdown: {exc}", file=sys.stderr)
    finally:
        faulthandler.cancel_dump_traceback_later()


def _end_process(held: list, name: str, code: int, bound: float) -> None:
    """Destroy the node, shut rclpy down and delete the DDS participant (the graph hears that it
    left), bounded by `bound` s; then end the process with `code`, skipping Python's finalization."""
    exit_after(bound, code)
    context = rclpy.utilities.get_default_context()  # try_shutdown puts a new one in its place
    try:
        node, executor = held
        held.clear()
        if node is not None:
            destroy_node(node)
        if executor is not None:
            executor.shutdown()
        del node, executor
    except Exception as exc:  # the context may already be gone
        print(f"{name}: during shutdown: {exc}", file=sys.stderr)
    finally:
        rclpy.try_shutdown()
    gc.collect()          # what still held the node's handles: the participant can go now
    context.destroy()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def exit_after(seconds: float, code: int) -> None:
    """In `seconds`, print every thread's stack and end the process with `code`, whatever holds the
    GIL: a glibc timer runs `_exit(code)` in a thread of its own. Where there is none (not glibc),
    the watchdog's exit code 1 instead."""
    faulthandler.dump_traceback_later(max(0.0, seconds - 0.05), exit=False)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        event = _SigEvent(value=code, notify=_SIGEV_THREAD,
                          function=ctypes.cast(libc._exit, ctypes.c_void_p).value)
        timer = ctypes.c_void_p()
        whole, frac = divmod(float(seconds), 1.0)
        spec = _ITimerSpec(value=_TimeSpec(int(whole), int(frac * 1e9)))
        if (libc.timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0
                or libc.timer_settime(timer, 0, ctypes.byref(spec), None) != 0):
            raise OSError(ctypes.get_errno(), "timer_create")
    except (OSError, AttributeError):
        _watchdog(seconds)


class _SigEvent(ctypes.Structure):
    """glibc's struct sigevent (64 bytes): the value, then for SIGEV_THREAD the function and its
    attributes in the union. `_exit` takes the value's low int: the exit code."""
    _fields_ = [("value", ctypes.c_void_p), ("signo", ctypes.c_int), ("notify", ctypes.c_int),
                ("function", ctypes.c_void_p), ("attributes", ctypes.c_void_p), ("pad", ctypes.c_int * 8)]


class _TimeSpec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [("interval", _TimeSpec), ("value", _TimeSpec)]


_SIGEV_THREAD = 2
_CLOCK_MONOTONIC = 1
