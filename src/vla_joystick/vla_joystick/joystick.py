"""Linux joystick reading core for ``joy_node`` (no rclpy): evdev events → ``sensor_msgs/Joy`` values.

It reproduces the standard ROS ``joy`` node's conventions so teleop configs carry over:

- axes and buttons are numbered like the kernel's joydev (``/dev/input/jsX``) that ``joy_linux`` reads:
  absolute axes in ascending event-code order; buttons from ``BTN_JOYSTICK`` upwards first, then
  ``BTN_MISC``..``BTN_JOYSTICK - 1`` (an Xbox pad gives A=0, B=1, X=2, Y=3, LB=4, RB=5, ...);
- each axis is scaled to [-1, 1] with the device's own min/max, a deadzone is cut out of the centre
  and the rest is rescaled so the output still reaches ±1, and the sign is inverted like ``joy``
  (stick left/up = +1; a released trigger reads +1);
- button changes publish at once, axis changes at most once per ``coalesce_interval``, and the last
  state is republished at ``autorepeat_rate`` while nothing changes;
- when the device is unplugged, publishing stops (consumers time out) and it is reopened with backoff.

:class:`JoystickLoop` is the reader thread's body; the device is behind a small interface
(:class:`JoystickDevice`) so it is tested with synthetic events as well as a uinput device.
"""

from __future__ import annotations

import errno
import math
import os
import select
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

# Linux input ABI constants (linux/input-event-codes.h); stable, so evdev is needed only to open devices.
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3
BTN_MISC, BTN_JOYSTICK, BTN_GAMEPAD, BTN_DIGI = 0x100, 0x120, 0x130, 0x140
BTN_TOUCH, BTN_TRIGGER_HAPPY, KEY_MAX = 0x14A, 0x2C0, 0x2FF

Event = tuple[int, int, int]  # (type, code, value)


class JoystickUnavailableError(RuntimeError):
    """No joystick could be opened (not found, permission denied, no axes); retried with backoff."""


class JoystickLostError(RuntimeError):
    """The open joystick stopped answering (unplugged)."""


def normalize_axis(value: float, minimum: int, maximum: int, deadzone: float) -> float:
    """Raw axis value → [-1, 1] like ``joy``: centre deadzone, rescaled so ±1 is still reached, inverted."""
    if maximum <= minimum:
        return 0.0
    # Integer centre (0 for -32768..32767), each side scaled on its own so both ends reach exactly ±1.
    centre = math.ceil((maximum + minimum) / 2.0)
    if value >= centre:
        v = (value - centre) / (maximum - centre) if maximum > centre else 0.0
    else:
        v = (value - centre) / (centre - minimum)
    v = min(1.0, max(-1.0, v))
    if abs(v) <= deadzone:
        return 0.0
    v = math.copysign((abs(v) - deadzone) / (1.0 - deadzone), v)
    return -v


def joydev_axis_order(abs_codes: Iterable[int]) -> list[int]:
    return sorted(set(abs_codes))


def joydev_button_order(key_codes: Iterable[int]) -> list[int]:
    """Button numbering of the kernel's joydev: codes >= BTN_JOYSTICK first, then BTN_MISC.. ; no KEY_*."""
    codes = sorted({c for c in key_codes if BTN_MISC <= c <= KEY_MAX})
    return [c for c in codes if c >= BTN_JOYSTICK] + [c for c in codes if c < BTN_JOYSTICK]


def looks_like_joystick(abs_codes: Iterable[int], key_codes: Iterable[int]) -> bool:
    """joydev's test: has absolute axes and a joystick/gamepad/trigger-happy button; not a touch device."""
    keys = set(key_codes)
    if not set(abs_codes) or BTN_TOUCH in keys or any(BTN_DIGI <= k < BTN_DIGI + 0x10 for k in keys):
        return False
    happy = range(BTN_TRIGGER_HAPPY, BTN_TRIGGER_HAPPY + 0x28)
    return any(BTN_JOYSTICK <= k < BTN_DIGI or k in happy for k in keys)


@dataclass(frozen=True)
class AxisInfo:
    minimum: int
    maximum: int
    value: int = 0


