"""``joy_node``: a Linux joystick (evdev) → ``sensor_msgs/Joy``, for machines without joystick_drivers.

Thin wrapper around :mod:`vla_joystick.joystick`: a reader thread blocks on the device
(select with a timeout, no busy loop) and publishes ``joy`` with the standard joy node's deadzone,
autorepeat and numbering. Unplugging stops publishing (consumers time out); it reopens by itself.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Sequence

from rclpy.node import Node
from sensor_msgs.msg import Joy
from vla_common.ros.node_main import run_node
from vla_common.ros.parameters import THREAD_PRIORITY, Param, ParameterTable

from vla_joystick.joystick import DEFAULT_AUTOREPEAT_RATE, JoystickLoop, default_opener

NODE_NAME = "joy_node"

# All read-only: they configure the device and the reader thread, which start with the node.
PARAMETERS = ParameterTable([
    THREAD_PRIORITY,   # on the operator's path: SCHED_FIFO where allowed (vla_common.priority)
    Param("device_path", "", "event device, e.g. /dev/input/by-id/usb-...-event-joystick; empty: search "
          "by device_name"),
    Param("device_name", "", "open the first device whose name contains this (case-insensitive); both "
          "empty: the first device that looks like a joystick"),
    Param("deadzone", 0.05, "centre deadzone as a fraction of the half range; the rest is rescaled so "
          "+-1 is still reached", range=(0.0, 0.9)),
    Param("autorepeat_rate", DEFAULT_AUTOREPEAT_RATE, "republish the unchanged state at this rate (Hz), "
          "well above 1 / the controller's joy_timeout; 0 disables",
          range=(0.0, 1000.0)),
    Param("coalesce_interval", 0.001, "axis changes are published at most once per this interval (s); "
          "button changes at once", range=(0.0, 1.0)),
    Param("frame_id", "", "header.frame_id of the Joy messages (empty: a Joy has no geometry, no frame)"),
])


class JoyNode(Node):
    def __init__(self, *, opener=None, **node_kwargs):
        super().__init__(NODE_NAME, **node_kwargs)
        p = PARAMETERS.declare(self)
        self._frame_id = p["frame_id"]
        self._pub = self.create_publisher(Joy, "joy", 10)
        self.loop = JoystickLoop(
            self._publish,
            opener=opener or default_opener(p["device_path"], p["device_name"]),
            deadzone=p["deadzone"],
            autorepeat_rate=p["autorepeat_rate"],
            coalesce_interval=p["coalesce_interval"],
            log=self._log,
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self.loop.run, args=(self._stop,), name="joy", daemon=True)
        self._thread.start()
        where = p["device_path"] or (f"name ~ '{p['device_name']}'" if p["device_name"] else "first joystick")
        self.get_logger().info(
            f"joy_node: {where} -> joy (deadzone {p['deadzone']:g}, autorepeat {p['autorepeat_rate']:g} Hz)"
        )

    def _publish(self, axes: Sequence[float], buttons: Sequence[int]) -> None:
        if not self.context.ok():  # shutting down: the reader thread may still be finishing a read
            return
        msg = Joy()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self._frame_id
        msg.axes = [float(a) for a in axes]
        msg.buttons = [int(b) for b in buttons]
        self._pub.publish(msg)

    def _log(self, level: str, text: str) -> None:
        # One call site per severity: rclpy refuses a call site whose severity changes between calls.
        if level == "warn":
            self.get_logger().warn(text)
        else:
            self.get_logger().info(text)

    def on_shutdown(self) -> None:
        """Stop the reader thread. No last message: an all-zero Joy is not the released state of every
        device (a released trigger reads +1), so consumers time out as with the standard joy node."""
        self._stop.set()
        self._thread.join(timeout=2.0)

    def destroy_node(self):
        self.on_shutdown()
        return super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(JoyNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
