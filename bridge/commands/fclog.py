"""Reading the flight controller's own logs: ArduPilot DataFlash ``.BIN``, a ground station's ``.tlog``, PX4 ``.ulg``.

``read_fc_log(path)`` returns an ``FcLog``: the bridge's NAMED_VALUE_FLOATs as the FC logged them
(ArduPilot ``NVAL``, PX4 ``debug_key_value``, or the ground station's ``NAMED_VALUE_FLOAT`` from
component 191), the FC's servo outputs, roll angle and roll rate, airspeed, and the events of the
flight (mode changes, parameter changes, failsafes, texts), all on the FC's boot clock in seconds.
The libraries made for these formats do the parsing: pymavlink's ``DFReader`` and ``mavutil`` logs,
``pyulog``. A ``.tlog`` records the ground station's reception time: messages that carry no FC time
stamp are put on the FC's clock through the FC's own stamped messages (ATTITUDE, SYSTEM_TIME).
"""

from __future__ import annotations

import codecs
import contextlib
import fcntl
import io
import logging
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpbridge.bridge.errors import UserError
from warpbridge.bridge.outputcheck import (
    ARDUPILOT_AILERON,
    ARDUPILOT_MIXED,
    ARDUPILOT_NAMES,
    PX4_AILERON,
    PX4_MIXED,
    PX4_SURFACES,
)

log = logging.getLogger(__name__)

FC_LOG_SUFFIXES = {".bin": "dataflash", ".tlog": "tlog", ".ulg": "ulog"}
BRIDGE_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: the bridge's named values in a tlog
PX4_SERVO_FUNCTION0 = 201  # PWM_MAIN_FUNCn of "Servo 1"
MAX_CHANNELS = 32  # ArduPilot's SERVO1..32 (RCOU, RCO2, RCO3; SERVO_OUTPUT_RAW ports 0 and 1)
PX4_MAX_CHANNELS = 16  # PX4's actuator_outputs.output[16]
DF_HEAD = b"\xa3\x95"  # every DataFlash message starts with these
ULOG_MAGIC = b"ULog\x01\x12\x35"
MAVLINK_STX = (0xFE, 0xFD)  # MAVLink 1 and 2 frames; a tlog puts 8 bytes of time before each
MAVLINK_IFLAG_SIGNED, MAVLINK_SIGNATURE_LEN = 0x01, 13  # a signed MAVLink 2 frame carries 13 more bytes
SNIFF_BYTES = 65536
# MAV_TYPEs without a wing to warp: multirotors, helicopters, ground and water vehicles
WINGLESS_MAV_TYPES = {2, 3, 4, 10, 11, 12, 13, 14, 15, 29, 35, 43, 46}
US_WRAP = 2**32  # SERVO_OUTPUT_RAW.time_usec is 32 bits: it wraps every 71.6 min


@dataclass(frozen=True)
class Series:
    """Samples ``v`` at times ``t`` (s, FC boot clock, increasing)."""

    t: np.ndarray
    v: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def rate_hz(self) -> float:
        """Median sample rate (0 for fewer than two samples)."""
        if self.t.size < 2:
            return 0.0
        dt = float(np.median(np.diff(self.t)))
        return 1.0 / dt if dt > 0 else 0.0

    def at(self, t: np.ndarray, max_gap: float = math.inf) -> np.ndarray:
        """Linear interpolation at ``t``; NaN outside the samples or inside a gap longer than ``max_gap`` s."""
        t = np.asarray(t, dtype=np.float64)
        out = np.full(t.shape, np.nan)
        if self.t.size < 2:
            return out
        out = np.interp(t, self.t, self.v, left=np.nan, right=np.nan)
        if math.isfinite(max_gap):
            k = np.clip(np.searchsorted(self.t, t), 1, self.t.size - 1)
            out[(self.t[k] - self.t[k - 1]) > max_gap] = np.nan
        return out


@dataclass(frozen=True)
class FcEvent:
    """Something that happened at ``t`` (s, FC clock): ``kind`` is mode, param, failsafe, text or bridge."""

    t: float
    kind: str
    text: str


@dataclass
class FcLog:
    """What the review needs from a flight controller's log (times in s on the FC's boot clock)."""

    path: str
    fmt: str  # dataflash, tlog, ulog
    autopilot: str  # ardupilot, px4
    named: dict[str, Series]
    outputs_t: np.ndarray
    outputs: np.ndarray  # (samples, 32) servo outputs, us; NaN where not logged
    roll: Series | None  # deg
    roll_rate: Series | None  # deg/s
    airspeed: Series | None  # m/s
    events: list[FcEvent] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)
    aileron_channels: list[int] = field(default_factory=list)  # 1-based outputs that drive an aileron
    link_loss: dict[str, tuple[int, int]] = field(default_factory=dict)  # source -> (received, lost), tlog only
    notes: list[str] = field(default_factory=list)
    mav_type: int | None = None  # the vehicle's MAV_TYPE, as the log says it (None: the log does not say)
    vehicle_source: str = ""  # what in the log said it

    @property
    def vehicle(self) -> str:
        """The vehicle type's name (``FIXED_WING``, ``QUADROTOR``, ...), ``unknown`` when the log does not say."""
        return mav_type_name(self.mav_type)

    @property
    def wingless(self) -> bool:
        """The log says the vehicle has no wing: a multirotor, a helicopter, a ground or water vehicle."""
        return self.mav_type in WINGLESS_MAV_TYPES

    @property
    def max_channel(self) -> int:
        """The highest output number this log's format can carry: 16 in a ULog (``actuator_outputs``), 32 in a
        DataFlash log or a tlog (``SERVO_OUTPUT_RAW`` ports 0 and 1, PX4's AUX bank included)."""
        return PX4_MAX_CHANNELS if self.fmt == "ulog" else MAX_CHANNELS

    @property
    def span(self) -> tuple[float, float]:
        """First and last time of anything logged."""
        ts = [s.t for s in self.named.values() if len(s)] + [self.outputs_t]
        ts += [s.t for s in (self.roll, self.roll_rate, self.airspeed) if s is not None]
        ts = [a for a in ts if a.size]
        if not ts:
            return 0.0, 0.0
        return min(float(a[0]) for a in ts), max(float(a[-1]) for a in ts)

    @property
    def empty(self) -> bool:
        """Nothing the review reads was logged: no outputs, attitude, rates, airspeed or named values."""
        return (self.outputs_t.size == 0 and not any(len(s) for s in self.named.values())
                and all(s is None or len(s) == 0 for s in (self.roll, self.roll_rate, self.airspeed)))

    def output(self, channel: int) -> Series | None:
        """Servo output ``channel`` (1-based), us, or None when it was never logged."""
        if not 1 <= channel <= self.outputs.shape[1] or self.outputs_t.size == 0:
            return None
        v = self.outputs[:, channel - 1]
        ok = np.isfinite(v) & (v > 0)
        return Series(self.outputs_t[ok], v[ok]) if ok.any() else None


