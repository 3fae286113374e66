"""``warpbridge calibrate``: pre-flight self-calibration of the tendon model from the command line.

Starts the bridge with the given configuration (FC link, tendon servos, flex
sensors), waits for the flight controller's heartbeat, and runs the same
calibration a ground station starts with ``WB_CAL_RUN``: only while the FC
reports disarmed; both tendons fly a short excitation within the safe part of
the warp range, the record is fitted, and each wing's new model is applied
(and persisted beside the parameter file, for the next ``warpbridge run``) only
if it passes the held-out check. ``--restore`` swaps each wing's model with the
one before the last calibration. Do not run it while ``warpbridge run`` holds
the same servo port: from a running bridge, use the ground station.

Examples::

    warpbridge calibrate --config warpbridge.toml
    warpbridge calibrate --config warpbridge.toml --full
    warpbridge calibrate --config bench.toml --no-fc      # bench rig without a flight controller
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from warpbridge.bridge.errors import UserError

if TYPE_CHECKING:
    from warpbridge.bridge.app import Bridge
    from warpbridge.bridge.config import Config

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, required=True, help="the bridge's TOML configuration")
    parser.add_argument("--full", action="store_true", help="re-identify the full model (slower)")
    parser.add_argument("--restore", action="store_true", help="restore the model before the last calibration")
    parser.add_argument("--seconds", type=float, default=None, metavar="S",
                        help="excitation length, 8..29 s (default: WB_CAL_SEC, 20)")
    parser.add_argument("--timeout", type=float, default=10.0, metavar="S",
                        help="wait this long for the FC's heartbeat (default 10)")
    parser.add_argument("--no-fc", action="store_true",
                        help="bench rig without a flight controller: nobody can report arming; you take that on")


def main(args: argparse.Namespace) -> int:
    from warpbridge.bridge.app import Bridge
    from warpbridge.bridge.config import load_config
    from warpbridge.bridge.instance_lock import InstanceLock

    if args.seconds is not None and not 8.0 <= args.seconds <= 29.0:
        raise UserError("--seconds must be within 8..29")
    if not 0.0 <= args.timeout <= 600.0:
        raise UserError("--timeout must be within 0..600 s")
    config = load_config(args.config)
    with InstanceLock(config.params_file).acquire("calibrate"):
        return _calibrate(args, config, Bridge(config, connect_timeout=0.0 if args.no_fc else args.timeout))


def _calibrate(args: argparse.Namespace, config: Config, bridge: Bridge) -> int:
    from warpbridge.bridge.calibrate import CalState, Refused
    from warpbridge.bridge.loop_timer import LoopTimer

    try:
        tuning = bridge.tuning
        tuning.allow_no_fc = args.no_fc
        if args.seconds is not None:
            tuning.cal_seconds = args.seconds
        timer = LoopTimer(config.loop.rate_hz)
        for _ in range(int(config.loop.rate_hz)):  # a second of normal cycles: sensors read, state known
            bridge.tick()
            timer.wait()
        try:
            if args.restore:
                tuning.restore()
                print(f"previous model restored: {tuning.last_restore} (--restore again swaps back)")
                return 0
            tuning.start_calibration(full=args.full, source="command line")
        except Refused as e:
            raise UserError(f"calibration refused: {e}") from None
        print(f"calibrating for {tuning.cal_seconds:.0f} s: keep clear of the wings")
        while tuning.running:
            bridge.tick()
            timer.wait()
        for _ in range(int(config.loop.rate_hz)):  # the wings back where the FC wants them
            bridge.tick()
            timer.wait()
        if tuning.state == CalState.ABORTED:
            print(f"calibration aborted: {tuning.last_reason}")
            return 1
        for wing, res in tuning.last_results.items():
            if isinstance(res, str):
                print(f"{wing}: kept old model: {res}")
                continue
            tf = res.transform
            what = "full model" if res.full else (f"offset {tf.offset:+.3f} mm, gain {tf.gain:.4f}, "
                                                   f"width x{tf.az_scale:.3f}")
            print(f"{wing}: {what}; held-out RMS {res.heldout_rms:.3f} deg (old model {res.old_heldout_rms:.3f}, "
                  f"noise {res.noise:.3f}); {'APPLIED' if res.accepted else 'kept old model'}: {res.reason}")
        return 0
    finally:
        bridge.close()
