"""Test-suite wiring: what the ``lightsim`` command does at start-up."""

# photometric readers (IES/LDT) and the bulb catalogue register with the core's emitters
import lightsim.luminaires  # noqa: F401
from lightsim.engine.memory import keep_freed_memory, small_pages

# the command's memory policies (engine/memory.py): freed blocks reused, NumPy's arrays
# on normal pages (fresh huge pages are slow faults on the project's VMs). Tests of the
# policies themselves run in child processes.
keep_freed_memory()
small_pages()
