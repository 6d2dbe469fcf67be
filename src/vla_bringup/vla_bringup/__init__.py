"""Launch files, shared parameters and the `vla` tool (ros2 run / ros2 launch without ros2cli)."""
