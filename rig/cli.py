"""The ``rig`` command line: one module per subcommand under :mod:`rig.commands`.

Each module in :data:`COMMAND_MODULES` defines ``register(subparsers)``, which adds its parser and sets
``handler`` to a function ``(args) -> int`` returning an exit code from :mod:`rig.exit_codes`. Heavy
imports happen inside the handlers, so ``rig --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from rig import __version__, exit_codes
from rig.protocols.errors import ConfigError, DeviceFault, LogFileError, TransportError

COMMAND_MODULES: tuple[str, ...] = (
    "rig.commands.demo",
    "rig.commands.identify",
    "rig.commands.simulate",
    "rig.commands.inspect",
    "rig.commands.run",
    "rig.commands.diagnose",
    "rig.commands.report",
)

EPILOG = """exit codes:
  0  success
  1  unexpected error (a bug: please report it with the command line)
  2  bad input: a file, config key, argument or sample that cannot be used (the message names it)
  3  device fault or link failure (the message names the device and its fault code)
  4  empty feasible set: the data contradict the model structure and the noise bound
  130  interrupted by Ctrl-C (after a controlled stop; the log is complete up to the stop)
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig",
        description="Drive a gearbox test rig, simulate it, and identify backlash and dynamics from its logs.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", required=True)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return exit_codes.INTERRUPTED
    except (ValueError, ConfigError, LogFileError, FileNotFoundError, IsADirectoryError) as err:
        # identify's InvalidInputError and every config/log error are ValueErrors with a complete message.
        print(f"rig: error: {err}", file=sys.stderr)
        return exit_codes.BAD_INPUT
    except (DeviceFault, TransportError) as err:
        print(f"rig: device error: {err}", file=sys.stderr)
        return exit_codes.DEVICE_FAULT


if __name__ == "__main__":
    sys.exit(main())
