"""segloc: 2D laser localization by overlapping segment-based maps."""

__version__ = "0.2.0"
