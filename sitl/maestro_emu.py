"""A Pololu Maestro emulated on a pseudo-terminal, for tests and simulation.

``MaestroEmulator.start()`` returns the device path of a real pty that the bridge opens
with pyserial exactly as it would open ``/dev/ttyACM0`` (spec ``maestro:<path>``). The
emulator parses the compact protocol and the Pololu protocol (``0xAA, device number,
command & 0x7F, ...``) byte by byte: Set Target (0x84) calls ``on_target(channel,
quarter_us)``; Set Multiple Targets (0x9F), Set Speed (0x87), Set Acceleration (0x89),
Go Home (0xA2) are accepted; Get Position (0x90) answers ``read_analog(channel)`` for
an input channel (a callback returning None marks a servo channel, which answers its
target in quarter-us); Get Moving State (0x93) answers 0; Get Errors (0xA1) answers and
clears ``errors``. Garbage and interrupted commands set the serial protocol error bit
(0x0010) as the real board does. ``close_port()``/``reopen_port()`` simulate unplug and
replug: the pty path changes, so give ``link=`` a path to keep a stable symlink to the
current pty (like ``/dev/serial/by-id``, it is absent while unplugged). Run it standalone with::

    python -m sitl.maestro_emu --link maestro-pty --input 6=512
"""

from __future__ import annotations

import argparse
import logging
import os
import select
import signal
import sys
import threading
import time
import tty
from collections.abc import Callable

log = logging.getLogger(__name__)

PROTOCOL_ERROR = 1 << 4

# compact command byte -> number of data bytes (None: variable, Set Multiple Targets)
_DATA_BYTES: dict[int, int | None] = {
    0x84: 3,  # set target
    0x87: 3,  # set speed
    0x89: 3,  # set acceleration
    0x8A: 4,  # set PWM
    0x90: 1,  # get position
    0x93: 0,  # get moving state
    0x9F: None,  # set multiple targets: count, first channel, 2 bytes per target
    0xA1: 0,  # get errors
    0xA2: 0,  # go home
    0xA4: 0,  # stop script
    0xA7: 1,  # restart script at subroutine
    0xA8: 3,  # ... with parameter
    0xAE: 0,  # get script status
}


