"""Reading the flight controller's logs: DataFlash, tlog and ULog (``bridge.commands.fclog``).

The real logs are in tests/data (README.md there says how each was made): a flight of the real
ArduPlane 4.6.3 SITL with the bridge on its SERIAL1 (its DataFlash log and the ground station's tlog)
and pyulog's own PX4 sample log. The PX4 sample has no ``debug_key_value`` topic; the test that reads
one writes it into a copy of the real log with pyulog's writer, and the tlog's clock handling is
checked on a tlog written here with pymavlink, whose stamps are known.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from warpbridge.bridge.commands.fclog import FcLog, fc_log_format, read_fc_log
from warpbridge.bridge.commands.logfile import read_log
from warpbridge.bridge.errors import UserError
from warpbridge.bridge.mavlink_env import mavlink

DATA = Path(__file__).parent / "data"
BIN = DATA / "arduplane-flight.BIN"
TLOG = DATA / "arduplane-flight.tlog"
ULG = DATA / "px4-sample_log_small.ulg"
BRIDGE_NAMES = {"L_sp", "R_sp", "L_warp", "R_warp", "L_cmd", "R_cmd", "L_ff", "R_ff", "L_pi", "R_pi", "WB_mode",
                "WB_aspd", "WB_lat"}


@pytest.fixture(scope="module")
def dataflash() -> FcLog:
    return read_fc_log(BIN)


def test_format_follows_the_suffix():
    assert fc_log_format("a/00000012.BIN") == "dataflash"
    assert fc_log_format("x.tlog") == "tlog" and fc_log_format("x.ulg") == "ulog"
    assert fc_log_format("cycles.csv") is None


def test_arduplane_dataflash_log_holds_the_bridges_named_values(dataflash):
    fc = dataflash
    assert fc.fmt == "dataflash" and fc.autopilot == "ardupilot"
    assert BRIDGE_NAMES <= set(fc.named), sorted(fc.named)
    # the bridge sends each name at its telemetry rate, 10 Hz (WB_TLM_HZ)
    assert fc.named["L_sp"].rate_hz == pytest.approx(10.0, rel=0.15)
    # ArduPlane's SERVO1_FUNCTION 4 (aileron), from the PARM messages
    assert fc.aileron_channels == [1] and fc.params["SERVO1_FUNCTION"] == 4
    ail = fc.output(1)
    assert ail is not None and 1100 <= np.median(ail.v) <= 1900 and np.ptp(ail.v) > 200
    assert fc.roll is not None and fc.roll_rate is not None and fc.airspeed is not None
    assert fc.airspeed.v.max() > 10.0  # it flew
    kinds = {e.kind for e in fc.events}
    assert {"mode", "param"} <= kinds, fc.events
    assert any(e.text == "mode FBWA" for e in fc.events)


def test_dataflash_named_values_follow_the_fcs_aileron_through_the_mixer(dataflash):
    """The bridge's setpoints, as the FC logged them, are its mixer of the output the FC logged: for the
    left wing (not reversed) 6 + 6 a above trim, 6 (1 + a) below, a = (pwm - 1500) / 400 (bias 6, max 12)."""
    fc = dataflash
    sp = fc.named["L_sp"]
    a = (fc.output(1).at(sp.t - 0.06) - 1500.0) / 400.0  # the value the bridge used ~60 ms earlier
    ok = np.isfinite(a) & (fc.named["WB_mode"].at(sp.t) == 3.0)
    expect = np.where(a >= 0, 6 + 6 * np.clip(a, 0, 1), 6 * (1 + np.clip(a, -1, 0)))
    err = np.abs(sp.v[ok] - expect[ok])
    assert ok.sum() > 100 and np.median(err) < 0.3, np.median(err)


def test_roll_rate_integrates_to_the_roll_angle(dataflash):
    """The gyro's roll rate, integrated over two seconds, moves the roll angle by as much (an independent
    record: ATT is the attitude estimate, the rate the IMU's)."""
    fc = dataflash
    r, p = fc.roll, fc.roll_rate
    t = np.arange(max(r.t[0], p.t[0]) + 1, min(r.t[-1], p.t[-1]) - 3, 2.0)
    errs = []
    for a in t:
        sel = (p.t >= a) & (p.t <= a + 2)
        integral = np.trapezoid(p.v[sel], p.t[sel])
        errs.append(integral - (r.at(np.array([p.t[sel][-1]]))[0] - r.at(np.array([p.t[sel][0]]))[0]))
    errs = np.abs(np.array(errs))
    assert np.median(errs) < 2.0, errs


