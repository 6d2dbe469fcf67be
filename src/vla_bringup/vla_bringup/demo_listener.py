"""`demo_listener`: a minimal rclpy subscriber used to show and test `vla launch` (logs `chatter`)."""
from __future__ import annotations

import sys

import rclpy
from rcl_interfaces.msg import IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String


class DemoListener(Node):
    def __init__(self) -> None:
        super().__init__("demo_listener")
        self.exit_after = self.declare_parameter("exit_after", 0, ParameterDescriptor(
            description="exit cleanly after this many messages (0: never)",
            integer_range=[IntegerRange(from_value=0, to_value=1_000_000)])).value
        self.count = 0
        self.sub = self.create_subscription(String, "chatter", self.on_message, 10)

    def on_message(self, msg: String) -> None:
        self.count += 1
        self.get_logger().info(f"I heard: '{msg.data}'")
        if self.exit_after and self.count >= self.exit_after:
            raise SystemExit(0)


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = DemoListener()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException, SystemExit):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
