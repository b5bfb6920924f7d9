"""Synthetic data generation for chpf: render pools, training samples, BOP sequences."""