def test_ground_station_tlog_of_the_same_flight(dataflash):
    tl = read_fc_log(TLOG)
    assert tl.fmt == "tlog" and tl.autopilot == "ardupilot"
    assert {"L_sp", "R_sp", "L_warp", "WB_mode"} <= set(tl.named)
    assert tl.aileron_channels == [1] and tl.output(1) is not None
    # both put the bridge's values on the FC's clock: the same L_sp at the same FC time (within a link hop)
    a, b = dataflash.named["L_sp"], tl.named["L_sp"]
    lo, hi = max(a.t[0], b.t[0]), min(a.t[-1], b.t[-1])
    grid = np.arange(lo, hi, 0.05)
    best = min(np.nanmean(np.abs(a.at(grid) - b.at(grid + lag))) for lag in np.arange(-0.3, 0.3, 0.01))
    assert hi - lo > 20 and best < 0.2, best
    src = {k: v for k, v in tl.link_loss.items() if k.endswith("/191")}
    assert src and all(received > 100 for received, _ in src.values())
    received, lost = tl.link_loss["1/1"]  # the FC's own messages over a loopback TCP link: none lost
    assert received > 1000 and lost <= received // 100


def test_identify_reads_a_dataflash_log_by_wing(caplog):
    data = read_log(BIN, wing="left")
    assert data.airspeed is not None and data.warp is not None and len(data) > 100
    assert "10.0 Hz" in data.notes[0] or "Hz" in data.notes[0]
    assert any("too low to tell a delay" in n for n in data.notes)  # said plainly
    with pytest.raises(UserError, match="pass --wing"):
        read_log(BIN)


# ------------------------------------------------------------------------------------------------ PX4


def test_px4_ulog_outputs_attitude_rates_and_events():
    fc = read_fc_log(ULG)
    assert fc.fmt == "ulog" and fc.autopilot == "px4"
    assert fc.outputs_t.size > 10 and np.nanmax(fc.outputs[:, 0]) > 1000  # PWM, us
    assert fc.roll is not None and np.all(np.abs(fc.roll.v) <= 180)
    assert fc.roll_rate is not None and fc.roll_rate.rate_hz > 100
    assert fc.airspeed is not None
    assert fc.events and fc.events[0].text == "mode MANUAL"
    assert any("Takeoff detected" in e.text for e in fc.events)
    assert not fc.named and any("debug_key_value" in n for n in fc.notes)
    # the gyro integrated over the log moves as the attitude does
    p, r = fc.roll_rate, fc.roll
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (p.v[1:] + p.v[:-1]) * np.diff(p.t))])
    ra = r.at(p.t)
    ok = np.isfinite(ra)
    assert np.max(np.abs(integral[ok] - (ra[ok] - ra[ok][0]))) < 0.2


def _with_debug_key_value(src: Path, dst: Path, values: list[tuple[int, str, float]]) -> None:
    """A copy of a real ULog with a ``debug_key_value`` topic added (what PX4 logs of a NAMED_VALUE_FLOAT
    with its debug topics on), written by pyulog."""
    from pyulog import ULog

    u = ULog(str(src))
    fmt = object.__new__(ULog.MessageFormat)
    fmt.name, fmt.fields = "debug_key_value", [("uint64_t", 0, "timestamp"), ("char", 10, "key"),
                                               ("float", 0, "value")]
    u._message_formats[fmt.name] = fmt
    d = object.__new__(ULog.Data)
    d.multi_id, d.name, d.timestamp_idx = 0, fmt.name, 0
    d.msg_id = max(x.msg_id for x in u.data_list) + 1
    d.field_data = ([ULog._FieldData("timestamp", "uint64_t")]
                    + [ULog._FieldData(f"key[{i}]", "char") for i in range(10)] + [ULog._FieldData("value", "float")])
    keys = np.zeros((len(values), 10), dtype=np.int8)
    for j, (_, k, _) in enumerate(values):
        keys[j, : len(k)] = np.frombuffer(k.encode(), dtype=np.int8)
    d.data = {"timestamp": np.array([v[0] for v in values], dtype=np.uint64),
              "value": np.array([v[2] for v in values], dtype=np.float32)}
    d.data.update({f"key[{i}]": keys[:, i] for i in range(10)})
    u._data_list.append(d)
    u.write_ulog(str(dst))


