"""cornerman pipeline: multi-view, physics-based 3D motion capture of two athletes."""

__version__ = "0.1.0"
