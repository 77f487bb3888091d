"""Foxglove: a live WebSocket connection to the vessel process (``bridge``)."""
