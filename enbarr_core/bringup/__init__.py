"""Bringup: vessel profiles, the orchestrator that runs their nodes, and the command line."""
