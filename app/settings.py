"""The workbench's settings: preferences, recent projects and the last folder used.

Stored with QSettings in an INI file of the user scope (``volucal/volucal.ini`` in the user's
configuration folder), so that tests can point the user scope at a temporary folder.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from PySide6.QtCore import QSettings
from volucal.core.display_units import DisplayUnits
from volucal.core.identify import IdentifyOptions
from volucal.core.residuals import LoopOptions
from volucal.core.userror import UserError

ORGANIZATION = "volucal"
APPLICATION = "volucal"
RECENT_KEY = "recent/projects"
FOLDER_KEY = "recent/folder"


def store() -> QSettings:
    return QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANIZATION,
                     APPLICATION)


@dataclass(frozen=True)
class Preferences:
    """What the user may set once instead of every time (Edit ▸ Preferences)."""

    identify_spacing_mm: float = IdentifyOptions().spacing_mm
    loop_margin: float = LoopOptions().margin
    loop_max_steps: int = LoopOptions().max_steps
    drop_outliers: bool = False
    sensitivity_n: int = 1400
    map_step_mm: float = 50.0
    export_spacing_mm: float = 10.0
    max_recent: int = 8

    @classmethod
    def load(cls) -> Preferences:
        settings = store()
        defaults = cls()
        values: dict[str, Any] = {}
        for item in fields(cls):
            default = getattr(defaults, item.name)
            raw = settings.value(f"preferences/{item.name}", default)
            values[item.name] = _typed(raw, default)
        return cls(**values)

    def save(self) -> None:
        settings = store()
        for key, value in asdict(self).items():
            settings.setValue(f"preferences/{key}", value)
        settings.sync()


def _typed(raw: object, default: object) -> object:
    """A stored value as the type of its default (INI files give strings back)."""
    try:
        if isinstance(default, bool):
            return raw if isinstance(raw, bool) else str(raw).lower() in ("true", "1", "yes")
        if isinstance(default, int):
            return int(float(str(raw)))
        if isinstance(default, float):
            value = float(str(raw))
            return value if math.isfinite(value) else default
    except ValueError:
        return default
    return raw


def recent_projects() -> list[Path]:
    raw = store().value(RECENT_KEY, [])
    # an INI file gives one entry back as a string, several as a list
    items = [raw] if isinstance(raw, str) else list(raw) if isinstance(raw, list | tuple) else []
    return [Path(p) for p in items if p]


def remember_project(path: Path, limit: int | None = None) -> list[Path]:
    """Put ``path`` first in the recent projects; returns the new list."""
    limit = limit or Preferences.load().max_recent
    resolved = Path(path).resolve()
    items = [resolved] + [p for p in recent_projects() if p != resolved]
    items = items[:limit]
    settings = store()
    settings.setValue(RECENT_KEY, [str(p) for p in items])
    settings.sync()
    return items


def forget_project(path: Path) -> None:
    items = [p for p in recent_projects() if p != Path(path)]
    settings = store()
    settings.setValue(RECENT_KEY, [str(p) for p in items])
    settings.sync()


def last_folder() -> str:
    return str(store().value(FOLDER_KEY, str(Path.home())))


def set_last_folder(path: Path) -> None:
    folder = path if path.is_dir() else path.parent
    settings = store()
    settings.setValue(FOLDER_KEY, str(folder))
    settings.sync()


UNITS_KEY = "units/"


def display_units() -> DisplayUnits:
    """The units the views show (View ▸ Units); µm and µrad unless the user chose others."""
    settings = store()
    length = str(settings.value(UNITS_KEY + "length", "um"))
    angle = str(settings.value(UNITS_KEY + "angle", "urad"))
    try:
        return DisplayUnits(length, angle)
    except UserError:  # a settings file edited by hand
        return DisplayUnits()


def set_display_units(units: DisplayUnits) -> None:
    settings = store()
    settings.setValue(UNITS_KEY + "length", units.length)
    settings.setValue(UNITS_KEY + "angle", units.angle)
    settings.sync()
