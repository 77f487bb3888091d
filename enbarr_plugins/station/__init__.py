"""The web surface station: an operator page served by a node of the vessel's process."""
