"""hil.dryrun: (to be described)."""
