"""hil.analysis: (to be described)."""
