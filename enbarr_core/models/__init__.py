"""Vessel models (Fossen 2021): 6-DOF rigid body and 3-DOF surface vessel, and parameters."""
