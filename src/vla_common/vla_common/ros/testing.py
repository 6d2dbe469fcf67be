"""The in-process test harness of every package's node tests: a private rclpy context (so tests never
share one), one executor, and spin-until helpers that wait for a condition instead of sleeping.

A harness sees only its own nodes unless the test talks to processes it started (`other_processes`).
Fast DDS keeps a participant that an earlier test deleted, sometimes half torn down, until its 20 s
lease runs out, and rmw_fastrtps calls a service available only when the name has as many request
readers as reply writers: a stale `panda_bridge` with a reader and no writer made the next test's
`panda_bridge/change_state` "not available" (6 runs in 37 of the bridge tests, and once in CI).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from vla_common.ros.context import destroy_node, end_context
from vla_common.ros.discovery import discovered_by
from vla_common.ros.domain import DISCOVERY_VARIABLE
from vla_common.ros.spin import spin_until


class RosHarness:
    """A private rclpy context with one executor; nodes added with `add`. `other_processes`: discover
    the run's domain as the environment says (for node processes and launches the test starts)."""

    def __init__(self, other_processes: bool = False) -> None:
        self.context = Context()
        if other_processes:
            rclpy.init(context=self.context)
        else:
            _init_discovering_nothing_else(self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self.ended = False

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        return spin_until(self._spin_once, condition, timeout)

    def spin_for(self, seconds: float) -> None:
        spin_until(self._spin_once, lambda: False, seconds)

    def call(self, client, request, timeout: float = 20.0):
        assert client.wait_for_service(timeout_sec=timeout), f"service {client.srv_name} not available"
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"service {client.srv_name} timed out"
        return future.result()

    def discovered_by(self, node, remote: str, timeout: float = 30.0) -> bool:
        """True once the node `remote` (in a process the test started) has discovered `node`'s
        endpoints: see `vla_common.ros.discovery`. Call it after making the clients it is for."""
        return discovered_by(node, remote, self._spin_once, timeout)

    def _spin_once(self, seconds: float) -> None:
        self.executor.spin_once(timeout_sec=seconds)

    def shutdown(self) -> None:
        """Destroy the nodes and end the context; a second call does nothing."""
        if self.ended:
            return
        self.ended = True
        for node in self.nodes:
            self.executor.remove_node(node)
            destroy_node(node)
        self.executor.shutdown()
        end_context(self.context)


def _init_discovering_nothing_else(context: Context) -> None:
    """rclpy.init with discovery OFF (this context's nodes only): rcl reads the variable during init,
    so the environment that child processes inherit is put back at once."""
    before = os.environ.get(DISCOVERY_VARIABLE)
    os.environ[DISCOVERY_VARIABLE] = "OFF"
    try:
        rclpy.init(context=context)
    finally:
        if before is None:
            os.environ.pop(DISCOVERY_VARIABLE, None)
        else:
            os.environ[DISCOVERY_VARIABLE] = before
