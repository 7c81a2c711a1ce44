"""The real Aerotech grids in ../shared/realdata (skipped when absent): the vendor's method and
its .cal, volucal's correction against it, least-squares stitching of four zones against the
vendor's stitched table, two readers of the same data, and malformed copies of the real files."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from volucal.core.commands.grid_cmd import compare_with_cal
from volucal.core.compensation.export_grid2d import cal_as_table, read_aerotech_cal
from volucal.core.grid2d import GridMeasurement, rms
from volucal.core.grid2d_fit import identify_grid
from volucal.core.grid2d_table import GridColumnMap, GridFormat, read_grid_table
from volucal.core.grid2d_vendor import vendor_correction
from volucal.core.io.accuracy2d import read_accuracy2d
from volucal.core.userror import UserError

FOLDER = "aerotech_2d_stitching"
GRID = "643494-1-1-XWafer_YWafer_Accuracy2D.dat"
CAL = "643494-1-1-XWafer_YWafer.cal"
AXES = {"X": 6, "Y": 5}


REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


@pytest.fixture(scope="module")
def wafer():
    """The 643494 grid and its identification, fitted once for the module."""
    folder = REALDATA / FOLDER
    if not folder.is_dir():
        pytest.skip("../shared/realdata is not present on this machine")
    grid = read_accuracy2d(folder / GRID)
    return folder, grid, identify_grid(grid)


def test_the_vendor_method_reproduces_the_vendor_cal_to_the_last_digit(realdata):
    folder = realdata / FOLDER
    table = vendor_correction(read_accuracy2d(folder / GRID))
    _, vendor = cal_as_table(read_aerotech_cal(folder / CAL), AXES)
    assert np.max(np.abs(table.correction_um - vendor)) <= 5e-5  # the .cal's 0.1 nm rounding
    assert table.orthogonality_urad == pytest.approx(-81.631, abs=0.001)


def test_volucal_correction_against_the_vendor_cal(wafer):
    folder, grid, result = wafer
    comparison = compare_with_cal(result, folder / CAL, AXES)
    assert comparison["nodes"] == 71 * 71
    assert comparison["matching_sign"] == "same"
    assert comparison["same_sign"]["rms_um"]["X"] <= 0.2
    assert comparison["same_sign"]["rms_um"]["Y"] <= 0.2
    # squareness from mean slopes is the vendor's orthogonality with ISO's sign
    assert result.squareness_mean_urad == pytest.approx(81.631, abs=0.01)
    # the yaw of the upper axis (Y) is seen through X: the lines cut from the grid lost it
    assert "ECY" in result.functions and result.upper_axis == "Y"
    assert np.ptp(result.sampled("ECY")[1]) > 100.0


def test_four_zones_stitched_by_least_squares_match_the_vendor_stitch(realdata):
    folder = realdata / FOLDER
    zones = [read_accuracy2d(folder / f"642583-1-1-CZ{k}_raw.dat", position_unit="mm")
             for k in (1, 2, 3, 4)]
    result = identify_grid(zones)
    assert set(result.gauges) == {f"642583-1-1-CZ{k}_raw" for k in (1, 2, 3, 4)}
    comparison = compare_with_cal(result, folder / "642583-1-1-2D.cal", {"X": 3, "Y": 1})
    # the vendor's MATLAB stitch wrote its table with the opposite sign (its input holds
    # commanded − measured); after the gauge terms, the two stitches agree to 0.1 µm
    assert comparison["matching_sign"] == "opposite"
    assert comparison["opposite_sign"]["rms_um"]["X"] < 0.1
    assert comparison["opposite_sign"]["rms_um"]["Y"] < 0.1
    assert comparison["nodes"] == 51 * 51  # the padding of zeros around it is not measured


def test_between_the_fitted_rows_the_rows_offsets_are_not_carried(wafer):
    """Fitted on the even nodes (10 mm), the X errors of the odd rows: each row carries an offset
    of its own (the straightness of Y in X at a 5 mm pitch), which the cross-validation over
    held-out rows sees does not carry to the next row; the model's smooth trend then predicts
    the odd rows better than the node values interpolated linearly (the vendor's table)."""
    _, grid, _ = wafer
    ix = np.rint(grid.position_mm[:, 0] / 5.0).astype(int)
    iy = np.rint(grid.position_mm[:, 1] / 5.0).astype(int)
    fit = (ix % 2 == 0) & (iy % 2 == 0)
    even = GridMeasurement("even", grid.position_mm[fit], grid.deviation_um[fit],
                           upper_axis=grid.upper_axis)
    result = identify_grid(even)
    assert result.choices["EXY"]["carry"] < 0.5
    rows = (ix % 2 == 0) & (iy % 2 == 1)
    q = grid.position_mm[rows]
    measured = grid.deviation_um[rows, 0] - result.gauges["even"].evaluate(q)[:, 0]
    model = measured - result.error(q)[:, 0]
    # the node values interpolated linearly: the mean of the fitted rows either side
    lookup = measured - 0.5 * (result.error(q - [0.0, 5.0])[:, 0]
                               + result.error(q + [0.0, 5.0])[:, 0])
    assert rms(model) < rms(lookup) - 0.005
    assert rms(model) == pytest.approx(0.523, abs=0.002)


def test_the_generic_column_map_reads_the_vendors_matlab_input_like_the_preset(realdata):
    folder = realdata / FOLDER
    raw = read_accuracy2d(folder / "642583-1-1-CZ1_raw.dat", position_unit="mm")
    # % header: Ax1 is Y, Ax2 is X; columns Ax1CmdPos Ax2CmdPos Ax1RelErr Ax2RelErr (mm),
    # RelErr = commanded − measured, hence sign −1
    fmt = GridFormat(columns=GridColumnMap(x=4, y=3, deviation_x=6, deviation_y=5),
                     position_unit="mm", deviation_unit="mm", comment="%", sign=-1)
    matlab = read_grid_table(folder / "642583-1-1-CZ1_matlab_input.dat", fmt)
    order = np.lexsort((raw.position_mm[:, 1], raw.position_mm[:, 0]))
    other = np.lexsort((matlab.position_mm[:, 1], matlab.position_mm[:, 0]))
    np.testing.assert_allclose(matlab.position_mm[other], raw.position_mm[order])
    np.testing.assert_allclose(matlab.deviation_um[other], raw.deviation_um[order], atol=1e-9)


def _mutations(text: bytes, rng: np.random.Generator) -> list[tuple[str, bytes]]:
    lines = text.split(b"\r\n")
    out = [(f"cut at byte {n}", text[:n]) for n in (300, 2500, 3300, 3400, 200000, 565000)]
    for k in range(40):
        position = int(rng.integers(0, len(text)))
        flipped = bytearray(text)
        flipped[position] = int(rng.choice(list(b"0123456789.-eE x:;")))
        out.append((f"byte {position} flipped ({k})", bytes(flipped)))
    for a, b in ((0, 1), (2, 3), (4, 6), (0, 2), (5, 7)):
        swapped = []
        for number, line in enumerate(lines):
            fields = line.split()
            if number >= 42 and len(fields) == 8:
                fields[a], fields[b] = fields[b], fields[a]
                line = b"  ".join(fields)
            swapped.append(line)
        out.append((f"columns {a + 1} and {b + 1} swapped", b"\r\n".join(swapped)))
    row = lines[1000].split()
    out.append(("a value missing", b"\r\n".join(lines[:1000] + [b"  ".join(row[:7])]
                                                 + lines[1001:])))
    return out


def test_malformed_real_grid_files_give_one_line_naming_file_line_and_remedy(realdata, tmp_path):
    folder = realdata / FOLDER
    text = (folder / GRID).read_bytes()
    rng = np.random.default_rng(14)
    outcomes = {"error": 0, "read": 0}
    for label, data in _mutations(text, rng):
        path = tmp_path / "mutated.dat"
        path.write_bytes(data)
        shutil.copy(folder / GRID.replace(".dat", ".set"), tmp_path / "mutated.set")
        try:
            read_accuracy2d(path)
        except UserError as exc:
            message = str(exc)
            assert "\n" not in message, label
            assert message.startswith(str(path)), label
            assert ", line " in message, (label, message)
            assert any(word in message for word in ("check", "cut short", "expected", "give",
                                                    "not plausible", "map")), (label, message)
            outcomes["error"] += 1
        else:
            outcomes["read"] += 1  # a flip that leaves a valid number is not malformed
    assert outcomes["error"] >= 20
    assert outcomes["read"] >= 1


def test_swapping_commanded_and_measured_is_caught_at_its_line(realdata, tmp_path):
    folder = realdata / FOLDER
    lines = (folder / GRID).read_bytes().split(b"\r\n")
    fields = lines[1000].split()
    fields[0], fields[1] = fields[1], fields[0]
    lines[1000] = b"  ".join(fields)
    path = tmp_path / "swapped.dat"
    path.write_bytes(b"\r\n".join(lines))
    with pytest.raises(UserError, match=r"swapped\.dat, line 1001: commanded X = .* off the "
                       "grid's 5 mm nodes: check this line"):
        read_accuracy2d(path, position_unit="mm")
