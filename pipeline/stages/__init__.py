"""cornerman pipeline.stages."""
