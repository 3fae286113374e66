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
    "simulate": ("warpbridge.bridge.commands.simulate", "write a log simulated from a plant and an excitation"),
    "identify": ("warpbridge.bridge.commands.identify", "identify a Bouc-Wen model from a log"),
    "predict": ("warpbridge.bridge.commands.predict", "predict warp from a log's tendon input with a model"),
    "diagnose": ("warpbridge.bridge.commands.diagnose", "find and explain the gap between a model and a log"),
    "calibrate": ("warpbridge.bridge.commands.calibrate", "pre-flight self-calibration of the tendon model"),
}


def _available() -> dict[str, tuple[str, str]]:
    out = {}
    for name, (mod, help_) in COMMANDS.items():
        try:
            found = importlib.util.find_spec(mod) is not None
        except ModuleNotFoundError:  # the command's package is not installed
            found = False
        if found:
            out[name] = (mod, help_)
    return out


def _chosen(argv: list[str], names: set[str]) -> str | None:
    """The sub-command named in ``argv`` (the first word that is one), or None."""
    for word in argv:
        if word in names:
            return word
        if not word.startswith("-"):
            return None
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; only the chosen command's module is imported (all of them when ``argv`` is None).

    ``warpbridge run`` thus loads what a cycle needs and nothing of identification or plotting.
    """
    parser = argparse.ArgumentParser(
        prog="warpbridge",
        description="Hysteresis-compensated tendon-sheath wing warping beside a PX4/ArduPilot autopilot.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v for debug)")
    parser.add_argument("-q", "--quiet", action="count", default=0,
                        help="less log output: warnings and faults only (-qq: errors only)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    available = _available()
    chosen = None if argv is None else _chosen(argv, set(available))
    for name, (mod, help_) in available.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if argv is None or name == chosen:
            module = importlib.import_module(mod)
            module.add_arguments(p)
            p.set_defaults(_module=module)
    return parser


def log_level(verbose: int, quiet: int) -> int:
    """INFO by default (what the program connected to, asked for, mode changes, faults); -v debug, -q warnings."""
    return min(logging.ERROR, max(logging.DEBUG, logging.INFO - 10 * verbose + 10 * quiet))


def main(argv: list[str] | None = None) -> int:
    from warpbridge.bridge import jitcache

    jitcache.configure()  # before any command imports numba: a writable compile cache
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    logging.basicConfig(level=log_level(args.verbose, args.quiet), format="%(levelname)s %(name)s: %(message)s")
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
