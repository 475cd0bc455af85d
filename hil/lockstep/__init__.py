"""hil.lockstep: (to be described)."""
