"""Run one analysis over many files in parallel: local processes, or a Dask cluster.

Both go through the ``concurrent.futures.Executor`` interface: :class:`~concurrent.futures.ProcessPoolExecutor`
on the local cores, or the executor of a ``dask.distributed.Client`` (``Client(address).get_executor()``)
for a fleet of machines, so the same batch runs on either and this module writes no scheduler of its own.
Dask is optional (``pip install 'dask[distributed]'``); it is imported only when a scheduler is named.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from rig.protocols.errors import ConfigError


@dataclass(frozen=True)
class FileOutcome:
    """The result of one file, or the message of the error that stopped it (the other files go on)."""

    path: str
    result: Any = None
    error: str | None = None

    def to_json(self, key: str, result_to_json: Callable[[Any], Any]) -> dict[str, Any]:
        """``{"file": path, key: result_to_json(result)}``, or ``{"file": path, "error": message}``."""
        if self.error is not None:
            return {"file": self.path, "error": self.error}
        return {"file": self.path, key: result_to_json(self.result)}


BATCH_KIND = "batch"
BATCH_VERSION = 1


def batch_document(entries: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The ``--json`` object of a command given several files: ``{"kind": "batch", "version": 1,
    "results": entries}``, each entry naming its file(s) and holding a result document (itself with its
    ``kind``) or an ``error``. ``rig report`` reads it."""
    return {"kind": BATCH_KIND, "version": BATCH_VERSION, "results": list(entries)}


def _guarded(function: Callable[[str], Any], path: str) -> FileOutcome:
    try:
        return FileOutcome(path, result=function(path))
    except (ValueError, OSError) as err:  # bad input names itself; a bug still raises
        return FileOutcome(path, error=str(err))


@contextlib.contextmanager
def executor_for(jobs: int, scheduler: str | None = None) -> Iterator[Executor | None]:
    """A process pool of ``jobs`` workers (0: one per core), the executor of the Dask scheduler at
    ``scheduler``, or None for one job in this process."""
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError as err:
            raise ConfigError("--scheduler", "scheduler", "needs Dask: pip install 'dask[distributed]'") from err
        with Client(scheduler) as client:
            yield client.get_executor()
        return
    workers = usable_cores() if jobs == 0 else jobs
    if workers == 1:
        yield None
        return
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_start)
    try:
        yield pool
    except BaseException:
        # Ctrl-C or an error: do not wait minutes for the files in progress; the workers ignore SIGINT (the
        # main process alone reports it) and end at SIGTERM without a word
        workers = list((getattr(pool, "_processes", None) or {}).values())  # shutdown() forgets them
        pool.shutdown(wait=False, cancel_futures=True)
        for process in workers:
            with contextlib.suppress(Exception):
                process.terminate()
        raise
    else:
        pool.shutdown(wait=True)


def usable_cores() -> int:
    """The cores this process may run on (the affinity mask, which a container or taskset narrows)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _worker_start() -> None:
    """In each worker process: SIGINT ignored and SIGTERM at its default, so that a Ctrl-C is reported once,
    by the main process (which stops the workers), and warnings as the command's one-line notes."""
    import signal
    import warnings

    from rig.cli import show_warning_as_note

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by _sigint_held at the fork
    warnings.showwarning = show_warning_as_note


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """Hold SIGINT back while the workers are forked, so that none is born with the command's handler
    (which would report the Ctrl-C a second time); it is delivered to this process right after."""
    import signal
    import threading

    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def map_callable(executor: Executor | None, chunksize: int = 4) -> Callable[..., Any]:
    """A ``map(function, tasks)`` that runs on ``executor`` (in order), or the builtin ``map`` for None: the
    form :func:`identify.linear_block_bounds.bound_linear_block` takes its windows in (``identify`` imports
    nothing of ``rig``). Local processes get the tasks in chunks (small tasks cost less to send)."""
    if executor is None:
        return map
    if isinstance(executor, ProcessPoolExecutor):
        return functools.partial(executor.map, chunksize=chunksize)
    return executor.map


def map_files(function: Callable[[str], Any], paths: Sequence[str], *, jobs: int = 1,
              scheduler: str | None = None) -> list[FileOutcome]:
    """``function(path)`` for every path, in the order given; ``function`` must be picklable (a
    module-level function or a ``functools.partial`` of one) when it runs in other processes. Local
    processes are capped at the number of files and of usable cores (``--jobs 1000`` on three files
    starts three)."""
    if jobs < 0:
        raise ValueError(f"--jobs: expected 0 (all cores) or a positive number of processes, got {jobs}")
    if scheduler is None:
        jobs = min(usable_cores() if jobs == 0 else jobs, usable_cores(), max(1, len(paths)))
    with executor_for(jobs, scheduler) as executor:
        if executor is None:
            return [_guarded(function, path) for path in paths]
        with _sigint_held():
            futures = [executor.submit(_guarded, function, path) for path in paths]
        return [future.result() for future in futures]
