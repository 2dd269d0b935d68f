"""Benchmarks (`make bench`): each prints rates and ratios to a baseline measured in the same run."""
