"""`demo_talker`: a minimal rclpy publisher used to show and test `vla launch` (std_msgs/String on `chatter`).

`crash_after` makes it raise after N messages, which is how the tests show a crashing node.
"""
from __future__ import annotations

import sys

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String


class DemoTalker(Node):
    def __init__(self) -> None:
        super().__init__("demo_talker")
        self.message = self.declare_parameter(
            "message", "hello", ParameterDescriptor(description="text sent, followed by a counter")).value
        rate = self.declare_parameter("rate", 10.0, ParameterDescriptor(
            description="messages per second",
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=1000.0)])).value
        self.crash_after = self.declare_parameter("crash_after", 0, ParameterDescriptor(
            description="raise an exception after this many messages (0: never)",
            integer_range=[IntegerRange(from_value=0, to_value=1_000_000)])).value
        tags = self.declare_parameter("tags", ["demo"], ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING_ARRAY, description="free labels, logged at start")).value
        self.pub = self.create_publisher(String, "chatter", 10)
        self.count = 0
        self.timer = self.create_timer(1.0 / rate, self.tick)
        self.get_logger().info(f"params: message={self.message!r} rate={rate} crash_after={self.crash_after} "
                               f"tags={list(tags)}")

    def tick(self) -> None:
        self.count += 1
        self.pub.publish(String(data=f"{self.message} {self.count}"))
        self.get_logger().info(f"Publishing: '{self.message} {self.count}'")
        if self.crash_after and self.count >= self.crash_after:
            raise RuntimeError(f"simulated crash after {self.count} messages")


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = DemoTalker()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
