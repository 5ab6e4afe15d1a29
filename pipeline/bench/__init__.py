"""Benchmarks behind ``cornerman bench <name>``: each module has ``run_bench(**opts) -> rows`` and ``print_table(rows)``."""
