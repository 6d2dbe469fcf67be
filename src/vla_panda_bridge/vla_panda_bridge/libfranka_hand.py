"""The Franka Hand through libfranka's Gripper behind gripper.HandDriver (plain Python, no rclpy).

libfranka's Gripper calls block (a move, a grasp, homing until the fingers stop; read_once until the
hand's next state datagram), and the bindings hold the GIL while they do (measured with pylibfranka
0.21.3 against franka-sim: a thread that calls read_once in a loop lets the rest of its process run
only once per datagram, every 16.7 ms). So the Gripper lives in a process of its own, as the arm's
1 kHz loop does: `HandProcess` (the node's driver) starts `python -m vla_panda_bridge.libfranka_hand`
(after `prefix`, the loop's: e.g. `ip netns exec NS`) and supervises it as the loop's
(`child_process.ChildProcess`); they share latest-value slots (`hand_slots.HandSlots`, the bridge's one
IPC, `shm.py`): its `start`, `stop` and `read` only write or copy a slot.

In that process `LibfrankaHand` runs three threads: a reader (connects, then read_once in a loop: the
latest width and is_grasped), a commander (one motion at a time) and a stopper (Gripper.stop into a
running move or homing: libfranka answers each command by its id, so a stop on the same connection
interrupts it, as franka_gripper does, where the binding lets the stopper run during the call; the two
bindings here hold the GIL, so against them a running call ends first. Never into a grasp: a stop
after it closed would release what the hand holds, so a grasp is left to finish). A connection that
fails (the network, the hand switched off) makes `read` report an error, which GripperCore turns
into LOST; the reader reconnects every RECONNECT_PERIOD and the hand answers again. A motion the
hand refuses (libfranka's CommandException) is reported as that motion's failure. `stop` with no
motion running sends nothing: a finished grasp keeps holding (Gripper.stop would release its force).

Bindings: pylibfranka's Gripper (FR3) or panda-py's `panda_py.libfranka.Gripper` (Panda), the same
five calls; `open_gripper('auto')` tries pylibfranka first.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from vla_panda_bridge import gripper
from vla_panda_bridge.child_process import ChildProcess
from vla_panda_bridge.hand_slots import CONTROL, HandSlots
from vla_panda_bridge.libfranka_driver import _LOST

RECONNECT_PERIOD = 1.0     # s between connection attempts while the hand does not answer
STATE_WAIT = 1.0           # s a finished motion waits for the hand's states after it (bounded)
REPORT_PERIOD = 0.01       # s: the hand process reports a changed reading at most this often
BINDINGS = ("pylibfranka", "panda_py")


def gripper_class(binding: str) -> Callable[[str], Any]:
    """libfranka's Gripper class of a binding ('auto' is pylibfranka: see open_gripper)."""
    if binding == "panda_py":
        from panda_py import libfranka  # optional dependency: only a real Panda needs it
        return libfranka.Gripper
    import pylibfranka  # optional dependency: only a real arm / franka-sim needs it
    return pylibfranka.Gripper


def open_gripper(binding: str) -> Callable[[str], Any]:
    """A connect function for `binding` (a DRIVERS name): 'auto' tries pylibfranka's Gripper, then,
    where the hand speaks another protocol version, panda-py's."""
    if binding != "auto":
        return lambda ip: gripper_class(binding)(ip)

    def connect(ip: str):
        try:
            return gripper_class("pylibfranka")(ip)
        except ImportError:
            return gripper_class("panda_py")(ip)
        except Exception as exc:
            if "incompatible" not in str(exc).lower():
                raise
            try:
                return gripper_class("panda_py")(ip)
            except ImportError:
                raise exc from None
    return connect


def _lost(exc: BaseException) -> bool:
    """A connection that is gone (not a command the hand refused)."""
    if "Network" in type(exc).__name__:
        return True
    if "Command" in type(exc).__name__:
        return False
    return any(w in str(exc).lower() for w in _LOST)


def _text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


