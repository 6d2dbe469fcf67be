"""Test support: scripted persons who drive the arm through the operator station's page only (headless
Chromium through Selenium), by keyboard, by a single switch with scanning, and by a gamepad.

Each holds "toward the task" at full speed, as a person who sees the object ahead does (holding the
stick toward the task pushes the bread east: bench/bench_holds.py, 49 of 50 fresh layouts), reads the
page's state bar, lets go and presses again when it says "Let go" (or when the arm stays stopped
while they press), and lets go once the task is done (`done`: the evaluation's judge on the
simulation's ground truth, in place of the person's eyes). No rclpy here: the caller passes `done`.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

WORD = "return document.getElementById('state-word').textContent;"
SPACE_DOWN = "document.body.dispatchEvent(new KeyboardEvent('keydown', {key: ' ', bubbles: true}));"
SPACE_UP = "document.body.dispatchEvent(new KeyboardEvent('keyup', {key: ' ', bubbles: true}));"
# the switch closes when the highlight is on forward: checked and pressed in one step in the page
SWITCH_ON_FORWARD = ("if (window.station.scanner.current() !== 'forward') return false;" + SPACE_DOWN
                     + "return true;")
STOPPED_S = 1.5   # s pressing while the page says the arm is stopped: let go and press again


def until(cond: Callable[[], bool], timeout: float, poll: float = 0.05) -> bool:
    """Wait for a condition (polled), False after `timeout` s."""
    end = time.monotonic() + timeout
    while True:
        if cond():
            return True
        if time.monotonic() > end:
            return False
        time.sleep(poll)


@dataclass
class Drive:
    """What happened while a person drove: wall s from the first press to done, presses, the words the
    state bar said while pressed."""

    done: bool = False
    wall_s: float = float("nan")
    presses: int = 0
    words: list[str] = field(default_factory=list)


class PagePerson:
    name = "person"

    def __init__(self, driver) -> None:
        self.d = driver

    def word(self) -> str:
        return self.d.execute_script(WORD)

    def fast(self) -> None:
        """The caregiver sets the page's speed to Fast before handing over (the speed is the page's own)."""
        self.d.execute_script("const r = document.querySelector('input[name=speed][value=\"1.0\"]');"
                              "r.checked = true; r.dispatchEvent(new Event('change', {bubbles: true}));")

    def setup(self, settings: Callable[..., None]) -> None:
        """Before the trial: `settings(**values)` saves caregiver settings through the page."""
        self.fast()
        settings(input_device="buttons")

    def press(self) -> bool:
        raise NotImplementedError

    def release(self) -> None:
        raise NotImplementedError

    def drive(self, done: Callable[[], bool], limit_s: float) -> Drive:
        """Hold toward the task until `done`; let go and press again when the page says so."""
        out, t0 = Drive(), time.monotonic()
        pressed = self.press()
        out.presses += pressed
        stopped_since = None
        while not done() and time.monotonic() - t0 < limit_s:
            word = self.word()
            if not out.words or out.words[-1] != word:
                out.words.append(word)
            stopped = word in ("Stopped", "Waiting")
            stopped_since = (stopped_since or time.monotonic()) if stopped else None
            if not pressed or word == "Let go" or (
                    stopped_since is not None and time.monotonic() - stopped_since > STOPPED_S):
                self.release()
                until(lambda: done() or self.word() != "Let go", 3.0)
                pressed = self.press()
                out.presses += pressed
                stopped_since = None
            until(done, 0.1)
        self.release()
        out.done, out.wall_s = done(), time.monotonic() - t0
        return out


class KeyboardPerson(PagePerson):
    """Arrow up held (a real key through WebDriver); the speed chosen with the keyboard too."""
    name = "keyboard"

    def fast(self) -> None:
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        self.d.execute_script("document.querySelector('input[name=speed][value=\"1.0\"]').focus();")
        ActionChains(self.d).send_keys(Keys.SPACE).perform()            # Fast chosen in the group
        self.d.execute_script("document.activeElement.blur();")         # keys drive outside a field

    def press(self) -> bool:
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        ActionChains(self.d).key_down(Keys.ARROW_UP).perform()
        return True

    def release(self) -> None:
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        ActionChains(self.d).key_up(Keys.ARROW_UP).perform()


class SwitchPerson(PagePerson):
    """One switch (Space) with scanning at the default scan period: waits for the highlight on forward,
    holds the switch; after letting go the highlight stays on forward, so a second press is at once."""
    name = "single switch"

    def setup(self, settings) -> None:
        self.fast()
        settings(input_device="switch1", scan_period=1.5)

    def press(self) -> bool:
        return until(lambda: bool(self.d.execute_script(SWITCH_ON_FORWARD)), 30.0)

    def release(self) -> None:
        self.d.execute_script(SPACE_UP)


class GamepadPerson(PagePerson):
    """A gamepad's left stick pushed up (the Gamepad API faked in the page: navigator.getGamepads)."""
    name = "gamepad"

    def setup(self, settings) -> None:
        self.d.execute_script("window.fakePad = {connected: true, axes: [0, 0], buttons: [{pressed: false},"
                              " {pressed: false}]}; navigator.getGamepads = () => [window.fakePad];")
        self.fast()
        settings(input_device="gamepad")

    def press(self) -> bool:
        self.d.execute_script("window.fakePad.axes[1] = -1;")
        return True

    def release(self) -> None:
        self.d.execute_script("window.fakePad.axes[1] = 0;")


PERSONS = (KeyboardPerson, SwitchPerson, GamepadPerson)
