"""Generic tables with a column map: hand-written samples, a real vendor export, the writer's
round trip and bad input named by file and line."""

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.table import ColumnMap, TableFormat, cluster_targets, read_table, write_table
from volucal.core.measurement import LineData
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"


def test_csv_with_header_run_direction_time_and_air():
    table = read_table(DATA / "y_straightness_hand.csv")
    data = table.data
    assert table.unit == "um"  # from the header name deviation_um
    np.testing.assert_array_equal(data.targets_mm, [0, 100, 200, 300, 400])
    np.testing.assert_array_equal(data.run_direction, [1, -1, 1])
    np.testing.assert_array_equal(data.deviations[1], [0.10, 1.10, 2.00, 1.60, 0.50])
    np.testing.assert_array_equal(data.times_s[1], [180, 160, 140, 120, 100])
    assert data.start_time == datetime(2016, 12, 12, 11, 30, tzinfo=UTC).timestamp()
    assert data.air_temp_c[2, 4] == 20.47
    assert data.environment.air_temp_c == (20.40, 20.47)
    assert data.metadata["time_source"] == "time column"


def test_whitespace_without_header_mapped_by_number():
    fmt = TableFormat(columns=ColumnMap(position=1, deviation=2))
    table = read_table(DATA / "z_linear_hand.txt", fmt)
    data = table.data
    assert table.unit is None  # the file does not say: the plan's deviation_unit applies
    # runs split where the position repeats (-150, -150); the first run travels downwards
    np.testing.assert_array_equal(data.targets_mm, [-150, -100, -50, 0])
    np.testing.assert_array_equal(data.run_direction, [-1, 1])
    np.testing.assert_array_equal(data.deviations[0], [-2510, -1720, -850, 0])
    np.testing.assert_array_equal(data.deviations[1], [-2950, -2100, -1260, -400])
    # no time column: one second per row, in row order
    np.testing.assert_array_equal(data.times_s[0], [3, 2, 1, 0])
    assert data.metadata["time_source"].startswith("row order")


def test_semicolon_with_decimal_comma_and_units_in_brackets():
    fmt = TableFormat(columns=ColumnMap(deviation="Abweichung", run="Lauf"))
    table = read_table(DATA / "x_semicolon_hand.csv", fmt)
    assert table.unit == "um"
    np.testing.assert_array_equal(table.data.deviations, [[0.0, 1.25, 2.5], [-0.3, 0.95, 2.1]])
    np.testing.assert_array_equal(table.data.run_direction, [1, -1])


