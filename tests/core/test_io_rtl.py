"""Renishaw .rtl/.rta: the hand-written samples (from the format description, not our writer),
the writer's round trip, and bad files rejected with the file and line named."""

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.rtl import read_rtl, reading_times, write_rtl
from volucal.core.measurement import Environment, LineData
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"
HAND_RTL = DATA / "x_axis_hand.rtl"
HAND_RTA = DATA / "x_pitch_hand.rta"


def posix(text: str) -> float:
    return datetime.strptime(text, "%Y-%m-%d %H:%M").replace(tzinfo=UTC).timestamp()


def test_hand_written_rtl_is_keyed_on_target_number():
    log = read_rtl(HAND_RTL)
    data = log.data
    np.testing.assert_array_equal(data.targets_mm, [0, 100, 200, 300, 400])
    np.testing.assert_array_equal(data.run_direction, [1, -1, 1, -1])
    # run 2 is stored from target 5 down to 1, run 4 from 1 up to 5: both read by target number
    np.testing.assert_array_equal(data.deviations[1], [-1.8, 0.3, 2.5, 3.7, 6.2])
    np.testing.assert_array_equal(data.deviations[3], [-2.0, 0.1, 2.3, 3.9, 6.0])
    np.testing.assert_array_equal(data.deviations[0], [0.0, 2.1, 4.3, 5.9, 8.2])
    assert not log.angular and log.unit == "um"


def test_hand_written_rtl_times_environment_and_text():
    log = read_rtl(HAND_RTL)
    data = log.data
    assert log.start_time == data.start_time == posix("2016-12-12 10:46")
    assert log.end_time == posix("2016-12-12 11:06")
    # 20 minutes, 4 runs of 5 readings: one reading a minute, visits in travel order
    np.testing.assert_array_equal(data.times_s[0], [0, 60, 120, 180, 240])
    np.testing.assert_array_equal(data.times_s[1], [540, 480, 420, 360, 300])
    assert data.times_s.max() == 1140
    env = data.environment
    assert env.air_temp_c == (20.337280, 20.384956)
    assert env.air_pressure_kpa == (99.039005, 99.049346)
    assert env.air_humidity_pct == (46.954897, 46.893887)
    # sensors 2 and 3 read -10: unused
    assert env.material_temp_c == ((20.203292, 20.321342),)
    assert env.expansion_ppm_per_c == 11.5
    # per-reading air temperature interpolated over the file's time span
    assert data.air_temp_c[0, 0] == pytest.approx(20.33728)
    assert data.air_temp_c[3, 0] == pytest.approx(20.33728 + (20.384956 - 20.33728) * 1140 / 1200)
    assert data.metadata["machine"] == "VMC-400"
    assert data.metadata["axis"] == "X"
    assert log.user_text["TITLE"] == "X axis linear, Y=0 Z=0"
    assert log.header["Owner"] == "Renishaw"
    assert log.raw == HAND_RTL.read_bytes()


def test_hand_written_rta_with_descending_targets():
    log = read_rtl(HAND_RTA)
    data = log.data
    assert log.angular and log.unit == "urad"
    assert log.equipment == {"Optics": "angular"}
    # file targets 400, 200, 0: relative to the first, sorted ascending
    np.testing.assert_array_equal(data.targets_mm, [-400, -200, 0])
    np.testing.assert_array_equal(log.targets_file_mm, [400, 200, 0])
    # run 1 visits targets 1 -> 3, i.e. towards decreasing relative target
    np.testing.assert_array_equal(data.run_direction, [-1, 1])
    np.testing.assert_array_equal(data.deviations, [[6.8, 3.5, 0.0], [7.4, 3.9, 0.6]])
    np.testing.assert_array_equal(data.times_s, [[120, 60, 0], [180, 240, 300]])
    assert data.material_temp_c is None and data.environment.material_temp_c == ()


