"""A checklist of pass/fail items, as bring-up prints it.

Each :class:`CheckItem` is one line: its :class:`Status` (PASS, WARN, FAIL, or SKIP for an item
that could not be run, with the reason), what was checked, and a detail string with the values
measured (SI units). :class:`Checklist` collects them in order, logs each as it is added, and
renders the lines, the summary ("N passed, M failed, ...") and a JSON-ready dict. A checklist
passes when no item failed: warnings and skipped items do not fail it.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)


class Status(str, enum.Enum):
    PASS = "PASS"
    WARN = "WARN"
    FAIL = "FAIL"
    SKIP = "SKIP"


@dataclass(frozen=True)
class CheckItem:
    """One checklist line.

    Attributes:
        name: what was checked, e.g. "hip: bus voltage".
        status: PASS, WARN, FAIL or SKIP.
        detail: the values measured or why it failed, and what to check.
    """

    name: str
    status: Status
    detail: str

    def line(self, name_width: int = 0) -> str:
        return f"{self.status.value}  {self.name:<{name_width}}  {self.detail}"

    def to_dict(self) -> dict[str, str]:
        return {"name": self.name, "status": self.status.value, "detail": self.detail}


class Checklist:
    """Items in the order they were checked."""

    def __init__(self) -> None:
        self.items: list[CheckItem] = []

    def add(self, name: str, status: Status, detail: str) -> CheckItem:
        item = CheckItem(name, Status(status), detail)
        self.items.append(item)
        log.info("%s %s: %s", item.status.value, name, detail)
        return item

    def count(self, status: Status) -> int:
        return sum(1 for item in self.items if item.status is status)

    def find(self, name: str) -> CheckItem | None:
        """The last item called ``name``, or None."""
        for item in reversed(self.items):
            if item.name == name:
                return item
        return None

    @property
    def passed(self) -> bool:
        """True when no item failed (and there is at least one item)."""
        return bool(self.items) and self.count(Status.FAIL) == 0

    def summary(self) -> str:
        parts = [f"{self.count(Status.PASS)} passed", f"{self.count(Status.FAIL)} failed"]
        for status, word in ((Status.WARN, "warnings"), (Status.SKIP, "skipped")):
            if self.count(status):
                parts.append(f"{self.count(status)} {word}")
        return ", ".join(parts)

    def lines(self) -> list[str]:
        width = max((len(item.name) for item in self.items), default=0)
        return [item.line(width) for item in self.items]

    def to_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "summary": self.summary(),
            "counts": {s.value: self.count(s) for s in Status},
            "items": [item.to_dict() for item in self.items],
        }