class LibfrankaHand:
    """gripper.HandDriver over libfranka's Gripper at `ip`, in the process it runs in (see the module
    docstring). `connect(ip)` makes a connected Gripper (open_gripper(binding)); `clock` stamps
    readings for the finger speed."""

    def __init__(self, ip: str, max_width: float, connect: Callable[[str], Any],
                 clock: Callable[[], float] = time.monotonic, reconnect_period: float = RECONNECT_PERIOD):
        self.ip, self.max_width = ip, float(max_width)
        self._connect, self._clock, self._reconnect_period = connect, clock, reconnect_period
        self._lock = threading.Condition()
        self._hand: Any = None                    # the connected Gripper (None: not connected)
        self._reading = gripper.HandReading(width=0.0, moving=False, error=f"connecting to the hand at {ip}")
        self._last: tuple[float, float] | None = None   # (time, width) of the last state read
        self._reads = 0                                 # states stored
        self._pending: gripper.HandOp | None = None     # the next motion, not started yet
        self._running: gripper.HandOp | None = None     # the motion being run (its call, then its states)
        self._in_call: gripper.HandOp | None = None     # the motion whose blocking call has not returned
        self._failed = ""                               # why the last motion failed ("" none)
        self._stops_asked = self._stops_done = 0
        self._closed = False
        self.stops_sent = 0                             # Gripper.stop calls made (tests, logs)
        self.connects = 0
        self._threads = [threading.Thread(target=f, name=f"hand-{n}", daemon=True)
                         for n, f in (("reader", self._read_loop), ("commander", self._command_loop),
                                      ("stopper", self._stop_loop))]
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ HandDriver (non-blocking)
    def start(self, op: gripper.HandOp) -> None:
        """Queue `op` (the latest wins); a running motion is stopped first."""
        with self._lock:
            if self._hand is None:
                raise ConnectionError(self._reading.error or "the hand is not connected")
            self._pending, self._failed = op, ""
            if self._running is not None:
                self._stops_asked += 1
            self._lock.notify_all()

    def stop(self) -> None:
        """Stop a running motion (Gripper.stop from the stopper thread); drop one not started yet.
        Nothing is sent when no motion runs: a finished grasp keeps holding."""
        with self._lock:
            self._pending = None
            if self._running is not None:
                self._stops_asked += 1
                self._lock.notify_all()

    def read(self) -> gripper.HandReading:
        with self._lock:
            r = self._reading
            return gripper.HandReading(width=r.width, grasped=r.grasped, error=r.error,
                                       finger_velocity=r.finger_velocity, failed=self._failed,
                                       moving=self._pending is not None or self._running is not None)

    def close(self, timeout: float = 1.0) -> None:
        """Stop a running motion, end the threads (bounded: a blocked call is left to its daemon)."""
        self.stop()
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        deadline = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))

    # ------------------------------------------------------------------ threads
    def _read_loop(self) -> None:
        while not self._closed:
            hand = self._hand
            if hand is None:
                try:
                    hand = self._connect(self.ip)
                except Exception as exc:
                    self._lose(None, f"cannot connect to the hand at {self.ip}: {_text(exc)}")
                    with self._lock:
                        self._lock.wait_for(lambda: self._closed, self._reconnect_period)
                    continue
                with self._lock:
                    self._hand = hand
                    self.connects += 1
            try:
                state = hand.read_once()
            except Exception as exc:
                self._lose(hand, f"reading the hand: {_text(exc)}")
                continue
            self._store(state)

    def _store(self, state) -> None:
        now, width = self._clock(), float(state.width)
        with self._lock:
            v = 0.0
            if self._last is not None and now > self._last[0]:
                v = (width - self._last[1]) / (now - self._last[0])
            self._last = (now, width)
            self._reads += 1
            self._lock.notify_all()
            self._reading = gripper.HandReading(width=width, moving=False, grasped=bool(state.is_grasped),
                                                finger_velocity=v)

    def _lose(self, hand: Any, why: str) -> None:
        """The connection `hand` is gone (None: none was made): drop it; readings report `why`."""
        with self._lock:
            if hand is None or self._hand is hand:
                self._hand, self._last = None, None
                self._pending = None
                self._reading = gripper.HandReading(width=self._reading.width, moving=False, error=why)

    def _command_loop(self) -> None:
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._closed or (self._pending is not None
                                                             and self._stops_done >= self._stops_asked))
                if self._closed:
                    return
                op, hand, asked = self._pending, self._hand, self._stops_asked
                self._pending, self._running = None, op
            failed = ""
            try:
                if hand is None:
                    raise ConnectionError("the hand is not connected")
                with self._lock:
                    self._in_call = op
                try:
                    if op.kind == gripper.HOMING:
                        hand.homing()
                    elif op.kind == gripper.GRASP:
                        hand.grasp(op.width, op.speed, op.force, op.epsilon_inner, op.epsilon_outer)
                    else:
                        hand.move(op.width, op.speed)
                except Exception as exc:
                    with self._lock:
                        self._in_call = None
                    if _lost(exc):
                        raise
                    with self._lock:
                        stopped = self._stops_asked > asked       # aborted by our stop: no failure
                    failed = "" if stopped else f"the hand refused the {_kind(op)}: {_text(exc)}"
            except Exception as exc:
                self._lose(hand, f"during {_kind(op)}: {_text(exc)}")
            with self._lock:
                self._in_call = None
                # The reader's second state from now was sent after the motion ended (the first may
                # have been queued before): only then is the motion over for `read`.
                self._lock.wait_for(lambda n=self._reads, h=hand: self._reads >= n + 2 or self._hand is not h
                                    or self._closed, STATE_WAIT)
                self._running = None
                if failed and self._pending is None:
                    self._failed = failed
                self._lock.notify_all()

    def _stop_loop(self) -> None:
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._closed or self._stops_asked > self._stops_done)
                if self._closed:
                    return
                # Only into a call still running, and never into a grasp: a stop that arrives after the
                # grasp closed (the bindings hold the GIL, so it cannot get there sooner) would release
                # what the hand holds. A grasp is left to finish.
                asked, hand, call = self._stops_asked, self._hand, self._in_call
            if call is not None and call.kind != gripper.GRASP and hand is not None:
                try:
                    hand.stop()
                    self.stops_sent += 1
                except Exception as exc:
                    if _lost(exc):
                        self._lose(hand, f"during stop: {_text(exc)}")
            with self._lock:
                self._stops_done = asked
                self._lock.notify_all()


