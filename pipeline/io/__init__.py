"""cornerman pipeline.io."""
