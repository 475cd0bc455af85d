"""hil.faults: (to be described)."""
