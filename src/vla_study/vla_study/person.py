"""A real participant's trial: a person drives, the experimenter starts and ends each trial.

The person's input reaches the controller as any `joy` does: the operator station's page (the address
is printed when the graph starts) or a joystick's `joy_node` started beside the graph. The study
publishes nothing on `joy` for a person; it only watches what the person sends, to count their inputs
as the simulated participant counts its own (a new deflection from rest or the other way, a press of
the end-effector's mode button, a reversal of the stick).

The experimenter, at the study's terminal:
- confirms that the participant is ready once the scene is reset (on the simulated robot the runner
  resets it through `~/reset`; the trial's clock starts at the confirmation);
- ends the trial when the participant says done (Enter), or the protocol's time limit ends it.
Both are calls on an :class:`Experimenter`, so that a test (or another front end) can play the part.

On the real robot (protocol `robot: real`, vla_study/robot_backend.py) the experimenter also places the
object by hand at the trial's start point (said in words and in metres in the robot's base frame) and
confirms, and, after the trial, scores it: success y/n and, optionally, the object's displacement as
measured on the table (`Experimenter.score`): without a simulation nothing else measures the object.
"""
from __future__ import annotations

import math
import select
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol as TypingProtocol

import numpy as np
from vla_common.robot import READY_POSE
from vla_common.tasks import parse_task
from vla_evaluation.kinematic import plannable_layout
from vla_latent_controller.teleop import TeleopParams

# |axis| above this counts as a deflection: the controller's deadband (declared there)
DEFLECTED = TeleopParams().deadband


class Experimenter(TypingProtocol):
    def confirm(self, text: str) -> None:
        """Block until the experimenter confirms `text`."""

    def wait_done(self, text: str, ended: Callable[[], bool]) -> bool:
        """Block until the experimenter says the participant is done (True) or `ended()` (False)."""

    def score(self, text: str) -> TrialScore:
        """The experimenter's judgement of a trial on the real robot (asked once the arm is stopped)."""


MAX_DISPLACEMENT_CM = 200.0  # beyond the table: a typing error


@dataclass(frozen=True)
class TrialScore:
    """The experimenter's score of a real-robot trial: success, and the object's displacement from its
    start point as measured by hand (m; None: not measured)."""

    success: bool
    displacement_m: float | None = None


def parse_success(text: str) -> bool | None:
    """y/yes -> True, n/no -> False, anything else None (asked again)."""
    t = text.strip().lower()
    return True if t in ("y", "yes") else False if t in ("n", "no") else None


def parse_displacement_cm(text: str) -> tuple[bool, float | None]:
    """(valid, metres): empty -> (True, None) (not measured); a number of cm in 0..MAX_DISPLACEMENT_CM
    -> (True, m); anything else (False, None)."""
    t = text.strip().replace(",", ".")
    if not t:
        return True, None
    try:
        cm = float(t)
    except ValueError:
        return False, None
    if not (0.0 <= cm <= MAX_DISPLACEMENT_CM):   # NaN fails both comparisons
        return False, None
    return True, round(cm / 100.0, 4)


def placement_words(x: float, y: float) -> str:
    """A point of the robot's base frame (x forward, y to the robot's left) in words, in cm."""
    side = "on the base's axis" if abs(y) < 0.005 else (
        f"{abs(y) * 100:.0f} cm to the robot's {'left' if y > 0 else 'right'}")
    return f"{x * 100:.0f} cm in front of the robot's base, {side}"


class TerminalExperimenter:
    """The experimenter at the study's terminal: Enter confirms, Enter ends the trial."""

    def __init__(self, stream=None, poll_s: float = 0.1) -> None:
        self.stream, self.poll_s = stream if stream is not None else sys.stdin, poll_s

    def confirm(self, text: str) -> None:
        print(f"\n{text} [Enter]", flush=True)
        self.stream.readline()

    def wait_done(self, text: str, ended: Callable[[], bool]) -> bool:
        """Enter, or the time limit; polls stdin so that no reader is left waiting after the trial
        (it would swallow the next confirmation)."""
        print(f"{text} [Enter]", flush=True)
        while not ended():
            ready, _, _ = select.select([self.stream], [], [], self.poll_s)
            if ready:
                self.stream.readline()
                return True
        return False

    def _ask(self, question: str) -> str:
        print(question, end="", flush=True)
        line = self.stream.readline()
        if not line:   # stdin closed: no answer will ever come
            raise EOFError("the terminal closed while the experimenter was asked to score a trial")
        return line

    def score(self, text: str) -> TrialScore:
        """Success y/n (asked until answered), then the measured displacement in cm (Enter: not measured;
        asked again until a number from 0 to MAX_DISPLACEMENT_CM)."""
        print(f"\n{text}", flush=True)
        while (ok := parse_success(self._ask("  Success? [y/n] "))) is None:
            print("  please answer y or n")
        while True:
            valid, disp = parse_displacement_cm(self._ask(
                "  The object's displacement from its start point, measured, in cm [Enter: not measured] "))
            if valid:
                return TrialScore(ok, disp)
            print(f"  please give a number of cm from 0 to {MAX_DISPLACEMENT_CM:g}, or only Enter")


