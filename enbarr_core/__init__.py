"""Enbarr core: what every vessel needs.

The node framework, estimation, control, guidance, allocation, vessel models, simulation,
recording, bringup and tools, one folder each (``docs/architecture.md``).
"""
