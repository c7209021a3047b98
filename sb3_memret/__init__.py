"""sb3-memret: a learnable external language memory for frozen robot policies."""

__version__ = "0.1.0"
