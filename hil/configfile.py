"""Configuration files and bus settings for the two HIL processes.

``controller_config_from_dict`` builds a :class:`controller.config.ControllerConfig` from a
nested dict (JSON): every key overrides the default of the field of that name, nested sections
(``cpg``, ``learner``, ...) field by field, ``axes`` as a list of complete axis dicts. Unknown
keys are an error. ``bus_kwargs`` passes only the bus settings given on the command line, so
python-can fills in the rest from its own configuration (``CAN_INTERFACE``, ``CAN_CHANNEL``,
``CAN_BITRATE``, ``CAN_CONFIG`` environment variables; ``~/can.conf``, ``~/.canrc``,
``./can.ini``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from controller.config import AxisConfig, ControllerConfig


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
    if path is None:
        return ControllerConfig()
    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a controller configuration is a JSON object")
    return controller_config_from_dict(data)


def controller_config_to_dict(config: ControllerConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


def bus_kwargs(interface: str | None, channel: str | None, bitrate: int | None) -> dict[str, Any]:
    kw: dict[str, Any] = {}
    if interface is not None:
        kw["interface"] = interface
    if channel is not None:
        kw["channel"] = channel
    if bitrate is not None:
        kw["bitrate"] = bitrate
    if "channel" in kw and "interface" not in kw and str(kw["channel"]).startswith(("vcan", "can")):
        from can.util import load_config

        try:
            found = load_config()
        except Exception:  # noqa: BLE001 - no python-can configuration at all
            found = {}
        if not found.get("interface"):
            kw["interface"] = "socketcan"
    return kw