Progress = Callable[[int, int], None]  # (done, total) bytes or messages


def fc_log_format(path: str | os.PathLike) -> str | None:
    """``dataflash``, ``tlog`` or ``ulog`` from the file name, None for anything else (a CSV)."""
    return FC_LOG_SUFFIXES.get(Path(path).suffix.lower())


def mav_type_name(mav_type: int | None) -> str:
    """``QUADROTOR`` for MAV_TYPE 2, ...; ``unknown`` for None."""
    if mav_type is None:
        return "unknown"
    from pymavlink import mavutil

    entry = mavutil.mavlink.enums["MAV_TYPE"].get(mav_type)
    return entry.name.removeprefix("MAV_TYPE_") if entry is not None else str(mav_type)


def sniff_format(path: Path) -> str | None:
    """``dataflash``, ``ulog`` or ``tlog`` from the file's first bytes, None when they are none of these."""
    with path.open("rb") as fh:
        head = fh.read(SNIFF_BYTES)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DF_HEAD) or DF_HEAD + b"\x80" in head:  # a FMT message, possibly after some junk
        return "dataflash"
    # a tlog: 8 bytes of big-endian microseconds, then a MAVLink frame, then the next record
    for start in (0, 1, 2, 3):
        k, frames = start, 0
        while k + 10 < len(head) and frames < 3:
            stx, n = head[k + 8], head[k + 9]
            if stx not in MAVLINK_STX:
                break
            signed = stx == 0xFD and head[k + 10] & MAVLINK_IFLAG_SIGNED
            k += 8 + n + (8 if stx == 0xFE else 12 + (MAVLINK_SIGNATURE_LEN if signed else 0))
            frames += 1
        if frames >= 3 or (frames and k >= len(head)):
            return "tlog"
    return None


def check_readable(path: str | os.PathLike, what: str = "") -> Path:
    """``path`` as a Path if it is a non-empty file; a UserError saying why not (``what``: the argument)."""
    p = Path(path)
    said = f"{what} {p}" if what else str(p)
    if p.is_dir():
        raise UserError(f"{said}: is a directory, not a file")
    if not p.exists():
        raise UserError(f"{said}: no such file")
    if not p.is_file():
        raise UserError(f"{said}: not a regular file")
    if p.stat().st_size == 0:
        raise UserError(f"{said}: empty file")
    return p


MAX_PASSED_LINES = 200  # lines of other output written during a read that are passed on; the rest counted
MAX_LINE = 65536  # text without a newline longer than this is taken as a line (a \r progress bar, say)


class Chatter:
    """What the log readers print, taken line by line as it is read back: their lines about skipped bytes
    counted (pymavlink prints one per bad byte: hundreds of megabytes on a corrupt tail), other lines passed
    on to ``out`` (the first ``MAX_PASSED_LINES``)."""

    def __init__(self, out) -> None:
        self.out = out
        self.bad_headers = self.skipped = self.passed = self.dropped = 0
        self.ulog_corrupt = False
        self._tail = ""

    def feed(self, fh) -> None:
        """Everything a binary file holds, in blocks, then the last line if it had no newline."""
        decoder = codecs.getincrementaldecoder("utf-8")("replace")
        while block := fh.read(1 << 16):
            self._write(decoder.decode(block))
        self._write(decoder.decode(b"", final=True))
        if self._tail:
            self._line(self._tail)
            self._tail = ""
        if self.dropped and self.out is not None:
            self.out.write(f"... {self.dropped} more lines written while the log was read\n")

    def _write(self, text: str) -> None:
        lines = (self._tail + text).split("\n")
        self._tail = lines.pop()
        if len(self._tail) > MAX_LINE:
            lines.append(self._tail)
            self._tail = ""
        for line in lines:
            self._line(line)

    def _line(self, line: str) -> None:
        if line.startswith("bad header"):
            self.bad_headers += 1
        elif m := SKIPPED_LINE.match(line):
            self.skipped += int(m.group(1))
        elif "corruption detected" in line or "Failed to find sync" in line:
            self.ulog_corrupt = True
        elif self.passed < MAX_PASSED_LINES:
            self.passed += 1
            if self.out is not None:
                self.out.write(line[:1000] + "\n")
        else:
            self.dropped += 1

    def note(self) -> str | None:
        """One line for what the readers said they skipped, or None when they skipped nothing."""
        if self.bad_headers or self.skipped:
            # the indexer reports each bad byte; the message reader the same bytes again as runs: the larger count
            return f"skipped {max(self.bad_headers, self.skipped)} bytes of corrupt data"
        return ULOG_CORRUPT_NOTE if self.ulog_corrupt else None


SKIPPED_LINE = re.compile(r"Skipped (\d+) bad bytes")


def _flush(stream) -> None:
    if stream is not None:
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


def _is_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def _sink():
    """A temporary file on a descriptor above 2 (with stdin, stdout or stderr closed, a new file would take
    their number and be written by whatever writes there)."""
    f = tempfile.TemporaryFile()
    if f.fileno() > 2:
        return f
    high = fcntl.fcntl(f.fileno(), fcntl.F_DUPFD, 3)
    f.close()
    return os.fdopen(high, "w+b")


