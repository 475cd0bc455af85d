"""controller.bringup: (to be described)."""
