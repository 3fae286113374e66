"""The Maestro driver against the emulated board on a real pty; backend selection; back-off."""

from __future__ import annotations

import math
import threading
import time

import pytest
import serial

from warpbridge import hw
from warpbridge.hw.base import Backoff, NullSensor, parse_serial_spec
from warpbridge.hw.errors import DeviceError
from warpbridge.hw.loop import LoopBackend
from warpbridge.hw.maestro import NO_REPLY, Maestro, error_names
from warpbridge.sitl.maestro_emu import PROTOCOL_ERROR, MaestroEmulator

# How long a read that expects an answer waits for it. The emulated board is a thread of this process, which a
# busy machine can starve for far longer than a real board's millisecond (the driver's default, 20 ms, is for
# that): the answer ends the wait, so a long one costs nothing when the board answers.
ANSWER_S = 2.0


class Board:
    """An emulated board recording the targets it receives; analog inputs from a dict."""

    def __init__(self, **kw):
        self.targets: list[tuple[int, int]] = []
        self.analog: dict[int, int] = {}
        self.emu = MaestroEmulator(
            on_target=lambda ch, q: self.targets.append((ch, q)), read_analog=self.analog.get, **kw
        )


@pytest.fixture
def board():
    b = Board()
    b.emu.start()
    yield b
    b.emu.stop()


@pytest.fixture
def maestro(board):
    m = Maestro(board.emu.device_path, limits={0: (1100.0, 1900.0)}, timeout=ANSWER_S)
    yield m
    m.close()


def test_targets_arrive_in_exact_quarter_microseconds(board, maestro):
    maestro.set_pulse(0, 1500.25)
    maestro.set_pulse(1, 1234.5)
    maestro.set_pulse(2, 1800.0)
    # the board answers in order, so once it answers, every target before has arrived
    assert maestro.read_pulse(2) == 1800.0
    assert board.targets == [(0, 6001), (1, 4938), (2, 7200)]
    assert maestro.read_pulse(0) == 1500.25


def test_set_target_bytes_follow_the_compact_protocol(board, maestro):
    maestro.set_pulse(3, 1500.25)  # 6001 = 0x1771: low 7 bits 0x71, high 7 bits 0x2E
    maestro.read_counts(3)
    assert bytes(board.emu.received[:4]) == bytes([0x84, 3, 0x71, 0x2E])
    assert bytes(board.emu.received[4:6]) == bytes([0x90, 3])


def test_pulses_are_rounded_to_quarter_microseconds(board, maestro):
    maestro.set_pulse(1, 1500.1)
    maestro.set_pulse(1, 1500.2)
    maestro.read_counts(1)
    assert board.targets == [(1, 6000), (1, 6001)]


def test_analog_inputs_come_back(board, maestro):
    board.analog[5] = 700
    board.analog[6] = 0
    assert maestro.read_counts(5) == 700.0
    assert maestro.read_counts(6) == 0.0
    board.analog[5] = 1023
    assert maestro.read_counts(5) == 1023.0


def test_error_bits_are_reported_named_and_cleared(board, maestro):
    board.emu.errors = 0x0011
    bits = maestro.poll_errors()
    assert bits == 0x0011
    assert maestro.error_names(bits) == ["serial signal error", "serial protocol error"]
    assert maestro.poll_errors() == 0


def test_error_names_cover_every_documented_bit():
    names = error_names(0x01FF)
    assert len(names) == 9 and names[-1] == "script program counter error"
    assert error_names(1 << 12) == ["bit 12"]
    assert error_names(NO_REPLY) == ["no reply"]


def test_pulses_are_clamped_to_the_channel_limits(board, maestro):
    maestro.set_pulse(0, 2500.0)
    maestro.set_pulse(0, 100.0)
    maestro.set_pulse(4, 2600.0)  # channel without own limits: default 1000..2000
    maestro.read_counts(4)
    assert board.targets == [(0, 1900 * 4), (0, 1100 * 4), (4, 2000 * 4)]


def test_non_finite_pulse_is_refused_and_nothing_written(board, maestro):
    with pytest.raises(ValueError):
        maestro.set_pulse(0, math.nan)
    with pytest.raises(ValueError):
        maestro.set_pulse(24, 1500.0)
    maestro.read_counts(0)
    assert board.targets == []


