"""Core nodes: thin translators between messages and the algorithms in ``algorithms``."""
