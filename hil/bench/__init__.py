"""hil.bench: (to be described)."""