class JoystickMapping:
    """Joy state of one device: applies events, keeps ``axes`` (floats) and ``buttons`` (0/1)."""

    AXIS, BUTTON, SYNC, DROPPED = "axis", "button", "sync", "dropped"

    def __init__(self, axes: dict[int, AxisInfo], key_codes: Iterable[int], deadzone: float = 0.05):
        if not 0.0 <= deadzone < 1.0:
            raise ValueError(f"deadzone must be in [0, 1), got {deadzone}")
        self.deadzone = deadzone
        self.axis_info = dict(axes)
        self.axis_codes = joydev_axis_order(axes)
        self.button_codes = joydev_button_order(key_codes)
        self._axis_index = {c: i for i, c in enumerate(self.axis_codes)}
        self._button_index = {c: i for i, c in enumerate(self.button_codes)}
        self.axes = [0.0] * len(self.axis_codes)
        self.buttons = [0] * len(self.button_codes)
        for code, info in self.axis_info.items():
            self._set_axis(code, info.value)

    def _set_axis(self, code: int, value: int) -> bool:
        info = self.axis_info[code]
        i = self._axis_index[code]
        new = normalize_axis(value, info.minimum, info.maximum, self.deadzone)
        changed = new != self.axes[i]
        self.axes[i] = new
        return changed

    def set_state(self, abs_values: dict[int, int], pressed: Iterable[int]) -> None:
        """Resynchronise from the device's current state (at open and after SYN_DROPPED)."""
        for code, value in abs_values.items():
            if code in self._axis_index:
                self._set_axis(code, value)
        pressed = set(pressed)
        self.buttons = [1 if c in pressed else 0 for c in self.button_codes]

    def handle(self, ev_type: int, code: int, value: int) -> str | None:
        """Apply one event; returns what changed (AXIS, BUTTON), SYNC/DROPPED for SYN events, else None."""
        if ev_type == EV_ABS and code in self._axis_index:
            return self.AXIS if self._set_axis(code, value) else None
        if ev_type == EV_KEY and code in self._button_index:
            i = self._button_index[code]
            pressed = 1 if value else 0  # 2 = kernel key autorepeat: still pressed
            if pressed != self.buttons[i]:
                self.buttons[i] = pressed
                return self.BUTTON
            return None
        if ev_type == EV_SYN:
            return self.DROPPED if code == SYN_DROPPED else self.SYNC if code == SYN_REPORT else None
        return None

    def snapshot(self) -> tuple[list[float], list[int]]:
        return list(self.axes), list(self.buttons)


# The unchanged state is repeated at 50 Hz: the controller zeroes the arm after `joy_timeout` (0.1 s)
# without a message, and that stop is one the operator did not choose, so motion then waits for the
# stick's neutral (vla_common.arming). At 20 Hz two lost repeats were enough to stop the arm; at 50 Hz
# it takes five in a row, while a real loss of the joystick still stops it within 0.1 s.
DEFAULT_AUTOREPEAT_RATE = 50.0


class PublishScheduler:
    """When to publish: buttons at once, axes rate-limited by ``coalesce_interval``, autorepeat when idle."""

    def __init__(self, autorepeat_rate: float = DEFAULT_AUTOREPEAT_RATE, coalesce_interval: float = 0.001):
        if autorepeat_rate < 0 or coalesce_interval < 0:
            raise ValueError("autorepeat_rate and coalesce_interval must be >= 0")
        self.repeat_period = 1.0 / autorepeat_rate if autorepeat_rate > 0 else None
        self.coalesce_interval = coalesce_interval
        self.last_publish = float("-inf")
        self._now = False
        self._soon = False

    def changed(self, button: bool, axis: bool) -> None:
        """A complete event packet (SYN_REPORT) changed buttons and/or axes."""
        self._now |= button
        self._soon |= axis

    def force(self) -> None:
        self._now = True

    def deadline(self) -> float | None:
        """Monotonic time of the next publish, or None when nothing is due until an event arrives."""
        times = []
        if self._now:
            times.append(float("-inf"))
        if self._soon:
            times.append(self.last_publish + self.coalesce_interval)
        if self.repeat_period is not None:
            times.append(self.last_publish + self.repeat_period)
        return min(times) if times else None

    def due(self, now: float) -> bool:
        d = self.deadline()
        return d is not None and now >= d

    def published(self, now: float) -> None:
        self.last_publish = now
        self._now = self._soon = False


class JoystickDevice(Protocol):
    name: str
    path: str

    def axes(self) -> dict[int, AxisInfo]: ...
    def key_codes(self) -> list[int]: ...
    def pressed(self) -> list[int]: ...
    def read(self, timeout: float) -> list[Event]: ...  # raises JoystickLostError
    def close(self) -> None: ...


