"""plan.toml: reading, validation messages that name entry, field and line, writing, and the
import of every line into a Measurement."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.plan import (
    UNCERTAINTY_KEYS,
    import_plan,
    load_measurement,
    load_plan,
    plan_text,
    write_plan,
)
from volucal.core.io.rtl import read_rtl, write_rtl
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"
PLAN = DATA / "plan.toml"


def test_sample_plan():
    plan = load_plan(PLAN)
    assert plan.machine.name == "VMC-400"
    assert plan.machine.stroke("Z") == (-150.0, 0.0)
    assert plan.machine.screw_lead_mm == {"X": 16.0, "Y": 16.0, "Z": 10.0}
    names = [spec.name for spec in plan.lines]
    assert names == ["x_y0_z0", "x_pitch_hand", "y_straightness_x", "z_linear", "z_iso"]
    pitch = plan.lines[1]
    assert pitch.quantity == "angular" and pitch.deviation_unit == "urad"
    assert pitch.reflector_mm == (0.0, 0.0, 150.0)
    assert plan.lines[0].reflector_mm == (0.0, 0.0, 200.0)  # default: the tool offset
    assert Path(pitch.file) == (DATA / "x_pitch_hand.rta").resolve()
    z = plan.lines[3]
    assert z.sign == -1 and z.deviation_unit == "nm"
    assert z.reader == {"columns": {"position": 1, "deviation": 2}}
    assert plan.uncertainty == {"laser_ppm": 0.5, "air_temp_sensor_c": 0.1}
    assert plan.path == PLAN.resolve()


def test_write_plan_round_trip(tmp_path):
    plan = load_plan(copy_plan(tmp_path))
    (tmp_path / "sub").mkdir()
    write_plan(tmp_path / "sub" / "written.toml", plan)
    text = (tmp_path / "sub" / "written.toml").read_text()
    assert 'file = "../x_axis_hand.rtl"' in text  # relative to the written plan's folder
    # outside the plan's folder: read only with the user's explicit permission
    with pytest.raises(FormatError, match="outside the plan's folder"):
        load_plan(tmp_path / "sub" / "written.toml")
    back = load_plan(tmp_path / "sub" / "written.toml", files_root=tmp_path)
    folder = tmp_path / "sub"
    assert back.machine == plan.machine
    assert back.uncertainty == plan.uncertainty
    for a, b in zip(back.lines, plan.lines, strict=True):
        assert Path(a.file).name == Path(b.file).name
        assert (a.name, a.quantity, a.start_mm, a.direction, a.sensitive, a.reflector_mm,
                a.deviation_unit, a.sign, a.env_corrected, dict(a.reader)) == (
            b.name, b.quantity, b.start_mm, b.direction, b.sensitive, b.reflector_mm,
            b.deviation_unit, b.sign, b.env_corrected, dict(b.reader))
    assert plan_text(back, folder) == text


def test_import_orders_lines_by_time_and_converts():
    result = import_plan(load_plan(PLAN))
    measurement = result.measurement
    order = [line.name for line in measurement.lines]
    # the two tables without times start at 0 (1970); then Dec 12 10:46, Dec 12 11:30, Jan 5
    assert order == ["z_linear", "z_iso", "x_y0_z0", "y_straightness_x", "x_pitch_hand"]
    z = measurement.line("z_linear").data
    # nm, flipped by sign = -1: the file's -850 nm at -50 mm is +0.85 µm
    assert z.deviations[0, 2] == pytest.approx(0.85)
    imported = {line.name: line for line in result.lines}
    assert imported["z_linear"].raw.deviations[0, 2] == -850  # raw: as in the file
    assert imported["z_linear"].raw_unit == "nm"
    assert imported["z_linear"].corrections == ("deviations converted from nm to um",)
    assert "flipped" in imported["z_linear"].sign_convention
    assert imported["x_y0_z0"].source_bytes == (DATA / "x_axis_hand.rtl").read_bytes()
    assert result.flags == []
    assert measurement.uncertainty == {"laser_ppm": 0.5, "air_temp_sensor_c": 0.1}
    np.testing.assert_array_equal(measurement.line("x_y0_z0").data.deviations,
                                  read_rtl(DATA / "x_axis_hand.rtl").data.deviations)


def copy_plan(tmp_path, replace_from: str = "", replace_to: str = "") -> Path:
    for item in DATA.iterdir():
        if item.is_file():
            shutil.copy(item, tmp_path / item.name)
    text = PLAN.read_text()
    if replace_from:
        assert replace_from in text
        text = text.replace(replace_from, replace_to, 1)
    path = tmp_path / "plan.toml"
    path.write_text(text)
    return path


def test_env_corrected_false_applies_edlen_and_material(tmp_path):
    path = copy_plan(tmp_path, 'name = "x_y0_z0"\n', 'name = "x_y0_z0"\nenv_corrected = false\n')
    imported = {line.name: line for line in import_plan(load_plan(path)).lines}
    line = imported["x_y0_z0"]
    assert len(line.corrections) == 2
    shift = line.corrected.deviations - line.raw.deviations
    assert abs(shift[0, 0]) < 1e-6 and 1.2 < shift[0, 4] < 1.8  # see test_environment
    # the angular line is untouched by env_corrected = false
    path = copy_plan(tmp_path, 'file = "x_pitch_hand.rta"\n',
                     'file = "x_pitch_hand.rta"\nenv_corrected = false\n')
    pitch = {line.name: line for line in import_plan(load_plan(path)).lines}["x_pitch_hand"]
    assert pitch.corrections == () and "no effect" in pitch.notes[0]


def test_outliers_are_flagged_and_dropped_only_on_request(tmp_path):
    rng = np.random.default_rng(3)
    from volucal.core.io.rtl import reading_times
    from volucal.core.measurement import LineData

    runs, count = 10, 11
    direction = np.tile([1, -1], runs // 2)
    deviations = np.round(rng.normal(0, 0.3, (runs, count)), 4)
    deviations[0] -= deviations[0, 0]
    deviations[6, 5] += 12.0
    data = LineData(np.linspace(0, 400, count), deviations, direction,
                    reading_times(runs, count, 600.0, direction), start_time=1.7e9)
    path = copy_plan(tmp_path)
    write_rtl(tmp_path / "x_axis_hand.rtl", data)
    plan = load_plan(path)
    kept = import_plan(plan)
    assert [(f.line, f.run, f.target) for f in kept.flags] == [("x_y0_z0", 7, 6)]
    assert kept.measurement.line("x_y0_z0").data.deviations[6, 5] == deviations[6, 5]
    dropped = load_measurement(plan, screen_outliers="drop")
    assert np.isnan(dropped.line("x_y0_z0").data.deviations[6, 5])
    with pytest.raises(ValueError):
        load_measurement(plan, screen_outliers="maybe")


# ---- validation -----------------------------------------------------------------------------


def plan_error(tmp_path, old: str, new: str) -> FormatError:
    path = copy_plan(tmp_path, old, new)
    with pytest.raises(FormatError) as info:
        load_plan(path)
    assert info.value.path == str(path)
    return info.value


def line_number(path_text: str, fragment: str) -> int:
    for number, text in enumerate(path_text.splitlines(), start=1):
        if fragment in text:
            return number
    raise AssertionError(fragment)


@pytest.mark.parametrize(
    "old, new, message, entry, fragment",
    [
        ("direction = [1, 0, 0]\n", "direction = [0, 0, 0]\n",
         "[[line]] 1 ('x_y0_z0'), field 'direction': a zero-length vector", 1, "direction ="),
        ("sensitive = [1, 0, 0]", "sensitive = [0, 1, 0]",
         "[[line]] 3 ('y_straightness_x'), field 'sensitive': sensitive (0.0, 1.0, 0.0) must be "
         "perpendicular", 3, "sensitive ="),
        ('quantity = "linear"', 'quantity = "linar"',
         "[[line]] 1 ('x_y0_z0'), field 'quantity'", 1, "quantity ="),
        ("sign = -1", "sign = 2", "[[line]] 4 ('z_linear'), field 'sign'", 4, "sign ="),
        ("start = [0, 0, 0]", "start = [0, 0]", "field 'start': expected three numbers", 1,
         "start ="),
        ('file = "x_pitch_hand.rta"', 'file = "x_pitch_hand.rta"\ncolour = "red"',
         "[[line]] 2, field 'colour': unknown field", 2, "colour ="),
        ('name = "z_iso"', 'name = "x_y0_z0"', "[[line]] 5 ('x_y0_z0'), field 'name': the name "
         "is already used by [[line]] 1", 5, "name ="),
        ("laser_ppm = 0.5", "laser_ppm = -1", "[uncertainty], field 'laser_ppm'", None,
         "laser_ppm"),
        ("laser_ppm = 0.5", "laser_pm = 0.5", "[uncertainty], field 'laser_pm': unknown", None,
         "laser_pm"),
        ("Z = [-150, 0] }", "Z = [0, -150] }", "[machine], field 'stroke'", None, "stroke ="),
        ('chain = "WXYFZT"', 'chain = "WXQFZT"', "[machine], field 'chain'", None, "chain ="),
        ("columns = { position = 1, deviation = 2 }", "columns = { position = 1, dev = 2 }",
         "field 'columns': unknown column key(s) dev", 4, "columns ="),
        ('deviation_unit = "nm"', 'deviation_unit = "parsec"', "field 'deviation_unit'", 4,
         "deviation_unit ="),
        ('name = "z_linear"', 'name = "z/linear"', "field 'name': a name cannot contain '/'", 4,
         "name ="),
    ],
)
def test_validation_names_entry_field_and_line(tmp_path, old, new, message, entry, fragment):
    error = plan_error(tmp_path, old, new)
    assert message in error.reason, error.reason
    lines = (tmp_path / "plan.toml").read_text().splitlines()
    headers = [n for n, text in enumerate(lines, start=1) if text.strip() == "[[line]]"]
    after = headers[entry - 1] if entry else 0
    expected = next(n for n, text in enumerate(lines, start=1) if n > after and fragment in text)
    assert error.line == expected


def test_toml_syntax_error_names_the_line(tmp_path):
    error = plan_error(tmp_path, "laser_ppm = 0.5", "laser_ppm = = 0.5")
    assert error.reason.startswith("TOML syntax")
    assert error.line == line_number((tmp_path / "plan.toml").read_text(), "laser_ppm = =")


def test_required_fields_and_tables(tmp_path):
    error = plan_error(tmp_path, 'quantity = "straightness"\n', "")
    assert "[[line]] 3 ('y_straightness_x'): field 'quantity' is required" in error.reason
    error = plan_error(tmp_path, "[machine]", "[machin]")
    assert "unknown table or key machin" in error.reason
    assert UNCERTAINTY_KEYS["laser_ppm"]


def test_missing_file_names_entry_and_field(tmp_path):
    path = copy_plan(tmp_path)
    (tmp_path / "z_iso_hand.txt").unlink()
    with pytest.raises(FormatError) as info:
        import_plan(load_plan(path))
    assert "[[line]] 5 ('z_iso'), field 'file'" in info.value.reason
    assert info.value.line == line_number(path.read_text(), 'file = "z_iso_hand.txt"')


def test_unit_that_does_not_fit_the_quantity(tmp_path):
    path = copy_plan(tmp_path, 'deviation_unit = "nm"', 'deviation_unit = "nm"\nformat = "table"')
    plan = load_plan(path)
    assert plan.lines[3].reader["format"] == "table"
    path = copy_plan(tmp_path, 'file = "x_pitch_hand.rta"\nquantity = "angular"',
                     'file = "z_iso_hand.txt"\nquantity = "angular"')
    with pytest.raises(FormatError, match=r"\[\[line\]\] 2 \('z_iso_hand'\), field "
                       r"'deviation_unit': .* um \(a length\)"):
        import_plan(load_plan(path))


def test_data_file_errors_name_the_data_file(tmp_path):
    path = copy_plan(tmp_path)
    text = (tmp_path / "x_axis_hand.rtl").read_text().replace("Run-count: 4", "Run-count: x")
    (tmp_path / "x_axis_hand.rtl").write_text(text)
    with pytest.raises(FormatError) as info:
        import_plan(load_plan(path))
    assert info.value.path == str((tmp_path / "x_axis_hand.rtl").resolve())
    assert info.value.line == line_number(text, "Run-count")
