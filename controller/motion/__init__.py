"""controller.motion: (to be described)."""