class EvdevJoystick:
    """A joystick opened through python-evdev (``/dev/input/eventN``)."""

    def __init__(self, device):
        self._dev = device
        self.name = device.name
        self.path = device.path

    def axes(self) -> dict[int, AxisInfo]:
        try:
            caps = self._dev.capabilities(absinfo=True)
        except OSError as exc:
            raise JoystickLostError(str(exc)) from exc
        return {code: AxisInfo(info.min, info.max, info.value) for code, info in caps.get(EV_ABS, [])}

    def key_codes(self) -> list[int]:
        return list(self._dev.capabilities(absinfo=False).get(EV_KEY, []))

    def pressed(self) -> list[int]:
        try:
            return list(self._dev.active_keys())
        except OSError as exc:
            raise JoystickLostError(str(exc)) from exc

    def read(self, timeout: float) -> list[Event]:
        try:
            ready, _, _ = select.select([self._dev.fd], [], [], max(0.0, timeout))
            if not ready:
                return []
            return [(ev.type, ev.code, ev.value) for ev in self._dev.read()]
        except BlockingIOError:
            return []
        except (OSError, ValueError) as exc:  # ENODEV on unplug; ValueError if the fd was closed
            raise JoystickLostError(f"{self.path}: {exc}") from exc

    def close(self) -> None:
        try:
            self._dev.close()
        except OSError:
            pass


def open_joystick(device_path: str = "", device_name: str = "") -> EvdevJoystick:
    """Open ``device_path``; else the first device whose name contains ``device_name``; else the first
    device that looks like a joystick. Raises :class:`JoystickUnavailableError` with the reason."""
    try:  # optional here: the core and its tests run without it; opening a device needs it
        import evdev
    except ImportError as exc:  # pragma: no cover - evdev is in requirements.txt
        raise JoystickUnavailableError(f"python-evdev is not installed ({exc})") from exc
    if device_path:
        return EvdevJoystick(_open_path(evdev, device_path))
    paths = sorted(evdev.list_devices())
    if not paths:
        raise JoystickUnavailableError("no input devices in /dev/input (none plugged in, or no permission)")
    denied = []
    for path in paths:
        try:
            dev = evdev.InputDevice(path)
        except PermissionError:
            denied.append(path)
            continue
        except OSError:
            continue
        caps = dev.capabilities(absinfo=False)
        if device_name:
            ok = device_name.lower() in dev.name.lower()
        else:
            ok = looks_like_joystick(caps.get(EV_ABS, []), caps.get(EV_KEY, []))
        if ok:
            return EvdevJoystick(dev)
        dev.close()
    what = f"named like {device_name!r}" if device_name else "that looks like a joystick"
    hint = f"; permission denied on {', '.join(denied)} (join the 'input' group)" if denied else ""
    raise JoystickUnavailableError(f"no input device {what}{hint}")


def _open_path(evdev, path: str):
    try:
        return evdev.InputDevice(path)
    except FileNotFoundError as exc:
        raise JoystickUnavailableError(f"{path} does not exist (unplugged?)") from exc
    except PermissionError as exc:
        reason = f"permission denied on {path}: join the 'input' group or add a udev rule"
        raise JoystickUnavailableError(reason) from exc
    except OSError as exc:
        if exc.errno in (errno.ENODEV, errno.ENXIO):
            raise JoystickUnavailableError(f"{path}: no such device (unplugged?)") from exc
        raise JoystickUnavailableError(f"cannot open {path}: {exc}") from exc


