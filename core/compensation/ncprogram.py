"""Volumetric compensation by rewriting an NC program (works on any controller).

An RS274/NGC subset is read; every target point is replaced by the command that lands the tool on
it (the exact inverse of the error source, :mod:`.inverse`), straight feed moves are split where
the correction changes along them, and arcs are turned into chords within a stated tolerance, so
the correction is followed between the program's points. The direction each axis moves is known
from the program, so reversal is compensated too.

Supported: G0, G1, G2, G3 (centre by I/J/K or radius R, helical), G17/G18/G19, G20/G21, G90/G91
(the output is absolute), G90.1/G91.1, G92/G92.1, G54–G59 (their offsets given in the options;
zero otherwise), line numbers, F/S/T/M words, G4 dwell and the modal codes that do not move the
axes (G40, G49, G61, G61.1, G64, G80, G94, G97), comments ``( )`` and ``;``, ``%`` lines, block
delete ``/``. Anything else that can move the axes or change coordinates (G28, G30, G53, G10,
G38.x, G43, G41/G42, canned cycles, parameters ``#``, expressions ``[ ]``, O-words) is refused
with the line and the reason, or — when asked — copied unchanged and flagged.

Coordinates: machine position = program position + work offset (G54–G59) + G92 offset. The
correction is computed at the machine position; the emitted program coordinates are the
compensated machine position minus the offsets *as the controller holds them*: a G92 executed on
the controller takes its offset from the compensated (actual command) position, and the rewriter
tracks that so every later point stays right.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..machine import AXES
from ..userror import FormatError
from .inverse import invert
from .source import ErrorSource, measured_range

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3
MM_PER_INCH = 25.4

WORK_OFFSETS = ("G54", "G55", "G56", "G57", "G58", "G59")
#: Modal codes that do not move the axes or change coordinates: copied as they are.
PASSIVE_G = {"G4", "G40", "G49", "G61", "G61.1", "G64", "G80", "G94", "G97"}
#: The codes the rewriter interprets itself.
KNOWN_G = {
    "G0",
    "G1",
    "G2",
    "G3",
    "G17",
    "G18",
    "G19",
    "G20",
    "G21",
    "G90",
    "G91",
    "G90.1",
    "G91.1",
    "G92",
    "G92.1",
    *WORK_OFFSETS,
}
#: M codes that NGC executes after the motion of their line (program stops and ends).
M_AFTER_MOTION = {"M0", "M1", "M2", "M30", "M60"}
REFUSED_REASON = {
    "G28": "it moves to a stored position the rewriter cannot know",
    "G30": "it moves to a stored position the rewriter cannot know",
    "G53": "it moves in machine coordinates outside the work offsets",
    "G10": "it changes stored offsets",
    "G43": "tool length compensation changes the tool point the correction is computed for; "
    "set the tool offset of the compensation instead",
    "G41": "cutter radius compensation offsets the path after the rewriter",
    "G42": "cutter radius compensation offsets the path after the rewriter",
    "G93": "inverse-time feed would change when moves are split",
}

_WORD = re.compile(r"([A-Z])([+-]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True)
class RewriteOptions:
    """How to rewrite.

    tool_offset_mm : tool point the correction is for; the machine's by default.
    correction_tolerance_um : a feed move is split until the straight command path between
        split points stays within this of the exact compensated command.
    arc_tolerance_mm : largest chord-to-arc distance when arcs are linearised.
    probe_step_mm : spacing at which the correction is sampled along feed moves.
    max_segment_mm : optional upper bound on the length of an emitted feed segment.
    work_offsets_mm : G54–G59 offsets (program units are not applied: mm), by code.
    unknown : "refuse" (default) or "pass" (copy unsupported lines unchanged and flag them).
    decimals_mm, decimals_inch : digits written after the decimal point.
    """

    tool_offset_mm: tuple[float, float, float] | None = None
    correction_tolerance_um: float = 0.1
    arc_tolerance_mm: float = 0.001
    probe_step_mm: float = 1.0
    max_segment_mm: float | None = None
    work_offsets_mm: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    unknown: str = "refuse"
    decimals_mm: int = 4
    decimals_inch: int = 6


@dataclass(frozen=True)
class RewriteResult:
    """The rewritten program and what happened to it."""

    text: str
    lines_in: int
    moves_in: int
    points_out: int
    max_correction_um: float
    tool_offset_mm: tuple[float, float, float]
    flags: tuple[str, ...]
    notes: tuple[str, ...]
    #: Where the largest correction is applied: the nominal point (mm) and the program line.
    max_correction_at_mm: tuple[float, float, float] | None = None
    max_correction_line: int | None = None

    def to_json(self) -> dict[str, object]:
        return {
            "lines_in": self.lines_in,
            "moves_in": self.moves_in,
            "points_out": self.points_out,
            "max_correction_um": self.max_correction_um,
            "tool_offset_mm": list(self.tool_offset_mm),
            "flags": list(self.flags),
            "notes": list(self.notes),
        }


# ---------------------------------------------------------------------------------------------
# Parsing
# ---------------------------------------------------------------------------------------------


@dataclass
class _Block:
    number: int
    delete: bool
    words: list[tuple[str, float, str]]  # (letter, value, text as written)
    comments: list[str]
    raw: str


def _parse_line(text: str, number: int, path: str) -> _Block | None:
    raw = text.rstrip("\r\n")
    line = raw.strip()
    if not line or line == "%":
        return None
    delete = line.startswith("/")
    if delete:
        line = line[1:]
    comments: list[str] = []
    body = []
    i = 0
    while i < len(line):
        ch = line[i]
        if ch == "(":
            end = line.find(")", i)
            if end < 0:
                raise FormatError(path, "a comment '(' is not closed on its line", number)
            if "(" in line[i + 1 : end]:
                raise FormatError(path, "nested comments are not allowed in RS274/NGC", number)
            comments.append(line[i + 1 : end])
            i = end + 1
        elif ch == ";":
            comments.append(line[i + 1 :].strip())
            break
        else:
            body.append(ch)
            i += 1
    code = "".join(body).upper().replace(" ", "").replace("\t", "")
    if "#" in code or "[" in code or "<" in code:
        raise FormatError(
            path,
            "parameters (#), expressions ([ ]) and named parameters are not supported by the "
            "rewriter; expand them first (e.g. run the program through the controller's "
            "interpreter) and rewrite the result",
            number,
        )
    if code.startswith("O"):
        raise FormatError(
            path,
            "O-words (subroutines, loops, conditions) are not supported by the rewriter",
            number,
        )
    words = []
    position = 0
    for match in _WORD.finditer(code):
        if match.start() != position:
            raise FormatError(
                path, f"cannot read {code[position : match.start()]!r} as an RS274/NGC word", number
            )
        words.append((match.group(1), float(match.group(2)), match.group(0)))
        position = match.end()
    if position != len(code):
        raise FormatError(path, f"cannot read {code[position:]!r} as an RS274/NGC word", number)
    return _Block(number, delete, words, comments, raw)


def _g_code(value: float) -> str:
    rounded = round(value, 1)
    return f"G{int(rounded)}" if rounded == int(rounded) else f"G{rounded:g}"


# ---------------------------------------------------------------------------------------------
# Interpretation: nominal geometry
# ---------------------------------------------------------------------------------------------


@dataclass
class _Move:
    """Nominal machine points (k, 3) reached one after the other, with approach signs."""

    rapid: bool
    points_mm: FloatArray
    approach: FloatArray
    splittable: bool


@dataclass
class _Event:
    block: _Block
    before: list[str]
    after: list[str]
    move: _Move | None = None
    g92_given_mm: dict[int, float] | None = None
    g92_reset: bool = False
    passthrough: bool = False
    position_mm: FloatArray = field(default_factory=lambda: np.zeros(3))


@dataclass
class _State:
    units_mm: float = 1.0  # mm per program unit
    plane: str = "G17"
    absolute: bool = True
    arc_absolute: bool = False
    motion: str | None = None
    work: str = "G54"
    g92_mm: FloatArray = field(default_factory=lambda: np.zeros(3))
    position_mm: FloatArray = field(default_factory=lambda: np.zeros(3))  # machine, nominal
    approach: FloatArray = field(default_factory=lambda: np.ones(3))


class _Rewriter:
    def __init__(self, source: ErrorSource, options: RewriteOptions, path: str) -> None:
        self.source = source
        self.options = options
        self.path = path
        self.flags: list[str] = []
        self.notes: list[str] = []
        self.used_work_offsets: set[str] = set()
        for code, offset in options.work_offsets_mm.items():
            if code not in WORK_OFFSETS or len(tuple(offset)) != 3:
                raise FormatError(path, f"work offset {code!r}: use G54..G59 with three values")

    def work_offset(self, code: str) -> FloatArray:
        return np.asarray(self.options.work_offsets_mm.get(code, (0.0, 0.0, 0.0)), dtype=float)

    # -- pass 1 ---------------------------------------------------------------------------------

    def interpret(self, text: str) -> tuple[list[_Event | str], int]:
        state = _State()
        events: list[_Event | str] = []
        lines = text.splitlines()
        for number, line in enumerate(lines, start=1):
            block = _parse_line(line, number, self.path)
            if block is None:
                events.append(line.rstrip("\r\n"))
                continue
            events.append(self._interpret_block(block, state))
        return events, len(lines)

    def _refuse(self, block: _Block, message: str) -> _Event:
        if self.options.unknown == "pass":
            self.flags.append(
                f"line {block.number}: copied unchanged ({message}); positions after it may be "
                "wrong if it moves the axes"
            )
            return _Event(block, [], [], passthrough=True)
        raise FormatError(
            self.path,
            f"{message}; remove it from the program, or rewrite with unknown words passed "
            "through unchanged (--pass-unknown) at your own risk",
            block.number,
        )

    def _interpret_block(self, block: _Block, state: _State) -> _Event:
        axes: dict[int, float] = {}
        centre: dict[str, float] = {}
        radius: float | None = None
        before: list[str] = []
        after: list[str] = []
        p_word: float | None = None
        g_codes = [_g_code(value) for letter, value, _ in block.words if letter == "G"]
        for code in g_codes:
            if code in REFUSED_REASON or not (code in KNOWN_G or code in PASSIVE_G):
                reason = REFUSED_REASON.get(code, "it is outside the supported RS274/NGC subset")
                return self._refuse(block, f"{code} is not supported by the rewriter: {reason}")
        for letter, value, written in block.words:
            if letter == "G":
                continue
            if letter in "XYZ":
                index = "XYZ".index(letter)
                if index in axes:
                    return self._refuse(block, f"{letter} appears twice on the line")
                axes[index] = value
            elif letter in "IJK":
                centre[letter] = value
            elif letter == "R":
                radius = value
            elif letter == "M":
                code = f"M{int(value)}" if value == int(value) else f"M{value:g}"
                (after if code in M_AFTER_MOTION else before).append(written)
            elif letter in "NFST":
                before.append(written)
            elif letter == "P":
                p_word = value
            else:
                return self._refuse(block, f"the word {written} is not supported by the rewriter")
        motion_here = None
        g92: str | None = None
        for code in g_codes:
            if code in ("G0", "G1", "G2", "G3"):
                motion_here = code
            elif code in ("G17", "G18", "G19"):
                state.plane = code
            elif code == "G20":
                state.units_mm = MM_PER_INCH
                before.append(code)
            elif code == "G21":
                state.units_mm = 1.0
                before.append(code)
            elif code == "G90":
                state.absolute = True
            elif code == "G91":
                state.absolute = False
            elif code == "G90.1":
                state.arc_absolute = True
            elif code == "G91.1":
                state.arc_absolute = False
            elif code in WORK_OFFSETS:
                state.work = code
                self.used_work_offsets.add(code)
                before.append(code)
            elif code in ("G92", "G92.1"):
                g92 = code
            elif code == "G80":
                state.motion = None
                before.append(code)
            elif code in PASSIVE_G:
                before.append(code)
        if p_word is not None:
            if "G4" in g_codes:
                before.append(f"P{p_word:g}")
            elif motion_here in ("G2", "G3") or (
                motion_here is None and state.motion in ("G2", "G3")
            ):
                if p_word != 1:
                    return self._refuse(block, "arcs with several turns (P) are not supported")
            else:
                return self._refuse(block, "a P word outside G4 dwell is not supported")
        event = _Event(block, before, after)
        if g92 == "G92.1":
            state.g92_mm = np.zeros(3)
            event.g92_reset = True
            return event
        if g92 == "G92":
            if not axes:
                raise FormatError(self.path, "G92 needs at least one of X, Y, Z", block.number)
            given = {k: v * state.units_mm for k, v in axes.items()}
            base = self.work_offset(state.work)
            for k, value in given.items():
                state.g92_mm[k] = state.position_mm[k] - base[k] - value
            event.g92_given_mm = given
            event.position_mm = state.position_mm.copy()
            return event
        if motion_here is not None:
            state.motion = motion_here
        if not axes:
            if centre or radius is not None:
                raise FormatError(self.path, "an arc needs end point words", block.number)
            return event
        if state.motion is None:
            return self._refuse(block, "axis words without an active motion mode (G0–G3)")
        offset = self.work_offset(state.work) + state.g92_mm
        start = state.position_mm.copy()
        target = start.copy()
        for k, value in axes.items():
            value_mm = value * state.units_mm
            target[k] = value_mm + offset[k] if state.absolute else start[k] + value_mm
        if state.motion in ("G0", "G1"):
            if centre or radius is not None:
                raise FormatError(self.path, "I, J, K or R words on a straight move", block.number)
            points = target[None, :]
        else:
            points = self._arc(block, state, start, target, centre, radius, offset)
        approach = self._approaches(state, start, points)
        event.move = _Move(state.motion == "G0", points, approach, state.motion == "G1")
        state.position_mm = target
        return event

    def _approaches(self, state: _State, start: FloatArray, points: FloatArray) -> FloatArray:
        out = np.empty_like(points)
        previous = start
        signs = state.approach.copy()
        for i, point in enumerate(points):
            delta = point - previous
            moving = np.abs(delta) > 1e-12
            signs = np.where(moving, np.sign(delta), signs)
            out[i] = signs
            previous = point
        state.approach = signs
        return out

    def _arc(
        self,
        block: _Block,
        state: _State,
        start: FloatArray,
        target: FloatArray,
        centre: dict[str, float],
        radius: float | None,
        offset: FloatArray,
    ) -> FloatArray:
        a, b, normal = {"G17": (0, 1, 2), "G18": (2, 0, 1), "G19": (1, 2, 0)}[state.plane]
        letters = {0: "I", 1: "J", 2: "K"}
        clockwise = state.motion == "G2"
        sa, sb = start[a], start[b]
        ea, eb = target[a], target[b]
        if radius is not None:
            if centre:
                raise FormatError(
                    self.path, "an arc takes either R or I/J/K, not both", block.number
                )
            r = radius * state.units_mm
            chord = math.hypot(ea - sa, eb - sb)
            if chord < 1e-9:
                raise FormatError(
                    self.path, "an R-format arc needs distinct end points", block.number
                )
            half = chord / 2.0
            if abs(r) < half - 1e-6:
                raise FormatError(
                    self.path,
                    f"radius {abs(r):g} mm is too small for a chord of {chord:g} mm",
                    block.number,
                )
            h = math.sqrt(max(r * r - half * half, 0.0))
            da, db = (ea - sa) / chord, (eb - sb) / chord
            # Right of the travel direction for a clockwise arc shorter than a half circle.
            side = 1.0 if clockwise else -1.0
            side *= 1.0 if r > 0 else -1.0
            ca = (sa + ea) / 2.0 + side * h * db
            cb = (sb + eb) / 2.0 - side * h * da
        else:
            needed = {letters[a], letters[b]}
            if not needed & set(centre):
                raise FormatError(
                    self.path,
                    f"an arc in {state.plane} needs {' or '.join(sorted(needed))} (or R)",
                    block.number,
                )
            ia = centre.get(letters[a], 0.0) * state.units_mm
            ib = centre.get(letters[b], 0.0) * state.units_mm
            if state.arc_absolute:
                ca, cb = ia + offset[a], ib + offset[b]
            else:
                ca, cb = sa + ia, sb + ib
        r_start = math.hypot(sa - ca, sb - cb)
        r_end = math.hypot(ea - ca, eb - cb)
        if abs(r_start - r_end) > 0.002:
            raise FormatError(
                self.path,
                f"arc radius differs at start ({r_start:.4f} mm) and end ({r_end:.4f} mm)",
                block.number,
            )
        phi_s = math.atan2(sb - cb, sa - ca)
        phi_e = math.atan2(eb - cb, ea - ca)
        full = math.hypot(ea - sa, eb - sb) < 1e-9
        if clockwise:
            sweep = -((phi_s - phi_e) % (2 * math.pi))
            if full or sweep == 0.0:
                sweep = -2 * math.pi
        else:
            sweep = (phi_e - phi_s) % (2 * math.pi)
            if full or sweep == 0.0:
                sweep = 2 * math.pi
        r = (r_start + r_end) / 2.0
        tolerance = self.options.arc_tolerance_mm
        if r <= tolerance:
            count = 1
        else:
            step = 2.0 * math.acos(1.0 - tolerance / r)
            count = max(1, math.ceil(abs(sweep) / step))
        t = np.arange(1, count + 1) / count
        angles = phi_s + sweep * t
        points = np.empty((count, 3))
        points[:, a] = ca + r * np.cos(angles)
        points[:, b] = cb + r * np.sin(angles)
        points[:, normal] = start[normal] + (target[normal] - start[normal]) * t
        points[-1] = target
        return points

    # -- passes 2 and 3 -------------------------------------------------------------------------

    def rewrite(self, text: str) -> RewriteResult:
        events, lines_in = self.interpret(text)
        moves = [e.move for e in events if isinstance(e, _Event) and e.move is not None]
        tool = self.options.tool_offset_mm or self.source.machine.tool_offset_mm
        tool_offset = (float(tool[0]), float(tool[1]), float(tool[2]))
        samples, owners = self._samples(moves)
        commands = np.empty((0, 3))
        if len(samples):
            approach = np.concatenate([a for _, a in samples])
            nominal = np.concatenate([p for p, _ in samples])
            commands = invert(self.source, nominal, approach, tool_offset).commanded_mm
            self._flag_range(nominal, owners, events)
        output, points_out, (max_corr, at_mm, at_line) = self._emit(
            events, samples, commands, tool_offset
        )
        unset = sorted(c for c in self.used_work_offsets if c not in self.options.work_offsets_mm)
        if unset:
            self.notes.append(
                f"work offsets {', '.join(unset)} were taken as zero; give their values so the "
                "correction is computed at the true machine position"
            )
        return RewriteResult(
            text=output,
            lines_in=lines_in,
            moves_in=len(moves),
            points_out=points_out,
            max_correction_um=max_corr,
            tool_offset_mm=tool_offset,
            flags=tuple(self.flags),
            notes=tuple(self.notes),
            max_correction_at_mm=at_mm,
            max_correction_line=at_line,
        )

    def _samples(self, moves: list[_Move]) -> tuple[list[tuple[FloatArray, FloatArray]], list[int]]:
        """Nominal points to correct: every target point, plus probes along feed moves."""
        samples = []
        owners = []
        start = np.zeros(3)
        for index, move in enumerate(moves):
            if move.splittable:
                end = move.points_mm[-1]
                length = float(np.linalg.norm(end - start))
                count = max(1, math.ceil(length / self.options.probe_step_mm))
                t = np.arange(0, count + 1)[:, None] / count
                points = start + (end - start) * t
                approach = np.broadcast_to(move.approach[-1], points.shape)
            else:
                points = np.vstack([start, move.points_mm])
                approach = np.vstack([move.approach[:1], move.approach])
            samples.append((points, np.asarray(approach, dtype=float)))
            owners.extend([index] * len(points))
            start = move.points_mm[-1]
        return samples, owners

    def _flag_range(
        self, nominal: FloatArray, owners: list[int], events: list[_Event | str]
    ) -> None:
        ranges = measured_range(self.source)
        lines = [e.block.number for e in events if isinstance(e, _Event) and e.move is not None]
        for k, axis in enumerate(AXES):
            low, high = ranges[axis]
            outside = (nominal[:, k] < low - 1e-9) | (nominal[:, k] > high + 1e-9)
            if not high > low:
                # an axis no line moved: one flag, not one per line
                moving = len({owners[i] for i in np.flatnonzero(outside)})
                if moving:
                    self.flags.append(
                        f"{axis}: no measured line moved {axis} (every reading at {axis} = "
                        f"{low:g} mm); {moving} program line(s) lie elsewhere along it, where "
                        "nothing was measured"
                    )
                continue
            for index in sorted({owners[i] for i in np.flatnonzero(outside)}):
                self.flags.append(
                    f"line {lines[index]}: {axis} goes beyond the measured range [{low:g}, "
                    f"{high:g}] mm; the correction there holds the end values (not extrapolated)"
                )

    def _emit(
        self,
        events: list[_Event | str],
        samples: list[tuple[FloatArray, FloatArray]],
        commands: FloatArray,
        tool_offset: tuple[float, float, float],
    ) -> tuple[str, int, tuple[float, tuple[float, float, float] | None, int | None]]:
        """The program text, the points written and the largest correction (µm, where, line)."""
        opts = self.options
        header = [
            "(volucal volumetric compensation: every target point corrected, feed moves split)",
            f"(tool offset assumed {tool_offset[0]:g} {tool_offset[1]:g} {tool_offset[2]:g} mm, "
            f"correction tolerance {opts.correction_tolerance_um:g} um, "
            f"arc tolerance {opts.arc_tolerance_mm:g} mm)",
            "G90",
        ]
        out: list[str] = []
        # A program that opens with "%" must keep it as its first line.
        while events and isinstance(events[0], str) and events[0].strip() in ("", "%"):
            out.append(str(events.pop(0)))
        out += header
        state_units = 1.0
        work = "G54"
        g92_controller = np.zeros(3)
        command_now: FloatArray | None = None
        cursor = 0
        points_out = 0
        largest: tuple[float, tuple[float, float, float] | None, int | None] = (0.0, None, None)
        for event in events:
            if isinstance(event, str):
                out.append(event)
                continue
            block = event.block
            prefix = "/" if block.delete else ""
            if event.passthrough:
                out.append(block.raw)
                continue
            for word in event.before:
                if word == "G20":
                    state_units = MM_PER_INCH
                elif word == "G21":
                    state_units = 1.0
                elif word in WORK_OFFSETS:
                    work = word
            comment = "".join(f" ({c.replace('(', '').replace(')', '')})" for c in block.comments)
            if not block.words:
                out.append(prefix + comment.strip())
                continue
            head = " ".join(event.before)
            if event.g92_reset:
                g92_controller = np.zeros(3)
                out.append(prefix + " ".join(filter(None, [head, "G92.1"])) + comment)
                continue
            if event.g92_given_mm is not None:
                base = self.work_offset(work)
                # Before any move the controller stands where the program assumes it does.
                current = command_now if command_now is not None else event.position_mm
                given = []
                for k, value in event.g92_given_mm.items():
                    g92_controller[k] = current[k] - base[k] - value
                    given.append(f"{'XYZ'[k]}{self._number(value / state_units, state_units)}")
                out.append(prefix + " ".join(filter(None, [head, "G92", *given])) + comment)
                continue
            if event.move is None:
                text = " ".join(filter(None, [head, " ".join(event.after)]))
                if text or comment:
                    out.append(prefix + text + comment)
                continue
            nominal, _ = samples[cursor]
            count = len(nominal)
            command = commands[:count]
            commands = commands[count:]
            cursor += 1
            size = np.max(np.abs(command - nominal), axis=1) * UM_PER_MM
            worst = int(np.argmax(size)) if len(size) else 0
            if len(size) and not float(size[worst]) <= largest[0]:  # NaN counts as largest
                point = (
                    float(nominal[worst, 0]),
                    float(nominal[worst, 1]),
                    float(nominal[worst, 2]),
                )
                largest = (float(size[worst]), point, block.number)
            keep = self._keep(event.move, nominal, command)
            offset = self.work_offset(work) + g92_controller
            code = "G0" if event.move.rapid else "G1"
            first = True
            for i in keep:
                xyz = (command[i] - offset) / state_units
                words = " ".join(
                    f"{axis}{self._number(v, state_units)}"
                    for axis, v in zip("XYZ", xyz, strict=True)
                )
                lead = head if first else ""
                out.append(
                    prefix
                    + " ".join(filter(None, [lead, code, words]))
                    + (comment if first else "")
                )
                first = False
                points_out += 1
            if event.after:
                out.append(prefix + " ".join(event.after))
            command_now = command[-1]
        return "\n".join(out) + "\n", points_out, largest

    def _keep(self, move: _Move, nominal: FloatArray, command: FloatArray) -> list[int]:
        """Indices of the points to emit (index 0 is the start point and is never emitted).

        A feed move is split by Douglas–Peucker on the compensated command: a split point is
        added wherever the straight command path between two kept points departs from the
        exact compensated command by more than the correction tolerance.
        """
        last = len(nominal) - 1
        if not move.splittable:
            return list(range(1, last + 1))
        tol_mm = self.options.correction_tolerance_um / UM_PER_MM
        limit = self.options.max_segment_mm
        keep = {last}
        stack = [(0, last)]
        while stack:
            lo, hi = stack.pop()
            if hi - lo < 2:
                continue
            t = np.linspace(0.0, 1.0, hi - lo + 1)[:, None]
            chord = command[lo] + (command[hi] - command[lo]) * t
            deviation = np.max(np.abs(chord - command[lo : hi + 1]), axis=1)
            worst = int(np.argmax(deviation))
            if deviation[worst] > tol_mm:
                mid = lo + worst
            elif limit is not None and np.linalg.norm(nominal[hi] - nominal[lo]) > limit:
                mid = (lo + hi) // 2
            else:
                continue
            keep.add(mid)
            stack.extend([(lo, mid), (mid, hi)])
        return sorted(keep)

    def _number(self, value: float, units_mm: float) -> str:
        digits = self.options.decimals_inch if units_mm != 1.0 else self.options.decimals_mm
        if abs(value) < 0.5 * 10.0**-digits:
            value = 0.0
        return f"{value:.{digits}f}"


def rewrite_program(
    source: ErrorSource, text: str, options: RewriteOptions | None = None, name: str = "<program>"
) -> RewriteResult:
    """Rewrite an RS274/NGC program so the machine described by ``source`` follows it exactly.

    Parameters
    ----------
    source : ErrorSource
        The machine's errors (E = actual − commanded, µm).
    text : str
        The program.
    options : RewriteOptions, optional
        Tolerances, tool offset, work offsets, what to do with unsupported words.
    name : str
        Shown in error messages (the file name).

    Raises
    ------
    FormatError
        For a line outside the supported subset (with ``unknown="refuse"``) or an invalid one,
        naming the line.
    """
    options = options or RewriteOptions()
    if options.unknown not in ("refuse", "pass"):
        raise FormatError(name, f"unknown={options.unknown!r}: use 'refuse' or 'pass'")
    for label, value in (
        ("correction tolerance", options.correction_tolerance_um),
        ("arc tolerance", options.arc_tolerance_mm),
        ("probe step", options.probe_step_mm),
    ):
        if not (math.isfinite(value) and value > 0):
            raise FormatError(name, f"{label} must be positive, got {value}")
    return _Rewriter(source, options, name).rewrite(text)


def rewrite_file(
    source: ErrorSource, in_path: Path, out_path: Path, options: RewriteOptions | None = None
) -> RewriteResult:
    """Read ``in_path``, rewrite it, write ``out_path``; see :func:`rewrite_program`."""
    try:
        text = Path(in_path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(in_path, f"cannot read the program: {exc}") from None
    result = rewrite_program(source, text, options, str(in_path))
    Path(out_path).write_text(result.text, encoding="utf-8")
    return result
