"""Generic tables with a column map: hand-written samples, a real vendor export, the writer's
round trip and bad input named by file and line."""

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.rtl import reading_times
from volucal.core.io.table import ColumnMap, cluster_targets, read_table, write_table
from volucal.core.io.table import TableFormat as ReadAlone
from volucal.core.measurement import LineData
from volucal.core.userror import FormatError


def TableFormat(**options: object) -> ReadAlone:  # noqa: N802
    """The reader as a plan sets it up: plan.toml states lengths in mm, so a position column
    without a unit is in mm (a table read alone has no such default: see the test below)."""
    options.setdefault("position_unit_default", "mm")
    return ReadAlone(**options)  # type: ignore[arg-type]


def test_a_table_read_alone_asks_for_the_unit_of_its_positions(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("position,deviation_um\n0,1\n5,2\n", encoding="utf-8")
    with pytest.raises(FormatError) as error:
        read_table(path, ReadAlone())
    message = str(error.value)
    assert str(path) in message and "line 1" in message
    assert "'position' has no unit" in message and "position_unit" in message
    assert read_table(path, ReadAlone(position_unit="inch")).data.targets_mm[1] == 5 * 25.4

DATA = Path(__file__).resolve().parents[1] / "data" / "io"


def test_csv_with_header_run_direction_time_and_air():
    table = read_table(DATA / "y_straightness_hand.csv", TableFormat())
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
    fmt = TableFormat(columns=ColumnMap(position=1, deviation=2), deviation_unit="nm")
    table = read_table(DATA / "z_linear_hand.txt", fmt)
    data = table.data
    assert table.unit == "nm"  # the file does not say: the declared unit (the plan's) applies
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
    path.write_text("position,deviation_um,time\n0,0,2020-01-01T00:00:00Z\n"
                    "5,1,2020-01-01T00:00:30Z\n")
    data = read_table(path, TableFormat()).data
    assert data.start_time == datetime(2020, 1, 1, tzinfo=UTC).timestamp()
    np.testing.assert_array_equal(data.times_s, [[0, 30]])


def test_real_vendor_flatness_export(realdata):
    """Aerotech flatness export: header above a ':START' marker, values in mm, pressure in
    mmHg; AirTemp, MatTemp, Pressure and Humidity are found by their vendor names."""
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    fmt = TableFormat(columns=ColumnMap(deviation="Flat"), deviation_unit="mm",
                      pressure_unit="mmHg", temperature_unit="C", data_marker=":START")
    table = read_table(path, fmt)
    data = table.data
    assert data.targets_mm.size == 33 and data.runs == 1
    np.testing.assert_array_equal(data.targets_mm, np.arange(0, 161, 5))
    assert data.deviations[0, 0] == 0.007082 and table.unit == "mm"
    assert data.environment.air_humidity_pct == (54.07, 54.19)
    assert data.material_temp_c[0, 0] == 20.40 and data.air_temp_c[0, 0] == 20.38
    # 734.31 mmHg = 97.90 kPa (101.325 kPa = 760 mmHg), never "734 kPa"
    low, high = data.environment.air_pressure_kpa
    assert low == high == pytest.approx(734.31 * 101.325 / 760, abs=1e-9)
    assert data.metadata["pressure_unit_in_file"] == "mmHg"


def test_real_vendor_files_without_units_ask_for_them(realdata):
    """The Aerotech files state no unit: each missing one is an error naming the file, the
    header line and the column — never a default."""
    flatness = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    base = {"columns": ColumnMap(deviation="Flat"), "data_marker": ":START"}
    cases = [
        ({}, "'Flat' has no unit"),
        ({"deviation_unit": "mm"}, "'AirTemp' has no unit"),
        ({"deviation_unit": "mm", "temperature_unit": "C"}, "'Pressure' has no unit"),
        ({"deviation_unit": "mm", "temperature_unit": "C", "pressure_unit": "kPa"},
         "734.31 kPa cannot be air pressure"),
        ({"deviation_unit": "mm", "temperature_unit": "F", "pressure_unit": "mmHg"},
         "air temperature"),
        ({"deviation_unit": "arcsec", "temperature_unit": "C", "pressure_unit": "mmHg"},
         "line 14 says this is a length measurement"),
    ]
    for options, message in cases:
        with pytest.raises(FormatError, match=message) as info:
            read_table(flatness, TableFormat(**base, **options))
        assert info.value.path == str(flatness) and info.value.line is not None
    angular = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Angular.dat"
    with pytest.raises(FormatError, match="'Pitch' has no unit"):
        read_table(angular, TableFormat(columns=ColumnMap(deviation="Pitch"),
                                        data_marker=":START", environment=False))
    with pytest.raises(FormatError, match="holds an angle, but its unit is µm"):
        read_table(angular, TableFormat(columns=ColumnMap(deviation="Pitch"), deviation_unit="um",
                                        data_marker=":START", environment=False))
    table = read_table(angular, TableFormat(columns=ColumnMap(deviation="Pitch"),
                                            deviation_unit="arcsec", data_marker=":START",
                                            temperature_unit="C"))
    assert table.unit == "arcsec" and table.data.deviations[0, 0] == 9.601346


def test_real_header_with_a_spaced_name(realdata):
    """'Position     Lower Data     Temperature': three columns, not four; deviation=Data is
    not a column (today's misreading took the temperature), 'Lower Data' is."""
    path = realdata / "aerotech_flatness_angular" / "519742-01-Lower_Flatness.dat"
    with pytest.raises(FormatError, match="no deviation column named 'Data'; the header has "
                       "'Position', 'Lower Data', 'Temperature'") as info:
        read_table(path, TableFormat(columns=ColumnMap(deviation="Data"), deviation_unit="um",
                                     data_marker=":START", environment=False))
    assert info.value.line == 42
    table = read_table(path, TableFormat(columns=ColumnMap(deviation="Lower Data"),
                                         deviation_unit="um", data_marker=":START",
                                         environment=False))
    assert table.header == ("Position", "Lower Data", "Temperature")
    assert table.data.deviations[0, 0] == -0.89 and table.data.deviations[0, -1] == -2.45


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
    # time moves on in the order the machine visits the targets, at uneven steps
    visits = reading_times(runs, count, 1000.0, data.run_direction)
    data = LineData(data.targets_mm, data.deviations, data.run_direction,
                    visits + rng.uniform(0, 0.5, (runs, count)), data.start_time,
                    air_temp_c=data.air_temp_c, material_temp_c=data.material_temp_c)
    path = tmp_path / "line.csv"
    write_table(path, data)
    back = read_table(path, TableFormat()).data
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
        ("x,y_um\n0,1\n", TableFormat(), "no position column named 'position'", 1),
        ("position,deviation_um\n0,1\n1,x\n", TableFormat(), "deviation: expected a number", 3),
        ("position,deviation_um\n0,1\n1\n", TableFormat(), "expected 2 fields as in the header",
         3),
        ("position,deviation_um\n0,1\n1,2,3\n", TableFormat(), "expected 2 fields", 3),
        ("position,deviation_um\n0,1\n1,2\n2,3\n1,4\n0,5\n", TableFormat(),
         None, None),
        ("position,deviation_um,run\n0,1,a\n5,2,a\n3,2,a\n", TableFormat(),
         "goes back on itself", 4),
        ("position,deviation_um,run\n0,1,a\n0,2,a\n", TableFormat(), "read twice in one run", 3),
        ("position,deviation_um,run\n0,1,a\n", TableFormat(), "single reading", 2),
        ("position,deviation_um,direction\n0,1,+\n5,2,sideways\n", TableFormat(), "direction", 3),
        ("position,deviation_um,run,direction\n0,1,a,+\n5,2,a,-\n", TableFormat(),
         "both directions", 2),
        ("0 1\n5 2\n", TableFormat(deviation_unit="um"), "no header row: map the position column",
         1),
        ("# only comments\n", TableFormat(), "no data rows", 1),
        ("position_mm,deviation_um\n0,1\n", TableFormat(deviation_unit="nm"),
         "declared as 'nm' \\(deviation_unit\\) but the header 'deviation_um' says 'µm'", 1),
        ("a,b\n:START\n0,1\n", TableFormat(data_marker=":BEGIN"), "marker", 3),
        # units: never assumed
        ("position,deviation\n0,1\n5,2\n", TableFormat(), "'deviation' has no unit", 1),
        ("position,deviation_um,time\n0,1,0\n5,2,1\n", TableFormat(), "'time' has no unit", 2),
        ("position,deviation_um,pressure\n0,1,99\n5,2,99\n", TableFormat(),
         "'pressure' has no unit", 1),
        ("position,deviation_um,air_temp\n0,1,20\n5,2,20\n", TableFormat(),
         "'air_temp' has no unit", 1),
        ("position,deviation_um,pressure_kpa\n0,1,734\n5,2,734\n", TableFormat(),
         "734 kPa cannot be air pressure", 2),
        ("position,deviation_um,pressure_kpa\n0,1,99\n5,2,99\n", TableFormat(pressure_unit="hPa"),
         "declared as 'hPa'", 1),
        ("position,yaw_um\n0,1\n5,2\n", TableFormat(columns=ColumnMap(deviation="yaw")),
         "holds an angle", 1),
        ("TestType : Angular\n:START\nposition deviation\n0 1\n5 2\n",
         TableFormat(deviation_unit="mm", data_marker=":START"), "angular measurement", 1),
        # the header and the rows agree, names are unique, mapped names exist exactly
        ("position deviation_um temperature\n0 1\n5 2\n", TableFormat(),
         "header \\(line 1\\) has 3 name\\(s\\) but the data rows have 2", 1),
        ("position,deviation_um,deviation_nm\n0,1,2\n5,2,3\n", TableFormat(),
         "2 columns could be the deviation", 1),
        ("position,deviation_um\n0,1\n5,2\n", TableFormat(columns=ColumnMap(position=1,
                                                                             deviation=1)),
         "mapped as both", 1),
        ("JobName : x\n\n:START\n0 1\n", TableFormat(deviation_unit="um"),
         "data seem to start after line 3 \\(':START'\\): give data_marker", 3),
        # values a laser cannot produce, and loose numbers
        ("position,deviation_um\n0,1\n5,1e300\n", TableFormat(), "beyond ±1e\\+06", 3),
        ("position_m,deviation_um\n0,1\n1e306,1\n", TableFormat(),
         "position \\(mm\\) overflows once converted", 3),
        ("position,deviation_mm\n0,1\n5,1e307\n", TableFormat(), "beyond", 3),
        ("position,deviation_um\n0,1\n1e999,1\n", TableFormat(), "beyond the range", 3),
        ("position,deviation_um\n0,1\n5,1_000\n", TableFormat(), "expected a number", 3),
        ("position,deviation_um\n0,1\n5,\u0661\n", TableFormat(), "expected a number", 3),
        ("position,deviation_um\n0,1\n5,\uff11\n", TableFormat(), "expected a number", 3),
        ("position,deviation_um\n0,1\n5,\u00a01\n", TableFormat(), "expected a number", 3),
        ("position,deviation_um\n0,1\n5,nan\n", TableFormat(), "expected a number", 3),
        ("position,deviation_um,time_s\n0,1,5\n5,2,4\n", TableFormat(), "time goes back", 3),
        ("position,deviation_um,humidity\n0,1,120\n5,2,50\n", TableFormat(), "humidity", 2),
    ],
)
def test_bad_tables(tmp_path, text, fmt, match, line):
    path = write(tmp_path, text)
    path.write_text(text, encoding="utf-8")
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