def test_px4_debug_key_value_are_the_bridges_named_values(tmp_path):
    vals = []
    for k in range(60):
        t = 21_000_000 + 100_000 * k
        vals += [(t, "L_sp", 6.0 + k / 10), (t + 1000, "R_sp", 6.0 - k / 20), (t + 2000, "L_warp", 5.0)]
    out = tmp_path / "with_dkv.ulg"
    _with_debug_key_value(ULG, out, vals)
    fc = read_fc_log(out)
    assert set(fc.named) == {"L_sp", "R_sp", "L_warp"}
    assert fc.named["L_sp"].t[0] == pytest.approx(21.0) and fc.named["L_sp"].rate_hz == pytest.approx(10.0)
    assert fc.named["R_sp"].v[10] == pytest.approx(5.5)


# ------------------------------------------------------------------------------------------------ tlog clock


def _tlog(path: Path, boot0: float, wall0: float, drop_bridge: set[int], mav_type: int = 1,
          signed: bool = False) -> None:
    """A tlog as a ground station writes it: 8-byte big-endian microseconds of reception, then the frame
    (``signed``: MAVLink 2 frames with their 13-byte signature)."""
    fc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    br = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    for conn in (fc, br) if signed else ():
        conn.signing.secret_key = bytes(range(32))
        conn.signing.sign_outgoing = True
        conn.signing.timestamp = 1
    with path.open("wb") as f:
        def put(conn, msg, wall):
            buf = msg.pack(conn)
            conn.seq = (conn.seq + 1) % 256
            f.write(struct.pack(">Q", int(wall * 1e6)) + buf)

        for k in range(400):
            boot = boot0 + 0.05 * k  # FC clock
            wall = wall0 + 0.05 * k + 0.002 + 0.003 * (k % 3)  # reception: 2..8 ms later
            if k % 20 == 0:
                put(fc, mavlink.MAVLink_heartbeat_message(mav_type, 3, 0, 0, 0, 3), wall)
            put(fc, mavlink.MAVLink_attitude_message(int(boot * 1e3) & 0xFFFFFFFF, 0.1, 0, 0, 0.2, 0, 0), wall)
            usec = int(boot * 1e6) & 0xFFFFFFFF
            put(fc, mavlink.MAVLink_servo_output_raw_message(usec, 0, 1500 + k, 1500, 1000, 1500, 0, 0, 0, 0), wall)
            if k % 2 == 0:
                msg = mavlink.MAVLink_named_value_float_message(k * 50, b"L_sp", float(k))
                if k in drop_bridge:
                    br.seq = (br.seq + 1) % 256  # sent, never received
                else:
                    put(br, msg, wall + 0.001)


def test_tlog_times_go_onto_the_fcs_clock_across_the_32_bit_wrap(tmp_path):
    # SERVO_OUTPUT_RAW's 32-bit microseconds wrap at 4294.967 s of the FC's boot time: this log crosses it
    p = tmp_path / "gcs.tlog"
    _tlog(p, boot0=4290.0, wall0=1.7e9, drop_bridge={10, 12, 50})
    fc = read_fc_log(p)
    assert fc.outputs_t.size == 400 and np.all(np.diff(fc.outputs_t) > 0)
    assert fc.outputs_t[-1] == pytest.approx(4290.0 + 0.05 * 399, abs=1e-5)
    assert fc.output(1).v[-1] == 1899
    sp = fc.named["L_sp"]
    # L_sp = k was received at wall0 + 0.05 k + 2..8 ms + 1 ms: on the FC's clock within the transit
    t_expected = 4290.0 + 0.05 * sp.v
    assert np.all(np.abs(sp.t - t_expected) < 0.01)
    assert fc.link_loss["1/191"] == (197, 3)
    assert fc.link_loss["1/1"][1] == 0


def test_unreadable_logs_are_refused_in_one_line(tmp_path):
    empty = tmp_path / "e.BIN"
    empty.write_bytes(b"")
    with pytest.raises(UserError, match="empty file"):
        read_fc_log(empty)
    with pytest.raises(UserError, match="no such file"):
        read_fc_log(tmp_path / "missing.ulg")
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(b"not a ulog at all" * 10)
    with pytest.raises(UserError, match="not a DataFlash/ULog/tlog file"):
        read_fc_log(bad)


