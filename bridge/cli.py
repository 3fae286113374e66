"""``warpbridge`` command line: one sub-command per module, loaded on demand.

Each command module provides ``add_arguments(parser)`` and ``main(args) -> int``.
Errors a user can fix (bad files, bad options, missing devices) are raised as
``UserError`` and printed as one line with a non-zero exit, never a traceback.
``--help`` lists every command of ``COMMANDS`` whether or not its module can be
imported; a command whose module (or a module it needs, such as an optional
dependency) cannot be imported fails with one line naming what is missing.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import logging
import sys
from types import ModuleType

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
    "review": ("warpbridge.bridge.commands.review", "review a flight from the FC's log and the cycle log"),
}


# exit status of a command that cannot be loaded (argparse and UserError use 2)
EXIT_UNAVAILABLE = 1


class CommandUnavailable(Exception):
    """A command's module, or a module it imports, cannot be imported (an incomplete install)."""

    def __init__(self, command: str, message: str) -> None:
        super().__init__(message)
        self.command = command


def version() -> str:
    """The installed distribution's version, or ``unknown`` when run from files that are not installed."""
    try:
        return importlib.metadata.version("warpbridge")
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def load(name: str) -> ModuleType:
    """The module of command ``name``; raises ``CommandUnavailable`` naming what is missing."""
    module = COMMANDS[name][0]
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise CommandUnavailable(name, f"cannot load {module}: {e}") from e


def _chosen(argv: list[str], names: set[str]) -> str | None:
    """The sub-command named in ``argv`` (the first word that is one), or None (also when ``--help`` or
    ``--version`` comes first: argparse answers those before it reaches the command)."""
    for word in argv:
        if word in ("-h", "--help", "--version"):
            return None
        if word in names:
            return word
        if not word.startswith("-"):
            return None
    return None


def needs_default(action: argparse.Action, text: str) -> bool:
    """Whether an option's help ``text`` should be followed by its default: it takes a value, has a default,
    and the text does not give it already (``--help`` and docs/commands.md alike)."""
    return bool(action.option_strings) and action.nargs != 0 and "default" not in text \
        and action.default not in (None, "", [], argparse.SUPPRESS)


class DefaultsFormatter(argparse.HelpFormatter):
    """Help that gives an option's default where its text does not already (``needs_default``)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        return text + " (default %(default)s)" if needs_default(action, text) else text


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; only the chosen command's module is imported (all of them when ``argv`` is None).

    ``warpbridge run`` thus loads what a cycle needs and nothing of identification or plotting.
    Every command is listed; raises ``CommandUnavailable`` when a module to import cannot be.
    """
    parser = argparse.ArgumentParser(
        prog="warpbridge",
        description="Hysteresis-compensated tendon-sheath wing warping beside a PX4/ArduPilot autopilot.",
    )
    parser.add_argument("-v", "--verbose", dest="verbose_top", action="count", default=0,
                        help="more log output (-v for debug)")
    parser.add_argument("-q", "--quiet", dest="quiet_top", action="count", default=0,
                        help="less log output: warnings and faults only (-qq: errors only)")
    parser.add_argument("--version", action="version", version=f"warpbridge {version()}",
                        help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = None if argv is None else _chosen(argv, set(COMMANDS))
    for name, (_path, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_, formatter_class=DefaultsFormatter)
        if argv is None or name == chosen:
            module = load(name)
            module.add_arguments(p)
            p.set_defaults(_module=module)
            _add_common(p)
    return parser


def _add_common(p: argparse.ArgumentParser) -> None:
    """The common options after the command as well (``warpbridge predict ... -v``), hidden from its help and
    marked ``common``; ``main`` adds the counts before and after the command. Where the command has an option
    of the same name (``identify --quiet``: no progress bar), that name stays the command's own."""
    taken = set(p._option_string_actions)
    for flags, kw in (("-v", "--verbose"), {"dest": "verbose_after", "action": "count", "default": 0}), \
                     (("-q", "--quiet"), {"dest": "quiet_after", "action": "count", "default": 0}), \
                     (("--version",), {"action": "version", "version": f"warpbridge {version()}"}):
        free = [f for f in flags if f not in taken]
        if free:
            action = p.add_argument(*free, help=argparse.SUPPRESS, **kw)
            action.common = True  # type: ignore[attr-defined]


def _subparser(parser: argparse.ArgumentParser, name: str | None) -> argparse.ArgumentParser | None:
    """The parser of command ``name`` (None when there is none)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name in action.choices:
            return action.choices[name]
    return None


NOISY_LIBRARIES = ("matplotlib", "numba", "PIL")


def log_level(verbose: int, quiet: int) -> int:
    """INFO by default (what the program connected to, asked for, mode changes, faults); -v debug, -q warnings."""
    return min(logging.ERROR, max(logging.DEBUG, logging.INFO - 10 * verbose + 10 * quiet))


def main(argv: list[str] | None = None) -> int:
    from warpbridge.bridge import jitcache

    jitcache.configure()  # before any command imports numba: a writable compile cache
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser(argv)
    except CommandUnavailable as e:
        print(f"warpbridge {e.command}: {e}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    args, extra = parser.parse_known_args(argv)
    if extra:  # an option the command does not know: its usage, not the top level's (unless it came first)
        name = getattr(args, "command", None)
        after = name is not None and all(x not in argv[:argv.index(name)] for x in extra)
        ((_subparser(parser, name) if after else None) or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    # the log level counts -v and -q before the command and after it; a command's own --quiet (which only it
    # reads, as ``args.quiet``) lowers it as well
    verbose = args.verbose_top + getattr(args, "verbose_after", 0)
    quiet = args.quiet_top + getattr(args, "quiet_after", 0) + int(bool(getattr(args, "quiet", False)))
    level = log_level(verbose, quiet)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for name in NOISY_LIBRARIES:  # their debug output is about themselves (fonts, compiler passes), not the run
        logging.getLogger(name).setLevel(max(logging.INFO, level))
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._module.main(args) or 0)
    except UserError as e:
        print(f"warpbridge {args.command}: error: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:  # imported only when needed (e.g. a plotting library): an incomplete install
        logging.getLogger(__name__).debug("import failed", exc_info=True)
        print(f"warpbridge {args.command}: cannot load a module it needs: {e}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    except KeyboardInterrupt:
        print(f"warpbridge {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