def test_quoted_header_names(tmp_path):
    path = tmp_path / "q.csv"
    path.write_text('"Position [mm]","Lower, Data [um]",Temperature\n0,1,20\n5,2,20\n')
    table = read_table(path, TableFormat(columns=ColumnMap(deviation="Lower, Data"),
                                         environment=False))
    assert table.header == ("Position [mm]", "Lower, Data [um]", "Temperature")
    np.testing.assert_array_equal(table.data.deviations, [[1, 2]])
    path.write_text('Position "Lower Data" Temperature\n0 1 20\n5 2 20\n')
    table = read_table(path, TableFormat(columns=ColumnMap(deviation="Lower Data"),
                                         deviation_unit="um", environment=False))
    np.testing.assert_array_equal(table.data.deviations, [[1, 2]])


def test_header_after_the_marker(tmp_path):
    path = tmp_path / "after.dat"
    path.write_text("JobName : probe\nIgnored\n:START\nPosition  Flat [um]\n0 1\n5 2\n")
    table = read_table(path, TableFormat(columns=ColumnMap(deviation="Flat"),
                                         data_marker=":START"))
    assert table.header == ("Position", "Flat [um]") and table.unit == "um"
    np.testing.assert_array_equal(table.data.deviations, [[1, 2]])


def test_vendor_environment_names_and_units(tmp_path):
    path = tmp_path / "env.csv"
    path.write_text("Position [in],Error [um],AirTemp [F],MatTemp [C],Air Prs [inHg],Air Hmd\n"
                    "0,1,68,20.5,29.92,40\n1,2,69.8,20.5,29.92,41\n")
    data = read_table(path, TableFormat(columns=ColumnMap(deviation="Error"))).data
    np.testing.assert_allclose(data.targets_mm, [0, 25.4])
    np.testing.assert_allclose(data.air_temp_c, [[20.0, 21.0]])
    np.testing.assert_allclose(data.environment.air_pressure_kpa,
                               (29.92 * 3.386389, 29.92 * 3.386389))
    assert data.environment.air_humidity_pct == (40, 41)


