"""``joy_node``: a Linux joystick (evdev) → ``sensor_msgs/Joy``, for machines without joystick_drivers.

Thin wrapper around :mod:`vla_joystick.joystick`: a reader thread blocks on the device
(select with a timeout, no busy loop) and publishes ``joy`` with the standard joy node's deadzone,
autorepeat and numbering. Unplugging stops publishing (consumers time out); it reopens by itself.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Sequence

import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Joy

from vla_joystick.joystick import JoystickLoop, default_opener


class JoyConfigError(ValueError):
    """A parameter value the node cannot start with."""


def _desc(text: str, float_range: tuple[float, float] | None = None) -> ParameterDescriptor:
    d = ParameterDescriptor(description=text, read_only=True)
    if float_range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float_range[0], to_value=float_range[1])]
    return d


class JoyNode(Node):
    def __init__(self, *, opener=None, **node_kwargs):
        super().__init__("joy_node", **node_kwargs)
        specs = {
            "device_path": (
                "",
                _desc(
                    "Event device, e.g. /dev/input/by-id/usb-…-event-joystick; empty = search by device_name"
                ),
            ),
            "device_name": (
                "",
                _desc(
                    "Open the first device whose name contains this (case-insensitive); "
                    "both empty = the first device that looks like a joystick"
                ),
            ),
            "deadzone": (
                0.05,
                _desc(
                    "Centre deadzone as a fraction of the half range; the rest is rescaled "
                    "so ±1 is still reached",
                    (0.0, 0.9),
                ),
            ),
            "autorepeat_rate": (
                20.0,
                _desc("Republish the unchanged state at this rate (Hz); 0 disables", (0.0, 1000.0)),
            ),
            "coalesce_interval": (
                0.001,
                _desc(
                    "Axis changes are published at most once per this interval (s); button changes at once",
                    (0.0, 1.0),
                ),
            ),
            "frame_id": ("joy", _desc("header.frame_id of the Joy messages")),
        }
        p = {}
        for name, (default, descriptor) in specs.items():
            try:
                p[name] = self.declare_parameter(name, default, descriptor).value
            except Exception as exc:  # out of range / wrong type in an override or params file
                raise JoyConfigError(f"parameter '{name}': {exc}") from exc
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

    def destroy_node(self):
        self._stop.set()
        self._thread.join(timeout=2.0)
        return super().destroy_node()


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = JoyNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except JoyConfigError as exc:
        print(f"joy_node: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        try:
            if node is not None:
                node.destroy_node()
            if rclpy.ok():
                rclpy.shutdown()
        except KeyboardInterrupt:  # a late Ctrl-C during cleanup is still a clean stop
            pass
    return code


if __name__ == "__main__":
    sys.exit(main())