def test_bad_limits_are_refused(board):
    with pytest.raises(ValueError, match="channel 2"):
        Maestro(board.emu.device_path, limits={2: (1900.0, 1100.0)})


def test_silent_board_gives_none_not_a_hang(board):
    board.analog[5] = 512
    board.emu.mute = True
    with Maestro(board.emu.device_path) as maestro:  # the driver's default timeout
        assert maestro.read_counts(5) is None
        assert maestro.poll_errors() == NO_REPLY
        board.emu.mute = False
        assert answers_until(lambda: maestro.read_counts(5)) == 512.0  # once the lost answer is given up on


def answers_until(read, deadline_s: float = 5.0):
    """Call ``read`` until it gives a value (the driver gives None while a late answer is due)."""
    end = time.monotonic() + deadline_s
    while (v := read()) is None and time.monotonic() < end:
        time.sleep(0.005)
    return v


def test_a_late_answer_is_never_taken_for_the_next_query(board):
    """A board (or a starved emulator) answering after the read gave up: that answer is dropped.

    The board answers channel 5 once, 0.3 s late: after the driver gave up on it (0.2 s) and while
    the next query's answer is awaited. Neither that query nor any later may take the late 111."""
    board.analog.update({5: 111, 6: 666})
    slow = threading.Event()
    slow.set()

    def analog(ch):
        if ch == 5 and slow.is_set():
            slow.clear()
            time.sleep(0.3)
        return board.analog.get(ch)

    board.emu.read_analog = analog
    with Maestro(board.emu.device_path, timeout=0.2, late_answer_s=60.0) as m:
        assert m.read_counts(5) is None  # gave up
        assert m.read_counts(6) is None  # nothing is asked while the answer to 5 may still come
        assert answers_until(lambda: m.read_counts(6)) == 666.0
        assert m.read_counts(5) == 111.0
        assert m.poll_errors() == 0
        slow.set()
        assert m.read_counts(5) is None  # late again, and now the error poll comes before the answer:
        assert m.poll_errors() == 0  # it waits for the late answer instead of reporting a silent board


def test_an_answer_that_never_comes_is_given_up_on(board):
    board.analog[5] = 512
    with Maestro(board.emu.device_path, timeout=0.02, late_answer_s=0.1) as m:
        board.emu.mute = True  # the board drops the query
        assert m.read_counts(5) is None
        board.emu.mute = False
        assert answers_until(lambda: m.read_counts(5)) == 512.0


def test_garbage_on_the_line_is_flagged_and_the_next_command_works(board, maestro):
    board.analog[2] = 333
    maestro._write(bytes([0x05, 0x84, 0x01, 0xFF]))  # stray data byte, interrupted command
    assert maestro.read_counts(2) == 333.0
    assert maestro.poll_errors() & PROTOCOL_ERROR


def test_pololu_protocol_with_device_number(board):
    board.analog[1] = 901
    with Maestro(board.emu.device_path, device_number=12, timeout=ANSWER_S) as m:
        m.set_pulse(3, 1600.0)
        assert m.read_counts(1) == 901.0
        assert board.targets == [(3, 6400)]
    with Maestro(board.emu.device_path, device_number=5, timeout=0.01) as other:
        other.set_pulse(3, 1200.0)
        assert other.read_counts(1) is None  # addressed to another board: ignored
    assert board.targets == [(3, 6400)]


def test_port_lost_raises_device_error_then_reopen_works(board, maestro):
    board.analog[5] = 640
    board.emu.close_port()
    with pytest.raises(DeviceError):
        maestro.set_pulse(1, 1500.0)
    with pytest.raises(DeviceError):
        maestro.read_counts(5)
    assert not maestro.is_open
    with pytest.raises(DeviceError):
        maestro.reopen()  # the old pty is gone
    new_path = board.emu.reopen_port()
    maestro.reopen(new_path)
    maestro.set_pulse(1, 1500.0)
    assert maestro.read_counts(5) == 640.0
    assert board.targets[-1] == (1, 6000)


