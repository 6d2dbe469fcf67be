"""joy_node's core with synthetic events, the node with a fake device, and a uinput device if allowed."""

import os
import queue
import subprocess
import threading
import time
from pathlib import Path

import pytest
from require import missing
from vla_joystick.joystick import (
    BTN_MISC,
    BTN_TOUCH,
    BTN_TRIGGER_HAPPY,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    AxisInfo,
    JoystickLoop,
    JoystickLostError,
    JoystickMapping,
    JoystickUnavailableError,
    PublishScheduler,
    joydev_button_order,
    looks_like_joystick,
    normalize_axis,
    open_joystick,
)
from vla_launch.run import RunError, find_executable

ABS_X, ABS_Y, ABS_Z, ABS_RZ, ABS_HAT0X = 0x00, 0x01, 0x02, 0x05, 0x10
BTN_SOUTH, BTN_EAST, BTN_NORTH, BTN_WEST, BTN_TL, BTN_TR = 0x130, 0x131, 0x133, 0x134, 0x136, 0x137
BTN_SELECT, BTN_START, BTN_MODE, BTN_THUMBL, BTN_THUMBR = 0x13A, 0x13B, 0x13C, 0x13D, 0x13E
KEY_A = 30
PAD_AXES = {
    ABS_X: AxisInfo(-32768, 32767, 0),
    ABS_Y: AxisInfo(-32768, 32767, 0),
    ABS_Z: AxisInfo(0, 255, 0),  # trigger, released
    ABS_HAT0X: AxisInfo(-1, 1, 0),
}
PAD_KEYS = [BTN_SOUTH, BTN_EAST, BTN_NORTH, BTN_WEST, BTN_TL, BTN_TR]


# -- axis mapping ------------------------------------------------------------------------------------
def test_normalize_reaches_full_range_inverted_with_deadzone():
    lo, hi = -32768, 32767
    assert normalize_axis(hi, lo, hi, 0.05) == pytest.approx(-1.0)  # right/down = -1 like ROS joy
    assert normalize_axis(lo, lo, hi, 0.05) == pytest.approx(1.0)
    assert normalize_axis(0, lo, hi, 0.05) == 0.0
    assert normalize_axis(int(0.05 * 32767), lo, hi, 0.05) == 0.0  # inside the deadzone
    just_out = normalize_axis(int(0.06 * 32768), lo, hi, 0.05)
    assert -0.02 < just_out < 0.0  # rescaled: starts near 0 at the deadzone edge, not at 0.05
    half = normalize_axis(int(0.525 * 32768), lo, hi, 0.05)
    assert half == pytest.approx(-0.5, abs=1e-3)  # (0.525 - 0.05) / 0.95
    values = [normalize_axis(v, lo, hi, 0.05) for v in range(lo, hi, 997)]
    assert values == sorted(values, reverse=True) and all(-1.0 <= v <= 1.0 for v in values)


def test_normalize_uses_device_range():
    assert normalize_axis(0, 0, 255, 0.05) == pytest.approx(1.0)  # released trigger reads +1 (ROS joy)
    assert normalize_axis(255, 0, 255, 0.05) == pytest.approx(-1.0)
    assert normalize_axis(128, 0, 255, 0.05) == 0.0 and normalize_axis(0, -32768, 32767, 0.0) == 0.0
    assert normalize_axis(-1, -1, 1, 0.05) == 1.0 and normalize_axis(1, -1, 1, 0.05) == -1.0  # hat
    assert normalize_axis(5, 3, 3, 0.05) == 0.0  # degenerate range: no NaN
    assert normalize_axis(40000, -32768, 32767, 0.0) == -1.0  # out of range clipped


def test_button_order_matches_joydev():
    keys = [
        KEY_A,
        BTN_MISC,
        BTN_THUMBR,
        BTN_SOUTH,
        BTN_TRIGGER_HAPPY,
        BTN_EAST,
        BTN_START,
        BTN_SELECT,
        BTN_MODE,
        BTN_THUMBL,
        BTN_NORTH,
        BTN_WEST,
        BTN_TL,
        BTN_TR,
    ]
    order = joydev_button_order(keys)
    # Xbox layout of ROS joy: A B X Y LB RB back start guide LS RS, then higher codes, then BTN_MISC
    assert order == [
        BTN_SOUTH,
        BTN_EAST,
        BTN_NORTH,
        BTN_WEST,
        BTN_TL,
        BTN_TR,
        BTN_SELECT,
        BTN_START,
        BTN_MODE,
        BTN_THUMBL,
        BTN_THUMBR,
        BTN_TRIGGER_HAPPY,
        BTN_MISC,
    ]
    assert KEY_A not in order


