"""Camera geometry without ROS: a checkerboard renderer and intrinsic calibration."""
