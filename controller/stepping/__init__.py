"""controller.stepping: (to be described)."""
