"""Motion-capture plugins: the vessel's pose on ``mocap/pose``."""
