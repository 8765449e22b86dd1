"""The ``rig`` command line: one module per subcommand under :mod:`rig.commands`.

Each module in :data:`COMMAND_MODULES` defines ``register(subparsers)``, which adds its parser and sets
``handler`` to a function ``(args) -> int`` returning an exit code from :mod:`rig.exit_codes`. Heavy
imports happen inside the handlers, so ``rig --help`` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import TextIO

from rig import __version__, exit_codes
from rig.protocols.errors import ConfigError, DeviceFault, LogFileError, TransportError

COMMAND_MODULES: tuple[str, ...] = (
    "rig.commands.demo",
    "rig.commands.identify",
    "rig.commands.simulate",
    "rig.commands.inspect",
    "rig.commands.run",
    "rig.commands.diagnose",
    "rig.commands.trend",
    "rig.commands.report",
    "rig.commands.export",
    "rig.commands.import_trace",
)

EPILOG = """exit codes:
  0  success
  1  unexpected error (a bug: please report it with the command line)
  2  bad input: a file, config key, argument or sample that cannot be used (the message names it)
  3  device fault or link failure (the message names the device and its fault code)
  4  empty feasible set: the data contradict the model structure and the noise bound
  5  the output could not be written (path not writable, directory missing, disk full); the message
     names the path, and a run stops the rig in a controlled way and keeps the samples flushed before
  130  interrupted by Ctrl-C / SIGINT (after a controlled stop; the log is complete up to the stop)
  143  terminated by SIGTERM (the same controlled stop)
A closed pipe (rig inspect LOG | head -1) ends the output quietly with exit code 0.
"""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, raised in the main thread so that every ``finally`` runs on the way out: the
    runner's controlled stop (quick stop, then disable) and the log's flush and close.

    A ``KeyboardInterrupt`` (a ``BaseException``), so no ``except Exception`` on the way swallows it."""

    def __init__(self, signal_number: int) -> None:
        self.signal_number = signal_number
        super().__init__(signal.Signals(signal_number).name)


DRIVE_COMMANDS = ("rig.commands.run", "rig.commands.demo")
"""Commands that enable a drive: only their messages speak of a controlled stop of it."""


@contextlib.contextmanager
def signals_as_interrupts(drives: bool = True) -> Iterator[None]:
    """Turn the first SIGINT or SIGTERM into :class:`Interrupted`; while the stop that follows runs,
    further signals are reported and ignored, so a second Ctrl-C cannot cut the controlled stop short
    (SIGKILL still ends the process at once). Handlers are restored on exit; outside the main thread
    (where Python cannot install handlers) nothing changes. ``drives``: the command enables a drive (the
    message about a second signal says what SIGKILL would leave)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    stopping = False

    def interrupt(signal_number: int, frame: FrameType | None) -> None:
        nonlocal stopping
        if stopping:
            if drives:
                print(f"rig: {signal.Signals(signal_number).name} again: still stopping in a controlled way "
                      "(SIGKILL abandons the stop and leaves the drive as it is)", file=sys.stderr, flush=True)
            return
        stopping = True
        raise Interrupted(signal_number)

    previous = {}
    for number in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(number) is signal.SIG_IGN:
            continue  # started with the signal ignored (nohup, a background job): keep it so
        previous[number] = signal.signal(number, interrupt)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def _interrupted_message(args: argparse.Namespace, err: KeyboardInterrupt, started: float) -> str:
    """'rig: interrupted by SIGTERM; run.csv keeps 1234 samples, readable up to the stop'."""
    from rig.log_file import count_samples

    name = signal.Signals(err.signal_number).name if isinstance(err, Interrupted) else "SIGINT"
    message = f"rig: interrupted by {name}"
    notes = getattr(err, "__notes__", ())
    if notes:
        message += f" ({'; '.join(notes)})"
    out = getattr(args, "out", None)
    if isinstance(out, str):
        try:
            written_now = os.stat(out).st_mtime >= started - 1.0  # not a file left by an earlier run
        except OSError:
            written_now = False
        samples = count_samples(out) if written_now else None
        message += (f"; {out} keeps {samples} samples, readable up to the stop" if samples is not None
                    else f"; no log was written to {out}")
    return message


def _with_notes(err: BaseException) -> str:
    """The error's message and its notes on one line (a transport notes what its controlled stop did)."""
    return "; ".join([str(err), *getattr(err, "__notes__", ())])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig",
        description="Drive a gearbox test rig, simulate it, and identify backlash and dynamics from its logs.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="show diagnostics on stderr: -v what the rig and the methods do (bring-up, stop, "
                             "device warnings, chosen orders), -vv details (damaged frames, python-can and canopen), "
                             "-vvv everything python-can and canopen log; put it before the command: rig -v run ...")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", required=True)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


OUR_LOGGERS = ("rig", "identify", "sim_backend")
"""The packages whose loggers ``-v`` shows (python-can's ``can`` and canopen's ``canopen`` join at ``-vv``)."""


