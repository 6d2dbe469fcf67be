"""The backend table: which robots each backend can drive and how to make it.

A backend's module is imported only when it is chosen: the MuJoCo one needs MuJoCo and the
simulator, which a bridge in front of a real arm must not require.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from vla_common.robot import RobotSpec

from vla_panda_bridge.backend import Backend, Host


def _mujoco(host: Host) -> Backend:
    from vla_panda_bridge.backend_mujoco import MujocoBackend  # MuJoCo: only when chosen

    return MujocoBackend(host)


def _ros2_control(host: Host) -> Backend:
    from vla_panda_bridge.backend_ros2_control import Ros2ControlBackend

    return Ros2ControlBackend(host)


def _libfranka(host: Host) -> Backend:
    from vla_panda_bridge.backend_libfranka import LibfrankaBackend  # pylibfranka/panda-py: in its process

    return LibfrankaBackend(host)


@dataclass(frozen=True)
class BackendRow:
    name: str
    robots: tuple[str, ...]          # robot models (vla_common.robot.ROBOTS) it can drive
    summary: str
    make: Callable[[Host], Backend]
    # The parameter with the joint torques (Nm) at which this robot's own reflex fires; "": the robot
    # model's tau_max (where the simulated arm's reflex fires). See `reflex_torque`.
    reflex_param: str = ""


BACKENDS: dict[str, BackendRow] = {row.name: row for row in (
    BackendRow("mujoco", ("panda",), "the simulated Panda (MuJoCo), stepped by the bridge", _mujoco),
    BackendRow("ros2_control", ("panda", "fr3"),
               "a ros2_control arm behind a JointGroupVelocityController", _ros2_control),
    BackendRow("libfranka", ("fr3", "panda"),
               "a Franka arm through libfranka (pylibfranka or panda-py), 1 kHz loop in its own process",
               _libfranka, reflex_param="upper_torque_thresholds"),
)}


def reflex_torque(params: Mapping[str, Any], spec: RobotSpec) -> list[float]:
    """The joint torques (Nm) at which the robot behind `params["backend"]` stops itself with a reflex:
    the safety filter's contact slowing acts at fractions of them, so it comes before the reflex. A
    real Franka's fires at the collision thresholds libfranka configures (12-20 Nm by default, far
    below tau_max); the simulated arm's at tau_max."""
    name = BACKENDS[params["backend"]].reflex_param
    return [float(x) for x in (params[name] if name else spec.tau_max)]
