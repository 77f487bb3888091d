"""Simulation: simulator nodes that run the vessel models in place of the water."""