@contextlib.contextmanager
def _library_chatter() -> Iterator[Chatter]:
    """pymavlink and pyulog print what they skip (one line per byte of a bad block; pymavlink's indexer from C,
    to the process's descriptors): caught, Python's and the C library's alike, in one file, and counted when
    the block is left (``Chatter``); what else was written meanwhile (this program's log lines, a library's
    other words) goes on to stderr then. A progress bar drawn on a copy of stderr's descriptor taken before
    (``review``'s) stays live. A closed stdout or stderr stays closed."""
    said = Chatter(sys.stderr)
    open_fds = [fd for fd in (1, 2) if _is_open(fd)]
    with _sink() as sink:
        # Python's writes go to the same file as the descriptors', in the order they are made
        text = io.TextIOWrapper(io.FileIO(sink.fileno(), "w", closefd=False), encoding="utf-8", errors="replace",
                                line_buffering=True, write_through=True)
        saved: dict[int, int] = {}
        for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
            _flush(stream)
            if fd in open_fds:
                saved[fd] = os.dup(fd)
                os.dup2(sink.fileno(), fd)
        try:
            with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
                yield said
        finally:
            _flush(text)
            for stream in (sys.stdout, sys.stderr):
                _flush(stream)
            for fd, old in saved.items():
                os.dup2(old, fd)
                os.close(old)
            sink.seek(0)
            said.feed(sink)
            _flush(said.out)


ULOG_CORRUPT_NOTE = "skipped corrupt data (the ULog reader resynchronised past it)"


def read_fc_log(path: str | os.PathLike, progress: Progress | None = None) -> FcLog:
    """Read a ``.BIN``, ``.tlog`` or ``.ulg``; raises UserError with a one-line reason when it cannot.

    The format is told by the file's first bytes (a ``.ulg`` renamed ``.BIN`` is read as a ULog), the suffix
    only says what was expected."""
    p = Path(path)
    expected = fc_log_format(p)
    if expected is None:
        raise UserError(f"{p}: not a flight controller log (.BIN, .tlog or .ulg)")
    check_readable(p)
    fmt = sniff_format(p)
    if fmt is None:
        raise UserError(f"{p}: not a DataFlash/ULog/tlog file (its first bytes are none of these formats)")
    if fmt != expected:
        log.info("%s: named as %s, reads as %s", p, expected, fmt)
    reader = {"dataflash": _read_dataflash, "tlog": _read_tlog, "ulog": _read_ulog}[fmt]
    with _library_chatter() as said:
        out = reader(p, progress)
    if (note := said.note()) is not None and note not in out.notes:
        out.notes.append(note)
    for note in out.notes:
        if note.startswith("skipped "):
            log.warning("%s: %s", p, note)
    if out.empty:
        raise UserError(f"{p}: the FC log holds no samples (no servo outputs, attitude, rates, airspeed or the "
                        "bridge's named values)" + (f"; {out.notes[0]}" if out.notes else ""))
    for n in out.notes:
        if not n.startswith("skipped "):
            log.info("%s: %s", p, n)
    return out


# ---------------------------------------------------------------------------------------------- helpers


class _Columns:
    """Accumulates (t, value) pairs per key, then makes sorted ``Series``."""

    def __init__(self) -> None:
        self.t: dict[str, list[float]] = {}
        self.v: dict[str, list[float]] = {}

    def add(self, key: str, t: float, v: float) -> None:
        if v is None or not math.isfinite(v) or not math.isfinite(t):
            return
        self.t.setdefault(key, []).append(t)
        self.v.setdefault(key, []).append(float(v))

    def series(self) -> dict[str, Series]:
        out = {}
        for k in self.t:
            out[k] = _series(np.array(self.t[k]), np.array(self.v[k]))
        return out


def _series(t: np.ndarray, v: np.ndarray) -> Series:
    """Sorted by time, repeated stamps keep the last value."""
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if t.size > 1:
        last = np.ones(t.size, bool)
        last[:-1] = np.diff(t) > 0
        t, v = t[last], v[last]
    return Series(t, v)


def _text(x: object) -> str:
    if isinstance(x, bytes | bytearray):
        x = bytes(x).split(b"\0", 1)[0].decode("ascii", "replace")
    return str(x).rstrip("\0").strip()


def _outputs_array(rows: list[tuple[float, list[float]]]) -> tuple[np.ndarray, np.ndarray]:
    if not rows:
        return np.zeros(0), np.zeros((0, MAX_CHANNELS))
    t = np.array([r[0] for r in rows])
    a = np.full((len(rows), MAX_CHANNELS), np.nan)
    for i, (_, vals) in enumerate(rows):
        n = min(len(vals), MAX_CHANNELS)
        a[i, :n] = vals[:n]
    order = np.argsort(t, kind="stable")
    return t[order], a[order]


def ardupilot_ailerons(params: dict[str, float]) -> list[int]:
    """1-based outputs that carry roll, as the bridge's output check names them: ailerons (``SERVOn_FUNCTION``
    4, 18) first, then outputs carrying roll mixed with another axis (flaperons, elevons, spoilers), each in
    output order."""
    fn = {int(k[5:-9]): int(v) for k, v in params.items() if re.fullmatch(r"SERVO\d+_FUNCTION", k)}
    return (sorted(ch for ch, f in fn.items() if f in ARDUPILOT_AILERON)
            + sorted(ch for ch, f in fn.items() if f in ARDUPILOT_MIXED))


def px4_ailerons(params: dict[str, float]) -> list[int]:
    """1-based PWM outputs whose servo the control allocation calls an aileron, then those it calls an elevon
    (roll mixed with pitch), each in output order."""
    kind = {}
    for k, v in params.items():
        if k.startswith("PWM_MAIN_FUNC") and k[13:].isdigit():
            servo = int(v) - PX4_SERVO_FUNCTION0
            if 0 <= servo < 8:
                kind[int(k[13:])] = int(params.get(f"CA_SV_CS{servo}_TYPE", 0))
    return (sorted(ch for ch, t in kind.items() if t in PX4_AILERON)
            + sorted(ch for ch, t in kind.items() if t in PX4_MIXED))


