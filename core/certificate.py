"""The certificate fields of a calibration report: who it is for, which machine, who measured.

A calibration certificate names the customer, the machine (and its serial number), its own
number, the operator, the dates of measurement and of issue and the place, and ends with a
signature block. Where the measurement already says it, the fields start from the logs' own text
(Renishaw's USER-TEXT: Machine, Serial No, By, Date, Location) and the project's machine; the
user completes or corrects them (the workbench's report dialog, or ``volucal report``'s options)
and the project keeps them under ``/report/certificate`` (``certificate_json``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from typing import Any

from .userror import UserError

#: (key, label) of every field, in the order the report lists them.
FIELDS: tuple[tuple[str, str], ...] = (
    ("customer", "Customer"),
    ("machine", "Machine"),
    ("serial", "Machine serial number"),
    ("certificate_number", "Certificate number"),
    ("operator", "Calibrated by"),
    ("measured", "Date of measurement"),
    ("issued", "Date of issue"),
    ("place", "Place of calibration"),
    ("approver", "Approved by"),
)
KEYS = tuple(key for key, _ in FIELDS)
LABELS = dict(FIELDS)


@dataclass(frozen=True)
class Certificate:
    """The certificate fields (``values[key]``, text; a missing key is an empty field)."""

    values: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = sorted(set(self.values) - set(KEYS))
        if unknown:
            raise UserError(
                f"certificate field(s) {', '.join(unknown)}: the fields are {', '.join(KEYS)}"
            )

    def get(self, key: str) -> str:
        return str(self.values.get(key, "") or "").strip()

    def with_values(self, **changes: str | None) -> Certificate:
        """A copy with the given fields replaced (None leaves a field as it is)."""
        values = dict(self.values)
        values.update({k: str(v) for k, v in changes.items() if v is not None})
        return replace(self, values=values)

    def rows(self) -> list[tuple[str, str]]:
        """(label, value) of every field, "—" for an empty one."""
        return [(label, self.get(key) or "—") for key, label in FIELDS]

    def to_json(self) -> dict[str, str]:
        return {key: self.get(key) for key in KEYS if self.get(key)}

    def to_tree(self) -> dict[str, Any]:
        return {"certificate_json": json.dumps(self.to_json())}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Certificate:
        return cls({str(k): str(v) for k, v in dict(data).items() if k in KEYS})

    @classmethod
    def from_logs(cls, project: Any) -> Certificate:
        """What the project's machine and logs say (the first non-empty value of each)."""

        def first(key: str) -> str:
            for stored in project.lines.values():
                value = str(stored.corrected.metadata.get(key, "") or "").strip()
                if value:
                    return value
            return ""

        starts = [s.corrected.start_time for s in project.lines.values() if s.corrected.start_time]
        measured = (
            datetime.fromtimestamp(min(starts), UTC).strftime("%Y-%m-%d")
            if starts
            else first("date")
        )
        machine = first("machine") or (project.machine.name if project.machine else "")
        return cls(
            {
                "machine": machine,
                "serial": first("serial"),
                "operator": first("operator"),
                "measured": measured,
                "place": first("location"),
            }
        )

    @classmethod
    def of_project(cls, project: Any) -> Certificate:
        """The stored fields over what the logs say (a stored empty field stays empty only
        when it was never stored)."""
        defaults = cls.from_logs(project)
        if "certificate" not in project.results("report"):
            return defaults
        tree = project.result("report", "certificate")
        stored = cls.from_json(json.loads(str(tree.get("certificate_json", "{}"))))
        return defaults.with_values(**stored.to_json())
