"""controller.daemon: (to be described)."""
