"""MAVLink FTP parameter download: ArduPilot's param.pck bytes and the read-only FTP server.

The packed file is checked against bytes worked out by hand from ArduPilot's format description and
against MAVProxy's own decoder (``MAVProxy.modules.lib.param_ftp``, a second implementation), when
MAVProxy is installed. The server is driven the way MAVProxy's FTP client drives it: open, burst
read, re-read a lost block, terminate.
"""

from __future__ import annotations

import errno
import struct

import pytest

from warpbridge.bridge.mavftp import (
    DATA_MAX,
    ERR_END_OF_FILE,
    ERR_FAIL,
    ERR_FAIL_ERRNO,
    ERR_FILE_NOT_FOUND,
    ERR_FILE_PROTECTED,
    ERR_NO_SESSIONS_AVAILABLE,
    ERR_UNKNOWN_COMMAND,
    OP_ACK,
    OP_BURST_READ_FILE,
    OP_CALC_FILE_CRC32,
    OP_CREATE_FILE,
    OP_LIST_DIRECTORY,
    OP_NAK,
    OP_OPEN_FILE_RO,
    OP_READ_FILE,
    OP_RESET_SESSIONS,
    OP_TERMINATE_SESSION,
    PAYLOAD_LEN,
    FtpOp,
    FtpServer,
    PackedParam,
    pack_params,
)

PARAMS = [PackedParam("WB_A", 3, integer=True, default=1), PackedParam("WB_B", 0.5, default=0.5),
          PackedParam("X", 1.0, default=2.0)]


def test_param_pck_bytes_worked_out_by_hand():
    data = pack_params(PARAMS)
    assert data == bytes.fromhex(
        "1b67" "0300" "0300"  # magic 0x671b, 3 in this file, 3 in all
        "03" "30" "57425f41" "03000000"  # int32, 0 shared + 4 new ("WB_A"), 3
        "04" "03" "42" "0000003f"  # float, 3 shared ("WB_") + 1 new ("B"), 0.5
        "04" "00" "58" "0000803f"  # float, 0 shared + 1 new ("X"), 1.0
    )
    with_defaults = pack_params(PARAMS, with_defaults=True)
    assert with_defaults == bytes.fromhex(
        "1c67" "0300" "0300"
        "13" "30" "57425f41" "03000000" "01000000"  # the default follows: 3 differs from 1
        "04" "03" "42" "0000003f"  # 0.5 is its default: no default stored
        "14" "00" "58" "0000803f" "00000040"
    )
    part = pack_params(PARAMS, start=1, count=1)  # a window: the first name shares nothing
    assert part == bytes.fromhex("1b67" "0100" "0300" "04" "30" "57425f42" "0000003f")


def test_a_name_that_is_a_prefix_of_the_one_before_still_carries_a_new_byte():
    data = pack_params([PackedParam("WB_AB", 1.0), PackedParam("WB_A", 2.0)])
    second = data[6 + 2 + 5 + 4:]
    assert second[:3] == bytes([4, 3 | (0 << 4)]) + b"A"  # 3 shared ("WB_") + "A"


def test_mavproxys_decoder_reads_the_file():
    param_ftp = pytest.importorskip("MAVProxy.modules.lib.param_ftp")
    params = [PackedParam(f"WB_P{i:02d}_{'X' * (i % 9)}"[:16], float(i) if i % 3 == 0 else i * 0.25,
                          integer=(i % 3 == 0), default=1.0) for i in range(60)]
    for with_defaults in (False, True):
        got = param_ftp.ftp_param_decode(pack_params(params, with_defaults=with_defaults))
        assert got is not None
        assert [(n.decode(), v) for n, v, _t in got.params] == [
            (p.name, int(p.value) if p.integer else pytest.approx(p.value)) for p in params]
        assert [t for _n, _v, t in got.params] == [3 if p.integer else 4 for p in params]
        if with_defaults:
            assert [v for _n, v, _t in got.defaults] == [1 if p.integer else 1.0 for p in params]


# ---------------------------------------------------------------------- the server


class Client:
    """Builds requests as MAVProxy's FTP client does and parses the replies."""

    def __init__(self, server: FtpServer, sender=(255, 190), session: int = 7) -> None:
        self.server, self.sender, self.session, self.seq = server, sender, session, 0

    def ask(self, opcode: int, data: bytes = b"", *, size: int | None = None, offset: int = 0,
            seq: int | None = None) -> list[FtpOp]:
        if seq is None:
            seq, self.seq = self.seq, self.seq + 1
        req = FtpOp(seq, self.session, opcode, len(data) if size is None else size, 0, 0, offset, data)
        replies = [FtpOp.parse(p) for p in self.server.handle(self.sender, req.pack())]
        for r in replies:
            assert r.session == self.session and r.req_opcode == opcode
        return replies


def nak(op: FtpOp) -> int | None:
    return op.data[0] if op.opcode == OP_NAK else None


@pytest.fixture
def server():
    now = [100.0]
    srv = FtpServer(lambda: PARAMS * 30, clock=lambda: now[0])  # 90 entries: several blocks
    srv.now = now
    return srv


