"""cornerman pipeline.backends."""
