"""Vision: camera models, calibration boards and camera calibration (pure; no ROS)."""
