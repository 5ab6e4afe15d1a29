"""Stage steps: I/O adapters between the runner and the pure stage functions."""
