"""MAVLink 2 and the ardupilotmega dialect, fixed before pymavlink is imported.

pymavlink chooses MAVLink 1 or 2 from the environment variable ``MAVLINK20`` and
the message set from ``MAVLINK_DIALECT``, both read when ``pymavlink.mavutil`` is
first imported. Every bridge module imports MAVLink through this module
(``from warpbridge.bridge.mavlink_env import mavutil, mavlink``) so that the bridge always
speaks MAVLink 2 with the ardupilotmega dialect (which includes common.xml). If
something imported pymavlink earlier with other settings, the dialect is
switched here.
"""

from __future__ import annotations

import os

DIALECT = "ardupilotmega"

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = DIALECT

from pymavlink import mavutil  # noqa: E402

if mavutil.current_dialect != DIALECT or mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
    mavutil.set_dialect(DIALECT)

mavlink = mavutil.mavlink

__all__ = ["DIALECT", "mavlink", "mavutil"]
