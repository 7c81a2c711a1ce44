"""ISO 230-2 target/run tables: both forms, real ecmc files, round trip, bad input."""

from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.iso_table import read_iso_table, write_iso_table
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"


def test_hand_written_ecmc_form():
    table = read_iso_table(DATA / "ecmc_hand.dat")
    data = table.data
    assert table.form == "ecmc" and table.unit == "mm"
    assert table.header["REF_PV"] == "IOC:axis1-Enc-PosAct"
    np.testing.assert_array_equal(data.targets_mm, [0, 10, 20])
    np.testing.assert_array_equal(data.run_direction, [1, -1, 1, -1])
    # deviations are reference − target, in the file's unit (mm)
    np.testing.assert_allclose(data.deviations[0], [0.0012, 0.0025, 0.0031], atol=1e-12)
    np.testing.assert_allclose(data.deviations[3], [0.0004, 0.0012, 0.0020], atol=1e-12)
    # no times in the file: readings 1 s apart in visit order
    np.testing.assert_array_equal(data.times_s[1], [5, 4, 3])
    assert data.metadata["time_source"].startswith("visit order")


def test_hand_written_column_form():
    table = read_iso_table(DATA / "z_iso_hand.txt")
    data = table.data
    assert table.form == "columns" and table.unit == "um"
    np.testing.assert_array_equal(data.targets_mm, [0, 60, 120, 180])
    np.testing.assert_array_equal(data.run_direction, [1, -1, 1, -1, 1, -1])
    np.testing.assert_array_equal(data.deviations[:, 0], [0.0, -1.5, 0.3, -1.2, 0.1, -1.4])


def test_real_ecmc_files(realdata):
    psi = read_iso_table(realdata / "psi_ecmc_iso230_2" / "psi_test_fat_sat_report.md_ISO230.dat")
    assert psi.header["REF_PV"] == "sls-sioc-ecat01:m0s001-Enc01-PosAct"
    np.testing.assert_allclose(psi.targets_file_mm, [-10, -4.88, 0.24, 5.36, 10.48])
    assert psi.data.deviations.shape == (10, 5)
    assert psi.data.deviations[0, 0] == pytest.approx(-10.0000990190 + 10)
    assert psi.data.deviations[1, 4] == pytest.approx(10.4798999810 - 10.48)
    ess = read_iso_table(realdata / "ess_ecmc_iso230_2" / "iso230-2_testdata.dat")
    assert ess.data.deviations[0, 1] == pytest.approx(25.02160 - 25.0)


def test_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    table = read_iso_table(DATA / "z_iso_hand.txt")
    data = table.data
    deviations = data.deviations + rng.normal(0, 1e-3, data.deviations.shape)
    deviations[2, 1] = np.nan
    from dataclasses import replace

    changed = replace(data, deviations=deviations)
    path = tmp_path / "t.txt"
    write_iso_table(path, changed, unit="um", first_target_mm=-180.0)
    back = read_iso_table(path)
    np.testing.assert_array_equal(back.data.deviations, deviations)
    np.testing.assert_array_equal(back.data.run_direction, data.run_direction)
    np.testing.assert_array_equal(back.targets_file_mm, data.targets_mm - 180.0)


@pytest.mark.parametrize(
    "text, match, line",
    [
        ("TGT_DATA[1]=1\nREF_DATA_FWD[1,1]=1\nREF_DATA_FWD[1,1]=2\n", "given twice", 3),
        ("POSITIONS=2\nTGT_DATA[1]=1\nREF_DATA_FWD[1,1]=1\n", r"TGT_DATA\[2\] is missing", 3),
        ("CYCLES=2\nTGT_DATA[1]=1\nREF_DATA_FWD[1,1]=1\n", r"REF_DATA_FWD\[1,2\] is missing", 3),
        ("TGT_DATA[1]=1\nREF_DATA_FWD[1]=1\n", r"expected an index \[i,j\]", 2),
        ("TGT_DATA[1]=1\nREF_DATA_FWD[1,1]=abc\n", "expected a number", 2),
        ("TGT_DATA[1]=1\nthis is not an entry\n", "expected NAME=value", 2),
        ("TGT_DATA[1]=1\nTGT_DATA[2]=0.5\nTGT_DATA[3]=2\nREF_DATA_FWD[1,1]=1\n"
         "REF_DATA_FWD[2,1]=1\nREF_DATA_FWD[3,1]=1\n", "strictly increasing", 1),
        ("CYCLES=0\nTGT_DATA[1]=1\n", "out of range", 1),
        ("# unit: um\ntarget_mm up_1 down_1\n0 1 2\n5 1\n", "expected 3 fields", 4),
        ("target_mm up_1 sideways_1\n0 1 2\n", "not understood", 1),
        ("# unit: um\ntarget_mm up_1\n0 x\n", "expected a number", 3),
        ("# unit: parsec\ntarget_mm up_1\n0 1\n", "not supported", 1),
        # no unit: never assumed; values a laser cannot produce; loose numbers; spacing 0
        ("target_mm up_1\n0 1\n", "does not state its deviation unit", 1),
        ("# unit: mm\ntarget_mm up_1\n0 1e300\n", "beyond ±1e\\+06", 3),
        ("# unit: um\ntarget_mm up_1\n1e308 1\n", "beyond", 3),
        ("# unit: um\ntarget_mm up_1\n0 1\n1_000 2\n", "expected a number", 4),
        ("# unit: um\ntarget_mm up_1\n0 1\n0.00001 2\n", "at least 0.0001 mm apart", 3),
        ("TGT_DATA[1]=1e308\nREF_DATA_FWD[1,1]=1\n", "beyond", 1),
        ("TGT_DATA[1]=1\nREF_DATA_FWD[1,1]=1e307\n", "beyond", 2),
        ("TGT_DATA[\u0661]=1\nREF_DATA_FWD[1,1]=1\n", "expected a whole number", 1),
        ("CYCLES=5000\nPOSITIONS=100000\nTGT_DATA[1]=1\nREF_DATA_FWD[1,1]=1\n",
         "beyond the 2,000,000 readings", 2),
    ],
)
def test_bad_tables(tmp_path, text, match, line):
    path = tmp_path / "bad.dat"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FormatError, match=match) as info:
        read_iso_table(path)
    assert info.value.line == line and info.value.path == str(path)