def test_looks_like_joystick():
    assert looks_like_joystick([ABS_X, ABS_Y], [BTN_SOUTH])
    assert looks_like_joystick([ABS_X], [BTN_TRIGGER_HAPPY + 3])
    assert not looks_like_joystick([], [BTN_SOUTH])  # keyboard-like: no axes
    assert not looks_like_joystick([ABS_X, ABS_Y], [BTN_TOUCH, 0x110])  # touchpad
    assert not looks_like_joystick([ABS_X, ABS_Y], [KEY_A])


def test_mapping_applies_events():
    m = JoystickMapping(PAD_AXES, PAD_KEYS, deadzone=0.05)
    assert m.axes == [0.0, 0.0, 1.0, 0.0]  # X, Y, Z (released trigger), HAT0X
    assert m.handle(EV_ABS, ABS_Y, -32768) == JoystickMapping.AXIS  # stick up
    assert m.axes[1] == pytest.approx(1.0)
    assert m.handle(EV_ABS, ABS_Y, -32768) is None  # unchanged
    assert m.handle(EV_ABS, ABS_RZ, 10) is None  # an axis the device did not announce
    assert m.handle(EV_KEY, BTN_EAST, 1) == JoystickMapping.BUTTON and m.buttons[1] == 1
    assert m.handle(EV_KEY, BTN_EAST, 2) is None and m.buttons[1] == 1  # kernel key repeat: still held
    assert m.handle(EV_KEY, KEY_A, 1) is None
    assert m.handle(EV_SYN, SYN_REPORT, 0) == JoystickMapping.SYNC
    assert m.handle(EV_SYN, SYN_DROPPED, 0) == JoystickMapping.DROPPED
    m.set_state({ABS_X: 32767}, [BTN_TR])
    assert m.axes[0] == pytest.approx(-1.0) and m.buttons == [0, 0, 0, 0, 0, 1]
    with pytest.raises(ValueError):
        JoystickMapping(PAD_AXES, PAD_KEYS, deadzone=1.0)


def test_scheduler_buttons_now_axes_coalesced_autorepeat():
    s = PublishScheduler(autorepeat_rate=20.0, coalesce_interval=0.01)
    s.published(1.0)
    assert s.deadline() == pytest.approx(1.05)  # autorepeat only
    s.changed(button=False, axis=True)
    assert not s.due(1.005) and s.due(1.01)  # axes: at most once per coalesce interval
    s.published(1.01)
    s.changed(button=True, axis=False)
    assert s.due(1.011)  # buttons: at once
    idle = PublishScheduler(autorepeat_rate=0.0)
    idle.published(0.0)
    assert idle.deadline() is None  # no autorepeat: wait for events
    with pytest.raises(ValueError):
        PublishScheduler(autorepeat_rate=-1.0)


# -- the reading loop with a scripted device and a fake clock --------------------------------------
class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, stop, seconds):
        self.t += seconds


class ScriptedDevice:
    """Events scheduled at fake times; ``lost_at`` makes reads fail like an unplugged device."""

    def __init__(self, clock, script=(), lost_at=None, name="Fake Pad", pressed=()):
        self.clock = clock
        self.script = sorted(script, key=lambda item: item[0])
        self.lost_at = lost_at
        self.name, self.path = name, "/dev/input/event42"
        self._pressed = list(pressed)
        self.closed = False

    def axes(self):
        return dict(PAD_AXES)

    def key_codes(self):
        return list(PAD_KEYS)

    def pressed(self):
        return list(self._pressed)

    def read(self, timeout):
        if self.lost_at is not None and self.clock.t >= self.lost_at:
            raise JoystickLostError("No such device")
        if self.script and self.script[0][0] <= self.clock.t + timeout:
            self.clock.t = max(self.clock.t, self.script[0][0])
            events = []
            while self.script and self.script[0][0] <= self.clock.t:
                events.extend(self.script.pop(0)[1])
            return events
        self.clock.t += timeout
        return []

    def close(self):
        self.closed = True


def packet(*events):
    return list(events) + [(EV_SYN, SYN_REPORT, 0)]


def run_loop(loop, clock, until):
    while clock.t < until:
        loop.step()


