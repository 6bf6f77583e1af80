"""Benchmarks behind ``lightsim bench``: each returns rows (dicts) with in-run baselines."""