@contextlib.contextmanager
def logging_to_stderr(verbosity: int) -> Iterator[None]:
    """While the command runs, log records of our packages (and, from ``-vv``, of python-can and canopen) go
    to stderr as ``rig: LEVEL logger: message`` lines: ``-v`` INFO, ``-vv`` DEBUG for ours and INFO for
    theirs, ``-vvv`` DEBUG for all. Without ``-v`` nothing is configured (Python shows WARNING and above).
    Levels and the handler are restored on exit (tests call :func:`main` many times in one process)."""
    if verbosity <= 0:
        yield
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("rig: %(levelname)s %(name)s: %(message)s"))
    ours = logging.INFO if verbosity == 1 else logging.DEBUG
    levels = {name: ours for name in OUR_LOGGERS}
    if verbosity >= 2:
        levels.update({name: logging.INFO if verbosity == 2 else logging.DEBUG for name in ("can", "canopen")})
    loggers = {name: logging.getLogger(name) for name in levels}
    previous = {name: (logger.level, logger.propagate) for name, logger in loggers.items()}
    for name, logger in loggers.items():
        logger.setLevel(levels[name])
        logger.addHandler(handler)
        logger.propagate = False  # one line per record, whatever the root logger does
    try:
        yield
    finally:
        for name, logger in loggers.items():
            logger.removeHandler(handler)
            logger.setLevel(previous[name][0])
            logger.propagate = previous[name][1]


def show_warning_as_note(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                         file: TextIO | None = None, line: str | None = None) -> None:
    """``warnings.showwarning`` of the command: one line ``rig: note: MESSAGE`` on stderr, without the
    source line Python prints (a user cannot act on a line of numpy)."""
    text = " ".join(str(message).split())
    if category is not UserWarning and not issubclass(category, UserWarning):
        text += f" ({category.__name__} in {Path(filename).name})"  # numpy's "invalid value encountered in ..."
    try:
        print(f"rig: note: {text}", file=sys.stderr if file is None else file)
    except OSError:
        pass  # stderr closed: nothing to tell


def _quiet_closed_pipe() -> None:
    """stdout's reader went away (``rig inspect log | head -1``): drop what is left of the output, so that
    neither this exit nor the interpreter's last flush prints a traceback."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    started = time.time()
    drives = getattr(args.handler, "__module__", "") in DRIVE_COMMANDS
    analyses = getattr(args.handler, "__module__", "") in ANALYSIS_COMMANDS
    try:
        with signals_as_interrupts(drives), warnings.catch_warnings(), logging_to_stderr(args.verbose), \
                _blas_threads(analyses):
            warnings.showwarning = show_warning_as_note
            try:
                return int(args.handler(args))
            finally:
                sys.stdout.flush()
    except BrokenPipeError:
        _quiet_closed_pipe()
        return exit_codes.SUCCESS
    except OSError as err:
        if err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO) and not err.filename:
            # a write to stdout (`--json > /dev/full`); file outputs raise OutputPathError, a ValueError
            reason = os.strerror(err.errno) + f" ({errno.errorcode.get(err.errno, err.errno)})"
            print(f"rig: error: standard output: cannot write: {reason}; redirect the output to a file on a disk "
                  "with free space", file=sys.stderr)
            _quiet_closed_pipe()  # what is still buffered would fail again at exit
            return exit_codes.WRITE_FAILED
        if isinstance(err, (FileNotFoundError, IsADirectoryError, PermissionError, NotADirectoryError)):
            return _report_input_os_error(err)
        raise
    except KeyboardInterrupt as err:
        print(_interrupted_message(args, err, started), file=sys.stderr)
        is_term = isinstance(err, Interrupted) and err.signal_number == signal.SIGTERM
        return exit_codes.TERMINATED if is_term else exit_codes.INTERRUPTED
    except (ValueError, ConfigError, LogFileError, FileNotFoundError, IsADirectoryError) as err:
        # identify's InvalidInputError and every config/log error are ValueErrors with a complete message.
        print(f"rig: error: {_with_notes(err)}", file=sys.stderr)
        from rig.log_file import LogWriteError  # here, not at the top: numpy stays out of `rig --help`

        return exit_codes.WRITE_FAILED if isinstance(err, LogWriteError) else exit_codes.BAD_INPUT
    except (DeviceFault, TransportError) as err:
        print(f"rig: device error: {_with_notes(err)}", file=sys.stderr)
        return exit_codes.DEVICE_FAULT


ANALYSIS_COMMANDS = frozenset({"rig.commands.diagnose", "rig.commands.identify_hammerstein",
                               "rig.commands.identify_output_backlash", "rig.commands.demo"})
"""Commands that run the identification methods: their BLAS runs on ``RIG_BLAS_THREADS`` threads (default
1; :mod:`rig.blas_threads`)."""


def _blas_threads(analyses: bool) -> contextlib.AbstractContextManager[None]:
    if not analyses:
        return contextlib.nullcontext()
    from rig.blas_threads import limited_blas_threads

    return limited_blas_threads()


def _report_input_os_error(err: OSError) -> int:
    """An input that cannot be read (an output's error is an OutputPathError, reported with exit 5)."""
    if err.filename is None:
        print(f"rig: error: {err}", file=sys.stderr)
    else:
        print(f"rig: error: {err.filename}: {err.strerror}", file=sys.stderr)
    return exit_codes.BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
