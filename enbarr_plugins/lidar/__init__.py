"""Lidar plugins: one revolution of a 2-D scanning lidar on ``scan`` (vessel frame)."""