def make_loop(opener, clock, published, **kw):
    def publish(axes, buttons):
        published.append((clock.t, list(axes), list(buttons)))

    kw.setdefault("coalesce_interval", 0.01)
    return JoystickLoop(publish, opener=opener, clock=clock, sleep=clock.sleep, **kw)


def test_loop_publishes_initial_state_events_and_autorepeat():
    clock, published = FakeClock(), []
    script = [
        (100.222, packet((EV_ABS, ABS_X, -32768), (EV_ABS, ABS_Y, 32767))),
        (100.333, packet((EV_KEY, BTN_SOUTH, 1))),
    ]
    dev = ScriptedDevice(clock, script)
    loop = make_loop(lambda: dev, clock, published, autorepeat_rate=20.0)
    run_loop(loop, clock, 101.0)
    assert published[0][0] == pytest.approx(100.0) and published[0][1] == [0.0, 0.0, 1.0, 0.0]
    both = [p for p in published if p[1][:2] == [pytest.approx(1.0), pytest.approx(-1.0)]]
    assert both and 100.222 <= both[0][0] <= 100.232  # both axes in one message, within coalesce_interval
    press = [p for p in published if p[2][0] == 1]
    assert press[0][0] == pytest.approx(100.333)  # buttons at once
    gaps = [b[0] - a[0] for a, b in zip(published, published[1:])]
    assert max(gaps) == pytest.approx(0.05, abs=1e-6)  # autorepeat at 20 Hz while idle (never longer)
    assert 19 <= len(published) <= 23


def test_loop_coalesces_fast_axis_motion():
    clock, published = FakeClock(), []
    script = [(100.1 + i * 0.001, packet((EV_ABS, ABS_X, -1000 * i))) for i in range(1, 31)]
    dev = ScriptedDevice(clock, script)
    loop = make_loop(lambda: dev, clock, published, autorepeat_rate=0.0, coalesce_interval=0.01)
    run_loop(loop, clock, 100.5)
    moving = [p for p in published if 100.1 <= p[0] <= 100.2]
    assert 3 <= len(moving) <= 5  # 30 packets in 30 ms -> about one message per 10 ms
    assert published[-1][1][0] == pytest.approx(normalize_axis(-30000, -32768, 32767, 0.05))  # latest value


def test_loop_no_autorepeat_publishes_only_on_change():
    clock, published = FakeClock(), []
    dev = ScriptedDevice(clock, [(100.5, packet((EV_KEY, BTN_EAST, 1)))])
    loop = make_loop(lambda: dev, clock, published, autorepeat_rate=0.0)
    run_loop(loop, clock, 102.0)
    assert [p[0] for p in published] == [pytest.approx(100.0), pytest.approx(100.5)]


def test_loop_unplug_stops_publishing_and_replug_resumes():
    clock, published, logs = FakeClock(), [], []
    first = ScriptedDevice(clock, [(100.1, packet((EV_ABS, ABS_X, 32767)))], lost_at=100.5)
    second = ScriptedDevice(clock, [], pressed=[BTN_WEST])
    attempts = []

    def opener():
        attempts.append(clock.t)
        if len(attempts) == 1:
            return first
        if clock.t < 103.0:
            raise JoystickUnavailableError("/dev/input/event42 does not exist (unplugged?)")
        return second

    loop = JoystickLoop(
        lambda a, b: published.append((clock.t, list(a), list(b))),
        opener=opener,
        clock=clock,
        sleep=clock.sleep,
        autorepeat_rate=20.0,
        retry_initial=0.25,
        retry_max=1.0,
        log=lambda level, text: logs.append((level, text)),
    )
    run_loop(loop, clock, 104.0)
    assert first.closed and loop.connects == 2 and loop.connected
    assert not [p for p in published if 100.6 < p[0] < 103.0]  # silent while unplugged
    resumed = [p for p in published if p[0] >= 103.0]
    assert resumed and resumed[0][2] == [0, 0, 0, 1, 0, 0]  # state read from the new device
    # backoff while unplugged: 0.25, 0.5, 1, 1 s ... not a retry per poll
    gaps = [b - a for a, b in zip(attempts[1:], attempts[2:])]
    assert gaps[:3] == pytest.approx([0.25, 0.5, 1.0], abs=1e-6) and max(gaps) <= 1.0 + 1e-6
    assert any("lost" in text for level, text in logs if level == "warn")
    assert sum("does not exist" in text for _, text in logs) == 1  # the same reason is logged once


