"""MAVLink FTP, read-only, serving the parameter file: ``FtpServer(params)`` answers FILE_TRANSFER_PROTOCOL.

Ground stations that know ArduPilot (MAVProxy, Mission Planner) first fetch a
component's parameters as the file ``@PARAM/param.pck`` over MAVLink FTP and fall
back to PARAM_REQUEST_LIST only after their FTP timeout (MAVProxy: ten 1 s
retries). This module answers that download the way ArduPilot's ``GCS_FTP`` and
``AP_Filesystem_Param`` do, so a fetch takes one round trip and a burst.

Wire format (the 251-byte payload of FILE_TRANSFER_PROTOCOL): a 12-byte header
``<seq u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8,
pad u8, offset u32>`` (little-endian) and up to 239 data bytes. A reply carries
the request's seq + 1 (each packet of a burst one more), its session, ACK or NAK
as opcode and the request's opcode as req_opcode; a NAK's first data byte is the
error code (``ERR_FAIL_ERRNO`` adds the errno).

Served: OpenFileRO of ``@PARAM/param.pck`` (options ``?withdefaults=1``,
``start=N``, ``count=C`` as ArduPilot takes them; the file is packed once at the
open, so re-reads of lost packets always see the same bytes), ReadFile,
BurstReadFile, TerminateSession, ResetSessions and ListDirectory of ``/`` and
``@PARAM``. Any other file: NAK FileNotFound; writes: NAK FileProtected; other
opcodes: NAK UnknownCommand, each at once, so no client waits for a timeout.

param.pck (ArduPilot's packed parameter file): header ``<magic u16 (0x671b;
0x671c with defaults), num_params u16, total_params u16>``, then per parameter a
type byte (1 int8, 2 int16, 3 int32, 4 float; bit 4: a default follows the
value), a byte ``common_len | (name_len - 1) << 4`` (name bytes shared with the
previous name, then the new ones), the new name bytes and the little-endian
value (and default). Zero bytes between entries are padding.
"""

from __future__ import annotations

import errno
import logging
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from urllib.parse import parse_qsl

log = logging.getLogger(__name__)

# opcodes
OP_NONE = 0
OP_TERMINATE_SESSION = 1
OP_RESET_SESSIONS = 2
OP_LIST_DIRECTORY = 3
OP_OPEN_FILE_RO = 4
OP_READ_FILE = 5
OP_CREATE_FILE = 6
OP_WRITE_FILE = 7
OP_REMOVE_FILE = 8
OP_CREATE_DIRECTORY = 9
OP_REMOVE_DIRECTORY = 10
OP_OPEN_FILE_WO = 11
OP_TRUNCATE_FILE = 12
OP_RENAME = 13
OP_CALC_FILE_CRC32 = 14
OP_BURST_READ_FILE = 15
OP_ACK = 128
OP_NAK = 129
WRITE_OPS = frozenset({OP_CREATE_FILE, OP_WRITE_FILE, OP_REMOVE_FILE, OP_CREATE_DIRECTORY, OP_REMOVE_DIRECTORY,
                       OP_OPEN_FILE_WO, OP_TRUNCATE_FILE, OP_RENAME})

# NAK error codes
ERR_NONE = 0
ERR_FAIL = 1
ERR_FAIL_ERRNO = 2
ERR_INVALID_DATA_SIZE = 3
ERR_INVALID_SESSION = 4
ERR_NO_SESSIONS_AVAILABLE = 5
ERR_END_OF_FILE = 6
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_EXISTS = 8
ERR_FILE_PROTECTED = 9
ERR_FILE_NOT_FOUND = 10

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251  # FILE_TRANSFER_PROTOCOL.payload
DATA_MAX = PAYLOAD_LEN - HEADER.size  # 239

PARAM_DIR = "@PARAM"
PARAM_FILE = "param.pck"
PCK_MAGIC, PCK_MAGIC_DEFAULTS = 0x671B, 0x671C
PCK_INT8, PCK_INT16, PCK_INT32, PCK_FLOAT = 1, 2, 3, 4
_PCK_FORMAT = {PCK_INT8: "<b", PCK_INT16: "<h", PCK_INT32: "<i", PCK_FLOAT: "<f"}

MAX_SESSIONS = 4
SESSION_BUSY_S = 3.0  # a session used within this long is not taken over (ArduPilot's FTP_SESSION_TIMEOUT)
SESSION_EXPIRE_S = 20.0  # idle sessions are closed after this long (FTP_SESSION_KILL_TIMEOUT)
MAX_BURST_PACKETS = 2000  # per BurstReadFile request, as ArduPilot


# ---------------------------------------------------------------------- param.pck


@dataclass(frozen=True)
class PackedParam:
    """One parameter as it goes into param.pck: integers as int32, the rest as float."""

    name: str
    value: float
    integer: bool = False
    default: float | None = None


