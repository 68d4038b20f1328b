"""sandtrack-tui: two camera videos of marker particles to verified 3D trajectories."""

__version__ = "0.1.0"
