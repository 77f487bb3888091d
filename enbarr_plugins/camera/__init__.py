"""Camera plugins: OpenCV capture (V4L2 or a video file) and its emulator (a test video)."""
