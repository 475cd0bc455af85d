"""controller.settings: (to be described)."""
