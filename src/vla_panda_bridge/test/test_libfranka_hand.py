"""LibfrankaHand (libfranka's Gripper behind gripper.HandDriver) against a fake Gripper with
libfranka's blocking semantics: calls never block the caller, a stop from another thread interrupts a
running move, a lost connection makes the core LOST and the driver reconnects, a refused command is
that motion's failure. Waits are on conditions (Events), never sleeps."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest
from vla_panda_bridge.gripper import GRASP, HOMING, MOVE, GripperCore, HandOp
from vla_panda_bridge.libfranka_hand import LibfrankaHand

from vla_panda_bridge import gripper

WAIT = 10.0


class NetworkException(RuntimeError):  # noqa: N818 (libfranka's name)
    pass


class CommandException(RuntimeError):  # noqa: N818 (libfranka's name)
    pass


class State:
    def __init__(self, width, grasped, t):
        self.width, self.is_grasped, self.max_width = width, grasped, 0.08
        self.time = type("Duration", (), {"to_sec": lambda _s, t=t: t})()


class FakeGripper:
    """libfranka's Gripper: read_once waits for the next state (here: a 2 ms tick); move/grasp block
    until done, or until stop() (from another thread) aborts them (CommandException, as libfranka's
    kAborted); `hold` makes a move block until stopped; `dead` makes every call raise NetworkException."""

    def __init__(self, ip, object_width=None, hold=False):
        self.ip, self.object_width, self.hold = ip, object_width, hold
        self.in_grasp, self.grasp_may_end = threading.Event(), threading.Event()
        self.grasp_may_end.set()
        self.width, self.grasped, self.t = 0.08, False, 0.0
        self.calls: list[tuple] = []
        self.dead = False
        self.in_move = threading.Event()
        self._stopped = threading.Event()

    def _check(self):
        if self.dead:
            raise NetworkException("libfranka gripper: UDP receive: Timeout")

    def read_once(self):
        self._check()
        time.sleep(0.002)
        self.t += 0.002
        return State(self.width, self.grasped, self.t)

    def homing(self):
        self._check()
        self.calls.append(("homing",))
        self.width, self.grasped = 0.08, False
        return True

    def move(self, width, speed):
        self._check()
        self.calls.append(("move", width, speed))
        if not 0.0 <= width <= 0.08:
            raise CommandException("libfranka gripper: Command failed!")
        if self.hold:
            self._stopped.clear()
            self.in_move.set()
            self._stopped.wait(WAIT)
            self.width = (self.width + width) / 2         # stopped half way
            self.in_move.clear()
            raise CommandException("libfranka gripper: Command aborted!")
        self.width, self.grasped = width, False
        return True

    def grasp(self, width, speed, force, eps_in, eps_out):
        self._check()
        self.calls.append(("grasp", width, speed, force, eps_in, eps_out))
        self.in_grasp.set()
        self.grasp_may_end.wait(WAIT)
        self.width = self.object_width or 0.0
        self.grasped = width - eps_in < self.width < width + eps_out
        return self.grasped

    def stop(self):
        self._check()
        self.calls.append(("stop",))
        self._stopped.set()
        return True


class Rig:
    def __init__(self, **fake):
        self.made: list[FakeGripper] = []
        self.refuse = False

        def connect(ip):
            if self.refuse:
                raise NetworkException("libfranka gripper: Connection refused")
            g = FakeGripper(ip, **fake)
            self.made.append(g)
            return g
        self.hand = LibfrankaHand("192.0.2.7", 0.08, connect, reconnect_period=0.01)
        self.core = GripperCore(self.hand)
        self.now = 0.0

    @property
    def fake(self) -> FakeGripper:
        return self.made[-1]

    def until(self, cond, timeout=WAIT) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.now += 1.0
            self.core.update(self.now)
            if cond():
                return True
            time.sleep(0.001)
        return False

    def state(self):
        return self.core.status.state

    def request(self, command, **kw):
        self.now += 1.0
        return self.core.request(command, self.now, **kw)


@pytest.fixture
def rig():
    r = Rig(object_width=0.03)
    assert r.until(lambda: r.made and r.state() == gripper.IDLE), r.core.status
    yield r
    r.hand.close()


def test_homing_move_and_grasp_reach_the_hand_and_the_core_follows(rig):
    ok, text = rig.request(gripper.HOMING)
    assert ok, text
    assert rig.until(lambda: rig.state() == gripper.IDLE and "homed" in rig.core.status.text)
    ok, _ = rig.request(gripper.MOVE, width=0.05, speed=0.04)
    assert ok and rig.until(lambda: rig.state() == gripper.IDLE and "moved" in rig.core.status.text)
    assert rig.core.status.width == pytest.approx(0.05)
    ok, _ = rig.request(gripper.GRASP, width=0.03, speed=0.05, force=30.0)
    assert ok and rig.until(lambda: rig.state() == gripper.HOLDING)
    assert rig.core.status.width == pytest.approx(0.03)
    assert rig.fake.calls == [("homing",), ("move", 0.05, 0.04), ("grasp", 0.03, 0.05, 30.0, 0.005, 0.005)]


def test_a_grasp_that_closes_outside_the_band_is_grasp_failed(rig):
    ok, _ = rig.request(gripper.GRASP, width=0.06, force=20.0)
    assert ok and rig.until(lambda: rig.state() == gripper.GRASP_FAILED)
    assert "not retried" in rig.core.status.text
    assert [c[0] for c in rig.fake.calls] == ["grasp"]


def test_start_stop_and_read_never_block_while_a_move_blocks():
    rig = Rig(hold=True)
    try:
        assert rig.until(lambda: rig.state() == gripper.IDLE)
        t0 = time.monotonic()
        rig.hand.start(HandOp(MOVE, 0.02, 0.05))
        assert rig.fake.in_move.wait(WAIT)               # the move blocks in the commander thread ...
        r = rig.hand.read()
        took = time.monotonic() - t0
        assert r.moving and not r.error
        assert took < 1.0, took                           # ... not in ours (bounded far above 2 ms)
        rig.hand.stop()                                   # interrupts it from the stopper thread
        assert rig.until(lambda: not rig.hand.read().moving)
        assert rig.fake.calls[-1] == ("stop",) and rig.hand.stops_sent == 1
        assert rig.hand.read().width == pytest.approx(0.05)  # stopped where it was, not opened
    finally:
        rig.hand.close()


def test_the_estop_during_a_move_stops_the_hand_where_it_is():
    rig = Rig(hold=True)
    try:
        assert rig.until(lambda: rig.state() == gripper.IDLE)
        assert rig.request(gripper.MOVE, width=0.0)[0]
        assert rig.fake.in_move.wait(WAIT)
        rig.core.set_estop(True)
        assert rig.state() == gripper.STOPPED
        assert rig.until(lambda: not rig.fake.in_move.is_set()
                         and rig.hand.read().width == pytest.approx(0.04))     # half way, as stopped
        ok, why = rig.request(gripper.OPEN)
        assert not ok and "e-stop" in why
        assert rig.hand.stops_sent == 1
    finally:
        rig.hand.close()


def test_stop_with_no_motion_running_sends_nothing_so_a_grasp_keeps_holding(rig):
    assert rig.request(gripper.GRASP, width=0.03)[0]
    assert rig.until(lambda: rig.state() == gripper.HOLDING)
    rig.core.set_estop(True)                              # the e-stop never opens a closed hand
    ok, _ = rig.request(gripper.STOP)
    assert ok and rig.state() == gripper.HOLDING
    assert rig.until(lambda: rig.hand._stops_done >= rig.hand._stops_asked)   # any stop handled
    assert ("stop",) not in rig.fake.calls and rig.hand.stops_sent == 0


def test_the_estop_during_a_grasp_lets_it_finish_and_never_releases_it(rig):
    """Gripper.stop after a grasp releases its force; with the bindings holding the GIL a stop can
    only arrive after the grasp, so none is sent into one."""
    rig.fake.grasp_may_end.clear()
    assert rig.request(gripper.GRASP, width=0.03)[0]
    assert rig.fake.in_grasp.wait(WAIT)
    rig.core.set_estop(True)
    assert rig.state() == gripper.STOPPED
    assert rig.until(lambda: rig.hand._stops_done >= rig.hand._stops_asked == 1)   # the stop handled
    rig.fake.grasp_may_end.set()
    assert rig.until(lambda: not rig.hand.read().moving)
    assert ("stop",) not in rig.fake.calls and rig.hand.stops_sent == 0
    assert rig.fake.grasped and rig.hand.read().width == pytest.approx(0.03) and rig.hand.read().grasped


def test_a_refused_move_is_that_motions_failure_and_the_hand_stays(rig):
    rig.hand.start(HandOp(MOVE, 0.5, 0.05))              # past the core (which would refuse it)
    rig.core._op = HandOp(MOVE, 0.5, 0.05)
    assert rig.until(lambda: rig.state() == gripper.STOPPED)
    assert "refused the move" in rig.core.status.text and "Command failed" in rig.core.status.text
    assert rig.hand.read().error == ""
    assert rig.request(gripper.MOVE, width=0.04)[0]      # the hand still takes motions
    assert rig.until(lambda: rig.state() == gripper.IDLE)


def test_a_lost_connection_makes_the_core_lost_and_the_driver_reconnects(rig):
    rig.refuse = True
    rig.fake.dead = True
    assert rig.until(lambda: rig.state() == gripper.LOST)
    text = rig.core.status.text                           # the loss, then the retries' reason
    assert text.startswith("hand lost") and ("UDP receive: Timeout" in text or "Connection refused" in text)
    ok, why = rig.request(gripper.OPEN)
    assert not ok and "lost" in why
    rig.refuse = False
    assert rig.until(lambda: rig.state() == gripper.IDLE and len(rig.made) == 2)
    assert "answers again" in rig.core.status.text
    assert rig.request(gripper.MOVE, width=0.04)[0]
    assert rig.until(lambda: rig.state() == gripper.IDLE and rig.made[-1].width == pytest.approx(0.04))


def test_no_hand_at_the_address_is_lost_with_the_reason_and_close_is_bounded():
    def refuse(ip):
        raise NetworkException(f"libfranka gripper: Connection to {ip} refused")
    hand = LibfrankaHand("192.0.2.9", 0.08, refuse, reconnect_period=0.01)
    core = GripperCore(hand)
    assert core.status.state == gripper.LOST
    end = time.monotonic() + WAIT
    while "refused" not in hand.read().error and time.monotonic() < end:
        time.sleep(0.001)
    assert "Connection to 192.0.2.9 refused" in hand.read().error
    with pytest.raises(ConnectionError):
        hand.start(HandOp(HOMING))
    t0 = time.monotonic()
    hand.close()
    assert time.monotonic() - t0 < 1.5
    assert not any(t.is_alive() for t in hand._threads)


def test_grasp_arguments_reach_libfranka_in_its_order(rig):
    assert rig.request(gripper.GRASP, width=0.03, speed=0.02, force=40.0, epsilon_inner=0.01,
                       epsilon_outer=0.02)[0]
    assert rig.until(lambda: rig.state() == gripper.HOLDING)
    assert rig.fake.calls[-1] == ("grasp", 0.03, 0.02, 40.0, 0.01, 0.02)
    assert GRASP == gripper.GRASP


# ------------------------------------------------------------------ HandProcess (the node's side)
FAKE_MODULE = '''
import time
class Duration:
    def __init__(self, t): self.t = t
    def to_sec(self): return self.t
class GripperState:
    def __init__(self, w, g, t):
        self.width, self.is_grasped, self.max_width, self.time = w, g, 0.08, Duration(t)
class CommandException(RuntimeError): pass
class Gripper:
    def __init__(self, ip):
        self.width, self.grasped, self.t = 0.08, False, 0.0
    def read_once(self):
        time.sleep(0.005); self.t += 0.005
        return GripperState(self.width, self.grasped, self.t)
    def homing(self): self.width = 0.08; return True
    def move(self, width, speed):
        if not 0.0 <= width <= 0.08: raise CommandException("libfranka gripper: Command failed!")
        self.width, self.grasped = width, False; return True
    def grasp(self, width, speed, force, ei, eo):
        self.width = 0.03; self.grasped = width - ei < 0.03 < width + eo; return self.grasped
    def stop(self): return True
'''


@pytest.fixture
def process(tmp_path):
    """A HandProcess whose child imports a fake pylibfranka (PYTHONPATH set by its prefix)."""
    import os
    import sys

    from vla_panda_bridge.libfranka_hand import HandProcess

    (tmp_path / "pylibfranka.py").write_text(FAKE_MODULE)
    path = os.pathsep.join([str(tmp_path), *sys.path[1:]])
    hand = HandProcess("192.0.2.7", 0.08, "pylibfranka", ["env", f"PYTHONPATH={path}"])
    yield hand
    hand.close()


def _poll(core: GripperCore, cond, timeout=WAIT) -> bool:
    end = time.monotonic() + timeout
    t = 0.0
    while time.monotonic() < end:
        t += 1.0
        core.update(t)
        if cond():
            return True
        time.sleep(0.002)
    return False


def test_the_hand_process_carries_motions_and_readings(process):
    core = GripperCore(process)
    assert _poll(core, lambda: core.status.state == gripper.IDLE), core.status
    assert core.status.width == pytest.approx(0.08)
    ok, _ = core.request(gripper.MOVE, 1e5, width=0.05)
    assert ok and process.read().moving                   # from the moment start returns
    assert _poll(core, lambda: core.status.state == gripper.IDLE and "moved" in core.status.text), core.status
    assert core.status.width == pytest.approx(0.05)
    ok, _ = core.request(gripper.GRASP, 1e6, width=0.03)
    assert ok and _poll(core, lambda: core.status.state == gripper.HOLDING), core.status
    process.start(HandOp(MOVE, 0.5, 0.05))                # past the core (which would refuse it): the
    core._op = HandOp(MOVE, 0.5, 0.05)                    # hand refuses it, that motion's failure
    assert _poll(core, lambda: core.status.state == gripper.STOPPED), core.status
    assert "refused the move" in core.status.text


def test_a_hand_process_that_dies_makes_the_hand_lost(process):
    core = GripperCore(process)
    assert _poll(core, lambda: core.status.state == gripper.IDLE), core.status
    first = process.pid
    os.kill(first, signal.SIGKILL)
    assert _poll(core, lambda: core.status.state == gripper.LOST), core.status
    assert "the hand process exited" in core.status.text
    with pytest.raises(ConnectionError):
        process.start(HandOp(HOMING))
    process.stop()                                        # harmless on a dead process
    # supervised as the arm's loop process: restarted, and the hand answers again
    assert _poll(core, lambda: core.status.state == gripper.IDLE, timeout=30.0), core.status
    assert process.pid != first and process.child.restarts == 1
    ok, _ = core.request(gripper.MOVE, 1e5, width=0.04)
    assert ok and _poll(core, lambda: core.status.state == gripper.IDLE and "moved" in core.status.text)


def test_closing_ends_the_hand_process(process):
    core = GripperCore(process)
    assert _poll(core, lambda: core.status.state == gripper.IDLE), core.status
    t0 = time.monotonic()
    pid, path = process.pid, process.slots.path
    process.close()
    assert time.monotonic() - t0 < 2.0 and not os.path.exists(path)
    with pytest.raises(ChildProcessError):                # reaped: gone
        os.waitpid(pid, os.WNOHANG)
