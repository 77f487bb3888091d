"""Joystick plugins: operator input as ``sensor_msgs/Joy``."""