# ------------------------------------------------------------------------------------------------ bad and old logs


def _df_message(mtype: int, body: bytes) -> bytes:
    return b"\xa3\x95" + bytes([mtype]) + body


def _df_fmt(mtype: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + struct.calcsize("<" + fmt.replace("c", "h").replace("Z", "64s"))
    return _df_message(0x80, struct.pack("<BB4s16s64s", mtype, length, name.encode(), fmt.encode(),
                                         columns.encode()))


def _old_dataflash(path: Path) -> None:
    """A DataFlash log as ArduPilot wrote them before 2015: RCOU and ATT stamped TimeMS (ms), Chan1..Chan8,
    the firmware's banner in MSG."""
    out = _df_message(0x80, struct.pack("<BB4s16s64s", 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"))
    out += _df_fmt(0x81, "RCOU", "IHHHHHHHH", "TimeMS,Chan1,Chan2,Chan3,Chan4,Chan5,Chan6,Chan7,Chan8")
    out += _df_fmt(0x82, "ATT", "Icc", "TimeMS,Roll,Pitch")
    out += _df_fmt(0x83, "MSG", "Z", "Message")
    out += _df_message(0x83, struct.pack("<64s", b"ArduPlane V2.78b"))
    for k in range(200):
        ms = 10_000 + 20 * k
        out += _df_message(0x81, struct.pack("<IHHHHHHHH", ms, 1500 + k, 1500, 1100, 1500, 0, 0, 0, 0))
        out += _df_message(0x82, struct.pack("<Ihh", ms, 100 * (k % 30), 0))
    path.write_bytes(out)


def test_a_log_stamped_in_milliseconds_is_read(tmp_path):
    p = tmp_path / "old.BIN"
    _old_dataflash(p)
    fc = read_fc_log(p)
    assert fc.outputs_t.size == 200 and fc.outputs_t[0] == pytest.approx(10.0) and fc.span[1] == pytest.approx(13.98)
    assert fc.output(1).v[-1] == 1699 and fc.output(3).v[0] == 1100
    assert fc.roll.v[5] == pytest.approx(5.0)  # centi-degrees
    assert fc.mav_type == 1 and fc.vehicle == "FIXED_WING"


@pytest.mark.parametrize("name", ["text.BIN", "random.BIN", "text.tlog", "random.ulg", "ulog.tlog"])
def test_a_file_of_no_log_format_is_said_to_be_none(tmp_path, name):
    p = tmp_path / name
    if name.startswith("text"):
        p.write_text("this is a text file, not a flight log\n" * 50)
    else:
        p.write_bytes(np.random.default_rng(1).integers(0, 256, 20000, dtype=np.uint8).tobytes()
                      .replace(b"\xa3\x95", b"\x00\x00").replace(b"ULog", b"xxxx"))
    if name == "ulog.tlog":  # a ULog renamed: read as what it is
        p.write_bytes(ULG.read_bytes())
        assert read_fc_log(p).fmt == "ulog"
        return
    with pytest.raises(UserError, match="not a DataFlash/ULog/tlog file"):
        read_fc_log(p)


def test_a_log_without_samples_says_so(tmp_path):
    p = tmp_path / "formats-only.BIN"
    p.write_bytes(_df_message(0x80, struct.pack("<BB4s16s64s", 0x80, 89, b"FMT", b"BBnNZ",
                                                b"Type,Length,Name,Format,Columns")) * 3)
    with pytest.raises(UserError, match="the FC log holds no samples"):
        read_fc_log(p)


def test_corrupt_bytes_are_counted_not_printed(tmp_path, capfd):
    data = bytearray(BIN.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4096] = np.random.default_rng(2).integers(0, 256, 4096, dtype=np.uint8).tobytes().replace(
        b"\xa3", b"\x00")
    p = tmp_path / "corrupt.BIN"
    p.write_bytes(bytes(data))
    capfd.readouterr()
    fc = read_fc_log(p)
    out, err = capfd.readouterr()
    assert "bad header" not in out + err and "Skipped" not in out + err
    said = [n for n in fc.notes if n.startswith("skipped ")]
    assert len(said) == 1 and 4000 <= int(said[0].split()[1]) <= 4200, fc.notes
    assert not any(n.startswith("skipped") for n in read_fc_log(BIN).notes)


# ------------------------------------------------------------------------------------------------ vehicle


def test_the_vehicle_type_each_log_carries(dataflash, tmp_path):
    from warpbridge.bridge.commands.fclog import ardupilot_vehicle, px4_vehicle

    assert (dataflash.mav_type, dataflash.vehicle) == (1, "FIXED_WING") and "ArduPlane" in dataflash.vehicle_source
    assert read_fc_log(TLOG).mav_type == 1  # the FC's heartbeat
    assert read_fc_log(ULG).mav_type == 22  # PX4's MAV_TYPE parameter (a VTOL)
    assert ardupilot_vehicle("ArduCopter V4.5.0-dev (e772012e)", {"FRAME_CLASS": 1.0})[0] == 2
    assert ardupilot_vehicle("APM:Copter V3.2", {})[0] == 2
    assert ardupilot_vehicle("ArduCopter V4.3", {"FRAME_CLASS": 6.0})[0] == 4  # a helicopter
    assert ardupilot_vehicle("", {"SERVO1_FUNCTION": 33.0, "SERVO2_FUNCTION": 34.0})[0] == 43
    assert ardupilot_vehicle("ArduPlane V4.6.3", {"Q_ENABLE": 1.0})[0] == 20
    assert ardupilot_vehicle("", {})[0] is None
    # no banner: a QuadPlane or tailsitter (motors and a wing), motors with flaperons: not refused as wingless
    elevons = {"SERVO1_FUNCTION": 77.0, "SERVO2_FUNCTION": 78.0, "SERVO5_FUNCTION": 33.0, "SERVO6_FUNCTION": 34.0}
    assert ardupilot_vehicle("", {**elevons, "Q_ENABLE": 1.0, "RLL2SRV_P": 1.0})[0] == 20
    assert ardupilot_vehicle("", elevons)[0] is None
    assert ardupilot_vehicle("", {"SERVO1_FUNCTION": 24.0, "SERVO2_FUNCTION": 25.0, "SERVO3_FUNCTION": 33.0})[0] is None
    assert ardupilot_vehicle("ArduPilot Ready", {"RLL2SRV_P": 1.0})[0] == 1  # not a banner: Plane's parameters
    # PX4's MAV_TYPE only: CA_AIRFRAME's numbers changed between releases (9 is "custom", 0 a default)
    assert px4_vehicle({"MAV_TYPE": 1.0, "CA_AIRFRAME": 0.0})[0] == 1
    assert px4_vehicle({"CA_AIRFRAME": 9.0}) == (None, "") and px4_vehicle({"CA_AIRFRAME": 0.0}) == (None, "")
    p = tmp_path / "quad.tlog"
    _tlog(p, boot0=10.0, wall0=1.7e9, drop_bridge=set(), mav_type=2)
    fc = read_fc_log(p)
    assert fc.wingless and fc.vehicle == "QUADROTOR" and fc.vehicle_source == "heartbeat MAV_TYPE 2"


def test_modes_are_named_by_the_vehicles_table():
    from warpbridge.bridge.commands.fclog import ardupilot_mode_names

    assert ardupilot_mode_names(2, "ArduCopter V4.5.0")[0] == "STABILIZE"
    assert ardupilot_mode_names(1, "ArduPlane V4.6.3")[0] == "MANUAL"
    assert ardupilot_mode_names(20, "ArduPlane V4.6.3")[19] == "QLOITER"
    assert ardupilot_mode_names(None, "") == {}  # a vehicle the log does not name: numbers, not a plane's names


def test_reading_keeps_the_readers_byte_by_byte_chatter_out_and_lets_the_rest_through(capfd):
    """pymavlink's indexer writes a line per bad byte to the process's stderr (from C): counted, not shown;
    anything else written while a log is read (this program's log lines) still reaches stderr."""
    import logging
    import os

    from warpbridge.bridge.commands import fclog

    handler = logging.StreamHandler()  # as logging.basicConfig sets it up: on the stderr of that moment
    logger = logging.getLogger("warpbridge.test_chatter")
    logger.addHandler(handler)
    try:
        with fclog._library_chatter() as said:
            os.write(2, b"bad header 0x00 0x00 at 5\n" * 4)
            print("Skipped 3 bad bytes")
            logger.warning("a line of ours")
            os.write(2, b"a library's other words\n")
    finally:
        logger.removeHandler(handler)
    out, err = capfd.readouterr()
    assert "bad header" not in out + err and "Skipped" not in out + err
    assert "a line of ours" in err and "a library's other words" in err
    assert said.note() == "skipped 4 bytes of corrupt data"


def test_a_signed_tlog_is_read_as_a_tlog(tmp_path):
    from warpbridge.bridge.commands.fclog import sniff_format

    p = tmp_path / "signed.tlog"
    _tlog(p, boot0=10.0, wall0=1.7e9, drop_bridge=set(), signed=True)
    assert p.read_bytes()[8] == 0xFD and p.read_bytes()[10] & 1  # MAVLink 2, signed
    assert sniff_format(p) == "tlog"
    assert read_fc_log(p).outputs_t.size == 400


def test_a_px4_tlog_carries_outputs_up_to_32():
    def empty(fmt: str) -> FcLog:
        return FcLog(f"x.{fmt}", fmt, "px4", {}, np.zeros(0), np.zeros((0, 32)), None, None, None)

    assert empty("tlog").max_channel == 32  # SERVO_OUTPUT_RAW port 1 (the AUX bank): outputs 17-32
    assert empty("ulog").max_channel == 16


def test_chatter_is_counted_as_it_comes_and_other_lines_passed_on_up_to_a_cap(tmp_path):
    """A corrupt tail of many megabytes prints a line per bad byte: counted line by line, never held whole;
    other lines pass on, the first ``MAX_PASSED_LINES`` of them, then a count."""
    import io

    from warpbridge.bridge.commands.fclog import MAX_PASSED_LINES, Chatter

    dump = tmp_path / "dump"
    with dump.open("wb") as f:
        f.write(b"bad header 0x00 0x00 at 1\n" * 100_000)
        f.write(b"other\n" * (MAX_PASSED_LINES + 5))
        f.write(b"Skipped 7 bad bytes in log at offset 3, type=None\nlast line without newline")
    out = io.StringIO()
    chatter = Chatter(out)
    with dump.open("rb") as fh:
        chatter.feed(fh)
    assert (chatter.bad_headers, chatter.skipped) == (100_000, 7)
    assert chatter.note() == "skipped 100000 bytes of corrupt data"
    lines = out.getvalue().splitlines()
    assert lines[:MAX_PASSED_LINES] == ["other"] * MAX_PASSED_LINES
    assert lines[MAX_PASSED_LINES:] == ["... 6 more lines written while the log was read"]


def test_review_runs_with_stdout_and_stderr_closed(tmp_path):
    """Started by a service with its streams closed: the report is written all the same."""
    import subprocess
    import sys

    out = tmp_path / "r.html"
    code = ("import sys\nfrom warpbridge.bridge.cli import main\nsys.exit(main(sys.argv[1:]))")
    proc = subprocess.run(["sh", "-c", 'exec "$0" "$@" 1>&- 2>&-', sys.executable, "-c", code, "review",
                           str(BIN), str(DATA / "arduplane-flight-cycles.csv"), "-o", str(out)], timeout=300)
    assert proc.returncode == 0 and out.stat().st_size > 10_000 and out.with_suffix(".json").exists()


CHATTER_SCRIPT = """
import os, sys
from warpbridge.bridge.commands import fclog
with fclog._library_chatter() as said:
    for i in range(150):
        print(f"python line {i}", file=sys.stderr)
    print("a library's print to stdout")
    os.write(2, b"bad header 0x00 0x00 at 1\\n" * 3)
    os.write(2, b"c line\\n")
print(f"counted {said.bad_headers} passed {said.passed} dropped {said.dropped}", file=sys.stderr)
"""


@pytest.mark.parametrize("closed", ["", "<&- >&-"])
def test_chatter_of_a_real_process_is_counted_once_and_passed_to_stderr(closed):
    """Outside pytest's capture: the readers' lines are counted once, whichever stream and level they come
    from; the rest reaches stderr in order, stdout's too (a report's stdout holds its results only), also
    with stdin and stdout closed (a temporary file then takes no standard descriptor's number)."""
    import subprocess
    import sys

    proc = subprocess.run(["sh", "-c", f'exec "$0" "$@" {closed}', sys.executable, "-c", CHATTER_SCRIPT],
                          stdout=None if closed else subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines[:150] == [f"python line {i}" for i in range(150)]
    assert lines[150:] == ["a library's print to stdout", "c line", "counted 3 passed 152 dropped 0"]
    assert not proc.stdout
