"""Vision without ROS: camera models and calibration, and objects in camera images."""