@dataclass
class InputTally:
    """A person's inputs, counted from the `joy` they send: the fields the study's rows take from the
    simulated participant (`trial_row`). What a person does not show (their lapses) is None."""

    axis: int = 0
    mode_button: int = 0
    n_inputs: int = 0
    n_switches: int = 0
    switch_s: float | None = None
    reversals: int = 0
    lapses: int | None = None
    sticks: list[float] = field(default_factory=list)
    _sign: int = 0
    _pressed: bool = False

    def on_joy(self, axes, buttons) -> None:
        a = float(axes[self.axis]) if len(axes) > self.axis else 0.0
        sign = 0 if abs(a) <= DEFLECTED else (1 if a > 0 else -1)
        if sign and sign != self._sign:
            self.n_inputs += 1              # from rest, or the other way
            if self._sign:
                self.reversals += 1
        self._sign = sign
        pressed = len(buttons) > self.mode_button >= 0 and bool(buttons[self.mode_button])
        if pressed and not self._pressed:
            self.n_inputs += 1              # the end-effector's mode button
        self._pressed = pressed
        self.sticks.append(a)

    def on_mode(self, changed: bool) -> None:
        """The controller's end-effector axis changed: one mode switch (however many presses)."""
        self.n_switches += int(changed)


class PersonDriver:
    """The trial of a person: the study watches; it ends at the experimenter's word or the time limit.
    Duck-types graph_backend's TrialDriver (tick, finished, t_start, t_end, t_done, sticks, op)."""

    def __init__(self, tally: InputTally, t_start: float, time_limit: float) -> None:
        self.op = tally
        self.t_start, self.time_limit = t_start, time_limit
        self.t_done: float | None = None
        self.t_end: float | None = None
        self.finished = threading.Event()
        self._said_done = threading.Event()
        self._ee_axis: str | None = None

    @property
    def sticks(self) -> list[float]:
        return self.op.sticks

    def said_done(self) -> None:
        self._said_done.set()

    def tick(self, obs) -> None:
        if self.finished.is_set():
            return
        t = obs.now() - self.t_start
        with obs.cond:
            ctrl = obs.ctrl
        if ctrl is not None and ctrl.ee_axis:
            self.op.on_mode(self._ee_axis is not None and ctrl.ee_axis != self._ee_axis)
            self._ee_axis = ctrl.ee_axis
        if self._said_done.is_set() or t >= self.time_limit:
            if self._said_done.is_set():
                self.t_done = t
            self.t_end = min(t, self.time_limit)
            with obs.cond:
                self.finished.set()
                obs.cond.notify_all()


def run_person_trial(driver: PersonDriver, experimenter: Experimenter, text: str,
                     wall_limit: float) -> None:
    """The experimenter's side of a trial: Enter when the participant says done (in this thread);
    returns once the trial has ended either way (or `wall_limit` wall s passed)."""
    deadline = time.monotonic() + wall_limit
    if experimenter.wait_done(text, lambda: driver.finished.is_set() or time.monotonic() > deadline):
        driver.said_done()


def start_point(trial, catalogue, kin):
    """The trial's start point (an ObjectPose in the robot's base frame) and the layout seed it came
    from: the placement the simulated study resets to for the same trial (practice: the fixed reset
    point `practice.reset_seed`; test trials: a seeded new placement)."""
    spec = parse_task(trial.task, catalogue)
    _objects, goal, _wps, used = plannable_layout(kin, spec, spec.object_class, int(trial.layout_seed),
                                                  np.asarray(READY_POSE), 1, catalogue=catalogue)
    return goal, used


def placement_text(trial, goal, q_now: np.ndarray) -> str:
    """What the experimenter is told before a trial: the trial, where the object goes, the arm's state."""
    far = float(np.max(np.abs(np.asarray(q_now) - np.asarray(READY_POSE))))
    name = goal.class_id.replace("_", " ")
    return (f"Trial {trial.order + 1} of {trial.participant}: {trial.task} with {trial.strategy} "
            f"({trial.phase}, trial {trial.trial + 1}).\n"
            + ("  Practice: this task's fixed reset point (the same for each of its practice trials).\n"
               if trial.phase == "practice" else "  A new start point for this test trial.\n")
            + f"  Place the {name} at x = {goal.x:.3f} m, y = {goal.y:.3f} m in the robot's base frame "
            f"({placement_words(goal.x, goal.y)}), turned {math.degrees(goal.yaw):.0f} deg about the "
            "vertical.\n"
            f"  The arm is stopped (e-stop latched by the study); its joints are within {far:.2f} rad of the "
            f"start (ready) pose.\n"
            "  Confirm when the object is placed and the participant is ready: the arm moves again "
            "once the stick has been at neutral")
