"""The backend table: where a study's trials run, who may drive there, and how to make it.

A backend's module is imported only when it is chosen (the pattern of vla_panda_bridge.backends): the
graph's needs rclpy and launches processes; `--check` and the analysis need none. Each backend follows
trial.TrialBackend. A backend that is gone (GONE) is refused with why, before anything is made.
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
    BackendRow("robot", "attached to the lab's running robot graph: the experimenter places the object and "
               "scores the trial", False, True, _robot),
)}


# Backends that were and are no more, and why (old protocols and rows name them: they load, they do not run).
GONE = {"physics": "the in-process physics backend is gone (issue 33): its loop was a copy of the graph's "
                   "with another safety-layer configuration, the controller's stick mapping mirrored rather "
                   "than run and no detector in the loop, so it gave other numbers for the same trial; the "
                   "graph runs in lockstep now, deterministic at any load: use backend: graph "
                   "(--backend graph)"}


def backend_refusal(protocol: Protocol) -> str | None:
    """Why the protocol's backend cannot run (it is gone), or None."""
    name = backend_name(protocol)
    if name not in GONE:
        return None
    return f"{protocol.origin.get('backend', protocol.source or 'the protocol')}: {GONE[name]}"


def backend_name(protocol: Protocol) -> str:
    """The table's row for a protocol: its `backend`, or `robot` when it runs on the real robot."""
    return "robot" if protocol.robot == "real" else protocol.backend


def make_backend(where: Where) -> TrialBackend:
    if why := backend_refusal(where.protocol):
        raise SystemExit(f"protocol refused: {why}")
    return BACKENDS[backend_name(where.protocol)].make(where)
