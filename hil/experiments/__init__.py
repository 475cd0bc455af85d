"""hil.experiments: (to be described)."""
