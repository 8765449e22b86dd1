"""Output paths checked before the work starts, and write failures named (exit code 5).

Every command that writes a file or a directory calls :func:`check_output_file` or :func:`check_output_dir`
before it reads, computes or drives anything, so that twelve seconds of diagnosis or an enabled drive are
not lost to a directory that does not exist. The check writes and removes a small probe file (as root,
``os.access`` says yes to a read-only directory of a writable file system, and only a real write finds a
full disk). :func:`writing` turns an ``OSError`` of the write itself (the disk filled up meanwhile) into the
same error. Both raise :class:`OutputPathError`, a :class:`~rig.log_file.LogWriteError`, which ``rig.cli``
reports with exit code 5.

Nothing is overwritten silently. An existing output file is refused unless the command was given ``--force``
(:func:`refuse_existing`, called by :func:`check_output_file`); a whole file is written under a temporary name
in its directory and moved into place only when it is complete (:func:`atomic_output`), without replacing a
file that appeared meanwhile unless forced; a log that is streamed while a run goes (readable up to its last
flush at any instant) is claimed before the run starts, by an exclusive create, or with ``--force`` by a lock
that a second run on the same file cannot take (:func:`claim_output_file`); and a report directory that holds
anything but an earlier report of ours is refused (:func:`check_report_dir`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

from rig.log_file import LogWriteError, _os_reason

__all__ = ["ClaimedOutput", "OutputPathError", "REPORT_MARKER", "atomic_output", "check_output_dir",
           "check_output_file", "check_report_dir", "claim_output_file", "is_regular_target", "mark_report_dir",
           "refuse_existing", "refuse_overwriting_inputs", "writing"]

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


def is_regular_target(path: str | Path) -> bool:
    """Whether ``path`` is (or would be) a regular file: not a device, a pipe or a terminal (``/dev/stdout``,
    ``/dev/null``), which are written as they are: nothing there can be overwritten."""
    target = Path(path)
    if target.parent in _STREAM_DIRECTORIES:  # /dev/stdout is a regular file when stdout is redirected to one
        return False
    return not target.exists() or target.is_file()


_STREAM_DIRECTORIES = (Path("/dev"), Path("/dev/fd"), Path("/proc/self/fd"))
"""Paths in these directories name a stream of the process or a device, never a file to create or replace."""


def refuse_existing(path: str | Path, option: str = "", force: bool = False) -> None:
    """Refuse an existing regular file at ``path`` unless ``force`` (the command's ``--force``)."""
    target = Path(path)
    if not force and target.is_file() and is_regular_target(target):
        raise OutputPathError(f"{target}: the file exists" + (f" ({option})" if option else "") + "; nothing was "
                              "written. Choose another path, or give --force to replace it")


def check_output_file(path: str | Path, option: str = "", inputs: Iterable[str | Path] = (), *,
                      force: bool = False) -> Path:
    """Check before the work that ``path`` can be written as a file; return it. An existing file is refused
    unless ``force`` (:func:`refuse_existing`).

    Raises :class:`OutputPathError` naming ``option``, the path, the reason and what to do: the file exists
    (without ``force``), the directory is missing, the path is a directory or is one of ``inputs``, the
    directory refuses new files, the disk is full, or an existing file cannot be written.
    """
    target = Path(path)
    refuse_overwriting_inputs(target, inputs, option)
    refuse_existing(target, option, force)
    if target.is_dir():
        raise OutputPathError(f"{_what(option, target)}: Is a directory (EISDIR); give a file name in it, e.g. "
                              f"{target / 'result'}")
    parent = target.parent
    if not parent.exists():
        raise OutputPathError(f"{_what(option, target)}: the directory {parent} does not exist; create it "
                              f"(mkdir -p {parent}) or choose another path")
    if not parent.is_dir():
        raise OutputPathError(f"{_what(option, target)}: {parent} is not a directory; choose another path")
    if target.exists() and not is_regular_target(target):  # a device or a pipe: written as it is (/dev/null, /dev/full)
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


def _publish(temporary: Path, target: Path, option: str, force: bool) -> None:
    """Move the complete ``temporary`` to ``target`` (same directory): with ``force`` by an atomic replace;
    else by a hard link, which fails if ``target`` appeared meanwhile (another command wrote it), then the
    temporary name is removed."""
    if force:
        os.replace(temporary, target)
        return
    try:
        os.link(temporary, target)
    except FileExistsError:
        raise OutputPathError(f"{target}: the file appeared while this command wrote it" + (f" ({option})" if option
                              else "") + f"; it was left as it is, and nothing was written. Choose another path, "
                              "or give --force to replace it") from None
    except OSError as err:
        if err.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        # a file system without hard links (FAT, some network shares): the check just before the rename
        refuse_existing(target, option, force)
        os.replace(temporary, target)
        return
    os.unlink(temporary)


@contextlib.contextmanager
def atomic_output(path: str | Path, option: str = "", *, force: bool = False,
                  suffix: str | None = None) -> Iterator[Path]:
    """Give a temporary path next to ``path`` to write the whole file to; when the block ends without an
    error, move it into place (:func:`_publish`: an existing ``path`` is replaced only with ``force``); on an
    error, remove it, leaving ``path`` as it was. The temporary name ends in ``suffix`` (default: the
    suffix of ``path``), for writers that choose the format by it. A device or pipe (``/dev/stdout``) is
    written directly. ``OSError`` becomes :class:`OutputPathError` (:func:`writing`)."""
    target = Path(path)
    if not is_regular_target(target):
        with writing(target, option):
            yield target
        return
    refuse_existing(target, option, force)
    with writing(target, option):
        handle, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix if suffix is None else suffix,
                                        dir=target.parent)
        os.close(handle)
        temporary = Path(name)
        try:
            yield temporary
            _publish(temporary, target, option, force)
        finally:
            with contextlib.suppress(OSError):
                temporary.unlink()


