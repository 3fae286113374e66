"""``warpbridge`` command line: one sub-command per module, loaded on demand.

Each command module provides ``add_arguments(parser)`` and ``main(args) -> int``.
Errors a user can fix (bad files, bad options, missing devices) are raised as
``UserError`` and printed as one line with a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import sys

from warpbridge.bridge.errors import UserError

# name -> (module, one-line help). ``sitl`` lives in the sitl package: it is
# loaded by name so that the running bridge never imports simulation code.
COMMANDS: dict[str, tuple[str, str]] = {
    "sitl": ("warpbridge.sitl.cmd_sitl", "run the SITL demo: mock autopilot, simulated wings, the bridge"),
    "run": ("warpbridge.bridge.cmd_run", "run the bridge on a real flight controller"),
    "simulate": ("warpbridge.bridge.cmd_simulate", "write a log simulated from a plant and an excitation"),
    "identify": ("warpbridge.bridge.cmd_identify", "identify a Bouc-Wen model from a log"),
    "predict": ("warpbridge.bridge.cmd_predict", "predict warp from a log's tendon input with a model"),
    "diagnose": ("warpbridge.bridge.cmd_diagnose", "find and explain the gap between a model and a log"),
    "calibrate": ("warpbridge.bridge.cmd_calibrate", "pre-flight self-calibration of the tendon model"),
}


def _available() -> dict[str, tuple[str, str]]:
    out = {}
    for name, (mod, help_) in COMMANDS.items():
        if importlib.util.find_spec(mod) is not None:
            out[name] = (mod, help_)
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warpbridge",
        description="Hysteresis-compensated tendon-sheath wing warping beside a PX4/ArduPilot autopilot.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (mod, help_) in _available().items():
        p = sub.add_parser(name, help=help_, description=help_)
        module = importlib.import_module(mod)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._module.main(args) or 0)
    except UserError as e:
        print(f"warpbridge {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"warpbridge {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
