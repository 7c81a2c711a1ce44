"""The plan editor's rows: a line's plan fields as the user types them (GUI-free).

A row holds text (vectors as "x, y, z"); :meth:`LineRow.to_spec` turns it into a
:class:`~volucal.core.measurement.LineSpec`, whose validation gives the messages the user reads.
:func:`guess_spec` proposes a row for a log file dropped without a plan, from the file's
extension and name (``x_straight_y.rtl``: an X line, straightness, sensitive along Y); the user
corrects it in the editor.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from volucal.core.io.units import is_angle
from volucal.core.machine import AXES, Machine
from volucal.core.measurement import QUANTITIES, LineSpec, PlanError

UNIT_VECTORS = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}
ANGULAR_EXTENSIONS = (".rta",)


def format_vector(values: tuple[float, float, float] | None) -> str:
    """"x, y, z" with every digit a float needs to come back unchanged (a diagonal's direction
    must not move by a rounding)."""
    if values is None:
        return ""
    return ", ".join(_number(v) for v in values)


def _number(value: float) -> str:
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def parse_vector(text: str, where: str) -> tuple[float, float, float]:
    parts = [p for p in re.split(r"[,;\s]+", text.strip().strip("[]()")) if p]
    if len(parts) != 3:
        raise PlanError(f"{where}: expected three numbers 'x, y, z', got {text!r}")
    try:
        x, y, z = (float(p) for p in parts)
    except ValueError:
        raise PlanError(f"{where}: {text!r} has a value that is not a number") from None
    return (x, y, z)


@dataclass
class LineRow:
    """One ``[[line]]`` of the plan being edited."""

    name: str
    file: str
    quantity: str
    start: str
    direction: str
    sensitive: str
    reflector: str
    sign: int = 1
    env_corrected: bool = True
    deviation_unit: str | None = None
    reader: Mapping[str, object] = field(default_factory=dict)

    @classmethod
    def from_spec(cls, spec: LineSpec) -> LineRow:
        return cls(
            name=spec.name,
            file=spec.file or "",
            quantity=spec.quantity,
            start=format_vector(spec.start_mm),
            direction=format_vector(spec.direction),
            sensitive=format_vector(spec.sensitive),
            reflector=format_vector(spec.reflector_mm),
            sign=spec.sign,
            env_corrected=spec.env_corrected,
            deviation_unit=spec.deviation_unit if spec.deviation_unit_stated else None,
            reader=dict(spec.reader),
        )

    def to_spec(self) -> LineSpec:
        """The LineSpec of this row; raises PlanError naming the line and the field."""
        where = f"line {self.name!r}"
        if not self.name.strip() or "/" in self.name or self.name.startswith("."):
            raise PlanError(f"{where}: a name must be non-empty, without '/', not starting "
                            "with '.'")
        if self.quantity not in QUANTITIES:
            raise PlanError(f"{where}: quantity must be one of {', '.join(QUANTITIES)}")
        # no unit chosen: the file must state its own (a .rtl is µm, a .rta µrad); a table that
        # does not is refused at import with a message that asks for one, never read as µm
        unit = self.deviation_unit
        stated = unit is not None
        if unit is None:
            unit = "urad" if self.quantity == "angular" else "um"
        elif is_angle(unit) != (self.quantity == "angular"):
            raise PlanError(
                f"{where}: the unit {unit!r} does not fit a {self.quantity} line; give "
                + ("an angle unit (urad, mrad, arcsec, deg)" if self.quantity == "angular"
                   else "a length unit (nm, um, mm, in)")
            )
        return LineSpec(
            name=self.name.strip(),
            quantity=self.quantity,
            start_mm=parse_vector(self.start, f"{where}: start"),
            direction=parse_vector(self.direction, f"{where}: direction"),
            reflector_mm=parse_vector(self.reflector, f"{where}: reflector"),
            sensitive=parse_vector(self.sensitive, f"{where}: sensitive")
            if self.sensitive.strip() else None,
            file=self.file,
            deviation_unit=unit,
            deviation_unit_stated=stated,
            sign=self.sign,
            env_corrected=self.env_corrected,
            reader=dict(self.reader),
        )


def _axes_in_name(stem: str) -> list[str]:
    """Axis letters standing alone in a file name: ``x_straight_y`` → ["X", "Y"]."""
    return [t.upper() for t in re.split(r"[^A-Za-z]+", stem) if t.upper() in AXES]


def guess_spec(path: Path, machine: Machine) -> LineSpec:
    """A first guess of a log file's plan entry (module notes); the user checks it."""
    stem = path.stem
    lowered = stem.lower()
    axes = _axes_in_name(stem) or ["X"]
    along = axes[0]
    if path.suffix.lower() in ANGULAR_EXTENSIONS or "angle" in lowered or "angular" in lowered:
        quantity = "angular"
    elif "straight" in lowered:
        quantity = "straightness"
    else:
        quantity = "linear"
    sensitive = None
    if quantity != "linear":
        others = [a for a in axes[1:] if a != along] or [a for a in AXES if a != along]
        sensitive = UNIT_VECTORS[others[0]]
    start = tuple(machine.stroke(a)[0] for a in AXES)
    return LineSpec(
        name=re.sub(r"[/\s]+", "_", stem).lstrip(".") or "line",
        quantity=quantity,
        start_mm=start,  # type: ignore[arg-type]
        direction=UNIT_VECTORS[along],
        reflector_mm=machine.tool_offset_mm,
        sensitive=sensitive,
        file=str(path.resolve()),
        deviation_unit="urad" if quantity == "angular" else "um",
        deviation_unit_stated=False,
    )


def unique_names(rows: list[LineRow]) -> None:
    """Rename repeated names in place (``name``, ``name_2``...): plan names must be unique."""
    seen: dict[str, int] = {}
    for row in rows:
        base = row.name
        count = seen.get(base, 0)
        seen[base] = count + 1
        if count:
            row.name = f"{base}_{count + 1}"
