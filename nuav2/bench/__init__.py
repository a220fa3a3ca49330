"""Benchmarks behind `nuav2 bench ...`: each times our path against a baseline in the same run."""
