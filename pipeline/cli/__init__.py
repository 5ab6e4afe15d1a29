"""cornerman pipeline.cli."""