def pack_params(params: Sequence[PackedParam], *, with_defaults: bool = False, start: int = 0,
                count: int = 0) -> bytes:
    """ArduPilot's param.pck for ``params[start:start + count]`` (count 0: to the end), no padding."""
    chosen = list(params[start:start + count] if count else params[start:])
    magic = PCK_MAGIC_DEFAULTS if with_defaults else PCK_MAGIC
    out = bytearray(struct.pack("<HHH", magic, len(chosen), len(params)))
    last = b""
    for p in chosen:
        name = p.name.encode("ascii")
        common = 0
        while common < min(len(name), len(last), 15) and name[common] == last[common]:
            common += 1
        if common == len(name):  # at least one new byte
            common -= 1
        rest = name[common:]
        ptype = PCK_INT32 if p.integer else PCK_FLOAT
        fmt = _PCK_FORMAT[ptype]
        has_default = with_defaults and p.default is not None and p.default != p.value
        out += bytes([ptype | (int(has_default) << 4), common | ((len(rest) - 1) << 4)]) + rest
        out += struct.pack(fmt, _as(p.value, p.integer))
        if has_default:
            out += struct.pack(fmt, _as(p.default, p.integer))
        last = name
    return bytes(out)


def _as(v: float | None, integer: bool) -> int | float:
    return int(round(v)) if integer else float(v)


def param_file_options(query: str) -> dict[str, int] | None:
    """``withdefaults=1&start=N&count=C`` -> options for ``pack_params``; None if any is bad."""
    opts = {"with_defaults": 0, "start": 0, "count": 0}
    names = {"withdefaults": "with_defaults", "start": "start", "count": "count"}
    for key, value in parse_qsl(query, keep_blank_values=True):
        if key not in names or not value.isdigit():
            return None
        v = int(value)
        if (key == "withdefaults" and v > 1) or v >= 0xFFFF:
            return None
        opts[names[key]] = v
    return opts


# ---------------------------------------------------------------------- the protocol


@dataclass
class FtpOp:
    """One FTP request or reply."""

    seq: int
    session: int
    opcode: int
    size: int = 0
    req_opcode: int = 0
    burst_complete: int = 0
    offset: int = 0
    data: bytes = b""

    @classmethod
    def parse(cls, payload: Sequence[int] | bytes) -> FtpOp:
        raw = bytes(payload)[:PAYLOAD_LEN].ljust(PAYLOAD_LEN, b"\0")
        seq, session, opcode, size, req_opcode, burst, _pad, offset = HEADER.unpack_from(raw)
        data = raw[HEADER.size:]
        return cls(seq, session, opcode, size, req_opcode, burst, offset, data[:size] if size <= DATA_MAX else data)

    def pack(self) -> bytes:
        """The 251-byte payload (data zero-padded)."""
        head = HEADER.pack(self.seq & 0xFFFF, self.session, self.opcode, self.size, self.req_opcode,
                           self.burst_complete, 0, self.offset & 0xFFFFFFFF)
        return (head + self.data[:DATA_MAX]).ljust(PAYLOAD_LEN, b"\0")

    def name(self) -> str | None:
        """The path a request carries (``size`` bytes, a trailing NUL allowed); None if malformed."""
        if not 0 < self.size <= DATA_MAX:
            return None
        raw = self.data[: self.size]
        if raw.endswith(b"\0"):
            raw = raw[:-1]
        if not raw or b"\0" in raw:
            return None
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError:
            return None


@dataclass
class _Session:
    path: str
    data: bytes
    used: float


