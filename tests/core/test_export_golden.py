"""Golden files of every controller export, checked by hand against the formats' documentation.

The machine of tests/data/golden/README.md: strokes 400 × 400 × 350 mm, tool offset 0, errors
EXX = 0.01·x µm, EYY = −0.02·y µm, EZZ = 0.03·z µm, squareness EC0Y = 10 µrad (so E_x = −0.01·y
µm), reversal of X 2 µm, tables every 100 mm. Every value in the golden files follows from these
by hand; the README lists each line's rule and its source.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from compensation_models import linear_model
from volucal.core.compensation import ExportOptions, ModelSource, ReversalSource, export_model
from volucal.core.machine import Machine

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden"

CASES = {
    "linuxcnc": ("linuxcnc", ExportOptions(spacing_mm=100.0)),
    "linuxcnc_type1": ("linuxcnc", ExportOptions(spacing_mm=100.0, linuxcnc_type=1)),
    "siemens": ("siemens", ExportOptions(spacing_mm=100.0)),
    "fanuc": ("fanuc", ExportOptions(spacing_mm=100.0)),
    "heidenhain": ("heidenhain", ExportOptions(spacing_mm=100.0)),
    "isg": ("isg", ExportOptions(spacing_mm=100.0)),
}


def golden_source() -> ReversalSource:
    machine = Machine(
        name="golden",
        chain="WXYFZT",
        stroke_mm={"X": (0, 400), "Y": (0, 400), "Z": (0, 350)},
        tool_offset_mm=(0, 0, 0),
    )
    model = linear_model({"EXX": 0.01, "EYY": -0.02, "EZZ": 0.03}, machine, {"EC0Y": 10.0})
    return ReversalSource(ModelSource(model), {"X": 2.0})


@pytest.mark.parametrize("case", sorted(CASES))
def test_export_matches_golden_files(case: str, tmp_path: Path) -> None:
    fmt, options = CASES[case]
    result = export_model(golden_source(), fmt, tmp_path, options)
    expected = sorted(p.name for p in (GOLDEN / case).iterdir())
    written = sorted(p.name for p in result.files if p.name != "volucal_export.json")
    assert written == expected
    for name in expected:
        assert (tmp_path / name).read_text() == (GOLDEN / case / name).read_text(), name


def _triplets(path: Path) -> np.ndarray:
    return np.array([[float(v) for v in line.split()] for line in path.read_text().splitlines()])


def test_linuxcnc_golden_values_follow_the_documented_rule() -> None:
    """Type 0: actual = nominal + E (LinuxCNC adds nominal − actual); type 1: offset = −E."""
    x0 = _triplets(GOLDEN / "linuxcnc" / "joint0_X.comp")
    x1 = _triplets(GOLDEN / "linuxcnc_type1" / "joint0_X.comp")
    nominal = np.arange(0.0, 401.0, 100.0)
    error_up = (0.01 * nominal + 1.0) / 1e3  # reversal 2 µm: +1 µm approached from below
    error_down = (0.01 * nominal - 1.0) / 1e3
    np.testing.assert_allclose(x0[:, 0], nominal)
    np.testing.assert_allclose(x0[:, 1], nominal + error_up, atol=1e-6)
    np.testing.assert_allclose(x0[:, 2], nominal + error_down, atol=1e-6)
    np.testing.assert_allclose(x1[:, 1], -error_up, atol=1e-6)
    np.testing.assert_allclose(x1[:, 2], -error_down, atol=1e-6)
    assert len(x0) <= 256


def test_fanuc_golden_increments_sum_to_the_correction() -> None:
    """Pitch error data are increments: their running sum from the reference is the absolute
    correction −E, e.g. Y: +2 µm per 100 mm (EYY = −0.02·y)."""
    lines = (GOLDEN / "fanuc" / "FANUC_PITCH.TXT").read_text().splitlines()
    assert lines[0] == lines[-1] == "%"
    data = {int(line[1:6]) - 10000: int(line.split("P")[1]) for line in lines if line[:2] == "N1"}
    y = [data[n] for n in range(6, 10)]  # 3621 Y = 5 is the reference's own section
    assert np.cumsum(y).tolist() == [2, 4, 6, 8]
    z = [data[n] for n in range(11, 15)]
    # 3 µm per 100 mm up to 300 mm; the point at 400 mm lies beyond the 350 mm stroke, where
    # the error is held at its end value (10.5 µm): rounded absolute −10 → increment −1.
    assert np.cumsum(z).tolist() == [-3, -6, -9, -10]
