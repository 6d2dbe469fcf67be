"""The launch tool: `vla run` and `vla launch` for machines without ros2cli.
"""
