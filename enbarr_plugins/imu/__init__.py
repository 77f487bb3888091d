"""IMU plugins: the simulated 9-DOF IMU."""