def roll_surface(fc: FcLog, channel: int) -> str:
    """What output ``channel`` is by the log's parameters ("left flaperon"), "" when they do not say."""
    if fc.autopilot == "px4":
        servo = int(fc.params.get(f"PWM_MAIN_FUNC{channel}", 0)) - PX4_SERVO_FUNCTION0
        return PX4_SURFACES.get(int(fc.params.get(f"CA_SV_CS{servo}_TYPE", 0)), "") if 0 <= servo < 8 else ""
    return ARDUPILOT_NAMES.get(int(fc.params.get(f"SERVO{channel}_FUNCTION", -1)), "")


def _mode_event(t: float, name: str) -> FcEvent:
    return FcEvent(t, "mode", f"mode {name}")


FAILSAFE_WORDS = ("failsafe", "crash", "variance", "breach")
HOUSEKEEPING_PARAMS = ("STAT_", "BARO1_GND", "BARO2_GND", "BARO3_GND")  # the FC rewrites these itself


def _text_event(t: float, text: str) -> FcEvent:
    low = text.lower()
    if low.startswith("wb "):
        kind = "failsafe" if "failsafe" in low else "bridge"
    else:
        kind = "failsafe" if any(w in low for w in FAILSAFE_WORDS) else "text"
    return FcEvent(t, kind, text)


# ---------------------------------------------------------------------------------------------- DataFlash

DF_BULK = ("NVAL", "RCOU", "RCO2", "RCO3", "ATT", "RATE", "PIDR", "IMU", "ARSP", "CTUN")  # read as columns
DF_EVENTS = ("MODE", "MSG", "PARM", "ERR")  # read message by message (few, with text)
ERR_SUBSYS = {2: "radio", 5: "radio failsafe", 6: "battery failsafe", 7: "GPS failsafe", 8: "GCS failsafe",
              9: "fence", 12: "EKF/IMU", 16: "EKF failsafe", 17: "baro", 24: "failsafe", 26: "pilot input"}
_STRUCT_TO_NUMPY = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
                    "f": "<f4", "d": "<f8"}


def _df_dtype(msg_struct: str) -> np.dtype | None:
    """A packed numpy dtype for a DataFlash message body, from DFReader's struct format (None if unknown)."""
    fields = []
    for count, code in re.findall(r"(\d*)([a-zA-Z])", msg_struct.lstrip("<")):
        if code == "s":
            fields.append(f"S{count}")
        elif code in _STRUCT_TO_NUMPY and not count:
            fields.append(_STRUCT_TO_NUMPY[code])
        else:
            return None
    return np.dtype([(f"f{i}", t) for i, t in enumerate(fields)])


def _df_columns(df, name: str) -> dict[str, np.ndarray] | None:
    """Every message of type ``name`` as columns (multipliers applied), gathered straight from the file at
    the offsets pymavlink's DFReader indexed; None when the log has none or a format we cannot map."""
    mtype = df.name_to_id.get(name)
    if mtype is None or df.counts[mtype] <= 0:
        return None
    fmt = df.formats[mtype]
    dtype = _df_dtype(fmt.msg_struct)
    if dtype is None or dtype.itemsize != fmt.len - 3:
        return None
    offs = np.asarray(df.offsets[mtype][: df.counts[mtype]], dtype=np.int64)
    offs = offs[offs + fmt.len <= df.data_len]
    buf = np.frombuffer(df.data_map, dtype=np.uint8)
    rows = np.ascontiguousarray(buf[offs[:, None] + 3 + np.arange(fmt.len - 3)]).view(dtype).ravel()
    out = {}
    for i, col in enumerate(fmt.columns):
        v = rows[f"f{i}"]
        mult = fmt.msg_mults[i] if i < len(fmt.msg_mults) else None
        out[col] = v.astype(np.float64) * mult if mult else v
    if "TimeUS" not in out and "TimeMS" in out:  # logs before 2015 stamp in milliseconds
        out["TimeUS"] = out["TimeMS"].astype(np.float64) * 1e3
    return out


def _dataflash_reader(path: str):
    """pymavlink's DFReader_binary (its index of every message's offset) without its search for a GPS
    time base: that search reads a log without GPS messages to its end, and this reader needs only TimeUS,
    the FC's boot clock."""
    from pymavlink import DFReader

    class BootClockReader(DFReader.DFReader_binary):
        def init_clock(self) -> None:
            self._rewind(keep_messages=True)
            if any("TimeUS" in f.columns for f in self.formats.values()) or not any(
                    "TimeMS" in f.columns for f in self.formats.values()):
                self.init_clock_usec()
            else:  # a log before 2015, stamped in milliseconds
                self.init_clock_msec()

    return BootClockReader(path, zero_time_base=True)


