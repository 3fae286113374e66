"""MAVLink 2 message signing for the FC link: the key file and a hardened signature check.

With a key, every frame the bridge sends is signed, and ``FcLink`` refuses
unsigned or wrongly signed commands (PARAM_SET, COMMAND_LONG, ... anything that
is not the FC's own stream) and counts them. The FC's stream (HEARTBEAT,
SERVO_OUTPUT_RAW, ACTUATOR_OUTPUT_STATUS, VFR_HUD, COMMAND_ACK from the FC's
system, component 1) may stay unsigned: ``accept_unsigned_from_fc`` (default
true) is for an FC without the key on that port.

The key file holds the 32-byte secret as 64 hex digits, or a passphrase from
which the key is derived as SHA-256 of its UTF-8 bytes, the way MAVProxy's
``signing setup <passphrase>`` and Mission Planner do, so the same passphrase
gives the same key everywhere. Lines starting with ``#`` and blank lines are
ignored; the first other line is the key or the passphrase (no surrounding
spaces). ``python -m bridge.signing KEYFILE`` prints the key in hex, for
checking against the ground station.

``Signer`` replaces pymavlink's ``MAVLink.check_signature``, which records a
stream's timestamp *before* checking the signature: a forged frame with a far
future timestamp would then lock the real sender's stream out, and random
link ids would grow its table without bound. Here the signature is checked
first and only an authentic frame moves a stream's timestamp. The state
(stream timestamps, our send timestamp) survives reconnects, so a reconnect
does not reopen the replay window.
"""

from __future__ import annotations

import argparse
import hashlib
import hmac
import logging
import os
import stat
import struct
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from warpbridge.bridge.errors import UserError

log = logging.getLogger(__name__)

KEY_LEN = 32
EPOCH_2015 = 1420070400  # MAVLink signing timestamps count 10 us units from 2015-01-01 UTC
NEW_STREAM_SLACK = 6_000_000  # a new stream may be up to 60 s behind our timestamp (as in the C library)
MAX_STREAMS = 256  # authentic streams remembered (link id, system, component)


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte key MAVProxy (``signing setup``) and Mission Planner derive: SHA-256 of the text."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def parse_key(text: str) -> bytes:
    """Key from key-file text: 64 hex digits, or a passphrase (SHA-256). Raises ValueError."""
    lines = [ln.strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    if not lines:
        raise ValueError("no key in the file")
    line = lines[0]
    if len(line) == 2 * KEY_LEN and all(c in "0123456789abcdefABCDEF" for c in line):
        key = bytes.fromhex(line)
    else:
        if len(line) < 8:
            raise ValueError("passphrase shorter than 8 characters")
        key = key_from_passphrase(line)
    if key == bytes(KEY_LEN):
        raise ValueError("an all-zero key disables signing; use another")
    return key


def load_key(path: str | os.PathLike[str]) -> bytes:
    """Read a key file; UserError (one line) if it cannot be read or holds no usable key."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise UserError(f"signing key file {p}: cannot read: {e.strerror or e}") from None
    try:
        key = parse_key(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise UserError(f"signing key file {p}: not text (expected 64 hex digits or a passphrase)") from None
    except ValueError as e:
        raise UserError(f"signing key file {p}: {e}") from None
    try:
        mode = p.stat().st_mode
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning("signing key file %s is readable by others (chmod 600 it)", p)
    except OSError:
        pass
    return key


@dataclass(frozen=True)
class SigningPolicy:
    """What ``FcLink`` does with signing: the key, and whether the FC's own stream may be unsigned."""

    key: bytes
    accept_unsigned_from_fc: bool = True

    def __post_init__(self) -> None:
        if len(self.key) != KEY_LEN:
            raise ValueError(f"a MAVLink signing key is {KEY_LEN} bytes")

    def __repr__(self) -> str:  # never print the key
        return f"SigningPolicy(key=<{len(self.key)} bytes>, accept_unsigned_from_fc={self.accept_unsigned_from_fc})"


def policy_from_config(link_config: Any) -> SigningPolicy | None:
    """``[link] signing_key_file`` / ``signing_accept_unsigned_from_fc`` -> policy, None if no key file."""
    path = getattr(link_config, "signing_key_file", None)
    if path is None:
        return None
    accept = bool(getattr(link_config, "signing_accept_unsigned_from_fc", True))
    return SigningPolicy(load_key(path), accept)


def now_timestamp() -> int:
    """The current signing timestamp (10 us units since 2015), 0 for a clock before 2015."""
    return max(0, int((time.time() - EPOCH_2015) * 100_000))


class Signer:
    """Signing state for one link, installed into each (re)opened pymavlink connection."""

    def __init__(self, key: bytes, link_id: int = 0) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"a MAVLink signing key is {KEY_LEN} bytes")
        self.key = bytes(key)
        self.link_id = int(link_id) & 0xFF
        self.stream_timestamps: dict[tuple[int, int, int], int] = {}
        self.timestamp = now_timestamp()
        self._mav: Any = None  # the pymavlink MAVLink object currently signing
        self.good = 0
        self.bad = 0  # signature present but wrong, replayed or too old

    def install(self, conn: Any) -> None:
        """Set up signing on a pymavlink connection (``mavutil`` file): sign outgoing, check incoming.

        Unsigned and badly signed frames are still decoded (``msg._signed`` is False): the
        link decides what it accepts, knowing the sender and the message type."""
        self.timestamp = max(self.timestamp, self._current_timestamp(), now_timestamp())
        conn.setup_signing(self.key, sign_outgoing=True, allow_unsigned_callback=_accept_for_link_policy,
                           initial_timestamp=self.timestamp, link_id=self.link_id)
        conn.mav.check_signature = self.check_signature  # instance attribute wins over the method
        self._mav = conn.mav

    def installed_on(self, conn: Any) -> bool:
        mav = getattr(conn, "mav", None)
        return mav is not None and mav is self._mav and mav.signing.secret_key == self.key

    def _current_timestamp(self) -> int:
        return int(self._mav.signing.timestamp) if self._mav is not None else 0

    def check_signature(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        """Check a signed frame: signature first, then the timestamp (no replay, not too old)."""
        if len(msgbuf) < 13 + 10:
            self.bad += 1
            return False
        expected = hashlib.sha256(self.key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
            self.bad += 1
            return False
        link_id = msgbuf[-13]
        tlow, thigh = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
        timestamp = tlow + (thigh << 32)
        key = (link_id, src_system, src_component)
        ours = self._current_timestamp()
        last = self.stream_timestamps.get(key)
        if last is not None:
            if timestamp <= last:
                self.bad += 1  # replayed or reordered
                return False
        elif timestamp + NEW_STREAM_SLACK < ours:
            self.bad += 1  # a new stream more than a minute in the past: a replay
            return False
        if last is None and len(self.stream_timestamps) >= MAX_STREAMS:
            oldest = min(self.stream_timestamps, key=self.stream_timestamps.__getitem__)
            del self.stream_timestamps[oldest]
        self.stream_timestamps[key] = timestamp
        if self._mav is not None and timestamp > ours:
            self._mav.signing.timestamp = timestamp
        self.good += 1
        return True


def _accept_for_link_policy(mav: Any, msg_id: int) -> bool:
    """pymavlink's allow-unsigned callback: decode everything, ``FcLink`` applies the policy."""
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bridge.signing",
                                     description="print the MAVLink signing key a key file holds, in hex")
    parser.add_argument("keyfile")
    args = parser.parse_args(argv)
    try:
        key = load_key(args.keyfile)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(key.hex())
    return 0


if __name__ == "__main__":
    sys.exit(main())
