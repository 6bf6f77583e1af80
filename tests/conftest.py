"""Test-suite wiring: what the ``lightsim`` command does at start-up."""

# photometric readers (IES/LDT) and the bulb catalogue register with the core's emitters
import lightsim.luminaires  # noqa: F401