def _read_dataflash(p: Path, progress: Progress | None) -> FcLog:
    try:
        df = _dataflash_reader(str(p))
    except Exception as e:  # noqa: BLE001 - a damaged file: one line, not a traceback
        raise UserError(f"{p}: not a readable DataFlash log ({e})") from None
    cols = {}
    for k, name in enumerate(DF_BULK):
        c = _df_columns(df, name)
        if c is not None and "TimeUS" in c:
            cols[name] = c
        if progress is not None:
            progress(k + 1, len(DF_BULK) + 1)
    named = _df_named(cols.get("NVAL"))
    t_out, a_out = _df_outputs(cols.get("RCOU"), cols.get("RCO2"), cols.get("RCO3"))

    def series(name: str, field: str, scale: float = 1.0, instance0: bool = False) -> Series | None:
        c = cols.get(name)
        if c is None or field not in c:
            return None
        sel = c["I"] == 0 if instance0 and "I" in c else np.ones(c["TimeUS"].size, bool)
        v = c[field][sel].astype(np.float64) * scale
        ok = np.isfinite(v)
        return _series(c["TimeUS"][sel][ok] * 1e-6, v[ok]) if ok.any() else None

    # roll rate: RATE (Copter-style logs), else the IMU's gyro, else the roll controller's PIDR.Act (its
    # own measurement, current only while the controller runs)
    rate = (series("RATE", "R") or series("IMU", "GyrX", math.degrees(1.0), instance0=True)
            or series("PIDR", "Act"))
    airspeed = series("ARSP", "Airspeed", instance0=True) or series("CTUN", "As")
    events, params, modes, firmware = _df_events(df)
    mav_type, source = ardupilot_vehicle(firmware, params)
    mode_names = ardupilot_mode_names(mav_type, firmware)
    events += [_mode_event(t, mode_names.get(num, str(num)) if isinstance(num, int) else num) for t, num in modes]
    if progress is not None:
        progress(1, 1)
    fl = FcLog(path=str(p), fmt="dataflash", autopilot="ardupilot", named=named, outputs_t=t_out, outputs=a_out,
               roll=series("ATT", "Roll"), roll_rate=rate, airspeed=airspeed,
               events=sorted(events, key=lambda e: e.t), params=params, aileron_channels=ardupilot_ailerons(params),
               mav_type=mav_type, vehicle_source=source)
    _note_contents(fl)
    return fl


def _df_named(c: dict[str, np.ndarray] | None) -> dict[str, Series]:
    """NVAL columns -> one series per name (only what component 191, the bridge, sent)."""
    if c is None:
        return {}
    sel = c["SCom"] == BRIDGE_COMPONENT if "SCom" in c else np.ones(c["TimeUS"].size, bool)
    names, t, v = c["Name"][sel], c["TimeUS"][sel] * 1e-6, c["Value"][sel].astype(np.float64)
    out = {}
    for raw in np.unique(names):
        k = names == raw
        out[_text(raw)] = _series(t[k], v[k])
    return out


def _df_channel(col: str) -> int | None:
    """The 1-based output of an RCOU/RCO2/RCO3 column: ``C7`` (``Chan7`` in logs before 2015)."""
    m = re.fullmatch(r"(?:C|Chan)(\d+)", col)
    return int(m.group(1)) if m and 1 <= int(m.group(1)) <= MAX_CHANNELS else None


def _df_outputs(rcou, *more) -> tuple[np.ndarray, np.ndarray]:
    """RCOU (outputs 1-14), RCO2 (15-18) and RCO3 (19-32), the last two on RCOU's stamps -> times and a
    (samples, 32) array, us."""
    if rcou is None:
        return np.zeros(0), np.zeros((0, MAX_CHANNELS))
    t = rcou["TimeUS"] * 1e-6
    a = np.full((t.size, MAX_CHANNELS), np.nan)
    for col, v in rcou.items():
        if (ch := _df_channel(col)) is not None:
            a[:, ch - 1] = v
    for extra in more:
        if extra is None or not t.size:
            continue
        t2 = extra["TimeUS"] * 1e-6
        k = np.minimum(np.searchsorted(t, t2), t.size - 1)
        same = np.abs(t[k] - t2) < 1e-6
        for col, v in extra.items():
            if (ch := _df_channel(col)) is not None:
                a[k[same], ch - 1] = v[same]
    order = np.argsort(t, kind="stable")
    return t[order], a[order]


def _df_events(df) -> tuple[list[FcEvent], dict[str, float], list[tuple[float, int | str]], str]:
    """Texts, parameter changes and errors; the parameters as the flight ended; the mode changes (time, mode
    number, or the name a log without numbers gives); the firmware's banner (``ArduPlane V4.6.3 ...``)."""
    events: list[FcEvent] = []
    params: dict[str, float] = {}
    last: dict[str, float] = {}
    modes: list[tuple[float, int | str]] = []
    firmware = ""
    types = [t for t in DF_EVENTS if t in df.name_to_id]
    df.rewind()
    while types:
        m = df.recv_match(type=types, strict=True)
        if m is None:
            break
        mt = m.get_type()
        t = _df_time(m)
        if mt == "MODE":
            num = _f(m, "ModeNum")
            if num is None:  # logs before 2015: Mode is the number
                num = _f(m, "Mode")
            modes.append((t, int(num) if isinstance(num, int | float) else _text(num)))
        elif mt == "MSG":
            text = _text(_f(m, "Message", ""))
            if not firmware and firmware_kind(text) is not None:
                firmware = text
            events.append(_text_event(t, text))
        elif mt == "PARM":
            name, value = _text(_f(m, "Name", "")), float(_f(m, "Value", math.nan))
            if name in last and last[name] != value and not name.startswith(HOUSEKEEPING_PARAMS):
                events.append(FcEvent(t, "param", f"{name} {last[name]:g} -> {value:g}"))
            last[name] = value
            params.setdefault(name, value)
        elif mt == "ERR":
            subsys, code = int(_f(m, "Subsys", 0)), int(_f(m, "ECode", 0))
            sub = ERR_SUBSYS.get(subsys, f"subsystem {subsys}")
            kind = "failsafe" if "failsafe" in sub and code != 0 else "text"
            events.append(FcEvent(t, kind, f"ERR {sub} code {code}"))
    params.update(last)  # PARM is logged again on a change: the values the flight ended with
    return events, params, modes, firmware


def _df_time(m) -> float:
    """A DataFlash message's time, s: TimeUS, TimeMS in logs before 2015, else the reader's clock."""
    us = _f(m, "TimeUS")
    if us is not None:
        return us * 1e-6
    ms = _f(m, "TimeMS")
    if ms is not None:
        return ms * 1e-3
    return float(getattr(m, "_timestamp", 0.0) or 0.0)


FIRMWARE_BANNER = re.compile(r"^(Ardu\w+|APM:\w+|AntennaTracker|Blimp)\b")
# the firmware's banner -> MAV_TYPE (Copter's frame refined by FRAME_CLASS, Plane's by Q_ENABLE)
_ARDUPILOT_FIRMWARE = {"arduplane": 1, "apm:plane": 1, "arducopter": 2, "apm:copter": 2, "ardurover": 10,
                       "apm:rover": 10, "ardusub": 12, "apm:sub": 12, "antennatracker": 5, "blimp": 7}
