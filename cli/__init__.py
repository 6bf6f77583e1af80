"""Command-line interface: click commands only; parse, call the engine, print."""
