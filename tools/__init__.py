"""Benchmarks, studies and pack tooling."""
