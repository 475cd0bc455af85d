"""controller.cli: (to be described)."""