_COPTER_FRAME_CLASS = {1: 2, 2: 13, 3: 14, 4: 14, 5: 13, 6: 4, 7: 15, 8: 2, 10: 1, 11: 4, 12: 35, 13: 4, 14: 35,
                       15: 29}
ARDUPILOT_MOTOR_FUNCTIONS = range(33, 41)  # SERVOn_FUNCTION Motor1..Motor8
# SERVOn_FUNCTIONs of a wing's roll surface: aileron, differential spoilers, flaperons, elevons, V-tail
ARDUPILOT_WING_FUNCTIONS = {4, 16, 17, 24, 25, 77, 78, 79, 80, 86, 87}


def firmware_kind(text: str) -> int | None:
    """The MAV_TYPE an ArduPilot firmware banner names (``ArduPlane V4.5.7 (...)``: 1), None for other texts
    (``ArduPilot Ready``)."""
    m = FIRMWARE_BANNER.match(text)
    return _ARDUPILOT_FIRMWARE.get(m.group(1).lower()) if m else None


def ardupilot_vehicle(firmware: str, params: dict[str, float]) -> tuple[int | None, str]:
    """(MAV_TYPE, what said it) from the firmware's banner in the log's texts, else its parameters."""
    kind = firmware_kind(firmware)
    said = f"firmware {firmware.split(' (')[0]}"
    if kind == 2 and "FRAME_CLASS" in params:
        frame = int(params["FRAME_CLASS"])
        return _COPTER_FRAME_CLASS.get(frame, 2), f"{said}, FRAME_CLASS {frame}"
    if kind == 1 and params.get("Q_ENABLE", 0) >= 1:
        return 20, f"{said}, Q_ENABLE 1"
    if kind == 10 and int(params.get("FRAME_CLASS", 1)) == 2:
        return 11, f"{said}, FRAME_CLASS 2"
    if kind is not None:
        return kind, said
    # no banner: Plane's parameters first (a QuadPlane has motors and a wing)
    if params.get("Q_ENABLE", 0) >= 1:
        return 20, "parameter Q_ENABLE 1 (ArduPlane's)"
    if "RLL2SRV_P" in params or "RLL_RATE_FF" in params:
        return 1, "parameters RLL2SRV_P/RLL_RATE_FF (ArduPlane's)"
    if "FRAME_CLASS" in params and "ATC_RAT_RLL_P" in params:  # Copter's parameters
        frame = int(params["FRAME_CLASS"])
        return _COPTER_FRAME_CLASS.get(frame, 2), f"parameters FRAME_CLASS {frame}, ATC_RAT_RLL_P"
    functions = {int(v) for k, v in params.items() if re.fullmatch(r"SERVO\d+_FUNCTION", k)}
    if functions & set(ARDUPILOT_MOTOR_FUNCTIONS) and not functions & ARDUPILOT_WING_FUNCTIONS:
        return 43, "SERVOn_FUNCTION: motors and no roll surface of a wing"
    return None, ""


def ardupilot_mode_names(mav_type: int | None, firmware: str) -> dict[int, str]:
    """Mode number -> name for this vehicle (pymavlink's maps; Plane's for a QuadPlane); empty when the log
    does not say what the vehicle is: a copter's mode is not decoded with a plane's table."""
    from pymavlink import mavutil

    if firmware_kind(firmware) == 1:
        mav_type = 1  # a QuadPlane's modes are Plane's (pymavlink maps the VTOL types to them too)
    if mav_type is None:
        return {}
    return dict(mavutil.mode_mapping_bynumber(mav_type) or {})


def _f(m, name: str, default=None):
    """Field ``name`` of a DataFlash message, ``default`` when this log's format lacks it (formats change
    between firmware versions)."""
    try:
        return getattr(m, name)
    except AttributeError:
        return default


def _note_contents(fl: FcLog) -> None:
    if not fl.named:
        fl.notes.append("no named values of the bridge in this log (ArduPilot: NVAL; PX4: debug_key_value with "
                        "the logger's debug topics on; tlog: NAMED_VALUE_FLOAT from component 191)")
    else:
        rates = sorted(s.rate_hz for s in fl.named.values() if len(s) > 2)
        if rates:
            fl.notes.append(f"{len(fl.named)} named values of the bridge, median {rates[len(rates) // 2]:.1f} Hz")
    if fl.outputs_t.size == 0:
        fl.notes.append("no servo outputs logged")


# ---------------------------------------------------------------------------------------------- tlog


class _ClockMap:
    """Ground-station reception time -> FC boot time, from the FC's stamped messages (median offset)."""

    def __init__(self) -> None:
        self.pairs: list[float] = []

    def add(self, wall: float, boot_s: float) -> None:
        self.pairs.append(wall - boot_s)

    def offset(self) -> float | None:
        if not self.pairs:
            return None
        # the smallest transit is the truest; a low percentile resists a stray early stamp
        return float(np.percentile(self.pairs, 5))


