"""IMU plugins: the simulated 9-DOF IMU, LSM9DS1, FXOS8700+FXAS21002C and their emulators."""
