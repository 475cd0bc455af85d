"""hil.session: (to be described)."""
