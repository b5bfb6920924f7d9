"""chpf: Counter-Hypothetical Particle Filters for 6D object pose tracking (runtime, no torch)."""

__version__ = "0.1.0"