def test_replug_behind_a_stable_link_with_backoff(tmp_path):
    clock = [0.0]
    b = Board(link=tmp_path / "maestro")
    b.analog[0] = 100
    path = b.emu.start()
    try:
        m = Maestro(path, timeout=ANSWER_S)
        backoff = Backoff(initial_s=0.1, max_s=0.4, clock=lambda: clock[0])
        b.emu.close_port()
        with pytest.raises(DeviceError):
            m.read_counts(0)
        waits = []
        for _ in range(4):  # unplugged: each retry fails and the wait grows to max_s
            assert backoff.due()
            with pytest.raises(DeviceError):
                m.reopen()
            waits.append(backoff.failed())
            assert not backoff.due()
            clock[0] += waits[-1]
        assert waits == [0.1, 0.2, 0.4, 0.4]
        b.emu.reopen_port()
        assert backoff.due()
        m.reopen()  # same path: the link now points at the new pty
        backoff.succeeded()
        assert m.read_counts(0) == 100.0
        assert backoff.delay_s == 0.1
        m.close()
    finally:
        b.emu.stop()
    assert not (tmp_path / "maestro").exists()


def test_spy_url_dumps_the_traffic(board, tmp_path):
    board.analog[3] = 321
    log = tmp_path / "spy.txt"
    servo = hw.open_servo(f"maestro:spy://{board.emu.device_path}?file={log},115200,timeout={ANSWER_S:g}")
    servo.set_pulse(0, 1500.0)
    assert servo.read_counts(3) == 321.0
    servo.close()
    dump = log.read_text()
    assert "84 00 70 2E" in dump and "90 03" in dump and "41 01" in dump


def test_one_maestro_serves_servo_and_sensor(board):
    board.analog[6] = 250
    servo = hw.open_servo(f"maestro:{board.emu.device_path},timeout={ANSWER_S:g}", limits={0: (1200.0, 1800.0)})
    assert isinstance(servo, hw.ServoOutput)
    assert hw.open_sensor("maestro:", shared_servo=servo) is servo
    assert hw.open_sensor(f"maestro:{board.emu.device_path}", shared_servo=servo) is servo
    sensor = hw.open_sensor("maestro:", shared_servo=servo)
    assert isinstance(sensor, hw.WarpSensor)
    assert sensor.read_counts(6) == 250.0
    servo.set_pulse(0, 1900.0)
    sensor.read_counts(6)
    assert board.targets == [(0, 1800 * 4)]
    servo.close()


def test_missing_device_is_a_device_error(tmp_path):
    with pytest.raises(DeviceError, match="cannot open"):
        hw.open_servo(f"maestro:{tmp_path / 'ttyACM9'}")


@pytest.mark.parametrize(
    "text, expected",
    [
        ("/dev/ttyACM0", ("/dev/ttyACM0", 115200)),
        ("/dev/ttyAMA0,57600", ("/dev/ttyAMA0", 57600)),
        ("spy:///dev/ttyACM0?file=x.txt, 9600", ("spy:///dev/ttyACM0?file=x.txt", 9600)),
    ],
)
def test_serial_spec_parsing(text, expected):
    assert parse_serial_spec(text, 115200) == expected


@pytest.mark.parametrize("text", ["", "/dev/ttyACM0,fast", ",9600", "/dev/ttyACM0,0"])
def test_bad_serial_specs_are_refused(text):
    with pytest.raises(ValueError):
        parse_serial_spec(text, 115200)


@pytest.mark.parametrize("spec", ["nonsense", "can:/dev/can0", "none"])
def test_unknown_servo_specs_are_refused(spec):
    with pytest.raises(ValueError):
        hw.open_servo(spec)


def test_sensor_specs_none_and_errors():
    sensor = hw.open_sensor("none")
    assert isinstance(sensor, NullSensor) and sensor.read_counts(0) is None
    with pytest.raises(ValueError, match="Maestro"):
        hw.open_sensor("maestro:", shared_servo=None)
    with pytest.raises(ValueError):
        hw.open_sensor("wifi:thing")


def test_loop_backend_records_pulses_and_serves_counts():
    clock = [5.0]
    loop = hw.open_servo("loop:", clock=lambda: clock[0])
    assert isinstance(loop, LoopBackend)
    assert hw.open_sensor("loop:", shared_servo=loop) is loop
    loop.set_pulse(2, 1525.5)
    clock[0] = 6.0
    loop.set_pulse(2, 1530.0)
    assert loop.pulses[2] == (1530.0, 6.0)
    assert loop.history == [(5.0, 2, 1525.5), (6.0, 2, 1530.0)]
    assert loop.read_counts(0) is None
    loop.counts[0] = 400
    assert loop.read_counts(0) == 400.0
    loop.counts = lambda ch: 10.0 * ch
    assert loop.read_counts(3) == 30.0
    with pytest.raises(ValueError):
        loop.set_pulse(2, math.inf)


