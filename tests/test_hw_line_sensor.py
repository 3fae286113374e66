"""The line-printing sensor board on a real pty: good lines, garbage, staleness, port loss."""

from __future__ import annotations

import os
import tty

import pytest

from warpbridge import hw
from warpbridge.hw.errors import DeviceError
from warpbridge.hw.line_sensor import LineSensor, parse_line


class Board:
    """The far end of a pty: what the microcontroller would print."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)

    def print(self, text: bytes | str) -> None:
        os.write(self.master, text.encode() if isinstance(text, str) else text)

    def unplug(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1


@pytest.fixture
def board():
    b = Board()
    yield b
    b.unplug()


@pytest.fixture
def clock():
    return [0.0]


@pytest.fixture
def sensor(board, clock):
    s = LineSensor(board.path, stale_s=0.1, clock=lambda: clock[0])
    yield s
    s.close()


def test_latest_value_per_channel(board, sensor):
    board.print("51")  # tail of a line cut off by opening the port: dropped
    board.print("2,498\n512,498\n")
    assert sensor.wait_for_lines(1, timeout=5)
    assert sensor.read_counts(0) == 512.0
    assert sensor.read_counts(1) == 498.0
    assert sensor.read_counts(2) is None
    board.print("600 601\r\n")
    assert sensor.wait_for_lines(2, timeout=5)
    assert (sensor.read_counts(0), sensor.read_counts(1)) == (600.0, 601.0)
    assert sensor.garbage_lines == 0


def test_garbage_lines_are_counted_and_skipped(board, sensor):
    board.print("skip\n100,200\n")
    assert sensor.wait_for_lines(1, timeout=5)
    board.print(b"hello\n1,x\nnan,3\n\xff\xfe\n\n" + b"9" * 300 + b"\n300,400\n")
    assert sensor.wait_for_lines(2, timeout=5)
    assert (sensor.read_counts(0), sensor.read_counts(1)) == (300.0, 400.0)
    # hello, 1,x, nan,3, the undecodable line, the overlong line (its rest is dropped too)
    assert sensor.garbage_lines == 5


def test_stale_readings_give_none(board, sensor, clock):
    board.print("skip\n700\n")
    assert sensor.wait_for_lines(1, timeout=5)
    clock[0] = 0.1
    assert sensor.read_counts(0) == 700.0
    clock[0] = 0.25
    assert sensor.read_counts(0) is None
    board.print("710\n")
    assert sensor.wait_for_lines(2, timeout=5)
    assert sensor.read_counts(0) == 710.0


def test_fixed_channel_count_rejects_short_lines(board, clock):
    with LineSensor(board.path, channels=2, clock=lambda: clock[0]) as s:
        board.print("skip\n1,2,3\n5\n10,20\n")
        assert s.wait_for_lines(1, timeout=5)
        assert (s.read_counts(0), s.read_counts(1)) == (10.0, 20.0)
        assert s.garbage_lines == 2


def test_port_lost_raises_then_reopen_works(board, sensor, clock):
    board.print("skip\n1,2\n")
    assert sensor.wait_for_lines(1, timeout=5)
    board.unplug()
    assert sensor.wait_for_lines(100, timeout=5)  # returns early: the reader saw the loss
    with pytest.raises(DeviceError):
        sensor.read_counts(0)
    replug = Board()
    try:
        sensor.reopen(replug.path)
        replug.print("skip\n42,43\n")
        assert sensor.wait_for_lines(2, timeout=5)
        assert sensor.read_counts(1) == 43.0
    finally:
        sensor.close()
        replug.unplug()


def test_open_sensor_spec(board):
    s = hw.open_sensor(f"line:{board.path},9600")
    try:
        assert isinstance(s, LineSensor) and s.baudrate == 9600
        assert isinstance(s, hw.WarpSensor)
    finally:
        s.close()


@pytest.mark.parametrize(
    "raw, expected",
    [
        (b"512,498\n", [512.0, 498.0]),
        (b" 512 , 498 \r\n", [512.0, 498.0]),
        (b"512\t498\t17\n", [512.0, 498.0, 17.0]),
        (b"512,\n", [512.0]),
        (b"-3.5\n", [-3.5]),
        (b"\n", None),
        (b"512;498\n", None),
        (b"inf,1\n", None),
        (b"\x00\x01\n", None),
    ],
)
def test_parse_line(raw, expected):
    assert parse_line(raw) == expected
