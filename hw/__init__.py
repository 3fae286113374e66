"""Device drivers behind small interfaces: servo outputs, warp sensors, calibration.

Backends are chosen by a string, like pyserial URLs (the interfaces are in ``hw.base``):

=================================  ===================================================
``maestro:<url or device>[,baud]``  Pololu Maestro (``hw.maestro``); any pyserial URL,
                                    e.g. ``maestro:spy:///dev/ttyACM0`` to watch bytes;
                                    ``,timeout=S``: wait up to S s for an answer (0.02)
``line:<url or device>[,baud]``     sensor board printing lines of counts (``hw.line_sensor``)
``fc:`` / ``fc:ardupilot|px4``      the FC's spare outputs over MAVLink (``hw.fc_outputs``)
``loop:``                           in memory, for tests (``hw.loop``)
``none``                            no sensor
=================================  ===================================================
"""

from __future__ import annotations

import os
from typing import Any

from warpbridge.hw.base import NullSensor, ServoOutput, WarpSensor, parse_serial_spec
from warpbridge.hw.errors import DeviceError

__all__ = ["DeviceError", "ServoOutput", "WarpSensor", "open_sensor", "open_servo"]


def _maestro(rest: str, default_baud: int) -> tuple[str, int, dict[str, float]]:
    """``<url or device>[,baud][,timeout=S]`` -> (url, baud, Maestro options)."""
    head, sep, tail = rest.rpartition(",")
    options: dict[str, float] = {}
    if sep and tail.strip().startswith("timeout="):
        try:
            options["timeout"] = float(tail.strip()[len("timeout="):])
        except ValueError:
            raise ValueError(f"bad timeout in {rest!r}: expected timeout=<seconds>") from None
        if not 0 < options["timeout"] <= 10:
            raise ValueError(f"timeout in {rest!r} must be in (0, 10] s")
        rest = head
    url, baud = parse_serial_spec(rest, default_baud)
    return url, baud, options


def _split(spec: str) -> tuple[str, str]:
    kind, sep, rest = spec.strip().partition(":")
    if not sep and kind != "none":
        raise ValueError(f"bad device spec {spec!r}: expected kind:details, e.g. maestro:/dev/ttyACM0")
    return kind.lower(), rest


def open_servo(
    spec: str,
    *,
    mavlink_sender: Any = None,
    limits: dict[int, tuple[float, float]] | None = None,
    **options: Any,
) -> ServoOutput:
    """Open the servo backend named by ``spec``.

    ``limits`` (channel -> (min_us, max_us)) is each channel's safe pulse range.
    ``fc:`` needs ``mavlink_sender`` (a pymavlink connection, or an object whose ``.mav``
    is one); target ids and autopilot come from ``options`` or its attributes
    ``target_system``, ``target_component``, ``autopilot``. Other ``options`` go to the
    backend's constructor. Raises ValueError (bad spec) or DeviceError (cannot open).
    """
    kind, rest = _split(spec)
    if kind == "maestro":
        from warpbridge.hw.maestro import DEFAULT_BAUD, Maestro

        url, baud, extra = _maestro(rest, DEFAULT_BAUD)
        return Maestro(url, baud, limits=limits, **{**extra, **options})
    if kind == "fc":
        from warpbridge.hw.fc_outputs import AUTOPILOTS, FcOutputs

        if mavlink_sender is None:
            raise ValueError("servo spec 'fc:' needs a MAVLink connection (mavlink_sender)")
        autopilot = rest.strip().lower() or options.pop("autopilot", None)
        autopilot = autopilot or getattr(mavlink_sender, "autopilot", None) or "ardupilot"
        if autopilot not in AUTOPILOTS:
            raise ValueError(f"bad servo spec {spec!r}: autopilot must be one of {AUTOPILOTS}")
        ts = options.pop("target_system", None) or getattr(mavlink_sender, "target_system", 1) or 1
        tc = options.pop("target_component", None) or getattr(mavlink_sender, "target_component", 1) or 1
        return FcOutputs(mavlink_sender, ts, tc, autopilot, limits=limits, **options)
    if kind == "loop":
        from warpbridge.hw.loop import LoopBackend

        return LoopBackend(**options)
    raise ValueError(f"unknown servo spec {spec!r}: use maestro:<device>[,baud], fc:, or loop:")


def sensor_on_servo_port(sensor_spec: str, servo_spec: str) -> bool:
    """True when the sensor spec names the servo spec's Maestro (``maestro:`` alone, or its device): one
    device, open or lost together. Raises ValueError on a bad sensor spec (a bad servo spec is not its)."""
    kind, rest = _split(sensor_spec)
    if kind != "maestro":
        return False
    try:
        skind, srest = _split(servo_spec)
        servo_url = _maestro(srest, 0)[0] if skind == "maestro" else None
    except ValueError:  # the servo's spec: reported as the servo's
        return False
    return servo_url is not None and (not rest.strip() or _same_device(_maestro(rest, 0)[0], servo_url))


def _same_device(a: str, b: str | None) -> bool:
    """Whether two port names are one device (``/dev/serial/by-id/...`` is a link to ``/dev/ttyACM0``)."""
    return b is not None and (a == b or ("://" not in a + b and os.path.realpath(a) == os.path.realpath(b)))


def open_sensor(spec: str, *, shared_servo: Any = None, **options: Any) -> WarpSensor:
    """Open the sensor backend named by ``spec``.

    A Maestro serves servos and sensors on one port: with ``maestro:`` (no device) or
    the same device as ``shared_servo``, that object is returned. ``loop:`` likewise
    returns a shared ``LoopBackend``. Raises ValueError (bad spec) or DeviceError.
    """
    kind, rest = _split(spec)
    if kind == "none":
        return NullSensor()
    if kind == "maestro":
        from warpbridge.hw.maestro import DEFAULT_BAUD, Maestro

        same_port = not rest.strip() or _same_device(_maestro(rest, 0)[0], getattr(shared_servo, "url", None))
        if isinstance(shared_servo, Maestro) and same_port:
            return shared_servo
        if not rest.strip():
            raise ValueError("sensor spec 'maestro:' without a device needs the servo backend to be a Maestro")
        url, baud, extra = _maestro(rest, DEFAULT_BAUD)
        return Maestro(url, baud, **{**extra, **options})
    if kind == "line":
        from warpbridge.hw.line_sensor import DEFAULT_BAUD, LineSensor

        url, baud = parse_serial_spec(rest, DEFAULT_BAUD)
        return LineSensor(url, baud, **options)
    if kind == "loop":
        from warpbridge.hw.loop import LoopBackend

        if isinstance(shared_servo, LoopBackend):
            return shared_servo
        return LoopBackend(**options)
    raise ValueError(f"unknown sensor spec {spec!r}: use maestro:[device], line:<device>[,baud], loop:, or none")
