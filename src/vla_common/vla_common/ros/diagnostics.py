"""`/diagnostics` for every runtime node: one diagnostic_msgs/DiagnosticStatus per node, published as a
DiagnosticArray at 1 Hz and at once when the level changes, as diagnostic_updater does for a driver,
so that diagnostic_aggregator and rqt_robot_monitor show our nodes beside any other. Our own status
topics stay (they carry more); this is the standard view of the same state.

    self.diagnostics = Diagnostics(self)                       # in __init__
    self.diagnostics.update("warn", "no joint_states yet", mode="latent")
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN,
          "error": DiagnosticStatus.ERROR, "stale": DiagnosticStatus.STALE}
TOPIC = "/diagnostics"  # absolute, as diagnostic_updater publishes it, whatever the node's namespace


def level_of(level: str | int) -> bytes:
    """A DiagnosticStatus level from 'ok'/'warn'/'error'/'stale' or its number; ValueError otherwise."""
    if isinstance(level, str):
        if level.lower() not in LEVELS:
            raise ValueError(f"diagnostic level {level!r} is not one of {list(LEVELS)}")
        level = LEVELS[level.lower()]
    if isinstance(level, bytes):
        level = level[0]
    if int(level) not in (0, 1, 2, 3):
        raise ValueError(f"diagnostic level {level!r} is not 0..3")
    return bytes([int(level)])


def status_message(name: str, hardware_id: str, level: str | int, message: str,
                   values: dict[str, Any]) -> DiagnosticStatus:
    """One DiagnosticStatus; values become strings (floats with 6 significant digits)."""
    s = DiagnosticStatus(name=name, hardware_id=hardware_id, level=level_of(level), message=message)
    s.values = [KeyValue(key=str(k), value=f"{v:.6g}" if isinstance(v, float) else str(v))
                for k, v in values.items()]
    return s


class Diagnostics:
    """The node's one diagnostic status: `update()` sets it, a timer republishes it every `period` s."""

    def __init__(self, node: Node, hardware_id: str = "", period: float = 1.0) -> None:
        self._node = node
        self._pub = node.create_publisher(DiagnosticArray, TOPIC, 10)
        self.name = f"{node.get_fully_qualified_name().lstrip('/')}"
        self._hardware_id = hardware_id
        self._status = status_message(self.name, hardware_id, "ok", "starting", {})
        self._timer = node.create_timer(period, self.publish)

    @property
    def status(self) -> DiagnosticStatus:
        return self._status

    def update(self, level: str | int, message: str, **values: Any) -> None:
        """Set the status; publish at once when the level changed (a fault is seen without waiting)."""
        changed = level_of(level) != self._status.level
        self._status = status_message(self.name, self._hardware_id, level, message, values)
        if changed:
            self.publish()

    def publish(self) -> None:
        msg = DiagnosticArray(status=[self._status])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)
