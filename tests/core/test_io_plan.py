"""plan.toml: reading, validation messages that name entry, field and line, writing, and the
import of every line into a Measurement."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.plan import (
    UNCERTAINTY_KEYS,
    import_line,
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


def test_a_line_placed_apart_from_its_file_s_positions_gets_a_note(tmp_path):
    # z_iso's table lists its targets at 0 … 180 mm, the plan starts it at Z = -180 mm: the
    # laser's own positions, perhaps, or a start copied from another line; the import says so.
    # The .rta of x_pitch_hand runs from 400 down to 0, started at X = 400 in the plan: the same
    # places, no note
    lines = {line.name: line for line in import_plan(load_plan(DATA / "plan.toml")).lines}
    (note,) = [n for n in lines["z_iso"].notes if "puts its targets" in n]
    assert "at 0 … 180 mm" in note and "at Z -180 … 0 mm" in note
    for name in ("x_y0_z0", "x_pitch_hand", "z_linear"):
        assert not [n for n in lines[name].notes if "puts its targets" in n], name
    # a start copied from the line before: x_y0_z0's readings moved to X = 100 … 500
    path = copy_plan(tmp_path, 'start = [0, 0, 0]\ndirection = [1, 0, 0]',
                     'start = [100, 0, 0]\ndirection = [1, 0, 0]')
    moved = {line.name: line for line in import_plan(load_plan(path)).lines}["x_y0_z0"]
    (note,) = [n for n in moved.notes if "puts its targets" in n]
    assert "at 0 … 400 mm" in note and "at X 100 … 500 mm" in note
    # or run the other way: the same span, reversed
    path = copy_plan(tmp_path, 'start = [0, 0, 0]\ndirection = [1, 0, 0]',
                     'start = [400, 0, 0]\ndirection = [-1, 0, 0]')
    reversed_ = {line.name: line for line in import_plan(load_plan(path)).lines}["x_y0_z0"]
    (note,) = [n for n in reversed_.notes if "puts its targets" in n]
    assert "at 0 … 400 mm" in note and "at X 400 … 0 mm" in note
    # a start 0.05 mm off (a capture's first sample, an inch table's rounding) or a beam 40 mrad
    # off the axis (the file's positions are distances along the beam) is no misplacement
    for start, direction in (("[0.05, 0, 0]", "[1, 0, 0]"), ("[0, 0, 0]", "[1, 0.04, 0]")):
        path = copy_plan(tmp_path, 'start = [0, 0, 0]\ndirection = [1, 0, 0]',
                         f"start = {start}\ndirection = {direction}")
        line = {line.name: line for line in import_plan(load_plan(path)).lines}["x_y0_z0"]
        assert not [n for n in line.notes if "puts its targets" in n], (start, direction)
    # the import wizard's preview reads a file with a proposed entry, not the plan's: no note
    z_iso = next(s for s in load_plan(DATA / "plan.toml").lines if s.name == "z_iso")
    assert not [n for n in import_line(z_iso).notes if "puts its targets" in n]


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


# ---- units: from the file, the plan or nowhere ---------------------------------------------


def test_a_file_without_a_unit_and_a_plan_without_one_is_refused(tmp_path):
    path = copy_plan(tmp_path, 'deviation_unit = "nm"\n', "")
    with pytest.raises(FormatError) as info:
        import_plan(load_plan(path))
    assert info.value.path == str((tmp_path / "z_linear_hand.txt").resolve())
    assert "deviation column number 2 has no unit" in info.value.reason
    assert "deviation_unit" in info.value.reason


def test_a_unit_that_contradicts_the_file_is_refused(tmp_path):
    # the .rtl format defines µm
    path = copy_plan(tmp_path, 'name = "x_y0_z0"\n', 'name = "x_y0_z0"\ndeviation_unit = "mm"\n')
    with pytest.raises(FormatError, match=r"\[\[line\]\] 1 \('x_y0_z0'\), field "
                       "'deviation_unit': the file is a Renishaw .rtl log, whose deviations are "
                       "in µm by definition, but the plan says mm"):
        import_plan(load_plan(path))
    # the CSV's header says deviation_um
    path = copy_plan(tmp_path, 'name = "y_straightness_x"\n',
                     'name = "y_straightness_x"\ndeviation_unit = "nm"\n')
    with pytest.raises(FormatError, match="declared as 'nm' .* says 'µm'") as info:
        import_plan(load_plan(path))
    assert info.value.path == str((tmp_path / "y_straightness_hand.csv").resolve())
    # agreeing is fine, and a plan that omits the unit leaves it to the file
    path = copy_plan(tmp_path, 'name = "x_y0_z0"\n', 'name = "x_y0_z0"\ndeviation_unit = "um"\n')
    plan = load_plan(path)
    assert plan.lines[0].deviation_unit_stated and not plan.lines[1].deviation_unit_stated
    import_plan(plan)
    assert 'deviation_unit = "um"' in plan_text(plan).split("[[line]]")[1]
    assert "deviation_unit" not in plan_text(plan).split("[[line]]")[2]


def test_real_flatness_file_through_a_plan(tmp_path, realdata):
    """The Aerotech flatness file: mm deviations, mmHg pressure, °C temperatures, all given in
    the plan; the pressure is stored as 97.9 kPa (it was 734 kPa)."""
    source = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    shutil.copy(source, tmp_path / source.name)
    entry = (f'[machine]\nstroke = {{ X = [-80, 80], Y = [0, 100], Z = [0, 100] }}\n\n'
             f'[[line]]\nname = "x_flat"\nfile = "{source.name}"\nquantity = "straightness"\n'
             'start = [-80, 0, 0]\ndirection = [1, 0, 0]\nsensitive = [0, 0, 1]\n'
             'data_marker = ":START"\ncolumns = { deviation = "Flat" }\n')
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(entry)
    with pytest.raises(FormatError, match="'Flat' has no unit"):
        import_plan(load_plan(plan_path))
    plan_path.write_text(entry + 'deviation_unit = "mm"\n')
    with pytest.raises(FormatError, match="'AirTemp' has no unit.*temperature_unit"):
        import_plan(load_plan(plan_path))
    plan_path.write_text(entry + 'deviation_unit = "mm"\ntemperature_unit = "C"\n'
                         'pressure_unit = "mmHg"\n')
    line = import_plan(load_plan(plan_path)).lines[0]
    assert line.raw_unit == "mm"
    assert line.corrected.deviations[0, 0] == pytest.approx(7.082)
    assert line.corrected.environment.air_pressure_kpa[0] == pytest.approx(97.899, abs=1e-3)
    assert line.corrected.environment.material_temp_c == ((20.40, 20.40),)


def test_an_angular_file_is_not_imported_as_linear(tmp_path, realdata):
    source = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Angular.dat"
    shutil.copy(source, tmp_path / source.name)
    plan_path = tmp_path / "plan.toml"
    base = (f'[machine]\nstroke = {{ X = [-80, 80], Y = [0, 100], Z = [0, 100] }}\n\n'
            f'[[line]]\nfile = "{source.name}"\nstart = [-80, 0, 0]\ndirection = [1, 0, 0]\n'
            'data_marker = ":START"\ncolumns = { deviation = "Pitch" }\n'
            'temperature_unit = "C"\n')
    plan_path.write_text(base + 'quantity = "linear"\ndeviation_unit = "um"\n')
    with pytest.raises(FormatError, match="'Pitch' holds an angle"):
        import_plan(load_plan(plan_path))
    plan_path.write_text(base + 'quantity = "linear"\n')
    with pytest.raises(FormatError, match="'Pitch' has no unit"):
        import_plan(load_plan(plan_path))
    plan_path.write_text(base + 'quantity = "angular"\nsensitive = [0, 1, 0]\n'
                         'deviation_unit = "arcsec"\n')
    line = import_plan(load_plan(plan_path)).lines[0]
    assert line.corrected.deviations[0, 0] == pytest.approx(9.601346 * 4.84813681109536)


# ---- the plan's files: inside its folder, regular, bounded ---------------------------------


def plan_with_file(tmp_path, file: str, extra: str = "") -> Path:
    folder = tmp_path / "plan"
    folder.mkdir(exist_ok=True)
    shutil.copy(DATA / "x_axis_hand.rtl", folder / "x.rtl")
    path = folder / "plan.toml"
    path.write_text('[machine]\nstroke = { X = [0, 400], Y = [0, 400], Z = [0, 400] }\n\n'
                    f'[[line]]\nname = "x"\nfile = "{file}"\nquantity = "linear"\n'
                    f'start = [0, 0, 0]\ndirection = [1, 0, 0]\n{extra}')
    return path


def refused(path: Path, match: str, files_root: Path | None = None) -> FormatError:
    with pytest.raises(FormatError, match=match) as info:
        import_plan(load_plan(path, files_root=files_root))
    return info.value


def test_files_outside_the_plan_folder_are_refused(tmp_path):
    outside = tmp_path / "outside.rtl"
    shutil.copy(DATA / "x_axis_hand.rtl", outside)
    for name in (str(outside), "../outside.rtl", "sub/../../outside.rtl"):
        error = refused(plan_with_file(tmp_path, name), "outside the plan's folder")
        assert error.path.endswith("plan.toml") and error.line == 6  # the file = line
        assert "--files-root" in error.reason
    link = tmp_path / "plan" / "inside.rtl"
    link.symlink_to(outside)
    refused(plan_with_file(tmp_path, "inside.rtl"), "resolves to .*outside.rtl.*, outside")
    # with the user's explicit permission
    plan = load_plan(plan_with_file(tmp_path, "../outside.rtl"), files_root=tmp_path)
    assert import_plan(plan).lines[0].readings == 20
    # a link that stays inside is followed
    (tmp_path / "plan" / "alias.rtl").symlink_to(tmp_path / "plan" / "x.rtl")
    assert import_plan(load_plan(plan_with_file(tmp_path, "alias.rtl"))).lines[0].readings == 20


def test_system_files_are_never_quoted(tmp_path):
    """/proc/self/environ named in a plan: refused as outside, as not a measurement file and,
    even when allowed and declared a table, as binary — never quoting the environment."""
    secret = "volucal-secret-9f3a"
    os.environ["VOLUCAL_TEST_SECRET"] = secret
    try:
        messages = [
            str(refused(plan_with_file(tmp_path, "/proc/self/environ"), "outside")),
            str(refused(plan_with_file(tmp_path, "/proc/self/environ"), "not named as a "
                        "measurement file", files_root=Path("/"))),
            str(refused(plan_with_file(tmp_path, "/proc/self/environ", 'format = "table"\n'
                                       'deviation_unit = "um"\n'),
                        "binary data", files_root=Path("/"))),
            str(refused(plan_with_file(tmp_path, "/etc/passwd", 'format = "table"\n'
                                       'deviation_unit = "um"\n'),
                        "not a row of column names", files_root=Path("/"))),
        ]
    finally:
        del os.environ["VOLUCAL_TEST_SECRET"]
    for message in messages:
        assert secret not in message and "PATH=" not in message
    assert "root" not in messages[-1] and "/bin/" not in messages[-1]


def test_fifos_devices_folders_and_huge_files_are_refused(tmp_path):
    import threading

    folder = tmp_path / "plan"
    folder.mkdir()
    os.mkfifo(folder / "pipe.csv")
    (folder / "dir.csv").mkdir()
    with open(folder / "sparse.csv", "wb") as handle:
        handle.truncate(2 << 30)
    (folder / "zero.csv").symlink_to("/dev/zero")
    cases = {"pipe.csv": "FIFO", "dir.csv": "a folder", "sparse.csv": "2,147,483,648 bytes",
             "zero.csv": "a device"}
    for name, match in cases.items():
        outcome: list[str] = []

        def attempt(name: str = name, outcome: list[str] = outcome) -> None:
            try:
                import_plan(load_plan(plan_with_file(tmp_path, name, 'deviation_unit = "um"\n'
                                                     'format = "table"\n'),
                                      files_root=Path("/")))
            except FormatError as error:
                outcome.append(str(error))

        worker = threading.Thread(target=attempt, daemon=True)
        worker.start()
        worker.join(10.0)  # a FIFO opened for reading would block forever
        assert outcome and match in outcome[0], (name, outcome)


def test_symlink_loop_as_the_plan_file(tmp_path):
    (tmp_path / "a.toml").symlink_to(tmp_path / "b.toml")
    (tmp_path / "b.toml").symlink_to(tmp_path / "a.toml")
    with pytest.raises(FormatError, match="a loop of symbolic links"):
        load_plan(tmp_path / "a.toml")


def test_a_file_not_named_as_a_measurement(tmp_path):
    folder = tmp_path / "plan"
    folder.mkdir()
    shutil.copy(DATA / "x_axis_hand.rtl", folder / "x.log")
    refused(plan_with_file(tmp_path, "x.log"), "not named as a measurement file")
    plan = load_plan(plan_with_file(tmp_path, "x.log", 'format = "rtl"\n'))
    assert import_plan(plan).lines[0].readings == 20
