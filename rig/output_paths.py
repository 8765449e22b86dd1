"""Output paths checked before the work starts, and write failures named (exit code 5).

Every command that writes a file or a directory calls :func:`check_output_file` or :func:`check_output_dir`
before it reads, computes or drives anything, so that twelve seconds of diagnosis or an enabled drive are
not lost to a directory that does not exist. The check writes and removes a small probe file (as root,
``os.access`` says yes to a read-only directory of a writable file system, and only a real write finds a
full disk). :func:`writing` turns an ``OSError`` of the write itself (the disk filled up meanwhile) into the
same error. Both raise :class:`OutputPathError`, a :class:`~rig.log_file.LogWriteError`, which ``rig.cli``
reports with exit code 5.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from rig.log_file import LogWriteError, _os_reason

__all__ = ["OutputPathError", "check_output_dir", "check_output_file", "refuse_overwriting_inputs", "writing"]

_PROBE_BYTES = 4096  # one block: a full disk refuses it at fsync, where a 0-byte file would still be created


class OutputPathError(LogWriteError):
    """An output path that cannot be written; the message names the option, the path, the OS's reason and
    what to do."""


def _what(option: str, path: Path) -> str:
    """'run.csv: cannot write it (--out)', the start of every message."""
    return f"{path}: cannot write it" + (f" ({option})" if option else "")


def refuse_overwriting_inputs(path: str | Path, inputs: Iterable[str | Path], option: str) -> None:
    """Refuse an output that is one of the command's input files (``rig run cfg.toml --out cfg.toml``)."""
    target = Path(path)
    for given in inputs:
        source = Path(given)
        try:
            same = target.exists() and source.exists() and os.path.samefile(target, source)
        except OSError:
            same = False
        if same:
            raise OutputPathError(f"{_what(option, target)}: it is the input file {source}, which would be "
                                  "overwritten; choose another output path")


def _probe(directory: Path, option: str, target: Path) -> None:
    """Create, write, fsync and remove a small file in ``directory``."""
    try:
        handle, name = tempfile.mkstemp(prefix=".rig-write-check-", dir=directory)
    except OSError as err:
        if err.errno == errno.ENOENT:  # /proc/self: a directory in which no file can be created
            raise OutputPathError(f"{_what(option, target)}: no file can be created in {directory} (the file "
                                  "system does not allow it); choose another path") from None
        raise OutputPathError(f"{_what(option, target)}: no file can be created in {directory}: "
                              f"{_os_reason(err)}") from None
    try:
        os.write(handle, b"\0" * _PROBE_BYTES)
        os.fsync(handle)
    except OSError as err:
        raise OutputPathError(f"{_what(option, target)}: writing in {directory} fails: {_os_reason(err)}") from None
    finally:
        os.close(handle)
        with contextlib.suppress(OSError):
            os.unlink(name)


def check_output_file(path: str | Path, option: str = "", inputs: Iterable[str | Path] = ()) -> Path:
    """Check before the work that ``path`` can be written as a file (created or replaced); return it.

    Raises :class:`OutputPathError` naming ``option``, the path, the reason and what to do: the directory is
    missing, the path is a directory or is one of ``inputs``, the directory refuses new files, the disk is
    full, or an existing file cannot be written.
    """
    target = Path(path)
    refuse_overwriting_inputs(target, inputs, option)
    if target.is_dir():
        raise OutputPathError(f"{_what(option, target)}: Is a directory (EISDIR); give a file name in it, e.g. "
                              f"{target / 'result'}")
    parent = target.parent
    if not parent.exists():
        raise OutputPathError(f"{_what(option, target)}: the directory {parent} does not exist; create it "
                              f"(mkdir -p {parent}) or choose another path")
    if not parent.is_dir():
        raise OutputPathError(f"{_what(option, target)}: {parent} is not a directory; choose another path")
    if target.exists() and not target.is_file():  # a device or a pipe: written as it is (/dev/null, /dev/full)
        try:
            with target.open("ab") as handle:
                handle.write(b"")
        except OSError as err:
            raise OutputPathError(f"{_what(option, target)}: {_os_reason(err)}") from None
        return target
    if target.exists():
        try:
            with target.open("r+b"):
                pass
        except OSError as err:
            raise OutputPathError(f"{_what(option, target)}: the existing file cannot be replaced: "
                                  f"{_os_reason(err)}") from None
    _probe(parent, option, target)
    return target


def check_output_dir(path: str | Path, option: str = "", inputs: Iterable[str | Path] = ()) -> Path:
    """Check before the work that ``path`` is, or can be created as, a directory in which files can be
    written; return it. Missing parent directories are fine (they are created as ``mkdir -p`` would).

    Raises :class:`OutputPathError` as :func:`check_output_file` does; an existing file at ``path`` too.
    """
    target = Path(path)
    for given in inputs:
        refuse_overwriting_inputs(target, [given], option)
    if target.exists() and not target.is_dir():
        raise OutputPathError(f"{_what(option, target)}: it is an existing file, not a directory; give a "
                              "directory (it is created if missing)")
    existing = target
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise OutputPathError(f"{_what(option, target)}: {existing} is a file, not a directory; choose another path")
    _probe(existing, option, target)
    return target


@contextlib.contextmanager
def writing(path: str | Path, option: str = "") -> Iterator[None]:
    """Turn an ``OSError`` raised while writing ``path`` (the disk filled up after the check) into
    :class:`OutputPathError` naming it."""
    try:
        yield
    except OutputPathError:
        raise
    except OSError as err:
        where = Path(err.filename) if getattr(err, "filename", None) else Path(path)
        raise OutputPathError(f"{_what(option, where)}: {_os_reason(err)}") from None