def test_loop_resyncs_after_syn_dropped():
    clock, published = FakeClock(), []
    dev = ScriptedDevice(
        clock, [(100.2, [(EV_SYN, SYN_DROPPED, 0), (EV_KEY, BTN_NORTH, 1), (EV_SYN, SYN_REPORT, 0)])]
    )
    loop = make_loop(lambda: dev, clock, published, autorepeat_rate=0.0)
    run_loop(loop, clock, 100.1)
    dev._pressed = [BTN_TL]  # what the kernel reports after the overflow
    run_loop(loop, clock, 100.5)
    assert published[-1][2] == [0, 0, 0, 0, 1, 0]  # resynced from device state, dropped event ignored


def test_loop_survives_opener_and_publish_errors():
    clock, logs = FakeClock(), []

    def bad_opener():
        raise OSError("weird driver error")

    loop = JoystickLoop(
        lambda a, b: None,
        opener=bad_opener,
        clock=clock,
        sleep=clock.sleep,
        log=lambda level, text: logs.append(text),
    )
    run_loop(loop, clock, 101.0)
    assert not loop.connected and "weird driver error" in logs[0]

    def failing_publish(axes, buttons):
        raise RuntimeError("context is shut down")

    dev = ScriptedDevice(clock)
    loop = JoystickLoop(
        failing_publish,
        opener=lambda: dev,
        clock=clock,
        sleep=clock.sleep,
        log=lambda level, text: logs.append(text),
    )
    run_loop(loop, clock, 101.5)  # must not raise
    assert any("publishing the joystick state failed" in t for t in logs)


def test_missing_device_path_is_unavailable():
    with pytest.raises(JoystickUnavailableError, match="does not exist"):
        open_joystick("/dev/input/event_nonexistent_99")


# -- the node, with a queue-fed device in real time -------------------------------------------------
class QueueDevice:
    def __init__(self, name="Queue Pad"):
        self.name, self.path = name, "/dev/input/event77"
        self.events = queue.Queue()
        self.lost = threading.Event()

    def axes(self):
        return dict(PAD_AXES)

    def key_codes(self):
        return list(PAD_KEYS)

    def pressed(self):
        return []

    def read(self, timeout):
        if self.lost.is_set():
            raise JoystickLostError("No such device")
        try:
            events = [self.events.get(timeout=timeout)]
        except queue.Empty:
            return []
        while not self.events.empty():
            events.append(self.events.get_nowait())
        return events

    def close(self):
        pass


@pytest.mark.ros
def test_joy_node_publishes_stops_on_unplug_and_resumes():
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Joy
    from vla_common.ros.context import end_context
    from vla_common.ros.node_main import ConfigError
    from vla_joystick.joy_node import JoyNode

    ctx = Context()
    rclpy.init(context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    listener = rclpy.create_node("joy_listener", context=ctx)
    got = []
    listener.create_subscription(Joy, "joy", lambda m: got.append((time.monotonic(), m)), 50)
    executor.add_node(listener)
    dev = QueueDevice()
    devices = [dev, QueueDevice()]
    plugged = threading.Event()
    plugged.set()

    def opener():
        if not plugged.is_set() or not devices:
            raise JoystickUnavailableError("unplugged")
        return devices.pop(0)

    node = None
    try:
        with pytest.raises(ConfigError, match="deadzone"):
            JoyNode(context=ctx, parameter_overrides=[Parameter("deadzone", value=0.95)]).destroy_node()
        node = JoyNode(
            context=ctx,
            opener=opener,
            parameter_overrides=[
                Parameter("frame_id", value="pad"),
                Parameter("autorepeat_rate", value=50.0),
            ],
        )
        executor.add_node(node)

        def spin_until(pred, timeout=5.0):
            end = time.monotonic() + timeout
            while not pred() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
            return pred()

        assert spin_until(lambda: len(got) >= 3)
        msg = got[-1][1]
        assert msg.header.frame_id == "pad" and len(msg.axes) == 4 and len(msg.buttons) == 6
        assert msg.header.stamp.sec > 0
        for ev in packet((EV_ABS, ABS_X, -32768), (EV_KEY, BTN_SOUTH, 1)):
            dev.events.put(ev)
        assert spin_until(lambda: got[-1][1].buttons[0] == 1)
        assert got[-1][1].axes[0] == pytest.approx(1.0)
        plugged.clear()
        dev.lost.set()
        spin_until(lambda: False, 0.3)
        count = len(got)
        spin_until(lambda: False, 0.5)
        assert len(got) == count  # nothing published while unplugged
        plugged.set()
        assert spin_until(lambda: len(got) > count + 2)
        assert got[-1][1].buttons[0] == 0 and node.loop.connects == 2
    finally:
        if node is not None:
            node.destroy_node()
        listener.destroy_node()
        executor.shutdown()
        end_context(ctx)


# -- a real kernel device through uinput, where the kernel allows it -------------------------------
def _uinput_or_skip():
    if not os.access("/dev/uinput", os.W_OK):
        pytest.skip("/dev/uinput is not available here (container without the uinput module)")
    from evdev import AbsInfo, UInput, ecodes

    caps = {
        ecodes.EV_KEY: [ecodes.BTN_SOUTH, ecodes.BTN_EAST],
        ecodes.EV_ABS: [
            (ecodes.ABS_X, AbsInfo(0, -32768, 32767, 16, 128, 0)),
            (ecodes.ABS_Y, AbsInfo(0, -32768, 32767, 16, 128, 0)),
            (ecodes.ABS_Z, AbsInfo(0, 0, 255, 0, 0, 0)),
        ],
    }
    try:
        return UInput(caps, name="vla-test-pad"), caps
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"cannot create a uinput device: {exc}")


