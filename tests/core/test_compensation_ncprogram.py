"""RS274/NGC rewriting: corrected points, split moves, arcs, offsets, refusals."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from compensation_models import linear_model, paper_like_model
from volucal.core.compensation import (
    ModelSource,
    ReversalSource,
    RewriteOptions,
    rewrite_file,
    rewrite_program,
)
from volucal.core.compensation.inverse import invert
from volucal.core.errors import ErrorFunction, ErrorModel, PolynomialBasis
from volucal.core.machine import Machine
from volucal.core.userror import FormatError

MACHINE = Machine(
    name="test", stroke_mm={"X": (0, 400), "Y": (0, 400), "Z": (0, 350)}, tool_offset_mm=(0, 0, 0)
)


def zero_source() -> ModelSource:
    return ModelSource(ErrorModel.zero(MACHINE))


def moves(text: str) -> list[tuple[str, list[float]]]:
    """(G0|G1, [x, y, z]) of every emitted move, in order."""
    out = []
    for line in text.splitlines():
        match = re.search(r"\b(G[01]) X(-?[\d.]+) Y(-?[\d.]+) Z(-?[\d.]+)", line)
        if match:
            out.append((match.group(1), [float(match.group(i)) for i in (2, 3, 4)]))
    return out


def test_error_free_source_reproduces_the_program() -> None:
    text = "G21 G90\nG0 X10 Y20 Z30\nG1 X110 F500\nG91 G1 Y-5 Z-10\nM2\n"
    result = rewrite_program(zero_source(), text)
    assert moves(result.text) == [
        ("G0", [10.0, 20.0, 30.0]),
        ("G1", [110.0, 20.0, 30.0]),
        ("G1", [110.0, 15.0, 20.0]),  # G91 converted to absolute
    ]
    assert result.max_correction_um == 0.0
    lines = result.text.splitlines()
    assert lines[-1] == "M2" and "G90" in lines[:3]
    assert "G91" not in result.text


def test_targets_are_corrected_by_the_inverse() -> None:
    """E_x = 25·x µm (exaggerated): G1 X100 must become X = 100/1.025."""
    source = ModelSource(linear_model({"EXX": 25.0}, MACHINE))
    result = rewrite_program(source, "G1 X100 Y0 Z0 F100\n")
    target = moves(result.text)[-1][1]
    assert target[0] == pytest.approx(100 / 1.025, abs=5e-5)
    assert result.max_correction_um == pytest.approx((100 - 100 / 1.025) * 1e3, rel=1e-6)


def _cyclic_source(amplitude_um: float = 3.0, lead_mm: float = 16.0) -> ModelSource:
    """Positioning error with a 16 mm screw cycle: the correction changes along a move."""
    q = np.linspace(0.0, 400.0, 801)
    from volucal.core.errors import NodeTableBasis

    basis = NodeTableBasis(tuple(q))
    model = ErrorModel.zero(MACHINE)
    functions = dict(model.functions)
    functions["EXX"] = ErrorFunction("EXX", basis, amplitude_um * np.sin(2 * math.pi * q / lead_mm))
    return ModelSource(ErrorModel(MACHINE, functions))


def test_long_moves_are_split_to_follow_the_correction() -> None:
    source = _cyclic_source()
    tolerance = 0.1
    result = rewrite_program(
        source, "G0 X0 Y0 Z0\nG1 X400 F1000\n", RewriteOptions(correction_tolerance_um=tolerance)
    )
    points = np.array([p for _, p in moves(result.text)])
    assert len(points) > 50  # a 16 mm cycle over 400 mm needs many segments
    # Walk the emitted command path densely: the tool must stay within the tolerance (plus the
    # 0.05 µm rounding of four decimals) of the nominal line X = commanded + E.
    for a, b in zip(points[:-1], points[1:], strict=True):
        t = np.linspace(0, 1, 21)[:, None]
        path = a + (b - a) * t
        landed = path + source.error_um(path) / 1e3
        assert np.max(np.abs(landed[:, 1:])) < 1e-9
        exact = invert(source, np.column_stack([landed[:, 0], landed[:, 1:]]))
        deviation = np.abs(exact.commanded_mm[:, 0] - path[:, 0]) * 1e3
        assert np.max(deviation) <= tolerance + 0.06


def test_max_segment_bounds_the_split_length() -> None:
    result = rewrite_program(
        zero_source(), "G0 X0 Y0 Z0\nG1 X100 F100\n", RewriteOptions(max_segment_mm=10.0)
    )
    points = np.array([p for _, p in moves(result.text)])
    assert np.max(np.diff(points[:, 0])) <= 10.0 + 1e-9
    assert points[-1][0] == 100.0


def test_arcs_are_linearised_within_the_tolerance() -> None:
    """G2 from (0, 10) to (10, 0) about the origin: clockwise, through (7.07, 7.07)."""
    tolerance = 0.001
    for arc in ("G2 X10 Y0 I0 J-10", "G2 X10 Y0 R10"):
        text = f"G0 X0 Y10 Z0\n{arc} F100\n"
        result = rewrite_program(zero_source(), text, RewriteOptions(arc_tolerance_mm=tolerance))
        points = np.array([p for _, p in moves(result.text)[1:]])
        np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 1]), 10.0, atol=1e-4)
        angles = np.arctan2(points[:, 1], points[:, 0])
        assert np.all(np.diff(angles) < 0)  # clockwise
        chord = np.max(np.hypot(*np.diff(np.vstack([[0, 10, 0], points]), axis=0)[:, :2].T))
        sagitta = 10 - math.sqrt(100 - (chord / 2) ** 2)
        assert sagitta <= tolerance + 1e-9
        np.testing.assert_allclose(points[-1], [10, 0, 0])


def test_full_circle_large_arc_and_helix() -> None:
    result = rewrite_program(zero_source(), "G0 X20 Y10 Z0\nG3 X20 Y10 Z5 I-10 J0 F100\n")
    points = np.array([p for _, p in moves(result.text)[1:]])
    angles = np.unwrap(np.arctan2(points[:, 1] - 10, points[:, 0] - 10))
    assert angles[-1] - 0.0 == pytest.approx(2 * math.pi, abs=1e-6)  # one full turn, CCW
    assert np.all(np.diff(points[:, 2]) > 0) and points[-1][2] == 5.0  # helical
    # R < 0: the arc longer than half a circle.
    long_arc = rewrite_program(zero_source(), "G0 X0 Y10 Z0\nG2 X10 Y0 R-10 F100\n")
    pts = np.array([p for _, p in moves(long_arc.text)[1:]])
    centre = np.array([10.0, 10.0])  # the other centre on the chord's bisector
    np.testing.assert_allclose(np.hypot(*(pts[:, :2] - centre).T), 10.0, atol=1e-4)


def test_other_planes_follow_rs274_orientation() -> None:
    """G18 (ZX plane, Z first): G2 from Z10 X0 to Z0 X-10 about the origin passes X < 0."""
    result = rewrite_program(zero_source(), "G0 X0 Y0 Z10\nG18 G2 X-10 Z0 I0 K-10 F100\n")
    points = np.array([p for _, p in moves(result.text)[1:]])
    assert np.all(points[:, 0] <= 1e-9) and np.all(points[:, 1] == 0.0)
    np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 2]), 10.0, atol=1e-4)
    yz = rewrite_program(zero_source(), "G0 X0 Y10 Z0\nG19 G3 Y0 Z10 J-10 K0 F100\n")
    pts = np.array([p for _, p in moves(yz.text)[1:]])
    assert np.all(pts[:, 0] == 0.0) and np.all(pts[:, 1] >= -1e-9) and np.all(pts[:, 2] >= 0)


def test_work_offsets_and_g92_keep_the_controller_consistent() -> None:
    source = ModelSource(linear_model({"EXX": 25.0}, MACHINE))
    options = RewriteOptions(work_offsets_mm={"G55": (100.0, 0.0, 0.0)})
    result = rewrite_program(source, "G55\nG1 X50 Y0 Z0 F100\nG92 X0\nG1 X10\n", options)
    first, second = (p for _, p in moves(result.text))
    # Machine X = 150: the command is 150/1.025, written in G55 coordinates.
    assert first[0] == pytest.approx(150 / 1.025 - 100, abs=5e-5)
    # G92 X0 is taken by the controller at its (compensated) position 150/1.025; the next
    # target is machine X = 160, commanded 160/1.025, written relative to that G92 origin.
    assert second[0] == pytest.approx(160 / 1.025 - 150 / 1.025, abs=5e-5)
    assert "G92 X0.0000" in result.text and "G55" in result.text
    unset = rewrite_program(source, "G56\nG1 X1 F100\n")
    assert any("G56" in note for note in unset.notes)


def test_inches_are_written_in_inches() -> None:
    result = rewrite_program(zero_source(), "G20\nG0 X1 Y2 Z0.5\n")
    assert moves(result.text) == [("G0", [1.0, 2.0, 0.5])]
    assert "X1.000000" in result.text


def test_reversal_is_compensated_by_direction_of_travel() -> None:
    source = ReversalSource(zero_source(), {"X": 4.0})
    up = rewrite_program(source, "G0 X0 Y0 Z0\nG1 X100 F100\n")
    down = rewrite_program(source, "G0 X200 Y0 Z0\nG1 X100 F100\n")
    assert moves(up.text)[-1][1][0] == pytest.approx(100 - 0.002)
    assert moves(down.text)[-1][1][0] == pytest.approx(100 + 0.002)


def test_comments_numbers_and_program_markers_pass_through() -> None:
    text = "%\n(header comment)\nN10 G1 X5 Y0 Z0 F200 M3 (cut) ; trailing\n/N20 G0 Z10\nN30 M2\n%\n"
    result = rewrite_program(zero_source(), text)
    lines = result.text.splitlines()
    assert lines[0] == "%" and lines[-1] == "%"
    assert "(header comment)" in lines
    cut = next(line for line in lines if line.startswith("N10"))
    assert cut.startswith("N10 F200 M3 G1 X5.0000") and "(cut) (trailing)" in cut
    assert "/N20 G0 X5.0000 Y0.0000 Z10.0000" in lines
    assert "N30 M2" in lines


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("G28", "stored position"),
        ("G43 H1", "tool length"),
        ("G41 D1", "cutter radius"),
        ("G81 X1 Y1 Z-1 R1", "outside the supported"),
        ("#1 = 5", "parameters"),
        ("G1 X[1+2]", "expressions"),
        ("O100 sub", "O-words"),
        ("G1 X1 Q5", "Q5"),
        ("G1 X1 X2", "twice"),
        ("G2 X10 Y0 I0 J3", "radius differs"),
        ("G1 X1 (open", "not closed"),
    ],
)
def test_unsupported_lines_are_refused_with_the_line_number(line: str, message: str) -> None:
    with pytest.raises(FormatError, match=message) as error:
        rewrite_program(zero_source(), f"G0 X0 Y0 Z0\n{line}\n", name="part.ngc")
    assert error.value.line == 2 and error.value.path == "part.ngc"


def test_pass_mode_copies_unknown_lines_and_flags_them() -> None:
    result = rewrite_program(
        zero_source(), "G0 X0 Y0 Z0\nG28\nG1 X5 F10\n", RewriteOptions(unknown="pass")
    )
    assert "\nG28\n" in result.text
    assert any(flag.startswith("line 2:") for flag in result.flags)


def test_positions_beyond_the_measured_range_are_flagged() -> None:
    result = rewrite_program(ModelSource(paper_like_model()), "G0 X10 Y10 Z10\nG1 X450 F100\n")
    assert len(result.flags) == 1
    assert result.flags[0].startswith("line 2: X goes beyond the measured range [0, 400]")


def test_rewrite_file_reads_and_writes(tmp_path: Path) -> None:
    program = tmp_path / "in.ngc"
    program.write_text("G0 X1 Y2 Z3\n")
    out = tmp_path / "out.ngc"
    result = rewrite_file(zero_source(), program, out)
    assert out.read_text() == result.text
    with pytest.raises(FormatError, match="cannot read"):
        rewrite_file(zero_source(), tmp_path / "missing.ngc", out)


def test_tolerances_must_be_positive() -> None:
    with pytest.raises(FormatError, match="arc tolerance"):
        rewrite_program(zero_source(), "G0 X1\n", RewriteOptions(arc_tolerance_mm=0.0))
    with pytest.raises(FormatError, match="unknown"):
        rewrite_program(zero_source(), "G0 X1\n", RewriteOptions(unknown="skip"))


def test_polynomial_basis_import_is_the_one_used_by_models() -> None:
    # linear_model uses degree-1 Legendre polynomials: value(0) = 0, value(400) = 400·slope.
    model = linear_model({"EXX": 0.5}, MACHINE)
    assert isinstance(model.functions["EXX"].basis, PolynomialBasis)
    assert model.value("EXX", [0.0, 400.0]) == pytest.approx([0.0, 200.0])
