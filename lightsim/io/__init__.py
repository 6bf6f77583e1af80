"""Output files: OpenEXR lux maps, false-colour PNGs, JSON summaries; all written atomically."""