def test_sign_option_flips_the_deviations():
    plus = read_rtl(HAND_RTL).data.deviations
    minus = read_rtl(HAND_RTL, sign=-1).data.deviations
    np.testing.assert_array_equal(minus, -plus)
    with pytest.raises(ValueError):
        read_rtl(HAND_RTL, sign=2)


def test_reading_times_spread_each_run_over_its_slot():
    times = reading_times(2, 3, 60.0, np.array([1, -1]))
    np.testing.assert_array_equal(times, [[0, 10, 20], [50, 40, 30]])


def make_line(seed: int = 1, runs: int = 4, count: int = 7) -> LineData:
    rng = np.random.default_rng(seed)
    targets = np.sort(np.concatenate([[0.0], rng.uniform(1, 350, count - 2), [350.0]]))
    deviations = np.round(rng.normal(0, 3, (runs, count)), 4)
    directions = np.array([1 if r % 2 == 0 else -1 for r in range(runs)])
    times = reading_times(runs, count, 12.0 * runs * count, directions)
    return LineData(
        targets_mm=targets,
        deviations=deviations,
        run_direction=directions,
        times_s=times,
        start_time=1_767_225_600.0,
        environment=Environment(
            air_temp_c=(20.1, 20.23456789),
            air_pressure_kpa=(101.2, 101.25),
            air_humidity_pct=(45.0, 46.5),
            material_temp_c=((20.4, 20.9), (20.5, 21.0)),
            expansion_ppm_per_c=11.5,
        ),
        metadata={"machine": "VM-1", "serial": "VM-XL80-0001", "axis": "x_y0_z0"},
    )


@pytest.mark.parametrize("angular", [False, True])
def test_round_trip(tmp_path, angular):
    data = make_line()
    path = tmp_path / ("line.rta" if angular else "line.rtl")
    write_rtl(path, data, angular=angular)
    back = read_rtl(path)
    assert back.angular == angular
    np.testing.assert_array_equal(back.data.targets_mm, data.targets_mm)
    np.testing.assert_array_equal(back.data.deviations, data.deviations)
    np.testing.assert_array_equal(back.data.run_direction, data.run_direction)
    np.testing.assert_array_equal(back.data.times_s, data.times_s)
    assert back.data.start_time == data.start_time
    assert back.data.environment == data.environment
    assert dict(back.data.metadata) == dict(data.metadata)


def test_round_trip_with_first_target_offset_and_user_text(tmp_path):
    data = make_line(seed=3, runs=2, count=3)
    path = tmp_path / "line.rtl"
    write_rtl(path, data, first_target_mm=-150.0, user_text={"Machine": "M", "TITLE": "t"})
    back = read_rtl(path)
    np.testing.assert_array_equal(back.targets_file_mm, data.targets_mm - 150.0)
    np.testing.assert_array_equal(back.data.targets_mm, data.targets_mm)
    assert back.user_text["TITLE"] == "t" and back.user_text["Machine"] == "M"