def test_download_open_burst_reread_terminate(server):
    c = Client(server)
    path = b"@PARAM/param.pck?withdefaults=1\0"
    (ack,) = c.ask(OP_OPEN_FILE_RO, path, seq=10)
    expected = pack_params(PARAMS * 30, with_defaults=True)
    assert ack.opcode == OP_ACK and ack.seq == 11 and struct.unpack("<I", ack.data) == (len(expected),)
    replies = c.ask(OP_BURST_READ_FILE, size=80, seq=11)
    *data, end = replies
    assert [r.seq for r in replies] == list(range(12, 12 + len(replies)))  # each packet of the burst one more
    assert all(r.opcode == OP_ACK and r.size <= 80 for r in data)
    assert [r.offset for r in data] == list(range(0, len(expected), 80))
    assert nak(end) == ERR_END_OF_FILE and end.burst_complete == 1 and end.offset == len(expected)
    assert b"".join(r.data for r in data) == expected
    (again,) = c.ask(OP_READ_FILE, size=80, offset=160)  # a lost block, read again: the same bytes
    assert again.opcode == OP_ACK and again.offset == 160 and again.data == expected[160:240]
    (eof,) = c.ask(OP_READ_FILE, size=80, offset=len(expected))
    assert nak(eof) == ERR_END_OF_FILE
    (done,) = c.ask(OP_TERMINATE_SESSION)
    assert done.opcode == OP_ACK
    (gone,) = c.ask(OP_READ_FILE, size=80)
    assert nak(gone) == ERR_FILE_NOT_FOUND
    assert server.opened == 1


def test_the_file_is_a_snapshot_taken_at_the_open(server):
    values = [PackedParam("WB_A", 1.0)]
    srv = FtpServer(lambda: list(values))
    c = Client(srv)
    c.ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck")
    values[0] = PackedParam("WB_A", 2.0)  # a set lands during the download
    *data, _ = c.ask(OP_BURST_READ_FILE, size=DATA_MAX)
    assert b"".join(r.data for r in data) == pack_params([PackedParam("WB_A", 1.0)])


def test_a_retried_open_is_answered_again_and_a_second_file_refused(server):
    c = Client(server)
    first = c.ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck", seq=3)
    retry = c.ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck", seq=3)  # the ACK was lost
    assert first[0].pack() == retry[0].pack()
    (other,) = c.ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck?withdefaults=1")
    assert nak(other) == ERR_FAIL  # one file per session


@pytest.mark.parametrize("opcode, data, code", [
    (OP_OPEN_FILE_RO, b"@SYS/threads.txt", ERR_FILE_NOT_FOUND),
    (OP_OPEN_FILE_RO, b"@PARAM/param.pck?withdefaults=2", ERR_FAIL_ERRNO),
    (OP_OPEN_FILE_RO, b"@PARAM/param.pck?start=90", ERR_FAIL_ERRNO),  # no parameter 90
    (OP_CREATE_FILE, b"@PARAM/param.pck", ERR_FILE_PROTECTED),
    (OP_CALC_FILE_CRC32, b"@PARAM/param.pck", ERR_UNKNOWN_COMMAND),
    (99, b"", ERR_UNKNOWN_COMMAND),
    (OP_READ_FILE, b"", ERR_FILE_NOT_FOUND),  # nothing open
])
def test_everything_else_is_refused_at_once_with_the_right_nak(server, opcode, data, code):
    (reply,) = Client(server).ask(opcode, data)
    assert nak(reply) == code
    if code == ERR_FAIL_ERRNO:
        assert reply.size == 2 and reply.data[1] == errno.EINVAL


def test_listing_shows_the_parameter_file(server):
    c = Client(server)
    (root,) = c.ask(OP_LIST_DIRECTORY, b"/")
    assert root.data.split(b"\0")[0] == b"D@PARAM"
    (d,) = c.ask(OP_LIST_DIRECTORY, b"@PARAM")
    assert d.data.split(b"\0")[0] == f"Fparam.pck\t{len(pack_params(PARAMS * 30))}".encode()
    (end,) = c.ask(OP_LIST_DIRECTORY, b"@PARAM", offset=1)
    assert nak(end) == ERR_END_OF_FILE


def test_sessions_are_limited_reset_and_expire(server):
    clients = [Client(server, sender=(255, 190 + i)) for i in range(5)]
    for c in clients[:4]:
        assert c.ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck")[0].opcode == OP_ACK
    assert nak(clients[4].ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck")[0]) == ERR_NO_SESSIONS_AVAILABLE
    (reset,) = clients[0].ask(OP_RESET_SESSIONS)
    assert reset.opcode == OP_ACK
    assert clients[4].ask(OP_OPEN_FILE_RO, b"@PARAM/param.pck")[0].opcode == OP_ACK
    server.now[0] += 25.0  # idle sessions expire
    assert nak(clients[1].ask(OP_READ_FILE, size=10)[0]) == ERR_FILE_NOT_FOUND


def test_replies_and_malformed_requests():
    srv = FtpServer(lambda: PARAMS)
    assert srv.handle((255, 190), FtpOp(0, 1, OP_ACK, 0).pack()) == []  # a reply is not answered
    bad_name = FtpOp(0, 1, OP_OPEN_FILE_RO, 5, 0, 0, 0, b"ab\0cd").pack()
    assert FtpOp.parse(srv.handle((255, 190), bad_name)[0]).data[0] == 3  # ERR_INVALID_DATA_SIZE
    short = srv.handle((255, 190), b"\x01\x00")  # a truncated payload reads as zeros, not a crash
    assert FtpOp.parse(short[0]).opcode == OP_ACK  # opcode 0 (None) is acknowledged, as ArduPilot does
    assert all(len(p) == PAYLOAD_LEN for p in short)
