"""The leg's configuration: one TOML file, validated on load.

:mod:`controller.settings.schema` declares a setting once, in a configuration dataclass's field
metadata (type, default, unit, range, one line of documentation), and checks it;
:mod:`controller.settings.file` is the file: its sections, derived from those declarations,
reading, validation with every problem named, and writing back; :mod:`controller.settings.daemon`
is what the daemon runs with, the command line over the file, and the one bus-precedence rule.
This ``__init__`` imports nothing: the configuration dataclasses import the schema.

May import: the standard library (``tomllib``; ``tomli`` on Python 3.10), python-can, ``protocol``
and ``controller``; never ``hil`` or ``firmware_sim``.
"""