class FtpServer:
    """A read-only MAVLink FTP server for ``@PARAM/param.pck``; ``params()`` lists what to pack.

    ``handle(sender, payload)`` takes one request from ``sender`` (system, component) and returns the
    reply payloads in order (several for a burst read). ``opened`` counts parameter-file opens."""

    def __init__(self, params: Callable[[], Sequence[PackedParam]], *, clock: Callable[[], float] = time.monotonic,
                 max_sessions: int = MAX_SESSIONS) -> None:
        self.params = params
        self.clock = clock
        self.max_sessions = max_sessions
        self.sessions: dict[tuple[int, int, int], _Session] = {}
        self.opened = 0

    def handle(self, sender: tuple[int, int], payload: Sequence[int] | bytes) -> list[bytes]:
        req = FtpOp.parse(payload)
        now = self.clock()
        self._expire(now)
        if req.opcode in (OP_ACK, OP_NAK):
            return []  # a reply, not a request: not ours to answer
        if req.size > DATA_MAX:
            return [self._nak(req, ERR_INVALID_DATA_SIZE)]
        if req.opcode == OP_RESET_SESSIONS:
            for key in [k for k in self.sessions if k[:2] == sender]:
                del self.sessions[key]
            return [self._ack(req)]
        if req.opcode == OP_NONE:
            return [self._ack(req)]
        key = (sender[0], sender[1], req.session)
        if req.opcode == OP_TERMINATE_SESSION:
            self.sessions.pop(key, None)
            return [self._ack(req)]
        if req.opcode == OP_LIST_DIRECTORY:
            return [self._list(req)]
        if req.opcode == OP_OPEN_FILE_RO:
            return [self._open(req, key, now)]
        if req.opcode in (OP_READ_FILE, OP_BURST_READ_FILE):
            s = self.sessions.get(key)
            if s is None:
                return [self._nak(req, ERR_FILE_NOT_FOUND)]
            s.used = now
            return self._read(req, s.data) if req.opcode == OP_READ_FILE else self._burst(req, s.data)
        if req.opcode in WRITE_OPS:
            return [self._nak(req, ERR_FILE_PROTECTED)]
        return [self._nak(req, ERR_UNKNOWN_COMMAND)]

    # ------------------------------------------------------------------ operations

    def _open(self, req: FtpOp, key: tuple[int, int, int], now: float) -> bytes:
        path = req.name()
        if path is None:
            return self._nak(req, ERR_INVALID_DATA_SIZE)
        s = self.sessions.get(key)
        if s is not None:
            if s.path != path:
                return self._nak(req, ERR_FAIL)  # one file per session
            s.used = now  # a retried open whose ACK was lost: the same file, answered again
            return self._ack(req, struct.pack("<I", len(s.data)))
        base, _, query = path.lstrip("/").partition("?")
        if base != f"{PARAM_DIR}/{PARAM_FILE}":
            return self._nak(req, ERR_FILE_NOT_FOUND)
        opts = param_file_options(query)
        params = list(self.params())
        if opts is None or (opts["start"] and opts["start"] >= len(params)):
            return self._nak(req, ERR_FAIL_ERRNO, errno.EINVAL)
        if not self._make_room(now):
            return self._nak(req, ERR_NO_SESSIONS_AVAILABLE)
        data = pack_params(params, with_defaults=bool(opts["with_defaults"]), start=opts["start"],
                           count=opts["count"])
        self.sessions[key] = _Session(path, data, now)
        self.opened += 1
        log.info("parameter file (%d parameters, %d bytes) opened over MAVLink FTP by %d/%d",
                 len(params), len(data), key[0], key[1])
        return self._ack(req, struct.pack("<I", len(data)))

    def _read(self, req: FtpOp, data: bytes) -> list[bytes]:
        n = min(req.size or DATA_MAX, DATA_MAX)
        chunk = data[req.offset:req.offset + n]
        if not chunk:
            return [self._nak(req, ERR_END_OF_FILE)]
        return [self._ack(req, chunk, offset=req.offset)]

    def _burst(self, req: FtpOp, data: bytes) -> list[bytes]:
        n = min(req.size or DATA_MAX, DATA_MAX)
        out, offset, seq = [], req.offset, req.seq + 1
        for _ in range(MAX_BURST_PACKETS):
            chunk = data[offset:offset + n]
            if not chunk:
                out.append(self._reply(req, OP_NAK, bytes([ERR_END_OF_FILE]), offset=offset, seq=seq, burst=1))
                return out
            out.append(self._reply(req, OP_ACK, chunk, offset=offset, seq=seq))
            offset += len(chunk)
            seq += 1
        # the client asks again from here (ArduPilot marks the last packet of a full burst complete)
        last = FtpOp.parse(out[-1])
        last.burst_complete = 1
        out[-1] = last.pack()
        return out

    def _list(self, req: FtpOp) -> bytes:
        path = req.name()
        if path is None:
            return self._nak(req, ERR_INVALID_DATA_SIZE)
        path = path.strip("/")
        if path == "":
            entries = [f"D{PARAM_DIR}"]
        elif path == PARAM_DIR:
            size = len(pack_params(list(self.params())))
            entries = [f"F{PARAM_FILE}\t{size}"]
        else:
            return self._nak(req, ERR_FILE_NOT_FOUND)
        entries = entries[req.offset:]
        if not entries:
            return self._nak(req, ERR_END_OF_FILE)
        body = b"".join(e.encode("ascii") + b"\0" for e in entries)
        return self._ack(req, body, offset=req.offset)

    # ------------------------------------------------------------------ sessions and replies

    def _expire(self, now: float) -> None:
        for key in [k for k, s in self.sessions.items() if now - s.used > SESSION_EXPIRE_S]:
            del self.sessions[key]

    def _make_room(self, now: float) -> bool:
        if len(self.sessions) < self.max_sessions:
            return True
        key, oldest = min(self.sessions.items(), key=lambda kv: kv[1].used)
        if now - oldest.used < SESSION_BUSY_S:
            return False
        del self.sessions[key]
        return True

    def _reply(self, req: FtpOp, opcode: int, data: bytes = b"", *, offset: int = 0, seq: int | None = None,
               burst: int = 0) -> bytes:
        op = FtpOp(seq=req.seq + 1 if seq is None else seq, session=req.session, opcode=opcode, size=len(data),
                   req_opcode=req.opcode, burst_complete=burst, offset=offset, data=data)
        return op.pack()

    def _ack(self, req: FtpOp, data: bytes = b"", *, offset: int = 0) -> bytes:
        return self._reply(req, OP_ACK, data, offset=offset)

    def _nak(self, req: FtpOp, code: int, err: int | None = None) -> bytes:
        data = bytes([code]) if err is None else bytes([code, err & 0xFF])
        return self._reply(req, OP_NAK, data, offset=req.offset)
