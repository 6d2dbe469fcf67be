"""The one graph runner: a shipped launch file plus this process's own node, on a ROS domain of its own.

The evaluation (`graph.GraphEvaluator`) and demonstration generation (`generate.run_generation`) both
start a launch file through vla_launch (as `vla launch` does) and drive it from a node of theirs
spun in a private rclpy context. This class does that once, with one teardown order: our side first
(the spinner stops, so no callback runs on a node being destroyed; the node; the context), then the
launch (SIGINT to its processes, as Ctrl-C). The ROS domain comes from `vla_common.ros.domain`.
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Generic, Protocol, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from vla_common.ros.context import destroy_node, end_context
from vla_common.ros.domain import DISCOVERY_VARIABLE, DomainError, isolated_env, release_domain
from vla_launch.session import LaunchError, LaunchSession

# Read by rmw when our context starts: set for the runner's lifetime, then restored.
_CONTEXT_ENV = ("ROS_DOMAIN_ID", DISCOVERY_VARIABLE)


class HasNode(Protocol):
    node: Node


N = TypeVar("N", bound=HasNode)


class NodeSpinner(Generic[N]):
    """This process's own node in a private rclpy context on `domain`, spun in a thread of its own.
    `close()` tears it down in one order (the spinner stops, so no callback runs on a node being
    destroyed; the node; the context) and is idempotent. GraphRunner uses it beside the launch it
    starts; a study attached to a graph someone else started uses it alone."""

    def __init__(self, domain: int) -> None:
        self.domain = domain
        self.ctx: Context | None = None
        self.executor: EventsExecutor | None = None
        self.owner: N | None = None
        self._stop = threading.Event()
        self._spinner: threading.Thread | None = None

    def start(self, make: Callable[[Context], N]) -> N:
        """Create `make(context)`'s node in a new context on the domain and spin it (torn down again if
        anything fails)."""
        try:
            self.ctx = Context()
            rclpy.init(context=self.ctx, domain_id=self.domain,
                       signal_handler_options=SignalHandlerOptions.NO)
            self.owner = make(self.ctx)
            # in arrival order (a lockstep orchestrator reads a held step after everything it published)
            self.executor = EventsExecutor(context=self.ctx)
            self.executor.add_node(self.owner.node)
            self._spinner = threading.Thread(target=self._spin, daemon=True)
            self._spinner.start()
        except BaseException:
            self.close()
            raise
        return self.owner

    def _spin(self) -> None:
        try:
            while not self._stop.is_set() and self.ctx is not None and self.ctx.ok():
                self.executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass

    def close(self) -> None:
        self._stop.set()
        if self._spinner is not None:
            self._spinner.join(10.0)
            self._spinner = None
        if self.ctx is not None:
            ctx, self.ctx = self.ctx, None
            if self.executor is not None:
                self.executor.shutdown(timeout_sec=10.0)
            if self.owner is not None:
                destroy_node(self.owner.node)
            end_context(ctx)


class GraphRunner(Generic[N]):
    """`start(make)` launches, joins the domain and spins `make(context)`'s node; `alive()` raises
    `error` when a launched process has ended; `close()` tears down (idempotent)."""

    def __init__(self, launch: tuple[str, str], arguments: Mapping[str, object], *,
                 domain: int | None = None, busy: Callable[[int], bool] | None = None,
                 log_path: Path | None = None, error: type[Exception] = RuntimeError) -> None:
        self.launch, self.arguments, self.log_path, self.error = launch, dict(arguments), log_path, error
        try:
            self.env = isolated_env(domain, busy=busy)
        except DomainError as e:
            raise error(str(e)) from None
        self.env.setdefault("MUJOCO_GL", "egl")
        self.env.update(PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
        self.domain = int(self.env["ROS_DOMAIN_ID"])
        self.session: LaunchSession | None = None
        self.side: NodeSpinner[N] = NodeSpinner(self.domain)
        self._saved_env: dict[str, str | None] = {}

    def start(self, make: Callable[[Context], N]) -> N:
        """Launch the file, then create our node in a context on the same domain and spin it."""
        for key in _CONTEXT_ENV:
            self._saved_env[key] = os.environ.get(key)
            os.environ[key] = self.env[key]
        self.session = LaunchSession(*self.launch, self.arguments, env=self.env, log_path=self.log_path)
        try:
            self.session.start()
            owner = self.side.start(make)
        except LaunchError as e:
            self.close()
            raise self.error(str(e)) from None
        except BaseException:
            self.close()
            raise
        return owner

    @property
    def owner(self) -> N | None:
        return self.side.owner

    def alive(self) -> None:
        """`error` with the ended process's last output lines when a process of the launch has ended."""
        try:
            if self.session is not None:
                self.session.check()
        except LaunchError as e:
            raise self.error(str(e)) from None

    def tail(self) -> str:
        return self.session.tail() if self.session is not None else ""

    def close(self, log: Callable[[str], None] = print) -> int | None:
        """Our side first, then the launch; returns the launch's exit code (None if it never started)."""
        self.side.close()
        rc = None
        if self.session is not None:
            session, self.session = self.session, None
            try:
                rc = session.stop()
                if rc != 0:
                    log(f"[graph] the launch ended with exit code {rc}; see {session.log_path}")
            except LaunchError as e:
                log(f"[graph] {e}")
        for key, value in self._saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        self._saved_env.clear()
        release_domain(self.domain)  # a domain picked at random for this graph is free again
        return rc
