"""Bringup: vessel profiles, composition, the vessel guard, runner, supervisor and CLI."""
