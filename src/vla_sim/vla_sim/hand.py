"""The simulated Franka Hand: the Panda's two fingers as prismatic joints coupled to move together
(the URDF's mimic joint, an equality constraint in MuJoCo) and driven by one force-limited position
servo on the finger gap (a tendon whose length is the width between the fingers).

The servo's target moves towards the commanded width at the commanded speed and the force on each
finger is clipped to the commanded force, as a real hand grasps: it closes at `speed` until the
object stops it, then squeezes with `force`. Contacts are elliptic friction cones with a high
impedance ratio (scene.py) so that a squeezed object does not creep out of the grasp.

Only the physics lives here (no Franka semantics of success, epsilon or e-stop: those are the
bridge's gripper layer, the same for every backend). Plain MuJoCo on the scene's model; stepped
by PandaSim once per physics step.
"""
from __future__ import annotations

import math

import mujoco
from vla_common.kinematics import FINGER_JOINTS
from vla_common.robot import HAND

from vla_sim.scene import FINGER_BODIES, HAND_ACTUATOR, HAND_TENDON

# The servo's target goes this far past a closing goal, so that a closed hand presses its fingers
# together (or onto what it holds) with the commanded force instead of resting at zero force.
CLOSE_PRELOAD = 0.01
# The force of a hand at rest after a reset: closed, fingers pressed together (the pushing tasks).
REST_FORCE = 20.0


class SimHand:
    """The hand of one PandaSim (its model and data). `command(width, speed, force)` starts a motion;
    `step(h)` advances the servo's target; state: `width`, `width_speed`, `target`, `goal`,
    `force`, `holding()`."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model, self.data = model, data
        self._act = model.actuator(HAND_ACTUATOR).id
        self._tendon = model.tendon(HAND_TENDON).id
        self._qadr = [int(model.jnt_qposadr[model.joint(j).id]) for j in FINGER_JOINTS]
        self._dadr = [int(model.jnt_dofadr[model.joint(j).id]) for j in FINGER_JOINTS]
        self._fingers = [model.body(b).id for b in FINGER_BODIES]
        self.reset()

    def reset(self, width: float = 0.0) -> None:
        """Fingers at `width` (m) at rest, the servo holding them there (closed: pressed together)."""
        w = min(max(float(width), 0.0), HAND.max_width)
        for a in self._qadr:
            self.data.qpos[a] = w / 2
        for a in self._dadr:
            self.data.qvel[a] = 0.0
        self.goal = w
        self.speed = 0.05
        self.force = REST_FORCE
        self.target = w - CLOSE_PRELOAD if w <= 0.0 else w
        self._apply()

    # ------------------------------------------------------------------ state
    @property
    def width(self) -> float:
        """The measured gap between the fingers (m), never below 0: closed on nothing, MuJoCo's soft
        joint limits let each finger sink ~0.3 mm past zero, which a real hand reports as 0."""
        return max(0.0, float(self.data.qpos[self._qadr[0]] + self.data.qpos[self._qadr[1]]))

    @property
    def width_speed(self) -> float:
        return float(self.data.qvel[self._dadr[0]] + self.data.qvel[self._dadr[1]])

    @property
    def finger_positions(self) -> tuple[float, float]:
        """panda_finger_joint1, panda_finger_joint2 (m, each half the width)."""
        return float(self.data.qpos[self._qadr[0]]), float(self.data.qpos[self._qadr[1]])

    @property
    def finger_velocities(self) -> tuple[float, float]:
        return float(self.data.qvel[self._dadr[0]]), float(self.data.qvel[self._dadr[1]])

    @property
    def finger_forces(self) -> tuple[float, float]:
        """The servo's force on each finger (N, negative closes)."""
        f = float(self.data.actuator_force[self._act])
        return f, f

    @property
    def moving(self) -> bool:
        """The servo's target has not reached the goal yet."""
        return abs(self.target - self._final_target()) > 1e-9

    def holding(self, bodies: dict[str, int]) -> list[str]:
        """Names (keys of `bodies`: name -> body id) of the bodies both fingers touch now."""
        touched: list[set[int]] = [set(), set()]
        m, d = self.model, self.data
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            for k, f in enumerate(self._fingers):
                if b1 == f:
                    touched[k].add(b2)
                elif b2 == f:
                    touched[k].add(b1)
        both = touched[0] & touched[1]
        return [name for name, b in bodies.items() if b in both]

    # ------------------------------------------------------------------ control
    def command(self, width: float, speed: float, force: float) -> None:
        """Move the fingers to `width` (m) at `speed` (m/s), each pressing with at most `force` (N).
        ValueError outside the hand's range (the bridge's gripper layer refuses these first)."""
        values = (width, speed, force)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"hand command must be finite numbers, got {values!r}")
        h = HAND
        if not (0.0 <= width <= h.max_width and 0.0 < speed <= h.max_speed and 0.0 < force <= h.max_force):
            raise ValueError(f"hand command outside its range: width {width} m (0..{h.max_width}), "
                             f"speed {speed} m/s (0..{h.max_speed}], force {force} N (0..{h.max_force}]")
        self.goal, self.speed, self.force = float(width), float(speed), float(force)
        # a motion starts from where the fingers are (not from a preloaded target behind them)
        self.target = min(max(self.width, 0.0), HAND.max_width)
        self._apply()

    def stop(self) -> None:
        """Hold the fingers where they are now with the current force (what they hold stays held:
        the target stays on the closing side when the servo is squeezing)."""
        w = self.width
        squeezing = self.data.actuator_force[self._act] < -0.5 * self.force
        self.goal = w
        self.target = w - CLOSE_PRELOAD if squeezing else w
        self._apply()

    def _final_target(self) -> float:
        return self.goal - CLOSE_PRELOAD if self.goal <= 0.0 else self.goal

    def step(self, h: float) -> None:
        """Advance the servo's target by one physics step of `h` seconds."""
        final = self._final_target()
        delta = final - self.target
        limit = self.speed * h
        self.target = final if abs(delta) <= limit else self.target + math.copysign(limit, delta)
        self.data.ctrl[self._act] = self.target

    def _apply(self) -> None:
        self.model.actuator_forcerange[self._act] = (-self.force, self.force)
        self.data.ctrl[self._act] = self.target


__all__ = ["CLOSE_PRELOAD", "FINGER_BODIES", "REST_FORCE", "SimHand"]