def test_writer_refuses_what_the_format_cannot_hold(tmp_path):
    data = make_line()
    with pytest.raises(ValueError, match="alternating"):
        write_rtl(tmp_path / "a.rtl", LineData(data.targets_mm, data.deviations,
                                              np.array([1, 1, -1, -1]), data.times_s))
    broken = data.deviations.copy()
    broken[1, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_rtl(tmp_path / "b.rtl", LineData(data.targets_mm, broken, data.run_direction,
                                              data.times_s))


# ---- bad files ------------------------------------------------------------------------------


def edited(tmp_path, old: str, new: str, name: str = "bad.rtl") -> Path:
    text = HAND_RTL.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


def line_of(path: Path, fragment: str) -> int:
    for number, text in enumerate(path.read_text().splitlines(), start=1):
        if fragment in text:
            return number
    raise AssertionError(fragment)


def expect(path: Path, match: str, line: int) -> FormatError:
    with pytest.raises(FormatError, match=match) as info:
        read_rtl(path)
    assert info.value.path == str(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}, line {line}: ")
    return info.value


def test_truncated_file_names_the_missing_section(tmp_path):
    text = HAND_RTL.read_text()
    cut = text[: text.index("ENVIRONMENT::")]
    path = tmp_path / "cut.rtl"
    path.write_text(cut)
    last = len(cut.rstrip().splitlines())
    expect(path, "ENVIRONMENT:: section is missing", last)


def test_truncated_deviations(tmp_path):
    text = HAND_RTL.read_text()
    start = text.index("4  4     3.900")
    path = tmp_path / "cut.rtl"
    path.write_text(text[:start] + text[text.index("\n\nENVIRONMENT::"):])
    expect(path, r"18 deviation rows .* run 4, target 4 is missing",
           line_of(path, "4  3     2.300"))


def test_target_count_disagrees_with_targets(tmp_path):
    path = edited(tmp_path, "Target-count: 5", "Target-count: 6")
    expect(path, "Target-count says 6 targets but 5", line_of(path, "Target-count"))


def test_run_count_disagrees_with_rows(tmp_path):
    path = edited(tmp_path, "Run-count: 4", "Run-count: 3")
    expect(path, r"run 4 is outside 1…3", line_of(path, "4  1    -2.000"))


def test_repeated_row(tmp_path):
    path = edited(tmp_path, "3  5     8.400", "3  4     8.400")
    error = expect(path, "run 3, target 4 appears twice", line_of(path, "3  4     8.400"))
    assert "first at line" in error.reason


def test_odd_run_in_descending_order_contradicts_the_convention(tmp_path):
    text = HAND_RTL.read_text()
    rows = "\n".join(f"3  {t}     0.100" for t in (5, 4, 3, 2, 1))
    original = "\n".join(line for line in text.splitlines() if line.startswith("3  "))
    path = tmp_path / "bad.rtl"
    path.write_text(text.replace(original, rows))
    expect(path, "run 3 is odd", line_of(path, "3  5     0.100"))


def test_not_a_number(tmp_path):
    path = edited(tmp_path, "2  3     2.500", "2  3     2.5x0")
    expect(path, "deviation: expected a number, found '2.5x0'", line_of(path, "2.5x0"))


def test_end_before_start(tmp_path):
    path = edited(tmp_path, '"11:06 Dec 12 2016"', '"10:06 Dec 12 2016"')
    expect(path, "end is before the start", line_of(path, "Date Time"))


def test_unreadable_date(tmp_path):
    path = edited(tmp_path, '"11:06 Dec 12 2016"', '"soon"')
    expect(path, "Date Time", line_of(path, "Date Time"))


def test_targets_not_monotonic(tmp_path):
    path = edited(tmp_path, "200.000000  300.000000", "300.000000  200.000000")
    expect(path, "strictly increasing or strictly decreasing", line_of(path, "Targets :"))


def test_text_before_the_first_section(tmp_path):
    path = tmp_path / "junk.rtl"
    path.write_text("hello\n" + HAND_RTL.read_text())
    expect(path, "not a Renishaw", 1)


def test_missing_file_names_it(tmp_path):
    with pytest.raises(FormatError, match="file not found"):
        read_rtl(tmp_path / "absent.rtl")


# ---- values a laser cannot produce, loose numbers, sizes ------------------------------------


@pytest.mark.parametrize(
    "old, new, match, fragment",
    [
        ("2  3     2.500", "2  3     1e300", r"deviation 1e\+300 is beyond ±1e\+06", "1e300"),
        ("2  3     2.500", "2  3     1e999", "beyond the range of a number", "1e999"),
        ("2  3     2.500", "2  3     2_500", "expected a number, found '2_500'", "2_500"),
        ("2  3     2.500", "2  3     \u0662.500", "expected a number", "\u0662.500"),
        ("2  3     2.500", "2  3     \uff12.500", "expected a number", "\uff12.500"),
        ("2  3     2.500", "2  3     nan", "expected a number", "nan"),
        ("2  3     2.500", "\u0662  3     2.500", "run number: expected a whole number",
         "\u0662  3"),
        ("2  3     2.500", "2.0  3     2.500", "run number: expected a whole number", "2.0  3"),
        ("400.000000", "1e308", "target position", "1e308"),
        ("100.000000", "0.00001", "at least 0.0001 mm apart", "Targets :"),
        ("100.000000", "0.000000", "strictly increasing", "Targets :"),
        ("Air press  : 99.039005", "Air press  : 734.31", "Air press", "Air press"),
        ("Exp coeff  : 11.500000", "Exp coeff  : 1e9", "Exp coeff", "Exp coeff"),
    ],
)
def test_values_no_laser_produces(tmp_path, old, new, match, fragment):
    path = tmp_path / "bad.rtl"
    path.write_text(HAND_RTL.read_text().replace(old, new, 1), encoding="utf-8")
    lines = path.read_text(encoding="utf-8").splitlines()
    line = next(n for n, text in enumerate(lines, start=1) if fragment in text)
    expect(path, match, line)


def test_a_small_file_cannot_claim_a_huge_grid(tmp_path):
    """100,000 targets listed (an 800 KB file) and Run-count 1,000: 10⁸ readings claimed, refused
    from the counts before an array of that size exists (it took 4 GB; the peak memory of such
    imports is measured by benchmarks/bench_fuzz.py)."""
    text = HAND_RTL.read_text()
    targets = "\n".join(f"{i * 0.01:.2f}" for i in range(100_000))
    text = text.replace("Target-count: 5", "Target-count: 100000").replace(
        "  0.000000  100.000000  200.000000  300.000000  400.000000", targets).replace(
        "Run-count: 4", "Run-count: 1000")
    path = tmp_path / "huge.rtl"
    path.write_text(text)
    assert path.stat().st_size < 1_000_000
    expect(path, r"Run-count 1000 × Target-count 100000 = 100,000,000 readings, beyond the "
           "2,000,000", line_of(path, "DEVIATIONS::"))


def test_devices_fifos_and_folders_are_refused(tmp_path):
    import os
    import threading

    for path, kind in ((Path("/dev/zero"), "a device"), (tmp_path, "a folder")):
        with pytest.raises(FormatError, match=f"is {kind}, not a measurement file"):
            read_rtl(path)
    fifo = tmp_path / "pipe.rtl"
    os.mkfifo(fifo)
    outcome: list[str] = []

    def attempt() -> None:
        try:
            read_rtl(fifo)
        except FormatError as error:
            outcome.append(error.reason)

    worker = threading.Thread(target=attempt, daemon=True)
    worker.start()
    worker.join(5.0)  # a blocking open would never return
    assert outcome == ["is a FIFO (named pipe), not a measurement file"]


def test_a_loop_of_symbolic_links(tmp_path):
    (tmp_path / "a.rtl").symlink_to(tmp_path / "b.rtl")
    (tmp_path / "b.rtl").symlink_to(tmp_path / "a.rtl")
    with pytest.raises(FormatError, match="a loop of symbolic links"):
        read_rtl(tmp_path / "a.rtl")


def test_a_file_beyond_the_size_limit_is_not_read(tmp_path):
    """A 2 GB sparse file: refused from its size, before a byte is read."""
    path = tmp_path / "sparse.rtl"
    with open(path, "wb") as handle:
        handle.truncate(2 << 30)
    with pytest.raises(FormatError, match="is 2,147,483,648 bytes; volucal reads files of up to "
                       "67,108,864 bytes"):
        read_rtl(path)


def test_binary_content_is_refused_without_quoting_it(tmp_path):
    path = tmp_path / "env.rtl"
    path.write_bytes(b"HEADER::\nSECRET=hunter2\x00PATH=/usr/bin\x00")
    with pytest.raises(FormatError) as info:
        read_rtl(path)
    assert "binary data" in info.value.reason and "hunter2" not in str(info.value)
