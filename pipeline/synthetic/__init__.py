"""cornerman pipeline.synthetic."""