def _read_tlog(p: Path, progress: Progress | None) -> FcLog:
    from pymavlink import mavutil

    try:
        mlog = mavutil.mavlink_connection(str(p), dialect="ardupilotmega", notimestamps=False)
    except Exception as e:  # noqa: BLE001
        raise UserError(f"{p}: not a readable tlog ({e})") from None
    named_wall, other_wall = _Columns(), _Columns()
    other_boot = _Columns()
    outs: list[tuple[float, list[float]]] = []
    texts: list[tuple[float, str]] = []
    modes: list[tuple[float, int, int]] = []
    params: dict[str, float] = {}
    param_changes: list[tuple[float, str, float, float]] = []
    clock = _ClockMap()
    seqs: dict[str, tuple[int, int, int]] = {}  # source -> (last seq, received, lost)
    fc_sys: int | None = None
    fc_type: int | None = None
    autopilot = "ardupilot"
    us_unwrap = _Unwrap()
    size = max(1, p.stat().st_size)
    n = 0
    while True:  # every message, for the senders' sequence numbers; the ones used are picked below
        try:
            m = mlog.recv_match()
        except Exception as e:  # noqa: BLE001 - a truncated tail
            log.debug("tlog read stopped: %s", e)
            break
        if m is None:
            break
        n += 1
        if progress is not None and n % 20000 == 0:
            progress(mlog.f.tell() if hasattr(mlog, "f") else 0, size)
        mt = m.get_type()
        if mt == "BAD_DATA":
            continue
        wall = float(getattr(m, "_timestamp", 0.0))
        src_sys, src_comp = m.get_srcSystem(), m.get_srcComponent()
        key = f"{src_sys}/{src_comp}"
        seq = m.get_seq()
        last = seqs.get(key)
        if last is None:
            seqs[key] = (seq, 1, 0)
        else:
            gap = (seq - last[0] - 1) % 256
            seqs[key] = (seq, last[1] + 1, last[2] + (gap if gap < 128 else 0))
        if mt == "HEARTBEAT" and src_comp == 1 and m.type != mavutil.mavlink.MAV_TYPE_GCS:
            fc_sys, fc_type = src_sys, int(m.type)
            autopilot = "px4" if m.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4 else "ardupilot"
            if not modes or modes[-1][1] != m.custom_mode:
                modes.append((wall, int(m.custom_mode), int(m.type)))
            continue
        if mt == "NAMED_VALUE_FLOAT" and src_comp == BRIDGE_COMPONENT:
            named_wall.add(_text(m.name), wall, m.value)
        elif mt == "STATUSTEXT":
            texts.append((wall, _text(m.text)))
        elif src_comp != 1 or (fc_sys is not None and src_sys != fc_sys):
            continue
        elif mt == "SERVO_OUTPUT_RAW":
            t = us_unwrap(int(m.time_usec)) * 1e-6
            clock.add(wall, t)
            # 16 outputs a message; port 1 carries outputs 17-32 (ArduPilot's second bank, PX4's AUX instance)
            vals = [float(getattr(m, f"servo{i}_raw", 0) or math.nan) for i in range(1, 17)]
            if m.port:
                vals = [math.nan] * (16 * m.port) + vals
            outs.append((t, vals[:MAX_CHANNELS]))
        elif mt == "ACTUATOR_OUTPUT_STATUS":
            t = m.time_usec * 1e-6
            clock.add(wall, t)
            outs.append((t, [float(v) if v else math.nan for v in m.actuator][:MAX_CHANNELS]))
        elif mt == "ATTITUDE":
            t = m.time_boot_ms * 1e-3
            clock.add(wall, t)
            other_boot.add("roll", t, math.degrees(m.roll))
            other_boot.add("rate", t, math.degrees(m.rollspeed))
        elif mt == "SYSTEM_TIME":
            clock.add(wall, m.time_boot_ms * 1e-3)
        elif mt == "VFR_HUD":
            other_wall.add("airspeed", wall, m.airspeed)
        elif mt == "PARAM_VALUE":
            name = _text(m.param_id)
            if name in params and params[name] != m.param_value and not name.startswith(HOUSEKEEPING_PARAMS):
                param_changes.append((wall, name, params[name], float(m.param_value)))
            params[name] = float(m.param_value)
    if progress is not None:
        progress(size, size)
    offset = clock.offset()
    notes = []
    if offset is None:
        offset = 0.0
        notes.append("no FC time stamps (ATTITUDE, SYSTEM_TIME, SERVO_OUTPUT_RAW): times are the ground station's")

    def shift(cols: _Columns) -> dict[str, Series]:
        return {k: Series(s.t - offset, s.v) for k, s in cols.series().items()}

    named = shift(named_wall)
    ob = other_boot.series()
    ow = shift(other_wall)
    events = [_text_event(w - offset, s) for w, s in texts]
    events += [FcEvent(w - offset, "param", f"{name} {a:g} -> {b:g}") for w, name, a, b in param_changes]
    for w, mode, vtype in modes[1:] if len(modes) > 1 else modes:
        events.append(_mode_event(w - offset, _tlog_mode_name(mode, vtype, autopilot)))
    t_out, a_out = _outputs_array(outs)
    ail = px4_ailerons(params) if autopilot == "px4" else ardupilot_ailerons(params)
    loss = {k: (v[1], v[2]) for k, v in seqs.items()}
    fl = FcLog(path=str(p), fmt="tlog", autopilot=autopilot, named=named, outputs_t=t_out, outputs=a_out,
               roll=ob.get("roll"), roll_rate=ob.get("rate"), airspeed=ow.get("airspeed"),
               events=sorted(events, key=lambda e: e.t), params=params, aileron_channels=ail, link_loss=loss,
               notes=notes, mav_type=fc_type, vehicle_source="" if fc_type is None else f"heartbeat MAV_TYPE {fc_type}")
    _note_contents(fl)
    return fl


def _tlog_mode_name(mode: int, vtype: int, autopilot: str) -> str:
    from pymavlink import mavutil

    if autopilot == "ardupilot":
        names = mavutil.mode_mapping_bynumber(vtype) or {}
        return names.get(mode, str(mode))
    return str(mode)


