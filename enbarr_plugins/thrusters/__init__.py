"""Thruster plugins: the simulated ESCs and motors."""
