"""Configuration files and bus settings for the HIL processes and the controller daemon.

The configuration is one TOML file (:mod:`controller.settings.file`): ``controller --config FILE``
reads it (:func:`daemon_settings`), ``config check FILE`` and ``config show [FILE]`` check and
print it (:func:`main_config_check`, :func:`main_config_show`), ``hil`` and ``bench --hil`` write
``controller.toml`` for their sessions and ``replay`` reads it beside a log
(:func:`load_controller_config`).

Bus settings: ``controller --config FILE`` takes ``[bus]`` from the file, each of
``--interface/--channel/--bitrate`` given on the command line in its place. Without a file,
:func:`bus_kwargs` passes only the bus settings given on the command line, so python-can fills
in the rest from its own configuration (``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE``,
``CAN_CONFIG`` environment variables; ``~/can.conf``, ``~/.canrc``, ``./can.ini``).

Legacy JSON (sessions recorded before the switch to TOML): ``controller_config_from_dict``
builds a :class:`controller.config.ControllerConfig` from a nested dict: every key overrides the
default of the field of that name, nested sections (``cpg``, ``learner``, ...) field by field,
``axes`` as a list of complete axis dicts; unknown keys are an error. Only ``replay`` still reads
a ``controller.json`` (with a warning); the daemon reads TOML only.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.config import AxisConfig, ControllerConfig
from controller.settings.file import BusSettings, ConfigError, DeployConfig, load_config, summary, to_toml

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


@dataclass(frozen=True)
class DaemonSettings:
    """What the controller daemon runs with, the command line over the configuration file.

    Attributes:
        bus_kw: keyword arguments for :class:`can.Bus`.
        controller: the controller configuration.
        weights: the weights file, or None (not persisted).
        save_every_s: seconds of walking between weight saves [s].
        config: the configuration file's settings (None without a file).
    """

    bus_kw: dict[str, Any]
    controller: ControllerConfig
    weights: str | None
    save_every_s: float
    config: DeployConfig | None = None


def daemon_settings(config_path: str | Path | None, interface: str | None = None, channel: str | None = None,
                    bitrate: int | None = None, weights: str | None = None,
                    save_every_s: float | None = None) -> DaemonSettings:
    """The daemon's settings: with ``config_path`` (TOML, :func:`load_config`), its ``[bus]``,
    ``[weights]`` and controller, each bus setting, ``weights`` and ``save_every_s`` given (not
    None) in its place; without, the defaults and :func:`bus_kwargs` (python-can's own
    configuration for what the command line leaves out), no weights file, saves every 10 s."""
    from controller.daemon.autosave import AutosaveConfig

    if config_path is None:
        return DaemonSettings(bus_kwargs(interface, channel, bitrate), ControllerConfig(), weights,
                              AutosaveConfig.every_s if save_every_s is None else save_every_s)
    config = load_config(config_path)
    bus_kw = config.bus.can_kwargs()
    for key, value in (("interface", interface), ("channel", channel), ("bitrate", bitrate)):
        if value is not None:
            bus_kw[key] = value
    return DaemonSettings(bus_kw, config.controller, config.weights_file if weights is None else weights,
                          config.weights.save_every_s if save_every_s is None else save_every_s, config)


def session_config(controller: ControllerConfig, channel: str) -> DeployConfig:
    """The configuration file of a HIL session: ``controller`` on SocketCAN ``channel``."""
    return DeployConfig(bus=BusSettings(interface="socketcan", channel=channel), controller=controller)


def main_config_check(args) -> int:
    """``config check FILE``: exit 0 with a one-line summary, or 2 with every problem on its own line."""
    try:
        config = load_config(args.file)
    except ConfigError as exc:
        for line in exc.lines():
            print(line, file=sys.stderr)
        n = len(exc.problems)
        print(f"elegant-stepping config check: {args.file}: {n} problem{'s' if n != 1 else ''}", file=sys.stderr)
        return 2
    print(f"{args.file}: OK: {summary(config)}")
    return 0


def main_config_show(args) -> int:
    """``config show [FILE]``: the effective configuration (the file's, defaults for the rest) as TOML."""
    if args.file is None:
        config, where = DeployConfig(), "the defaults"
    else:
        try:
            config = load_config(args.file)
        except ConfigError as exc:
            for line in exc.lines():
                print(line, file=sys.stderr)
            return 2
        where = f"{args.file} with the defaults for what it leaves out"
    sys.stdout.write(to_toml(config, header=f"elegant-stepping configuration: {where}\n"
                                            "(each comment: what the key is, and what is allowed)"))
    return 0
