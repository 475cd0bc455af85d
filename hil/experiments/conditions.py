"""The experimental conditions of a learning run, declared once: the command line, the experiment TOML, the records.

:class:`Conditions` declares each condition with :func:`controller.settings.schema.setting` (kind,
unit, default, range, one line); from that single declaration come ``learn``'s and ``sweep``'s
options (:func:`add_arguments`), the experiment file's schema (:func:`read_experiment`,
``--experiment FILE``), the checks (:func:`~controller.settings.schema.check_settings`) and the
learn configuration's fields (:meth:`Conditions.learn_fields`). docs/runs.md lists them;
docs/experiment.example.toml is an example file.

Precedence: a condition given on the command line wins over the experiment file, which wins over
the default. A bad file is refused with one line naming the file and the key (an
:class:`~controller.errors.InputError`, exit 3); a bad option value is argparse's (exit 2).

``obstacle_heights_m``: for ``learn``, one height is every trial's; several are drawn per trial
(seeded, :attr:`hil.experiments.learn.LearnConfig.obstacle_heights_m`). For ``sweep`` the list is
the grid (one scenario per height), unless ``--mixed-heights`` makes it one drawn-per-trial
scenario: the same file means "these heights" to both, and the sweep says how to arrange them.

Where a run keeps its conditions (the choice, and why): the run-wide ones (rail speeds, start
range, sensor noise and dropout, obstacle depth, the height list) live once in the run's header,
the learn configuration that ``trials.jsonl``'s first line and ``metrics.json``'s ``config`` hold;
what is drawn per trial (``obstacle_height_m``, ``start_distance_m``) is in each trial's record.
A value constant over a run written 150 times could only ever disagree with itself, and a default
run's trial records stay byte for byte those of before these options (``compare`` exit 0 against
older runs); every record is read with its header (``metrics.json`` holds both).
"""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from controller.errors import InputError
from controller.settings.schema import Setting, check_settings, setting, settings_of


def _ordered(start: tuple[float, ...]) -> str | None:
    return None if start[0] <= start[1] else f"MIN must not exceed MAX ({start[0]:g} > {start[1]:g})"


SENSOR_FLOOR_M = 0.03
"""The range sensor's origin above the ground: an obstacle must be taller to be seen at all."""


@dataclass(frozen=True)
class Conditions:
    """The conditions of a learning run (every one also an option of ``learn`` and ``sweep`` and a
    key of the experiment TOML). The defaults are the paper's set-up: a run with them is the run
    of before these options, record for record."""

    rail_speed_m_s: float = setting(0.5, "m/s", 0.1, 3.0, "the plant's rail (carriage) speed")
    believed_rail_speed_m_s: float = setting(
        0.0, "m/s", 0.0, 3.0, "rail speed the controller is told (its gait's ground speed); 0: the plant's")
    start_m: tuple[float, ...] = setting(
        (2.2, 2.9), "m", 0.5, 3.2, "MIN,MAX: a trial's obstacle near edge ahead of the hip, uniform",
        items=(2, 2), check=_ordered)
    range_noise_m: float = setting(
        0.02, "m", 0.0, 0.5, "the range sensor's true noise, 1 sigma (the controller's filter keeps its own)")
    range_dropout: float = setting(0.05, "(probability)", 0.0, 0.95, "probability that a range sample is a dropout")
    obstacle_depth_m: float = setting(0.10, "m", 0.01, 0.30, "obstacle extent along the rail")
    obstacle_heights_m: tuple[float, ...] = setting(
        (0.08,), "m", SENSOR_FLOOR_M, 0.50,
        "obstacle heights (each also within the leg's limit): learn draws one per trial if several",
        items=(1, 100), exclude=((SENSOR_FLOOR_M, "the range sensor sees only what is taller than 3 cm"),))

    def __post_init__(self) -> None:
        for name in ("start_m", "obstacle_heights_m"):  # a list from TOML or a caller: stored as a tuple
            object.__setattr__(self, name, tuple(getattr(self, name)))
        check_settings(self)

    def learn_fields(self) -> dict[str, Any]:
        """The :class:`hil.experiments.learn.LearnConfig` fields these conditions set. One height is
        ``obstacle_height_m`` with no list (the configuration of before mixed heights: no draw)."""
        heights = self.obstacle_heights_m
        return {
            "obstacle_height_m": heights[0],
            "obstacle_heights_m": heights if len(heights) > 1 else (),
            "obstacle_depth_m": self.obstacle_depth_m,
            "range_noise_m": self.range_noise_m,
            "range_dropout_prob": self.range_dropout,
            "start_min_m": self.start_m[0],
            "start_max_m": self.start_m[1],
            "rail_speed_m_s": self.rail_speed_m_s,
            "believed_rail_speed_m_s": self.believed_rail_speed_m_s or None,  # 0 (or None): the plant's
        }

    def to_json(self) -> dict[str, Any]:
        """Every condition, as JSON writes it (lists for tuples)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def of_learn(cls, config: Any) -> Conditions:
        """The conditions of a learn configuration (the inverse of :meth:`learn_fields`); raises
        ValueError naming the condition a value breaks."""
        heights = tuple(config.obstacle_heights_m) or (config.obstacle_height_m,)
        believed = config.believed_rail_speed_m_s
        return cls(rail_speed_m_s=config.rail_speed_m_s,
                   believed_rail_speed_m_s=0.0 if believed is None or believed == config.rail_speed_m_s else believed,
                   start_m=(config.start_min_m, config.start_max_m), range_noise_m=config.range_noise_m,
                   range_dropout=config.range_dropout_prob, obstacle_depth_m=config.obstacle_depth_m,
                   obstacle_heights_m=heights)


SETTINGS: dict[str, Setting] = {s.key: s for s in settings_of(Conditions)}
"""The conditions' declarations by key (the TOML keys; the options are ``--`` + key with dashes)."""


