"""The backend table: where a study's trials run, who may drive there, and how to make it.

A backend's module is imported only when it is chosen (the pattern of vla_panda_bridge.backends): the
graph's needs rclpy and launches processes, the physics one MuJoCo; `--check` and the analysis need
neither. Each backend follows trial.TrialBackend.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vla_study.person import Experimenter
from vla_study.protocol import Protocol
from vla_study.trial import TrialBackend


@dataclass(frozen=True)
class Where:
    """What a backend is made from."""

    protocol: Protocol
    out: Path
    log: Callable[[str], None]
    experimenter: Experimenter | None = None  # for real participants
    use_sim_time: bool = False  # robot: the attached graph is a simulated one (a rehearsal, a test)


def _physics(w: Where) -> TrialBackend:
    from vla_study.physics_backend import PhysicsBackend  # MuJoCo: only when chosen

    return PhysicsBackend(w.protocol)


def _graph(w: Where) -> TrialBackend:
    from vla_study.graph_backend import GraphBackend  # rclpy and the launched graph: only when chosen

    return GraphBackend(w.protocol, w.out, w.log, experimenter=w.experimenter)


def _robot(w: Where) -> TrialBackend:
    from vla_study.robot_backend import RobotBackend

    return RobotBackend(w.protocol, w.out, w.log, experimenter=w.experimenter, use_sim_time=w.use_sim_time)


@dataclass(frozen=True)
class BackendRow:
    name: str
    summary: str
    simulated: bool  # simulated participants may drive here
    persons: bool  # real participants may drive here
    make: Callable[[Where], TrialBackend]


BACKENDS: dict[str, BackendRow] = {row.name: row for row in (
    BackendRow("graph", "the launched demo graph on the simulated Panda: the participant's stick as Joy, "
               "the scene reset by ~/reset, a bag per trial", True, True, _graph),
    BackendRow("physics", "the graph's computations in one process (MuJoCo, the bridge's safety filter, the "
               "controller's stick mapping): fast sweeps, no bags", True, False, _physics),
    BackendRow("robot", "attached to the lab's running robot graph: the experimenter places the object and "
               "scores the trial", False, True, _robot),
)}


def backend_name(protocol: Protocol) -> str:
    """The table's row for a protocol: its `backend`, or `robot` when it runs on the real robot."""
    return "robot" if protocol.robot == "real" else protocol.backend


def make_backend(where: Where) -> TrialBackend:
    return BACKENDS[backend_name(where.protocol)].make(where)