class MaestroEmulator:
    """A Maestro on a pty. Callbacks run on the emulator's thread."""

    def __init__(
        self,
        on_target: Callable[[int, int], None] | None = None,
        read_analog: Callable[[int], int | None] | None = None,
        *,
        device_number: int = 12,
        link: str | os.PathLike[str] | None = None,
    ) -> None:
        self.on_target = on_target
        self.read_analog = read_analog
        self.device_number = device_number
        self.link = os.fspath(link) if link is not None else None
        self.errors = 0
        self.mute = False
        """When True, queries get no answer (a board that stopped talking)."""
        self.targets: dict[int, int] = {}
        self.received = bytearray()
        """Every byte the bridge wrote, for tests."""
        self.path: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._wake_r = self._wake_w = -1
        self._thread: threading.Thread | None = None
        self._reset_parser()

    # --- pty lifecycle -------------------------------------------------------------
    def start(self) -> str:
        """Create the pty and start serving; returns the path the bridge should open."""
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._open_pty()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="maestro-emu", daemon=True)
        self._thread.start()
        return self.device_path

    @property
    def device_path(self) -> str:
        """The path to open: the symlink if ``link`` was given, else the pty itself."""
        if self.path is None:
            raise RuntimeError("emulator not started or port closed")
        return self.link if self.link is not None else self.path

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo or line editing before the client configures it
        os.set_blocking(master, False)
        with self._lock:
            self._master, self._slave = master, slave
            self.path = os.ttyname(slave)
            self._reset_parser()
        if self.link is not None:
            tmp = f"{self.link}.tmp{os.getpid()}"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.path, tmp)
            os.replace(tmp, self.link)
        log.info("maestro emulator on %s", self.path)

    def close_port(self) -> None:
        """Simulate unplugging: the pty goes away, the client's reads and writes fail."""
        self._wake()
        with self._lock:
            fds = (self._master, self._slave)
            self._master = self._slave = None
            self.path = None
        for fd in fds:
            if fd is not None:
                os.close(fd)
        if self.link is not None and os.path.islink(self.link):
            os.unlink(self.link)  # like /dev/serial/by-id: gone while unplugged

    def reopen_port(self) -> str:
        """Simulate plugging back in: a new pty (new path); returns ``device_path``."""
        self.close_port()
        self._open_pty()
        return self.device_path

    def stop(self) -> None:
        """Stop serving and remove the pty (and the symlink)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self.close_port()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> MaestroEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- serving -------------------------------------------------------------------
    def _serve(self) -> None:
        # The lock is held across select so that close_port() (which first wakes the
        # select through the pipe) never closes the master while select still holds it:
        # otherwise the pty would stay alive and the client would not see the unplug.
        while not self._stop.is_set():
            idle = False
            with self._lock:
                fd = self._master
                if fd is None:
                    idle = True
                else:
                    ready, _, _ = select.select([fd, self._wake_r], [], [], 0.05)
                    if self._wake_r in ready:
                        os.read(self._wake_r, 64)
                    if fd in ready:
                        try:
                            data = os.read(fd, 256)
                        except BlockingIOError:
                            data = None
                        except OSError:  # EIO: nobody holds the slave open
                            data = b""
                        if data == b"":
                            idle = True
                        elif data:
                            self._handle(fd, data)
            if idle:
                self._stop.wait(0.01)

    def _handle(self, fd: int, data: bytes) -> None:
        self.received.extend(data)
        for byte in data:
            reply = self._feed(byte)
            if reply and not self.mute:
                try:
                    os.write(fd, reply)
                except OSError as exc:
                    log.debug("maestro emulator: reply dropped: %s", exc)

    def _wake(self) -> None:
        if self._wake_w < 0:
            return
        try:
            os.write(self._wake_w, b"x")
        except BlockingIOError:
            pass

    # --- byte parser ---------------------------------------------------------------
    def _reset_parser(self) -> None:
        self._cmd: int | None = None  # compact command being collected
        self._need: int | None = 0
        self._data = bytearray()
        self._pololu = 0  # bytes seen of a Pololu header: 1 after 0xAA, 2 after device number
        self._for_us = True

    def _protocol_error(self, why: str) -> None:
        log.debug("maestro emulator: protocol error: %s", why)
        self.errors |= PROTOCOL_ERROR
        self._reset_parser()

    def _feed(self, byte: int) -> bytes | None:
        """Take one byte; returns the answer when a query completes."""
        if byte & 0x80:
            if self._cmd is not None or self._pololu == 2:
                self._protocol_error("command interrupted")
            self._pololu = 0  # a lone 0xAA is the baud-rate detection byte
            if byte == 0xAA:
                self._pololu = 1
                return None
            return self._begin(byte, for_us=True)
        if self._pololu == 1:  # device number
            self._for_us = byte == self.device_number
            self._pololu = 2
            return None
        if self._pololu == 2:  # command with its top bit cleared
            self._pololu = 0
            return self._begin(byte | 0x80, for_us=self._for_us)
        if self._cmd is None:
            self._protocol_error(f"stray data byte 0x{byte:02X}")
            return None
        self._data.append(byte)
        if self._cmd == 0x9F and self._need is None and len(self._data) == 2:
            self._need = 2 + 2 * self._data[0]
        if self._need is not None and len(self._data) >= self._need:
            return self._complete()
        return None

    def _begin(self, cmd: int, for_us: bool) -> bytes | None:
        if cmd not in _DATA_BYTES:
            if for_us:
                self._protocol_error(f"unknown command 0x{cmd:02X}")
            return None
        self._cmd, self._need, self._data = cmd, _DATA_BYTES[cmd], bytearray()
        self._for_us = for_us
        if self._need == 0:
            return self._complete()
        return None

    def _complete(self) -> bytes | None:
        cmd, data, for_us = self._cmd, bytes(self._data), self._for_us
        self._reset_parser()
        if not for_us:
            return None
        if cmd == 0x84:
            self._set_target(data[0], data[1] | (data[2] << 7))
        elif cmd == 0x9F:
            count, first = data[0], data[1]
            for i in range(count):
                self._set_target(first + i, data[2 + 2 * i] | (data[3 + 2 * i] << 7))
        elif cmd == 0x90:
            return self._position(data[0]).to_bytes(2, "little")
        elif cmd == 0xA1:
            bits, self.errors = self.errors, 0
            return (bits & 0xFFFF).to_bytes(2, "little")
        elif cmd in (0x93, 0xAE):
            return bytes([0 if cmd == 0x93 else 1])
        return None

    def _set_target(self, channel: int, quarter_us: int) -> None:
        self.targets[channel] = quarter_us
        if self.on_target is not None:
            self.on_target(channel, quarter_us)

    def _position(self, channel: int) -> int:
        if self.read_analog is not None:
            value = self.read_analog(channel)
            if value is not None:
                return min(max(int(value), 0), 1023)
        return self.targets.get(channel, 0)


def main(argv: list[str] | None = None) -> None:
    """Serve an emulated Maestro until interrupted, logging every target."""
    ap = argparse.ArgumentParser(prog="python -m sitl.maestro_emu", description=__doc__.split("\n")[0])
    ap.add_argument("--link", help="keep a symlink to the pty at this path")
    ap.add_argument(
        "--input",
        action="append",
        default=[],
        metavar="CH=COUNTS",
        help="answer Get Position on CH with a fixed analog reading (repeatable)",
    )
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    analog = {}
    for item in args.input:
        ch, _, value = item.partition("=")
        analog[int(ch)] = int(value)
    emu = MaestroEmulator(
        on_target=lambda ch, q: log.info("target ch%d %.2f us", ch, q / 4),
        read_analog=analog.get,
        link=args.link,
    )
    log.info("serving on %s", emu.start())
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # clean up the link on kill too
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()


if __name__ == "__main__":
    main()
