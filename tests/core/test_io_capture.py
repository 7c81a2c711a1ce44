"""Dynamic captures: the binary form and large CSV (chunked), round trips, binning onto targets
and bad files named by file and line."""

from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.capture import capture_line_data, read_capture, write_capture
from volucal.core.io.table import ColumnMap, TableFormat
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"


def sweep(rate_hz: float = 1000.0, step_mm: float = 10.0):
    """A forward and a backward sweep over 0…50 mm, pausing 0.2 s at every target, with a
    deviation of 0.1 µm per mm plus a reversal of ±1 µm."""
    position, direction = [], []
    dwell = int(0.2 * rate_hz)
    move = int(0.1 * rate_hz)
    targets = np.arange(0.0, 50.0 + step_mm / 2, step_mm)
    for sense, order in ((1, targets), (-1, targets[::-1])):
        for index, target in enumerate(order):
            position += [target] * dwell
            direction += [sense] * dwell
            if index + 1 < order.size:
                position += list(np.linspace(target, order[index + 1], move, endpoint=False))
                direction += [sense] * move
    position = np.asarray(position)
    deviation = 0.1 * position + np.asarray(direction) * 1.0
    time = np.arange(position.size) / rate_hz
    return time, position, deviation


def test_hand_written_binary_capture(tmp_path):
    """Bytes put together by hand from the format description, not by write_capture."""
    values = np.array([[0.0, 0.25], [0.5, 0.75], [1.0, 1.25]], dtype="<f8")
    head = (b"HEADER::\r\nSample rate: 2\r\nSample count: 3\r\nChannels: position_mm deviation\r\n"
            b"Units: nm\r\nStart time: 2026-01-01T00:00:00Z\r\nData:\r\n")
    path = tmp_path / "hand.rtx"
    path.write_bytes(head + values.tobytes() + b"\r\nEOF::\r\n")
    capture = read_capture(path)
    np.testing.assert_array_equal(capture.position_mm, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(capture.deviation, [0.25, 0.75, 1.25])
    np.testing.assert_array_equal(capture.time_s, [0.0, 0.5, 1.0])
    assert capture.unit == "nm" and capture.sample_rate_hz == 2.0
    assert capture.start_time == 1_767_225_600.0


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip(tmp_path, binary):
    time, position, deviation = sweep()
    path = tmp_path / ("c.rtx" if binary else "c.csv")
    write_capture(path, deviation, time_s=time, position_mm=position, unit="um",
                  start_time=1_767_225_600.0, binary=binary)
    capture = read_capture(path, chunk_bytes=4096)  # several chunks in the CSV case
    np.testing.assert_array_equal(capture.time_s, time)
    np.testing.assert_array_equal(capture.position_mm, position)
    np.testing.assert_array_equal(capture.deviation, deviation)
    assert capture.unit == "um"


def test_csv_capture_with_sample_rate_and_mapped_columns(tmp_path):
    path = tmp_path / "drift.txt"
    rows = "\n".join(f"{0.5 * i} {i % 7}" for i in range(20))
    path.write_text(f"# drift at a fixed point\nreading  dev_nm\n{rows}\n")
    fmt = TableFormat(columns=ColumnMap(deviation="reading"), deviation_unit="nm")
    capture = read_capture(path, fmt, sample_rate_hz=4.0, chunk_bytes=16)
    np.testing.assert_array_equal(capture.deviation, [0.5 * i for i in range(20)])
    np.testing.assert_array_equal(capture.time_s, np.arange(20) / 4.0)
    assert capture.position_mm is None and capture.unit == "nm"


def test_binning_a_sweep_onto_targets(tmp_path):
    time, position, deviation = sweep()
    path = tmp_path / "c.rtx"
    write_capture(path, deviation, time_s=time, position_mm=position)
    data = capture_line_data(read_capture(path), step_mm=10.0)
    np.testing.assert_array_equal(data.targets_mm, [0, 10, 20, 30, 40, 50])
    np.testing.assert_array_equal(data.run_direction, [1, -1])
    # at interior targets the samples moving in and out of the window balance: the forward run
    # reads 0.1·x + 1 and the backward run 0.1·x − 1 exactly
    inner = slice(1, 5)
    np.testing.assert_allclose(data.deviations[0, inner], 0.1 * data.targets_mm[inner] + 1.0)
    np.testing.assert_allclose(data.deviations[1, inner], 0.1 * data.targets_mm[inner] - 1.0,
                               atol=1e-12)
    # the turning visit (50 mm, where both dwells merge) belongs to the run that arrives there
    assert np.isfinite(data.deviations[0, 5]) and np.isnan(data.deviations[1, 5])
    # visits in travel order: the backward run reads 40 mm before 0 mm
    assert data.times_s[1, 4] < data.times_s[1, 0]


def test_binning_a_time_series():
    from volucal.core.io.capture import Capture

    time = np.arange(100) / 10.0
    capture = Capture(Path("x"), time, np.arange(100.0), None, "um")
    data = capture_line_data(capture, step_s=2.5)
    assert data.deviations.shape == (4, 1)
    np.testing.assert_allclose(data.deviations[:, 0], [12.0, 37.0, 62.0, 87.0])
    with pytest.raises(ValueError, match="step_mm"):
        capture_line_data(Capture(Path("x"), time, time, time, "um"))


# ---- bad files ------------------------------------------------------------------------------


def binary_file(tmp_path, count_text="3", payload=None, tail=b"\nEOF::\n") -> Path:
    values = np.arange(6, dtype="<f8") if payload is None else payload
    head = f"HEADER::\nSample rate: 10\nSample count: {count_text}\n" \
           "Channels: position_mm deviation\nUnits: um\nData:\n"
    path = tmp_path / "bad.rtx"
    path.write_bytes(head.encode() + values.tobytes() + tail)
    return path


@pytest.mark.parametrize(
    "kwargs, match, line",
    [
        ({"count_text": "4"}, "cut short or damaged", 6),
        ({"tail": b""}, "no EOF::", 6),
        ({"count_text": "x"}, "Sample count: expected a whole number", 3),
        ({"payload": np.array([0, 1, np.inf, 3, 4, 5], dtype="<f8")}, "sample 2", 6),
    ],
)
def test_bad_binary(tmp_path, kwargs, match, line):
    path = binary_file(tmp_path, **kwargs)
    with pytest.raises(FormatError, match=match) as info:
        read_capture(path)
    assert info.value.line == line and info.value.path == str(path)


def test_bad_csv_line_is_found_in_a_later_chunk(tmp_path):
    lines = [f"{i},{i * 0.1}" for i in range(50)]
    lines[37] = "37,oops"
    path = tmp_path / "c.csv"
    path.write_text("time_s,deviation_um\n" + "\n".join(lines) + "\n")
    with pytest.raises(FormatError, match="expected a number, found 'oops'") as info:
        read_capture(path, chunk_bytes=30)
    assert info.value.line == 39


def test_csv_capture_needs_times(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("deviation_um\n1\n2\n")
    with pytest.raises(FormatError, match="time column or a sample rate") as info:
        read_capture(path)
    assert info.value.line == 1


# ---- sizes and values: refused before anything is allocated ---------------------------------


def test_one_byte_short_is_refused(tmp_path):
    """The newline before EOF:: must not be read as data (it was: later values 1.3e294 µm)."""
    path = binary_file(tmp_path)
    raw = path.read_bytes()
    cut = raw.index(b"Data:\n") + len(b"Data:\n")
    path.write_bytes(raw[:cut] + raw[cut + 1:])  # one byte of the block lost
    with pytest.raises(FormatError, match="no EOF:: right after them") as info:
        read_capture(path)
    assert info.value.line == 6


def test_a_header_claiming_more_than_the_file_holds(tmp_path):
    for count in ("4", "100000000", "200000000"):
        path = binary_file(tmp_path, count_text=count)
        with pytest.raises(FormatError, match="cut short or damaged"):
            read_capture(path)
    path = binary_file(tmp_path, count_text="1000000000000")
    with pytest.raises(FormatError, match="Sample count 1000000000000 is outside"):
        read_capture(path)


def test_a_tiny_capture_spanning_a_kilometre_is_refused(tmp_path):
    """144 bytes, positions 0 and 1e9 mm: binned at 0.1 mm it asked for 7.45 GiB."""
    path = binary_file(tmp_path, count_text="3",
                       payload=np.array([0, 1, 1e9, 2, 0, 3], dtype="<f8"))
    with pytest.raises(FormatError, match=r"sample 2: position \(mm\) 1e\+09 is beyond"):
        read_capture(path)
    wide = binary_file(tmp_path, count_text="3",
                       payload=np.array([0, 1, 9e5, 2, 0, 3], dtype="<f8"))
    with pytest.raises(ValueError, match="more than the 100,000 targets"):
        capture_line_data(read_capture(wide), step_mm=0.1)


def test_values_no_laser_produces_in_captures(tmp_path):
    path = binary_file(tmp_path, payload=np.array([0, 1, 1, 1e300, 2, 0], dtype="<f8"))
    with pytest.raises(FormatError, match="sample 2: deviation"):
        read_capture(path)
    csv = tmp_path / "c.csv"
    csv.write_text("time_s,deviation_um\n0,1\n1,2\n0.5,3\n")
    with pytest.raises(FormatError, match="time goes back") as info:
        read_capture(csv)
    assert info.value.line == 4
    csv.write_text("time_s,deviation_um\n0,1\n1,2\n# a comment\n2,1e300\n")
    with pytest.raises(FormatError, match="deviation") as info:
        read_capture(csv)
    assert info.value.line == 5
    csv.write_text("time_s,deviation_um\n0,1\n1,\u00a02\n")
    with pytest.raises(FormatError, match="expected a number") as info:
        read_capture(csv)
    assert info.value.line == 3
    csv.write_text("time_s,deviation\n0,1\n1,2\n")
    with pytest.raises(FormatError, match="'deviation' has no unit"):
        read_capture(csv)


def test_binary_unit_must_agree_with_the_plan(tmp_path):
    path = binary_file(tmp_path)
    with pytest.raises(FormatError, match="Units: is 'um' but the deviation unit given is 'nm'"):
        read_capture(path, TableFormat(deviation_unit="nm"))
    path.write_bytes(path.read_bytes().replace(b"Units: um\n", b""))
    with pytest.raises(FormatError, match="no 'Units:' line"):
        read_capture(path)
    assert read_capture(path, TableFormat(deviation_unit="nm")).unit == "nm"
