"""Issue 33: an episode's commands are a function of its own inputs, not of how long the controller ran
before it. A lockstep controller counts the core's seconds from each re-latch (lockstep.EpisodeClock);
the same assisted episode after another one, or alone on a fresh controller, then gives bitwise the same
commands. On the lockstep clock's absolute seconds the last bits of every time difference (the
assistance's dt) depend on the offset, and so did the commands."""
import math
from pathlib import Path

import numpy as np
import pytest
from vla_common.camera_model import SIM_WEBCAM
from vla_common.catalogue import default_catalogue
from vla_common.detection import Detection
from vla_common.kinematics import PandaKinematics
from vla_common.robot import READY_POSE
from vla_latent_controller.assistance import Assistance
from vla_latent_controller.lockstep import EpisodeClock
from vla_latent_controller.model import LatentModel
from vla_latent_controller.teleop import TeleopCore, TeleopParams

MODELS = Path(__file__).resolve().parents[1] / "models"
NAMES = [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]
SIZE = (640, 480)
STEP_NS = 10_000_000           # a 100 Hz joint state
FRAME = 20                     # steps between camera frames (5 Hz)
EPOCH_NS = 1_000_000_000       # the lockstep clock's start


@pytest.fixture(scope="module")
def kin():
    return PandaKinematics()


def _bread() -> list[Detection]:
    cat = default_catalogue()
    u, v = SIM_WEBCAM.projector(*SIZE)([0.5, 0.05, 0.5 * cat.spec("bread").height])
    return [Detection("bread", 0.9, u, v, 40.0, 40.0)]


class Node:
    """What the controller node does in lockstep with its core: times from the step's stamp (ns) on
    its episode clock, which a re-latch restarts (`episode_clock` False: the clock's absolute seconds,
    as before issue 33), and the arm moved as commanded."""

    def __init__(self, kin, episode_clock: bool = True) -> None:
        self.core = TeleopCore(TeleopParams(assistance="high"), LatentModel.load(MODELS / "default"), kin,
                               camera=lambda: SIM_WEBCAM.pinhole(*SIZE))
        self.clock, self.episode_clock = EpisodeClock(), episode_clock
        self.ns, self.steps = EPOCH_NS, 0
        self.q = np.array(READY_POSE, float)

    def step(self, stick: float) -> np.ndarray:
        self.ns, self.steps = self.ns + STEP_NS, self.steps + 1
        t = self.clock.seconds(self.ns)
        self.core.on_joint_states(NAMES, [*self.q, 0.0, 0.0], t)
        self.core.on_joy([stick], [0] * 4, t)
        if self.steps % FRAME == 0:
            self.core.on_detections(_bread(), SIZE, t)
        cmd = self.core.step(t)[0].copy()
        self.q = self.q + cmd * STEP_NS * 1e-9
        return cmd

    def episode(self, seconds: float) -> list[np.ndarray]:
        """The scene reset (the arm at the ready pose), 0.5 s to settle, a re-latch, then the stick held."""
        self.q = np.array(READY_POSE, float)
        for _ in range(50):
            self.step(0.0)
        if self.episode_clock:
            self.core.restamp(self.clock.restart(self.ns))
        self.core.request_redetect(self.clock.seconds(self.ns))
        for _ in range(FRAME + 1):
            self.step(0.0)
        return [self.step(1.0) for _ in range(round(seconds * 100))]


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_an_assisted_episode_after_another_gives_the_same_commands_as_alone(kin):
    first, alone = Node(kin), Node(kin)
    first.episode(1.7)                        # another episode first: the clock runs on 2.4 s
    after = first.episode(2.0)
    assert _same(after, alone.episode(2.0))
    assert any(np.linalg.norm(c) > 0.1 for c in after)       # it drove, assisted
    assert alone.core.status.assist.goal_task                  # the assistance inferred a goal


def test_on_the_clocks_absolute_seconds_the_same_episode_came_out_differently(kin):
    first, alone = Node(kin, episode_clock=False), Node(kin, episode_clock=False)
    first.episode(1.7)
    assert not _same(first.episode(2.0), alone.episode(2.0))


def test_a_restarted_clock_maps_every_kept_time_to_what_the_new_origin_gives():
    clock = EpisodeClock()
    stamps = [EPOCH_NS + k * 7_919_993 for k in range(2000)]
    kept = [clock.seconds(s) for s in stamps]
    origin = stamps[1234]
    restamp = clock.restart(origin)
    fresh = [(s - origin) * 1e-9 for s in stamps]
    assert [restamp(t) for t in kept] == fresh
    assert [clock.seconds(s) for s in stamps] == fresh
    assert restamp(-math.inf) == -math.inf and math.isnan(restamp(math.nan))
    assert all(clock.stamp_ns(t) == s for t, s in zip(fresh, stamps))


def test_a_relatch_forgets_the_goal_the_status_showed(kin):
    a = Assistance(kin)
    a.state = a.shown("high", False)
    a.state.goal_task, a.state.stage = "bread/push_east", "hover"
    a.reset()
    assert a.state.goal_task == "" and a.state.stage == "" and a.state.level == "high"


def test_with_the_assistance_on_a_step_needs_every_frames_detections_since_the_latch(kin):
    node = Node(kin)
    for _ in range(FRAME):                    # the first detections latch
        node.step(0.0)
    core, t = node.core, node.clock.seconds(node.ns)
    assert core.latched is not None
    assert core.detection_wanted(t) == core.latched.t        # the assistance reads every array
    core.params.assistance = "off"
    assert core.detection_wanted(t) is None                  # the decoder alone: only a latch's
