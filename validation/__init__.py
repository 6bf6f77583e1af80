"""Validation: analytic cases, photo comparison, convergence, stability, benchmarks."""

# the scenes here load IES/LDT files and bulbs: register those readers with the core
import lightsim.luminaires  # noqa: F401
