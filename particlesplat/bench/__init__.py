"""Benchmarks of the library: renderer speed and edit fidelity."""
