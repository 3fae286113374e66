"""The flight controller as ``bridge.app.Bridge`` sees an ``FcLink``, with no socket: the state a
lock-step simulation sets directly, and sends that are only recorded."""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)


class SimLinkBase:
    """FcLink's attributes and send methods; subclasses decide what ``poll`` delivers."""

    component_id = 191

    def __init__(self) -> None:
        self.system_id = 1
        self.autopilot = "ardupilot"
        self.armed = False
        self.fc_alive = True
        self.ready = True
        self.mav = None
        self.servo_pwm: dict[int, float] = {}
        self.servo_raw: dict[int, float] = {}
        self.servo_invalid: set[int] = set()
        self.servo_time: float | None = None
        self.airspeed: float | None = None
        self.airspeed_time: float | None = None
        self.acks: dict[int, int] = {}
        self.texts: list[str] = []
        self.named: dict[str, float] = {}  # latest value of each NAMED_VALUE_FLOAT
        self.named_sent = 0

    def poll(self) -> list:
        return []

    def send_named_float(self, name: str, value: float) -> bool:
        self.named[name] = value
        self.named_sent += 1
        return True

    def send_statustext(self, severity: int, text: str) -> bool:
        self.texts.append(text)
        log.debug("STATUSTEXT %s", text)
        return True

    def send(self, msg) -> bool:
        return True

    def command_long_send(self, *args) -> bool:
        return True

    def set_servo_rate(self, rate_hz: float) -> None:
        log.debug("simulated link: servo rate %g Hz asked (the stream keeps its rate)", rate_hz)

    def connect(self, timeout: float = 0.0) -> bool:
        return True

    def close(self) -> None:
        pass
