"""Configuration fields that declare their own unit, range and meaning, once.

A configuration dataclass declares each setting with :func:`setting`::

    stance_s: float = setting(0.40, "s", 0.05, 5.0, "extension (stance) half of the ring")

(default, unit, lowest, highest, one line of documentation; the kind, a float here, is the field's
annotation). Everything else is derived from that declaration: the dataclass's ``__post_init__``
calls :func:`check_settings`, which refuses a value out of range when the object is created, and
the TOML schema (:mod:`controller.settings.file`) takes its keys, kinds, units, ranges and
comments from :func:`settings_of`. Checks that read more than one field stay in code, beside them.

This module imports nothing from the controller, so any module may declare its configuration here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any, Callable

REQUIRED: Any = dataclasses.MISSING
"""The default of a field that has none (given on every creation): ``setting(REQUIRED, ...)``."""

_KINDS = {"float": "float", "int": "int", "bool": "bool", "str": "str", "tuple[float, ...]": "floats", "tuple": "floats"}
"""A field's annotation -> its :attr:`Setting.kind`. ``"tuple"``: how a ``tuple[float, ...]`` field
reads in a module compiled with mypyc (:mod:`protocol.compiled`), which keeps only the bare type;
the one tuple setting (``HeightEstimatorConfig.beam_heights_m``) is of floats; a tuple of anything
else would need its own entry here."""


# ----------------------------------------------------------------------------- values in messages
def _num(x: float) -> str:
    """A bound or a computed figure, for a message: 1000 not 1000.0, 6.28319 not 6.283185307."""
    if isinstance(x, int) and not isinstance(x, bool):
        return str(x)
    if math.isfinite(x) and x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return f"{x:.6g}"


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string (quotation mark, backslash and control characters escaped)."""
    out = ['"']
    for ch in text:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch in "\b\t\n\f\r":
            out.append({"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_value(value: Any) -> str:
    """A value of a setting (bool, int, float, str, or a tuple/list of numbers) as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # the shortest text that reads back to the same float; valid TOML
    if isinstance(value, str):
        return toml_string(value)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


SHOW_MAX_CHARS = 80
"""The longest value a message quotes; a longer one is cut, with ``...`` (a message stays one line a
person reads, whatever the file holds)."""


def _show(value: Any) -> str:
    """The value found, for a message: as it would be written in TOML, at most
    :data:`SHOW_MAX_CHARS` characters."""
    if isinstance(value, dict):
        return "a table"
    try:
        text = toml_value(value)
    except TypeError:
        text = repr(value)
    return text if len(text) <= SHOW_MAX_CHARS else text[: SHOW_MAX_CHARS - 3] + "..."


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "true/false"
    return {int: "an integer", float: "a float", str: "a string", list: "an array", dict: "a table"}.get(
        type(value), type(value).__name__)


# ----------------------------------------------------------------------------- one setting
@dataclass(frozen=True)
class Setting:
    """One setting: a field of a configuration dataclass, a key of its TOML section.

    Attributes:
        key: the field's name (filled in by :func:`settings_of`).
        kind: ``"float"`` (an integer is taken too), ``"int"``, ``"bool"``, ``"str"``, or
            ``"floats"`` (an array of numbers); from the field's annotation.
        unit: the unit, as printed after the range (a physical unit, or words in parentheses).
        lo, hi: the allowed range (inclusive), for numbers and each number of an array.
        doc: one line: what it is.
        choices: the only values allowed, if not empty.
        exclude: (value, reason) pairs refused even inside the range.
        items: (fewest, most) numbers in an array.
        check: a further check of the value, returning a problem (without the field) or None.
    """

    key: str = ""
    kind: str = ""
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    doc: str = ""
    choices: tuple = ()
    exclude: tuple[tuple[Any, str], ...] = ()
    items: tuple[int, int] = (1, 1)
    check: Callable[[Any], str | None] | None = None

    def _unit(self) -> str:
        return f" {self.unit}" if self.unit else ""

    def _range(self) -> str:
        return f"[{_num(self.lo)}, {_num(self.hi)}]{self._unit()}"

    def _choices(self) -> str:
        shown = [_show(c) for c in self.choices]
        if len(shown) <= 2:
            return " or ".join(shown) + self._unit()
        return "one of " + ", ".join(shown[:-1]) + " or " + shown[-1] + self._unit()

    def allowed(self) -> str:
        """What is allowed, with the unit: ``[0.1, 1000] rev/rev``, ``1 or -1 (sign ...)``."""
        if self.kind == "bool":
            return "true or false"
        if self.choices:
            return self._choices()
        if self.lo is not None and self.hi is not None:
            text = ("each in " if self.kind == "floats" else "") + self._range()
            return text + "".join(f", not {_num(bad)}" for bad, _ in self.exclude)
        return self.unit or "any"

    def parse(self, value: Any) -> tuple[Any, str | None]:
        """A value read from TOML: (the value converted, None) or (None, the problem without the
        field's name)."""
        kind = self.kind
        if kind == "bool":
            if not isinstance(value, bool):
                return None, f"must be true or false ({self.doc}), not {_type_name(value)}"
            return value, None
        if kind == "str":
            if not isinstance(value, str):
                return None, f"must be a string ({self.doc}), not {_type_name(value)}"
            if self.choices and value not in self.choices:
                return None, f"must be {self._choices()}"
            if self.check is not None:
                problem = self.check(value)
                if problem:
                    return None, problem
            return value, None
        if kind == "floats":
            fewest, most = self.items
            if not isinstance(value, list):
                return None, f"must be an array of {fewest} to {most} numbers, each in {self._range()}, " \
                             f"not {_type_name(value)}"
            if not fewest <= len(value) <= most:
                return None, f"must list {fewest} to {most} numbers, each in {self._range()}; it lists {len(value)}"
            out = []
            for i, v in enumerate(value):
                number, problem = self._number(v, float)
                if problem:
                    return None, f"item {i} ({_show(v)}) {problem}"
                out.append(number)
            if self.check is not None:
                problem = self.check(tuple(out))
                if problem:
                    return None, problem
            return tuple(out), None
        return self._number(value, int if kind == "int" else float)

    def _number(self, value: Any, kind: type) -> tuple[Any, str | None]:
        ranged = self.lo is not None and self.hi is not None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and isinstance(value, float)):
            what = "an integer" if kind is int else "a number"
            if ranged:
                expect = f" in {self._range()}"
            else:
                expect = ", " + self._choices() + ("" if self.unit else f" ({self.doc})")
            return None, f"must be {what}{expect}, not {_type_name(value)}"
        number = kind(value)
        if ranged and not (math.isfinite(number) and self.lo <= number <= self.hi):
            return None, f"must be in {self._range()}"
        if self.choices and number not in self.choices:
            return None, f"must be {self._choices()}" + ("" if self.unit else f" ({self.doc})")
        for bad, reason in self.exclude:
            if number == bad:
                return None, f"must be in {self._range()} and not {_num(bad)}: {reason}"
        return number, None

    def refuse(self, value: Any) -> str | None:
        """What is wrong with ``value`` as the field's value in its dataclass (None: nothing), the
        check ``__post_init__`` makes: :meth:`parse`'s, worded ``must be in [lo, hi] unit, got x``
        for a number out of range, ``x: reason`` for an excluded value."""
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if self.kind in ("float", "int") and number and self.lo is not None and self.hi is not None \
                and not (math.isfinite(value) and self.lo <= value <= self.hi):
            return f"must be in [{self.lo}, {self.hi}]{self._unit()}, got {value!r}"
        for bad, reason in self.exclude:
            if number and value == bad:
                return f"{value!r}: {reason}"
        _, problem = self.parse(list(value) if self.kind == "floats" and isinstance(value, tuple) else value)
        return None if problem is None else f"{problem}, got {value!r}"


# ----------------------------------------------------------------------------- declaring, deriving
def setting(default: Any = REQUIRED, unit: str = "", lo: float | None = None, hi: float | None = None,
            doc: str = "", **kw: Any) -> Any:
    """A dataclass field that is a setting: its default, unit, range ``[lo, hi]`` and one line of
    documentation; ``kw``: ``choices``, ``exclude``, ``items``, ``check`` (see :class:`Setting`)."""
    return dataclasses.field(default=default, metadata={"setting": Setting(unit=unit, lo=lo, hi=hi, doc=doc, **kw)})


@functools.cache
def settings_of(cls: type) -> tuple[Setting, ...]:
    """The settings a configuration dataclass declares, in field order (fields declared without
    :func:`setting` are not settings)."""
    out = []
    for f in dataclasses.fields(cls):
        declared = f.metadata.get("setting")
        if declared is not None:
            annotation = f.type if isinstance(f.type, str) else f.type.__name__
            out.append(dataclasses.replace(declared, key=f.name, kind=_KINDS[annotation]))
    return tuple(out)


def check_settings(obj: Any, section: str = "") -> None:
    """Refuse, with a ValueError naming ``section.key``, the first field of ``obj`` (a
    configuration dataclass) whose value its setting does not allow. For ``__post_init__``."""
    prefix = f"{section}." if section else ""
    for s in settings_of(type(obj)):
        problem = s.refuse(getattr(obj, s.key))
        if problem:
            raise ValueError(f"{prefix}{s.key} {problem}")


__all__ = ["REQUIRED", "Setting", "setting", "settings_of", "check_settings", "toml_string", "toml_value"]
