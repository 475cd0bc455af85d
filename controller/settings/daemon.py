"""What the controller daemon runs with: the configuration file, the command line over it.

:func:`daemon_settings` is the one loader every leg verb uses (``run``, ``bringup``): the TOML
file (:func:`controller.settings.file.load_config`) and the command line's bus, weights and
save-period options in its place. :func:`bus_kwargs` is the one bus-precedence rule: command line
over the file's ``[bus]`` over python-can's own configuration. :func:`session_config` is the
configuration file a harness session writes for the daemon it starts.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.config import ControllerConfig
from controller.settings.file import (BusSettings, CalibrationSettings, DeployConfig, DriverSettings, ServiceSettings,
                                     load_config)

log = logging.getLogger(__name__)


def bus_kwargs(interface: str | None, channel: str | None, bitrate: int | None,
               file: BusSettings | None = None) -> dict[str, Any]:
    """Keyword arguments for :class:`can.Bus`, by the one precedence rule of every command that opens
    a bus: the command line (each of ``interface``, ``channel``, ``bitrate`` not None) over the
    configuration file's ``[bus]`` (``file``, its defaults included) over python-can's own
    configuration (``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE``, ``CAN_CONFIG``;
    ``~/can.conf``, ``~/.canrc``, ``./can.ini``), which python-can reads itself for what is left
    out. Without a file and without any interface, a ``vcan*``/``can*`` channel means SocketCAN."""
    given = {k: v for k, v in (("interface", interface), ("channel", channel), ("bitrate", bitrate)) if v is not None}
    if file is not None:
        return {**file.can_kwargs(), **given}
    kw = dict(given)
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
    return DaemonSettings(bus_kwargs(interface, channel, bitrate, file=config.bus), config.controller, config.weights_file if weights is None else weights,
                          config.weights.save_every_s if save_every_s is None else save_every_s, config)


def session_config(controller: ControllerConfig, channel: str, control_socket: str | Path,
                   drivers_watchdog_s: float | None = None) -> DeployConfig:
    """The configuration file of a harness session with the simulated leg: ``controller`` on
    SocketCAN ``channel`` (a vcan), its control socket at ``control_socket`` (in the session's own
    folder, so sessions never meet on one socket), and the simulated leg's calibration confirmed
    (it is exact by construction, as in ``configs/sim.toml``); ``drivers_watchdog_s``: the drivers'
    watchdog the controller writes at arming (None: the default)."""
    drivers = DriverSettings() if drivers_watchdog_s is None else DriverSettings(watchdog_timeout_s=drivers_watchdog_s)
    return DeployConfig(bus=BusSettings(interface="socketcan", channel=channel), controller=controller, drivers=drivers,
                        service=ServiceSettings(control_socket=str(control_socket)),
                        calibration=CalibrationSettings(confirmed=True, bringup="the simulated leg (firmware_sim): "
                                                        "calibration exact by construction"))