class JoystickLoop:
    """Reader-thread body: open with backoff, map events, publish per :class:`PublishScheduler`.

    ``publish(axes, buttons)`` is called from this thread; ``log(level, text)`` with level
    ``"info"``/``"warn"``. Never raises out of :meth:`run` for device trouble.
    """

    def __init__(
        self,
        publish: Callable[[Sequence[float], Sequence[int]], None],
        *,
        opener: Callable[[], JoystickDevice],
        deadzone: float = 0.05,
        autorepeat_rate: float = DEFAULT_AUTOREPEAT_RATE,
        coalesce_interval: float = 0.001,
        retry_initial: float = 0.25,
        retry_max: float = 4.0,
        log: Callable[[str, str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[threading.Event, float], object] | None = None,
        poll_cap: float = 0.1,
    ):
        if not 0.0 <= deadzone < 1.0:
            raise ValueError(f"deadzone must be in [0, 1), got {deadzone}")
        PublishScheduler(autorepeat_rate, coalesce_interval)  # validates
        self._publish = publish
        self._opener = opener
        self.deadzone = deadzone
        self.autorepeat_rate = autorepeat_rate
        self.coalesce_interval = coalesce_interval
        self.retry_initial = retry_initial
        self.retry_max = retry_max
        self._log_sink = log or (lambda level, text: None)
        self._clock = clock
        self._sleep = sleep or (lambda stop, seconds: stop.wait(seconds))
        self._poll_cap = poll_cap
        self.device: JoystickDevice | None = None
        self.mapping: JoystickMapping | None = None
        self.scheduler: PublishScheduler | None = None
        self.connects = 0
        self.published = 0
        self._retry_delay = retry_initial
        self._next_retry = float("-inf")
        self._last_reason = ""
        self._dropped = False
        self._pending_button = False
        self._pending_axis = False

    def _log(self, level: str, text: str) -> None:
        try:
            self._log_sink(level, text)
        except Exception:  # noqa: BLE001 - a logging failure must not kill the reader thread
            pass

    @property
    def connected(self) -> bool:
        return self.device is not None

    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            self.step(stop)
        self.close()

    def close(self) -> None:
        if self.device is not None:
            self.device.close()
            self.device = None

    def step(self, stop: threading.Event | None = None) -> None:
        """One wait-and-handle iteration; blocks at most ``poll_cap`` seconds."""
        stop = stop or threading.Event()
        now = self._clock()
        if self.device is None:
            if now < self._next_retry:
                self._sleep(stop, min(self._next_retry - now, self._poll_cap))
                return
            self._try_open(now)
            return
        deadline = self.scheduler.deadline()
        timeout = self._poll_cap if deadline is None else min(self._poll_cap, max(0.0, deadline - now))
        try:
            events = self.device.read(timeout)
            for ev_type, code, value in events:
                self._apply(ev_type, code, value)
        except JoystickLostError as exc:
            self._lost(str(exc))
            return
        now = self._clock()
        if self.scheduler.due(now):
            self._emit(now)

    def _apply(self, ev_type: int, code: int, value: int) -> None:
        kind = self.mapping.handle(ev_type, code, value)
        if kind == JoystickMapping.DROPPED:
            self._dropped = True  # kernel buffer overflowed: ignore up to SYN_REPORT, then resync
            return
        if self._dropped:
            if kind == JoystickMapping.SYNC:
                self._dropped = False
                values = {c: a.value for c, a in self.device.axes().items()}
                self.mapping.set_state(values, self.device.pressed())
                self.scheduler.force()
            return
        if kind == JoystickMapping.BUTTON:
            self._pending_button = True
        elif kind == JoystickMapping.AXIS:
            self._pending_axis = True
        elif kind == JoystickMapping.SYNC:
            self.scheduler.changed(self._pending_button, self._pending_axis)
            self._pending_button = self._pending_axis = False

    def _emit(self, now: float) -> None:
        axes, buttons = self.mapping.snapshot()
        self.scheduler.published(now)
        try:
            self._publish(axes, buttons)
        except Exception as exc:  # noqa: BLE001 - e.g. publishing during shutdown: keep the thread alive
            self._log("warn", f"publishing the joystick state failed: {exc!r}")
            return
        self.published += 1

    def _try_open(self, now: float) -> None:
        try:
            device = self._opener()
            axes = device.axes()
            keys = device.key_codes()
            pressed = device.pressed()
        except (JoystickUnavailableError, JoystickLostError) as exc:
            self._retry_later(now, str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - any driver error is a failed attempt, not a dead thread
            self._retry_later(now, f"opening the joystick failed: {exc!r}")
            return
        self.device = device
        self.mapping = JoystickMapping(axes, keys, self.deadzone)
        self.mapping.set_state({c: a.value for c, a in axes.items()}, pressed)
        self.scheduler = PublishScheduler(self.autorepeat_rate, self.coalesce_interval)
        self.scheduler.force()
        self._pending_button = self._pending_axis = False
        self._dropped = False
        self._retry_delay = self.retry_initial
        self._last_reason = ""
        self.connects += 1
        self._log(
            "info",
            f"opened joystick '{device.name}' at {device.path}: {len(self.mapping.axes)} axes, "
            f"{len(self.mapping.buttons)} buttons",
        )

    def _retry_later(self, now: float, reason: str) -> None:
        if reason != self._last_reason:  # log each new reason once, not every retry
            self._log("warn", f"{reason}; retrying (every {self.retry_initial:g}..{self.retry_max:g} s)")
            self._last_reason = reason
        self._next_retry = now + self._retry_delay
        self._retry_delay = min(self._retry_delay * 2.0, self.retry_max)

    def _lost(self, reason: str) -> None:
        self._log("warn", f"joystick lost ({reason}); stopped publishing, reopening")
        self.close()
        self.mapping = None
        self._retry_delay = self.retry_initial
        self._last_reason = ""
        self._next_retry = self._clock() + self.retry_initial


def default_opener(device_path: str = "", device_name: str = "") -> Callable[[], JoystickDevice]:
    path = os.path.expanduser(device_path) if device_path else ""
    return lambda: open_joystick(path, device_name)
