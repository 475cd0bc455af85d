"""controller.io: (to be described)."""