def test_uinput_device_end_to_end():
    ui, caps = _uinput_or_skip()
    from evdev import UInput, ecodes

    published, stop, opens = [], threading.Event(), []

    def opener():
        opens.append(time.monotonic())
        return open_joystick("", "vla-test-pad")

    loop = JoystickLoop(lambda a, b: published.append((list(a), list(b))), opener=opener,
                        autorepeat_rate=20.0)
    thread = threading.Thread(target=loop.run, args=(stop,), daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 5.0
        while not loop.connected and time.monotonic() < deadline:
            time.sleep(0.02)
        if not loop.connected:
            pytest.skip("uinput device node did not appear in /dev/input (no udev/devtmpfs?)")
        ui.write(ecodes.EV_ABS, ecodes.ABS_X, 32767)
        ui.write(ecodes.EV_KEY, ecodes.BTN_EAST, 1)
        ui.syn()
        deadline = time.monotonic() + 2.0
        while not (published and published[-1][1][1] == 1) and time.monotonic() < deadline:
            time.sleep(0.01)
        axes, buttons = published[-1]
        assert axes[0] == pytest.approx(-1.0) and buttons == [0, 1]
        ui.close()  # unplug
        deadline = time.monotonic() + 5.0
        while loop.connected and time.monotonic() < deadline:
            time.sleep(0.01)  # polling a condition, bounded by the deadline
        count, tried = len(published), len(opens)
        deadline = time.monotonic() + 5.0
        while len(opens) < tried + 2 and time.monotonic() < deadline:
            time.sleep(0.01)  # until the loop retried twice on its own schedule: 0.25 s + more, where
            #                   a connected loop would have sent several 20 Hz autorepeats
        assert len(opens) >= tried + 2 and len(published) == count and not loop.connected
        ui = UInput(caps, name="vla-test-pad")  # replug
        deadline = time.monotonic() + 5.0
        while len(published) == count and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(published) > count and loop.connects == 2
    finally:
        stop.set()
        thread.join(timeout=2.0)
        ui.close()


# -- the installed process: refused parameters and signals -----------------------------------------
def _joy_exe():
    try:
        return find_executable("vla_joystick", "joy_node")
    except RunError as err:
        missing("SETUP", f"joy_node: {err} (run make setup)")


@pytest.mark.slow
def test_joy_node_process_refuses_a_bad_parameter_with_exit_code_2():
    r = subprocess.run([_joy_exe(), "--ros-args", "-p", "deadzone:=0.95"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "deadzone" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
@pytest.mark.parametrize("signum", [2, 15])
def test_joy_node_process_stops_on_a_signal_without_a_device(signum):
    """No joystick here: the reader thread keeps retrying; a signal still ends the process cleanly."""
    proc = subprocess.Popen([_joy_exe(), "--ros-args", "-p", "device_path:=/dev/input/event_none_99"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        log = ""
        for line in proc.stdout:  # wait until it is up: its first retry warning
            log += line
            if "retrying" in line:
                break
        proc.send_signal(signum)
        assert proc.wait(timeout=10) == 0, log + proc.stdout.read()
        assert "Traceback" not in log + proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()


def test_every_parameter_has_a_readme_row():
    from vla_joystick.joy_node import PARAMETERS

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    missing = [p.name for p in PARAMETERS if f"| `{p.name}` |" not in readme]
    assert not missing, f"README lacks parameter rows for {missing}"
