"""The Franka Hand through libfranka's Gripper behind gripper.HandDriver (plain Python, no rclpy).

libfranka's Gripper calls block (a move, a grasp, homing until the fingers stop; read_once until the
hand's next state datagram), and the bindings hold the GIL while they do (measured with pylibfranka
0.21.3 against franka-sim: a thread that calls read_once in a loop lets the rest of its process run
only once per datagram, every 16.7 ms). So the Gripper lives in a process of its own, as the arm's
1 kHz loop does: `HandProcess` (the node's driver) starts `python -m vla_panda_bridge.libfranka_hand`
(after `prefix`, the loop's: e.g. `ip netns exec NS`) and exchanges JSON lines with it; its
`start`, `stop` and `read` only write a line or copy the latest reading.

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

import json
import math
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from vla_panda_bridge import gripper
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
    """gripper.HandDriver for the node: the Gripper in a process of its own (see the module
    docstring). Readings arrive on the process' stdout; ops and stops go to its stdin."""

    def __init__(self, ip: str, max_width: float, binding: str = "auto", prefix: str | list[str] = "",
                 python: str = sys.executable):
        self.max_width = float(max_width)
        words = shlex.split(prefix) if isinstance(prefix, str) else list(prefix)
        cmd = [*words, python, "-m", "vla_panda_bridge.libfranka_hand", ip, repr(self.max_width), binding]
        self._lock = threading.Lock()
        self._reading = gripper.HandReading(width=0.0, moving=False, error=f"connecting to the hand at {ip}")
        self._sent = self._done = 0                    # ops sent / ops the process reported finished
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                      bufsize=1, start_new_session=True)
        self._thread = threading.Thread(target=self._listen, name="hand-listen", daemon=True)
        self._thread.start()

    @property
    def pid(self) -> int:
        return self._proc.pid

    def start(self, op: gripper.HandOp) -> None:
        with self._lock:
            if self._reading.error:
                raise ConnectionError(self._reading.error)
            self._sent += 1
            self._send({"op": op.kind, "width": op.width, "speed": op.speed, "force": op.force,
                        "epsilon_inner": op.epsilon_inner, "epsilon_outer": op.epsilon_outer,
                        "seq": self._sent})

    def stop(self) -> None:
        with self._lock:
            self._send({"stop": True})

    def read(self) -> gripper.HandReading:
        with self._lock:
            r = self._reading
            return gripper.HandReading(width=r.width, grasped=r.grasped, error=r.error, failed=r.failed,
                                       finger_velocity=r.finger_velocity,
                                       moving=r.moving or self._done < self._sent)

    def close(self, timeout: float = 1.0) -> None:
        """Stop a running motion and end the process (killed after `timeout`)."""
        with self._lock:
            self._send({"close": True})
        try:
            self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()

    def _send(self, msg: dict) -> None:
        try:
            self._proc.stdin.write(json.dumps(msg) + "\n")
            self._proc.stdin.flush()
        except (BrokenPipeError, ValueError, OSError):
            pass                                    # the process is gone: _listen reports it

    def _listen(self) -> None:
        for line in self._proc.stdout:
            try:
                m = json.loads(line)
                r = gripper.HandReading(width=float(m["width"]), moving=bool(m["moving"]),
                                        grasped=m["grasped"], error=str(m["error"]), failed=str(m["failed"]),
                                        finger_velocity=float(m["v"]))
                done = int(m["done"])
            except (ValueError, KeyError, TypeError):
                continue                            # not a reading (a stray print): ignored
            with self._lock:
                self._reading, self._done = r, max(self._done, done)
        code = self._proc.wait()
        with self._lock:
            self._reading = gripper.HandReading(width=self._reading.width, moving=False,
                                                error=f"the hand process exited with code {code}")
            self._done = self._sent


def _serve(hand: LibfrankaHand, out) -> None:
    """The hand process: ops and stops from stdin to `hand`; its readings to `out` when they change
    (at most every REPORT_PERIOD), with the number of the last op that finished."""
    lock = threading.Lock()
    started = [0, 0]                                 # [seq of the last op started, seq finished]
    closing = threading.Event()

    def commands() -> None:
        for line in sys.stdin:
            try:
                m = json.loads(line)
            except ValueError:
                continue
            if m.get("close"):
                break
            if m.get("stop"):
                hand.stop()
                continue
            op = gripper.HandOp(int(m["op"]), float(m["width"]), float(m["speed"]), float(m["force"]),
                                float(m["epsilon_inner"]), float(m["epsilon_outer"]))
            with lock:
                try:
                    hand.start(op)
                    started[0] = int(m["seq"])
                except ConnectionError:
                    started[0] = started[1] = int(m["seq"])     # refused: reported by the reading's error
        closing.set()

    threading.Thread(target=commands, name="hand-commands", daemon=True).start()
    last = None
    while not closing.is_set():
        with lock:
            r = hand.read()
            if not r.moving:
                started[1] = started[0]
            msg = {"width": r.width if math.isfinite(r.width) else 0.0, "moving": r.moving,
                   "grasped": r.grasped, "error": r.error, "failed": r.failed, "v": r.finger_velocity,
                   "done": started[1]}
        if msg != last:
            out.write(json.dumps(msg) + "\n")
            out.flush()
            last = msg
        closing.wait(REPORT_PERIOD)
    hand.close()


def main(argv: list[str] | None = None) -> int:
    """python -m vla_panda_bridge.libfranka_hand IP MAX_WIDTH BINDING"""
    ip, max_width, binding = (argv if argv is not None else sys.argv[1:])
    out = sys.stdout
    sys.stdout = sys.stderr                          # stdout carries only readings
    try:
        _serve(LibfrankaHand(ip, float(max_width), open_gripper(binding)), out)
    except BrokenPipeError:
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
