"""Small helpers shared by the tests: free loopback ports and a hand-advanced clock."""

from __future__ import annotations

import socket


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ManualClock:
    """A clock the test advances by assigning ``t`` (seconds)."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = float(t)

    def __call__(self) -> float:
        return self.t


def drain_mavlink(sock, parser) -> list:
    """Every MAVLink message waiting on a non-blocking UDP socket, parsed (BAD_DATA dropped)."""
    out: list = []
    while True:
        try:
            data = sock.recv(65536)
        except (BlockingIOError, ConnectionRefusedError):
            return out
        out.extend(m for m in (parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA")
