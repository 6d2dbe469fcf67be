"""ROS 2 helpers every node uses: `run_node` (the one main), the parameter table, message converters
and the in-process test harness. The only part of vla_common that imports rclpy."""
