"""Guidance: the references a DP controller tracks (laws and the guidance node)."""
