"""Joystick driver: a Linux evdev joystick as sensor_msgs/Joy.
"""
