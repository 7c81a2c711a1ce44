"""The machine: kinematic chain, strokes, screw leads and tool offset.

The chain string lists the bodies from workpiece to tool in product order (DESIGN.md,
"Conventions"): ``W`` workpiece, ``X``/``Y``/``Z`` the linear axes, ``F`` the frame (bed), ``T`` the
tool. The paper's XYTZ machine is ``"WXYFZT"``: the volumetric error is built as
T(x)·E_X(x)·T(y)·E_Y(y)·T(z)·E_Z(z)·T(tool) (paper eq. 4). The position of ``F`` records which axes
carry the workpiece; it is kept for display and reports and does not change the product.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from .userror import UserError

AXES = ("X", "Y", "Z")
AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


class MachineError(UserError, ValueError):
    """A machine definition that cannot be right; the message names the field."""


def _finite(value: float, field_name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise MachineError(f"{field_name}: expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise MachineError(f"{field_name}: expected a finite number, got {value!r}")
    return number


def parse_chain(chain: str) -> tuple[str, ...]:
    """Validate a chain string and return the axis order (e.g. ``("X", "Y", "Z")``).

    A valid chain is a permutation of ``W X Y Z F T`` that starts with ``W`` and ends with ``T``.
    """
    if not isinstance(chain, str):
        raise MachineError(f"machine.chain: expected a string such as 'WXYFZT', got {chain!r}")
    letters = chain.strip().upper()
    unknown = sorted(set(letters) - set("WXYZFT"))
    if unknown:
        raise MachineError(
            f"machine.chain {chain!r}: unknown letter(s) {', '.join(unknown)}; use W (workpiece), "
            "X, Y, Z (axes), F (frame) and T (tool), e.g. 'WXYFZT'"
        )
    if sorted(letters) != sorted("WXYZFT"):
        raise MachineError(
            f"machine.chain {chain!r}: each of W, X, Y, Z, F, T must appear exactly once"
        )
    if letters[0] != "W" or letters[-1] != "T":
        raise MachineError(
            f"machine.chain {chain!r}: the chain runs from the workpiece W to the tool T"
        )
    return tuple(c for c in letters if c in AXES)


@dataclass(frozen=True)
class Machine:
    """A 3-axis serial machine tool.

    Parameters
    ----------
    name : str
        Free text shown in reports.
    chain : str
        Kinematic chain from workpiece to tool, e.g. ``"WXYFZT"`` (the paper's machine).
    stroke_mm : mapping of axis -> (min, max)
        Travel of each axis in mm; ``min < max``; negative ranges are allowed.
    screw_lead_mm : mapping of axis -> lead
        Optional ball-screw leads in mm (used to look for cyclic error).
    tool_offset_mm : (D1, D2, D3)
        Default tool point relative to the spindle gauge point, mm (paper's D1, D2, D3).
    reference_mm : (x, y, z) or None
        Where every error function is zero; the start of each stroke by default.
    """

    name: str = "machine"
    chain: str = "WXYFZT"
    stroke_mm: Mapping[str, tuple[float, float]] = field(
        default_factory=lambda: {"X": (0.0, 400.0), "Y": (0.0, 400.0), "Z": (0.0, 350.0)}
    )
    screw_lead_mm: Mapping[str, float] = field(default_factory=dict)
    tool_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reference_mm: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        order = parse_chain(self.chain)
        object.__setattr__(self, "chain", self.chain.strip().upper())
        strokes: dict[str, tuple[float, float]] = {}
        for axis in AXES:
            if axis not in self.stroke_mm:
                raise MachineError(f"machine.stroke: axis {axis} is missing")
            pair = self.stroke_mm[axis]
            if not isinstance(pair, Sequence) or len(pair) != 2:
                raise MachineError(
                    f"machine.stroke.{axis}: expected [min, max] in mm, got {pair!r}"
                )
            low = _finite(pair[0], f"machine.stroke.{axis}[0]")
            high = _finite(pair[1], f"machine.stroke.{axis}[1]")
            if not high > low:
                raise MachineError(
                    f"machine.stroke.{axis}: max ({high:g} mm) must be greater than "
                    f"min ({low:g} mm)"
                )
            strokes[axis] = (low, high)
        extra = sorted(set(self.stroke_mm) - set(AXES))
        if extra:
            raise MachineError(f"machine.stroke: unknown axis {', '.join(extra)}; use X, Y, Z")
        object.__setattr__(self, "stroke_mm", strokes)
        leads: dict[str, float] = {}
        for axis, lead in self.screw_lead_mm.items():
            if axis not in AXES:
                raise MachineError(f"machine.screw_lead: unknown axis {axis!r}; use X, Y, Z")
            value = _finite(lead, f"machine.screw_lead.{axis}")
            if value <= 0:
                raise MachineError(f"machine.screw_lead.{axis}: must be positive, got {value:g} mm")
            leads[axis] = value
        object.__setattr__(self, "screw_lead_mm", leads)
        object.__setattr__(
            self, "tool_offset_mm", _vector3(self.tool_offset_mm, "machine.tool_offset")
        )
        if self.reference_mm is None:
            reference = tuple(strokes[a][0] for a in AXES)
        else:
            reference = _vector3(self.reference_mm, "machine.reference")
            for axis, value in zip(AXES, reference, strict=True):
                low, high = strokes[axis]
                if not low <= value <= high:
                    raise MachineError(
                        f"machine.reference.{axis} = {value:g} mm lies outside the stroke "
                        f"[{low:g}, {high:g}] mm"
                    )
        object.__setattr__(self, "reference_mm", reference)
        object.__setattr__(self, "_order", order)

    @property
    def axis_order(self) -> tuple[str, ...]:
        """The axes in chain (product) order, e.g. ``("X", "Y", "Z")`` for ``"WXYFZT"``."""
        return self._order  # type: ignore[attr-defined,no-any-return]

    @property
    def workpiece_axes(self) -> tuple[str, ...]:
        """Axes between the workpiece and the frame: they carry the workpiece."""
        return tuple(c for c in self.chain[: self.chain.index("F")] if c in AXES)

    @property
    def tool_axes(self) -> tuple[str, ...]:
        """Axes between the frame and the tool: they carry the spindle."""
        return tuple(c for c in self.chain[self.chain.index("F") :] if c in AXES)

    def stroke(self, axis: str) -> tuple[float, float]:
        return self.stroke_mm[axis]

    def reference(self, axis: str) -> float:
        assert self.reference_mm is not None
        return self.reference_mm[AXIS_INDEX[axis]]


def _vector3(values: Sequence[float], field_name: str) -> tuple[float, float, float]:
    if isinstance(values, str) or not isinstance(values, Sequence) or len(values) != 3:
        raise MachineError(f"{field_name}: expected three numbers [x, y, z] in mm, got {values!r}")
    x, y, z = (_finite(v, f"{field_name}[{i}]") for i, v in enumerate(values))
    return (x, y, z)


PAPER_MACHINE = Machine(
    name="XYTZ vertical mill (paper, Table 4)",
    chain="WXYFZT",
    stroke_mm={"X": (0.0, 400.0), "Y": (0.0, 400.0), "Z": (0.0, 350.0)},
    screw_lead_mm={"X": 16.0, "Y": 16.0, "Z": 16.0},
    tool_offset_mm=(0.0, 0.0, 200.0),
)