def test_a_small_table_cannot_claim_a_huge_grid(tmp_path):
    """One run per row: 3,000 rows would make 3,000 runs × 3,000 targets (72 MB per array,
    3.35 GB at the issue's size); refused before the grid exists."""
    rows = "\n".join(f"{i},{i},{i}" for i in range(3000))
    path = tmp_path / "many.csv"
    path.write_text("position,deviation_um,run\n" + rows + "\n")
    with pytest.raises(FormatError, match="3,000 runs × 3,000 targets = 9,000,000 readings, "
                       "beyond the 2,000,000") as info:
        read_table(path, TableFormat())
    assert info.value.line == 3001


def test_rows_may_leave_out_empty_trailing_cells_with_a_delimiter(tmp_path, realdata):
    """The vendor's "Linear Error Plot" export: tab-separated, its last column ("Out of spec.")
    empty and left out of every row. Its straightness is the flatness file's."""
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_CalData.dat"
    fmt = TableFormat(columns=ColumnMap(position="Target Value", deviation="Error Value",
                                        run="Run #"),
                      deviation_unit="um", data_marker="Sorted by\tposition number")
    data = read_table(path, fmt).data
    assert data.targets_mm.size == 33 and data.deviations[0, 1] == -3.35552e-01
    # but not a column that is read, and never in a blank-separated file
    csv = tmp_path / "short.csv"
    csv.write_text("position,deviation_um,note\n0,1\n5\n")
    with pytest.raises(FormatError, match="expected 3 fields") as info:
        read_table(csv, TableFormat())
    assert info.value.line == 3
    csv.write_text("position deviation_um note\n0 1\n5 2\n")
    with pytest.raises(FormatError, match="has 3 name"):
        read_table(csv, TableFormat())
