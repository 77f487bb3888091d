"""Vision: what the camera sees, as pure modules (OpenCV and numpy) beside their nodes."""
