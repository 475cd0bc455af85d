"""Controller configurations recorded as JSON, before the configuration became TOML.

Only ``replay`` reads them (a ``controller.json`` beside an old bus log, with a warning); the
daemon and every new session use TOML (:mod:`controller.settings.file`). The JSON is a nested
dict: every key overrides the default of the field of that name, nested sections (``cpg``,
``learner``, ...) field by field, ``axes`` as a list of complete axis dicts; an unknown key is
an error naming it.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Any

from controller.config import ControllerConfig
from controller.io.axis import AxisConfig
from controller.settings.file import load_config

log = logging.getLogger(__name__)


def _from_dict(cls, base, data: dict[str, Any], where: str):
    names = {f.name for f in dataclasses.fields(cls)}
    changes = {}
    for key, value in data.items():
        if key not in names:
            raise ValueError(f"{where}{key}: no such setting (known: {', '.join(sorted(names))})")
        current = getattr(base, key)
        if key == "axes" and cls is ControllerConfig:
            changes[key] = tuple(AxisConfig(**{**a, **({"direction": int(a["direction"])} if "direction" in a else {})})
                                 for a in value)
        elif dataclasses.is_dataclass(current) and isinstance(value, dict):
            changes[key] = _from_dict(type(current), current, value, f"{where}{key}.")
        elif isinstance(current, tuple) and isinstance(value, list):
            changes[key] = tuple(value)
        else:
            changes[key] = value
    return dataclasses.replace(base, **changes)


def controller_config_from_dict(data: dict[str, Any]) -> ControllerConfig:
    return _from_dict(ControllerConfig, ControllerConfig(), data, "")


def load_controller_config(path: str | Path | None) -> ControllerConfig:
    """The controller configuration in ``path``: a TOML configuration (:func:`load_config`), or a
    legacy JSON one (``.json``, read with a warning); the defaults for None."""
    if path is None:
        return ControllerConfig()
    if Path(path).suffix.lower() != ".json":
        return load_config(path).controller
    log.warning("%s: a JSON controller configuration from before the switch to TOML, read as such; "
                "new sessions write controller.toml", path)
    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a controller configuration is a JSON object")
    return controller_config_from_dict(data)


def controller_config_to_dict(config: ControllerConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