def test_positions_in_other_units(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("position,deviation\n0,0\n0.01,1\n0.02,2\n")
    table = read_table(path, TableFormat(position_unit="m", deviation_unit="nm"))
    np.testing.assert_allclose(table.data.targets_mm, [0, 10, 20])
    assert table.unit == "nm"


def test_iso_time_column_sets_the_start(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("position,deviation,time\n0,0,2020-01-01T00:00:00Z\n"
                    "5,1,2020-01-01T00:00:30Z\n")
    data = read_table(path).data
    assert data.start_time == datetime(2020, 1, 1, tzinfo=UTC).timestamp()
    np.testing.assert_array_equal(data.times_s, [[0, 30]])


def test_real_vendor_flatness_export(realdata):
    """Aerotech flatness export: header above a ':START' marker, values in mm."""
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    fmt = TableFormat(columns=ColumnMap(position="Position", deviation="Flat",
                                        air_temp="AirTemp", material_temp="MatTemp",
                                        pressure="Pressure", humidity="Humidity"),
                      deviation_unit="mm", data_marker=":START")
    table = read_table(path, fmt)
    data = table.data
    assert data.targets_mm.size == 33 and data.runs == 1
    np.testing.assert_array_equal(data.targets_mm, np.arange(0, 161, 5))
    assert data.deviations[0, 0] == 0.007082
    assert data.environment.air_humidity_pct == (54.07, 54.19)
    assert data.material_temp_c[0, 0] == 20.40


def test_cluster_targets_merges_within_tolerance():
    targets, index = cluster_targets(np.array([0.0, 10.0004, 9.9998, 20.0]), 1e-3)
    np.testing.assert_allclose(targets, [0.0, 10.0001, 20.0])
    np.testing.assert_array_equal(index, [0, 1, 1, 2])


def test_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    runs, count = 4, 6
    deviations = rng.normal(0, 2, (runs, count))
    deviations[2, 3] = np.nan  # a missing reading stays missing
    data = LineData(
        targets_mm=np.sort(np.concatenate([[0.0], rng.uniform(1, 300, count - 1)])),
        deviations=deviations,
        run_direction=np.array([1, -1, 1, -1]),
        times_s=rng.uniform(0, 1000, (runs, count)),
        start_time=1_767_225_600.5,
        air_temp_c=rng.normal(20, 0.1, (runs, count)),
        material_temp_c=rng.normal(20.5, 0.1, (runs, count)),
    )
    path = tmp_path / "line.csv"
    write_table(path, data)
    back = read_table(path).data
    np.testing.assert_array_equal(back.targets_mm, data.targets_mm)
    np.testing.assert_array_equal(back.deviations, data.deviations)
    np.testing.assert_array_equal(back.run_direction, data.run_direction)
    times = np.where(np.isnan(deviations), np.nan, data.times_s)
    np.testing.assert_array_equal(back.times_s, times)
    np.testing.assert_array_equal(back.air_temp_c, np.where(np.isnan(deviations), np.nan,
                                                            data.air_temp_c))
    assert back.start_time == data.start_time


# ---- bad files ------------------------------------------------------------------------------


def write(tmp_path, text: str) -> Path:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, fmt, match, line",
    [
        ("pos,dev\n0,1\n", TableFormat(), "no position column named 'position'", 1),
        ("position,deviation\n0,1\n1,x\n", TableFormat(), "deviation: expected a number", 3),
        ("position,deviation\n0,1\n1\n", TableFormat(), "expected at least 2 fields", 3),
        ("position,deviation\n0,1\n1,2\n2,3\n1,4\n0,5\n", TableFormat(),
         None, None),
        ("position,deviation,run\n0,1,a\n5,2,a\n3,2,a\n", TableFormat(), "goes back on itself", 4),
        ("position,deviation,run\n0,1,a\n0,2,a\n", TableFormat(), "read twice in one run", 3),
        ("position,deviation,run\n0,1,a\n", TableFormat(), "single reading", 2),
        ("position,deviation,direction\n0,1,+\n5,2,sideways\n", TableFormat(), "direction", 3),
        ("position,deviation,run,direction\n0,1,a,+\n5,2,a,-\n", TableFormat(), "both directions",
         2),
        ("0 1\n5 2\n", TableFormat(), "no header row: map the position column", 1),
        ("# only comments\n", TableFormat(), "no data rows", 1),
        ("position_mm,deviation_um\n0,1\n", TableFormat(deviation_unit="nm"),
         "declared as 'nm' but the header says 'um'", 1),
        ("a,b\n:START\n0,1\n", TableFormat(data_marker=":BEGIN"), "marker", 3),
    ],
)
def test_bad_tables(tmp_path, text, fmt, match, line):
    path = write(tmp_path, text)
    if match is None:  # a reversal without a run column starts a new run: not an error
        data = read_table(path, fmt).data
        np.testing.assert_array_equal(data.run_direction, [1, -1])
        return
    with pytest.raises(FormatError, match=match) as info:
        read_table(path, fmt)
    assert info.value.path == str(path)
    assert info.value.line == line


def test_column_map_from_plan_mapping():
    columns = ColumnMap.from_mapping({"position": "X", "deviation": 3})
    assert columns.position == "X" and columns.deviation == 3
    with pytest.raises(ValueError, match="unknown column key"):
        ColumnMap.from_mapping({"postion": "X"})
    with pytest.raises(ValueError, match="start at 1"):
        ColumnMap.from_mapping({"position": 0})
