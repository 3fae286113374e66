"""Errors raised by the device drivers in ``hw``.

``DeviceError`` means the device is not usable right now (port lost, USB unplugged, no
such device): the caller stops driving it and retries with back-off via the backend's
``reopen()``. Bad configuration (spec strings, calibration tables) raises ``ValueError``.
"""

from __future__ import annotations


class DeviceError(Exception):
    """A device could not be opened, written or read; ``device`` names it for reports."""

    def __init__(self, message: str, device: str = "") -> None:
        super().__init__(f"{device}: {message}" if device else message)
        self.device = device
