"""Enbarr core: what every vessel needs (filtering, command handling, control, allocation,
simulation, bringup and recording)."""
