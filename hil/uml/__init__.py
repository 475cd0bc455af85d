"""hil.uml: (to be described)."""
