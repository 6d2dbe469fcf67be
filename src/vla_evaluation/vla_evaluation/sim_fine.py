"""The simulated operator's fine alignment in end-effector mode (tasks with the hand).

Five demonstrations teach the latent a path that ends a few centimetres from a new object's grasp
point (the decoder interpolates joint motions between the demonstrated object positions; a joint
blend of two grasps is 1-7 cm off the blend of their positions), and a 1-DoF latent cannot move the
hand sideways off that path. The grasp window is about a centimetre (bench_grasp_window). A person
who sees the hand stop short does what users of assistive arms do: switches the controller to
end-effector mode and nudges the hand one Cartesian axis at a time, then presses grasp, and switches
back to the latent for the carry. The same for the place when the carry ends short.

This core decides, from what a person sees (the TCP, the point the hand should reach and the
controller's mode and axis), the stick value and when to press the axis button. The order a person
takes: with the hand beside the object, up above it first (moving sideways at grasp height pushes
the object with a finger), then along x and y, then down; each axis until it is within `tolerance`,
pushing the stick in proportion to what is left, so the hand slows as it arrives.
No rclpy here: the node (sim_teleoperator_node) switches modes, presses and publishes the stick.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from vla_latent_controller.teleop import unit_to_stick

TOLERANCE = 0.0025      # m per axis: 4.3 mm at most in all three, within the grasp press's 5 mm
RAMP = 0.04             # m: the stick is at MAX_SPEED from this far, and in proportion below it
MIN_SPEED = 0.05        # of full stick speed: the slowest push that still moves the hand
MAX_SPEED = 0.75        # of full stick speed (0.15 m/s at the controller's 0.2 m/s)
CLEARANCE = 0.06        # m above the point: over the object's top before moving sideways
BESIDE = 0.015          # m off in x-y: the hand is beside the object, not over it
PRESS_INTERVAL = 0.3    # s between presses of the axis button (the controller's debounce: 0.25 s)
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class FineStep:
    """One decision: the stick value, whether to press the axis button now, and whether the hand is
    at the point (within `tolerance` in every axis)."""

    axis_value: float
    press_axis_button: bool
    done: bool
    axis: str = ""


def stick_for(error: float, deadband: float) -> float:
    """The stick value a person pushes for `error` (m) left on an axis: proportional within RAMP,
    between MIN_SPEED and MAX_SPEED of full speed, past the controller's deadband."""
    speed = float(np.clip(abs(error) / RAMP * MAX_SPEED, MIN_SPEED, MAX_SPEED))
    return unit_to_stick(float(np.sign(error)) * speed, deadband)


class FineAlign:
    """Moves the TCP to `goal` one axis at a time in the controller's end-effector mode."""

    def __init__(self, goal: np.ndarray, tcp: np.ndarray, deadband: float = 0.1,
                 tolerance: float = TOLERANCE, clear_first: bool = True) -> None:
        goal = np.asarray(goal, dtype=float).reshape(3)
        tcp = np.asarray(tcp, dtype=float).reshape(3)
        if not (np.all(np.isfinite(goal)) and np.all(np.isfinite(tcp))):
            raise ValueError("fine alignment needs a finite goal and TCP")
        if not 0.0 <= deadband < 1.0:
            raise ValueError(f"deadband must be in [0, 1), got {deadband}")
        self.goal, self.deadband, self.tolerance = goal, float(deadband), float(tolerance)
        # (axis index, target value): over the object first when the hand is beside it and low
        self.moves: list[tuple[int, float]] = []
        if clear_first and np.linalg.norm(tcp[:2] - goal[:2]) > BESIDE and tcp[2] < goal[2] + CLEARANCE:
            self.moves.append((2, goal[2] + CLEARANCE))
        self.moves += [(0, goal[0]), (1, goal[1]), (2, goal[2])]
        self.index = 0
        self.last_press = -np.inf

    def step(self, t: float, tcp: np.ndarray, ee_axis: str) -> FineStep:
        """The stick and button at time `t` (s) with the TCP at `tcp` and the controller's end-effector
        axis `ee_axis` (its status). Never raises on a bad TCP: the stick rests."""
        tcp = np.asarray(tcp, dtype=float).reshape(-1)
        if tcp.shape != (3,) or not np.all(np.isfinite(tcp)):
            return FineStep(0.0, False, False)
        while self.index < len(self.moves):
            i, target = self.moves[self.index]
            # the last pass over x, y, z checks the goal itself; the clearance move only its height
            if abs(target - tcp[i]) > self.tolerance:
                break
            self.index += 1
        if self.index >= len(self.moves):
            if np.all(np.abs(self.goal - tcp) <= self.tolerance):
                return FineStep(0.0, False, True)
            self.moves, self.index = [(k, float(self.goal[k])) for k in range(3)], 0   # drifted: again
            return self.step(t, tcp, ee_axis)
        i, target = self.moves[self.index]
        name = AXES[i]
        if ee_axis != name:   # a person presses until the station shows the axis they want
            if t - self.last_press >= PRESS_INTERVAL:
                self.last_press = t
                return FineStep(0.0, True, False, name)
            return FineStep(0.0, False, False, name)
        return FineStep(stick_for(target - tcp[i], self.deadband), False, False, name)
