"""hil.cli: (to be described)."""