def option(key: str) -> str:
    return "--" + key.replace("_", "-")


def changed_options(conditions: Mapping[str, Any], skip: tuple[str, ...] = ("obstacle_heights_m",)) -> list[str]:
    """The command-line words that set ``conditions`` (a :meth:`Conditions.to_json`, e.g. a
    sweep's ``config.json``) where they differ from the declared defaults, in declaration order:
    what a report's "reproduce" line needs beyond the grid (``skip``: the heights, which the sweep
    states itself)."""
    default = Conditions().to_json()
    words: list[str] = []
    for key in SETTINGS:
        if key in skip or key not in conditions:
            continue
        value = conditions[key]
        if value != default[key]:
            words += [option(key), _shown(tuple(value) if isinstance(value, list) else value)]
    return words


def parse_text(s: Setting, text: str) -> Any:
    """A condition's value from a command-line word (numbers; an array as a comma list); raises
    ValueError with the problem."""
    try:
        value: Any = [float(p) for p in text.split(",")] if s.kind == "floats" else float(text)
    except ValueError:
        raise ValueError(f"{s.key}: {text!r} is not {'a comma list of numbers' if s.kind == 'floats' else 'a number'}"
                         ) from None
    parsed, problem = s.parse(value)
    if problem:
        raise ValueError(f"{s.key}: {text!r}: {problem}")
    return parsed


def _argparse_type(s: Setting):
    def parse(text: str) -> Any:
        try:
            return parse_text(s, text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = s.key  # argparse names the option, not this function
    return parse


def _shown(value: Any) -> str:
    return ",".join(f"{v:g}" for v in value) if isinstance(value, tuple) else f"{value:g}"


def add_arguments(p: argparse.ArgumentParser, skip: tuple[str, ...] = (), helps: Mapping[str, str] | None = None) -> None:
    """``--experiment FILE`` and one option per condition (except ``skip``), each defaulting to
    None (not given: the file's value, else the declared default); ``helps`` replaces a help text."""
    p.add_argument("--experiment", metavar="FILE", default=None,
                   help="a TOML file of these conditions (docs/experiment.example.toml); options given here win")
    defaults = Conditions()
    for key, s in SETTINGS.items():
        if key in skip:
            continue
        text = (helps or {}).get(key) or f"{s.doc}: {s.allowed()} (default {_shown(getattr(defaults, key))})"
        metavar = "MIN,MAX" if key == "start_m" else ("LIST" if s.kind == "floats" else None)
        p.add_argument(option(key), dest=key, type=_argparse_type(s), default=None, metavar=metavar,
                       help=text.replace("%", "%%"))


def read_experiment(path: str | Path) -> dict[str, Any]:
    """The conditions an experiment TOML sets (only those it names), each parsed by its declaration.

    Raises:
        InputError: one line naming the file and, where one is at fault, the key: no such file,
            not TOML, an unknown key (a typo would otherwise run the defaults silently), a
            value of the wrong kind or out of range.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"--experiment {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"--experiment {path}: a folder, not a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"--experiment {path}: not TOML ({exc})") from None
    except RecursionError:
        raise InputError(f"--experiment {path}: nested too deep to be an experiment file") from None
    out: dict[str, Any] = {}
    for key, value in data.items():
        s = SETTINGS.get(key)
        if s is None:
            raise InputError(f"--experiment {path}: unknown key {key!r}; the conditions are {', '.join(SETTINGS)}")
        parsed, problem = s.parse(value)
        if problem:
            raise InputError(f"--experiment {path}: {key} {problem}")
        out[key] = parsed
    return out


def conditions_from(args: argparse.Namespace) -> Conditions:
    """The run's conditions: the declared defaults, then ``--experiment``'s file, then the options given.

    Raises:
        InputError: the file (:func:`read_experiment`), or a combination no single value breaks
            (e.g. a file's start range and ``--start-m``), naming where the values came from.
    """
    file = getattr(args, "experiment", None)
    values = read_experiment(file) if file is not None else {}
    given = {k: getattr(args, k) for k in SETTINGS if getattr(args, k, None) is not None}
    try:
        return Conditions(**{**values, **given})
    except ValueError as exc:
        where = f"--experiment {file} and the options" if file is not None else "the options"
        raise InputError(f"{where}: {exc}") from None


__all__ = ["Conditions", "SETTINGS", "add_arguments", "conditions_from", "option", "parse_text", "read_experiment"]


def check_leg_limit(heights: tuple[float, ...], depth_m: float, controller: Any, what: str) -> None:
    """Refuse (ValueError ``what: reason``) a height above what the leg can clear at all: the
    limit of its joints, torques and longest swing for the obstacle's ``depth_m`` and the rail
    speed the ``controller`` configuration is told (:func:`controller.motion.reach.check_height`,
    docs/leg_limits.md), not of any reflex or learner; such an experiment would only count
    mistakes. ``learn`` (:class:`hil.experiments.learn.LearnConfig`) and ``sweep``
    (:class:`hil.experiments.sweep.SweepConfig`) both call it; the tallest height decides."""
    from controller.motion.reach import check_height

    try:
        check_height(max(heights), depth_m, geometry=controller.geometry, axes=controller.axes, cpg=controller.cpg,
                     gait=controller.gait)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None
