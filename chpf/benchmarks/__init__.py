"""Micro-benchmarks of chpf building blocks; each runs with `python -m` and prints a table."""