class _Unwrap:
    """Unwraps a 32-bit microsecond counter (SERVO_OUTPUT_RAW.time_usec)."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.base = 0

    def __call__(self, us: int) -> int:
        if self.last is not None and us < self.last - US_WRAP // 2:
            self.base += US_WRAP
        self.last = us
        return self.base + us


# ---------------------------------------------------------------------------------------------- ULog

PX4_ARMED = 2  # vehicle_status.arming_state
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")
# PX4 keeps 9 characters of a name (debug_key_value's key ends with its terminating zero)
_PX4_CUT_NAMES = {"WB_cal_pc": "WB_cal_pct"}
PX4_NAV_STATES = {0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER", 5: "AUTO_RTL",
                  10: "ACRO", 12: "DESCEND", 13: "TERMINATION", 14: "OFFBOARD", 15: "STAB", 17: "AUTO_TAKEOFF",
                  18: "AUTO_LAND", 19: "AUTO_FOLLOW_TARGET", 20: "AUTO_PRECLAND", 21: "ORBIT"}


def px4_vehicle(params: dict[str, float]) -> tuple[int | None, str]:
    """(MAV_TYPE, what said it) from PX4's ``MAV_TYPE`` parameter. ``CA_AIRFRAME`` is not read: its numbers
    changed between releases (1 was a standard VTOL, now a fixed wing; 9 is "custom"), and a log from before
    control allocation holds its default, 0 (multirotor), whatever flew."""
    if "MAV_TYPE" in params:
        return int(params["MAV_TYPE"]), f"parameter MAV_TYPE {int(params['MAV_TYPE'])}"
    return None, ""


def _read_ulog(p: Path, progress: Progress | None) -> FcLog:
    try:
        from pyulog import ULog
    except ImportError as e:
        raise UserError(f"{p}: reading PX4 logs needs pyulog (pip install pyulog)") from e
    topics = ["debug_key_value", "actuator_outputs", "vehicle_attitude", "vehicle_angular_velocity",
              "airspeed_validated", "airspeed", "vehicle_status"]
    if progress is not None:
        progress(0, 1)
    try:
        ulog = ULog(str(p), topics)
    except Exception as e:  # noqa: BLE001
        raise UserError(f"{p}: not a readable ULog ({e})") from None
    if progress is not None:
        progress(1, 1)
    data = {}
    for d in ulog.data_list:
        if d.multi_id == 0 or d.name not in data:
            data.setdefault(d.name, d)
    named: dict[str, Series] = {}
    if "debug_key_value" in data:
        d = data["debug_key_value"].data
        t = d["timestamp"] * 1e-6
        keys = np.column_stack([d[f"key[{i}]"] for i in range(10) if f"key[{i}]" in d]).astype(np.uint8)
        names = np.array([bytes(r).split(b"\0", 1)[0].decode("ascii", "replace") for r in keys])
        for name in np.unique(names):
            sel = names == name
            named[_PX4_CUT_NAMES.get(str(name), str(name))] = _series(t[sel], d["value"][sel].astype(np.float64))
    t_out, a_out = np.zeros(0), np.zeros((0, MAX_CHANNELS))
    if "actuator_outputs" in data:
        d = data["actuator_outputs"].data
        t_out = d["timestamp"] * 1e-6
        a_out = np.full((t_out.size, MAX_CHANNELS), np.nan)
        for i in range(MAX_CHANNELS):
            if f"output[{i}]" in d:
                a_out[:, i] = d[f"output[{i}]"]
    if t_out.size and "vehicle_status" in data and int(ulog.initial_parameters.get("COM_PREARM_MODE", 0)) != 2:
        # disarmed, PX4 holds its outputs at their disarmed values (900 us in SITL, PWM_MAIN_DISn on
        # hardware), which are not commands: left out, as the bridge leaves them out
        d = data["vehicle_status"].data
        k = np.searchsorted(d["timestamp"] * 1e-6, t_out, side="right") - 1
        armed = (k >= 0) & (d["arming_state"][np.maximum(k, 0)] == PX4_ARMED)
        a_out[~armed] = np.nan
    roll = rate = airspeed = None
    if "vehicle_attitude" in data:
        d = data["vehicle_attitude"].data
        q0, q1, q2, q3 = (d[f"q[{i}]"] for i in range(4))
        roll = _series(d["timestamp"] * 1e-6, np.degrees(np.arctan2(2 * (q0 * q1 + q2 * q3),
                                                                    1 - 2 * (q1 * q1 + q2 * q2))))
    if "vehicle_angular_velocity" in data:
        d = data["vehicle_angular_velocity"].data
        rate = _series(d["timestamp"] * 1e-6, np.degrees(d["xyz[0]"].astype(np.float64)))
    for topic, fieldname in (("airspeed_validated", "calibrated_airspeed_m_s"),
                             ("airspeed", "indicated_airspeed_m_s")):
        if airspeed is None and topic in data and fieldname in data[topic].data:
            d = data[topic].data
            airspeed = _series(d["timestamp"] * 1e-6, d[fieldname].astype(np.float64))
    events: list[FcEvent] = []
    if "vehicle_status" in data:
        d = data["vehicle_status"].data
        ns = d["nav_state"]
        change = np.flatnonzero(np.r_[True, np.diff(ns) != 0])
        for i in change:
            events.append(_mode_event(d["timestamp"][i] * 1e-6, PX4_NAV_STATES.get(int(ns[i]), str(int(ns[i])))))
        if "failsafe" in d:
            fs = d["failsafe"].astype(int)
            for i in np.flatnonzero(np.diff(fs) > 0) + 1:
                events.append(FcEvent(d["timestamp"][i] * 1e-6, "failsafe", "PX4 failsafe"))
    for m in ulog.logged_messages:  # PX4 colours some of its texts with terminal escapes
        events.append(_text_event(m.timestamp * 1e-6, _text(ANSI_ESCAPE.sub("", m.message))))
    for ts, name, value in ulog.changed_parameters:
        if ts > ulog.start_timestamp:
            events.append(FcEvent(ts * 1e-6, "param", f"{name} -> {value:g}"))
    params = {k: float(v) for k, v in ulog.initial_parameters.items()}
    mav_type, source = px4_vehicle(params)
    fl = FcLog(path=str(p), fmt="ulog", autopilot="px4", named=named, outputs_t=t_out, outputs=a_out, roll=roll,
               roll_rate=rate, airspeed=airspeed, events=sorted(events, key=lambda e: e.t), params=params,
               aileron_channels=px4_ailerons(params), mav_type=mav_type, vehicle_source=source)
    if ulog.file_corruption:
        fl.notes.append(ULOG_CORRUPT_NOTE)
    if "debug_key_value" not in data:
        fl.notes.append("no debug_key_value topic: turn the logger's debug topics on (SDLOG_PROFILE) to log "
                        "the bridge's named values")
    _note_contents(fl)
    return fl
