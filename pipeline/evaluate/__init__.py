"""cornerman pipeline.evaluate."""
