"""scanmill: 3+2 five-axis machining planned straight from a raw point cloud."""

__version__ = "0.1.0"
