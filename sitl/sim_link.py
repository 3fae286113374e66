"""The flight controller as ``bridge.app.Bridge`` sees an ``FcLink``, with no socket: the state a
lock-step simulation sets directly, and sends that are only recorded, except a request for what an
output does (``SERVOn_FUNCTION``), which the simulated FC answers as ArduPilot does."""

from __future__ import annotations

import logging

from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.sitl.mock_autopilot import OutputFunctionParams

log = logging.getLogger(__name__)
FC_COMPONENT = 1


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
        self.output_functions = OutputFunctionParams("ardupilot")  # outputs 1, 2 ailerons, as the rig's FC
        self._replies: list = []
        self._fc = mavlink.MAVLink(None, srcSystem=self.system_id, srcComponent=FC_COMPONENT)

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
        self.fc_answer(msg)
        return True

    def fc_answer(self, msg) -> None:
        """Queue the FC's PARAM_VALUE for a PARAM_REQUEST_READ of an output-function parameter."""
        try:
            if msg.get_type() != "PARAM_REQUEST_READ" or msg.target_component != FC_COMPONENT:
                return
            name = msg.param_id.decode("ascii", "replace") if isinstance(msg.param_id, bytes) else msg.param_id
        except AttributeError:
            return
        name = name.rstrip("\x00")
        if name not in self.output_functions.values:
            return
        value, ptype = self.output_functions.encode(name)
        names = sorted(self.output_functions.values)
        reply = mavlink.MAVLink_param_value_message(name.encode("ascii"), value, ptype, len(names),
                                                    names.index(name))
        self._replies.append(self._fc.decode(bytearray(reply.pack(self._fc))))

    def take_replies(self) -> list:
        """The FC's answers queued since the last call (what ``poll`` hands the bridge)."""
        out, self._replies = self._replies, []
        return out

    def command_long_send(self, *args) -> bool:
        return True

    def set_servo_rate(self, rate_hz: float) -> None:
        log.debug("simulated link: servo rate %g Hz asked (the stream keeps its rate)", rate_hz)

    def connect(self, timeout: float = 0.0) -> bool:
        return True

    def close(self) -> None:
        pass