class ClaimedOutput:
    """A streamed output (a run's log) claimed before the run starts: created exclusively, or with ``force``
    opened without truncating and locked, so that a second run on the same file is refused before it drives
    anything. :meth:`open_text` truncates and gives the file to write; :meth:`release` removes a file this
    claim created and never wrote (the run failed before it started)."""

    def __init__(self, path: Path, descriptor: int | None, created: bool) -> None:
        self.path = path
        self._descriptor = descriptor
        self._created = created
        self._opened = False

    def open_text(self) -> IO[str]:
        """The claimed file, emptied, as a text file to write (the lock stays with it until it is closed)."""
        if self._descriptor is None:  # a device or pipe
            self._opened = True
            return self.path.open("w", encoding="utf-8", newline="\n")
        os.ftruncate(self._descriptor, 0)
        self._opened = True
        handle = os.fdopen(self._descriptor, "w", encoding="utf-8", newline="\n")
        self._descriptor = None
        return handle

    def hand_over(self) -> None:
        """The claimed file is written by a writer that opens it by name (python-can's trace writers): the
        lock stays with this claim until :meth:`release`, and the file is never removed by it."""
        self._opened = True

    def release(self) -> None:
        """Give the claim up: remove the file if this claim created it and nothing was written."""
        if self._descriptor is not None:
            os.close(self._descriptor)
            self._descriptor = None
            if self._created and not self._opened:
                with contextlib.suppress(OSError):
                    self.path.unlink()


def claim_output_file(path: str | Path, option: str = "", *, force: bool = False) -> ClaimedOutput:
    """Claim ``path`` for a streamed output (:class:`ClaimedOutput`); raise :class:`OutputPathError` naming
    it when it exists (without ``force``) or another process holds it (a run writing it now)."""
    import fcntl

    target = Path(path)
    if not is_regular_target(target):
        return ClaimedOutput(target, None, False)
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
    try:
        existed = force and target.exists()
        descriptor = os.open(target, flags | (0 if force else os.O_EXCL), 0o666)
        created = not existed
    except FileExistsError:
        refuse_existing(target, option, force)
        raise
    except OSError as err:
        raise OutputPathError(f"{_what(option, target)}: {_os_reason(err)}") from None
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        os.close(descriptor)
        if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise OutputPathError(f"{target}: another process is writing it now (another run on the same file)"
                                  + (f" ({option})" if option else "") + "; nothing was started. Wait for it to "
                                  "end, or choose another path") from None
        raise OutputPathError(f"{_what(option, target)}: it cannot be locked: {_os_reason(err)}") from None
    return ClaimedOutput(target, descriptor, created)


REPORT_MARKER = ".rig-report"
"""The file that marks a directory as a report written by rig (``rig demo``, ``rig report``, ``rig diagnose
--report``): such a directory may be written again; any other non-empty one is refused."""


def check_report_dir(path: str | Path, option: str = "", inputs: Iterable[str | Path] = (), *,
                     force: bool = False) -> Path:
    """:func:`check_output_dir`, and refuse an existing directory that holds anything but an earlier report
    of rig (its :data:`REPORT_MARKER`) unless ``force``, naming what is there."""
    target = check_output_dir(path, option, inputs)
    if force or not target.is_dir() or (target / REPORT_MARKER).is_file():
        return target
    present = sorted(entry.name for entry in target.iterdir())
    if present:
        shown = ", ".join(present[:5]) + (f" and {len(present) - 5} more" if len(present) > 5 else "")
        raise OutputPathError(f"{target}: the directory holds {shown}, and is not a report rig wrote" + (
            f" ({option})" if option else "") + "; nothing was written. Choose a new or empty directory, or give "
            "--force to write the report into it (files of the same names are replaced)")
    return target


def mark_report_dir(path: str | Path) -> None:
    """Mark ``path`` as a report directory of rig (:data:`REPORT_MARKER`)."""
    (Path(path) / REPORT_MARKER).write_text("a report written by rig; rig may write it again\n", encoding="utf-8")