def _kind(op: gripper.HandOp) -> str:
    return {gripper.HOMING: "homing", gripper.GRASP: "grasp"}.get(op.kind, "move")


# ---------------------------------------------------------------------------------- the node's side
class HandProcess:
    """gripper.HandDriver for the node: the Gripper in a process of its own (see the module docstring),
    supervised as the arm's loop process is (`child_process.ChildProcess`: one that exits is restarted
    with back-off; no stuck check, since a blocking Gripper call holds the process's GIL for seconds),
    and reached through shared-memory slots (`hand_slots.HandSlots`) as the loop is."""

    def __init__(self, ip: str, max_width: float, binding: str = "auto", prefix: str | list[str] = "",
                 python: str = sys.executable):
        self.max_width = float(max_width)
        self.slots = HandSlots.create()
        self.slots.control[CONTROL["parent_pid"]] = os.getpid()
        self.child = ChildProcess("hand", "vla_panda_bridge.libfranka_hand",
                                  ["--slots", self.slots.path, "--parent-pid", str(os.getpid()), ip,
                                   repr(self.max_width), binding], prefix=prefix, python=python,
                                  stuck_timeout=None)
        self._reading = gripper.HandReading(width=0.0, moving=False, error=f"connecting to the hand at {ip}")
        self._sent = self._done = 0                    # motions sent / the last the process finished
        self._closed = False
        self.child.start()

    @property
    def pid(self) -> int | None:
        return self.child.pid

    def start(self, op: gripper.HandOp) -> None:
        error = self.read().error
        if error:
            raise ConnectionError(error)
        self._sent += 1
        self.slots.write_op(self._sent, op)

    def stop(self) -> None:
        if not self._closed:
            self.slots.control[CONTROL["stop_req"]] += 1.0

    def read(self) -> gripper.HandReading:
        """The latest reading; the process supervised on the way (a dead one is restarted, and until
        the new one reads the hand, the reading's error says what happened)."""
        if self._closed:
            return gripper.HandReading(width=self._reading.width, moving=False, error="the hand is closed")
        self.child.poll(self.slots.reading_seq)
        got = self.slots.read_reading()
        if got is not None:
            self._reading, self._done = got
        r = self._reading
        return gripper.HandReading(width=r.width, grasped=r.grasped, error=self.child.note or r.error,
                                   failed=r.failed, finger_velocity=r.finger_velocity,
                                   moving=r.moving or self._done < self._sent)

    def close(self, timeout: float = 1.0) -> None:
        """Stop a running motion and end the process (killed after `timeout`)."""
        if self._closed:
            return
        self._closed = True
        self.slots.control[CONTROL["close"]] = 1.0
        self.child.close(timeout)
        self.slots.close()


def serve(hand: LibfrankaHand, slots: HandSlots, parent_pid: int | None) -> bool:
    """The hand process: each new motion in the slots to `hand`, stop requests, and every REPORT_PERIOD
    the reading with the number of the last motion that finished. Returns True when the node is gone."""
    got = slots.read_op()
    started = done = got[0] if got is not None else 0     # a restarted process replays nothing
    stops = slots.control[CONTROL["stop_req"]]
    while not slots.control[CONTROL["close"]]:
        if parent_pid is not None and os.getppid() != parent_pid:
            return True
        got = slots.read_op()
        if got is not None and got[0] > started:
            started = got[0]
            try:
                hand.start(got[1])
            except ConnectionError:
                done = started                              # refused: the reading's error says why
        if slots.control[CONTROL["stop_req"]] != stops:
            stops = slots.control[CONTROL["stop_req"]]
            hand.stop()
        r = hand.read()
        if not r.moving:
            done = started
        slots.write_reading(r, done)
        time.sleep(REPORT_PERIOD)
    return False


def main(argv: list[str] | None = None) -> int:
    """python -m vla_panda_bridge.libfranka_hand --slots PATH [--parent-pid PID] IP MAX_WIDTH BINDING"""
    ap = argparse.ArgumentParser(description="the Franka Hand's process of the bridge")
    ap.add_argument("--slots", required=True, help="the shared-memory file the bridge created")
    ap.add_argument("--parent-pid", type=int, default=None, help="exit when it is gone")
    ap.add_argument("ip")
    ap.add_argument("max_width", type=float)
    ap.add_argument("binding", choices=("auto", *BINDINGS))
    args = ap.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # the bridge stops it through its slots
    slots = HandSlots.attach(args.slots)
    signal.signal(signal.SIGTERM, lambda *_: slots.control.__setitem__(CONTROL["close"], 1.0))
    hand = LibfrankaHand(args.ip, args.max_width, open_gripper(args.binding))
    orphaned = serve(hand, slots, args.parent_pid)
    hand.close()
    slots.close()
    if orphaned:                                         # the bridge died without unlinking its slots
        try:
            os.unlink(args.slots)
        except FileNotFoundError:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