def test_loop_backend_simulates_loss_and_errors():
    loop = LoopBackend()
    loop.errors = 0b101
    assert loop.error_names(loop.poll_errors()) == ["bit 0", "bit 2"]
    assert loop.poll_errors() == 0
    loop.broken = True
    with pytest.raises(DeviceError):
        loop.set_pulse(0, 1500.0)
    with pytest.raises(DeviceError):
        loop.reopen()
    loop.broken = False
    loop.reopen()
    loop.set_pulse(0, 1500.0)
    assert loop.pulse(0) == 1500.0 and loop.reopen_count == 2


def test_backoff_rejects_bad_settings():
    with pytest.raises(ValueError):
        Backoff(initial_s=1.0, max_s=0.5)


def test_pyserial_exceptions_are_oserrors():
    # fc_outputs relies on this to map a lost serial MAVLink link to DeviceError
    assert issubclass(serial.SerialException, OSError)


def test_maestro_spec_takes_a_read_timeout(board):
    path = board.emu.device_path
    with hw.open_servo(f"maestro:{path},57600") as plain:
        assert (plain.timeout, plain.baudrate) == (0.02, 57600)
    with hw.open_servo(f"maestro:{path},timeout=0.3") as m:
        assert (m.timeout, m.baudrate) == (0.3, 115200)
        assert hw.open_sensor(f"maestro:{path},timeout=0.3", shared_servo=m) is m  # the same port
    for bad in ("timeout=x", "timeout=0", "timeout=20"):
        with pytest.raises(ValueError, match="timeout"):
            hw.open_servo(f"maestro:{path},{bad}")


def test_a_port_that_does_not_open_is_named_with_its_cause_once(tmp_path):
    """pyserial's text repeats the port and the errno; the error says the system's words for it once, and a
    resolver's error (negative errno) in its own words."""
    import socket

    from warpbridge.hw.base import open_error_text

    with pytest.raises(DeviceError) as e:
        Maestro(str(tmp_path / "ttyACM0"), 115200)
    assert str(e.value).endswith(f"cannot open {tmp_path / 'ttyACM0'}: No such file or directory")
    assert open_error_text(socket.gaierror(-2, "Name or service not known")) == "Name or service not known"


def test_a_port_one_bridge_has_open_is_refused_to_another_as_in_use(board, maestro, tmp_path):
    """Two configurations naming one board: the second process is told the port is in use, not left to
    interleave its bytes with the first's; the first's port still works, and a closed port opens again."""
    import subprocess
    import sys

    path = board.emu.device_path
    probe = ("import sys\nfrom warpbridge import hw\nfrom warpbridge.hw.errors import DeviceError\n"
             "try:\n    hw.open_servo(sys.argv[1]).close()\nexcept DeviceError as e:\n    print(e)\n"
             "    sys.exit(3)\n")
    other = subprocess.run([sys.executable, "-c", probe, f"maestro:{path}"], capture_output=True, text=True,
                           timeout=60)
    assert other.returncode == 3, other.stdout + other.stderr
    assert other.stdout.strip() == f"maestro: cannot open {path}: in use by another process (another bridge on " \
                                   "the same port?)"
    maestro.set_pulse(0, 1500.0)
    assert maestro.read_pulse(0) == 1500.0
    # a sensor naming the servo's board by another name (a /dev/serial/by-id link) shares its port
    link = tmp_path / "usb-Pololu_Maestro-if00"
    link.symlink_to(path)
    assert hw.open_sensor(f"maestro:{link}", shared_servo=maestro) is maestro
    assert hw.sensor_on_servo_port(f"maestro:{link}", f"maestro:{path}")  # lost and reopened with the servo
    maestro.close()
    again = subprocess.run([sys.executable, "-c", probe, f"maestro:{path}"], capture_output=True, text=True,
                           timeout=60)
    assert again.returncode == 0, again.stdout + again.stderr
