"""Perception: obstacles from the lidar scan (segmentation, fitting, tracking), beside its node."""
