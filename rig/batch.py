"""Run one analysis over many files in parallel: local processes, or a Dask cluster.

Both go through the ``concurrent.futures.Executor`` interface: :class:`~concurrent.futures.ProcessPoolExecutor`
on the local cores, or the executor of a ``dask.distributed.Client`` (``Client(address).get_executor()``)
for a fleet of machines, so the same batch runs on either and this module writes no scheduler of its own.
Dask is optional (``pip install 'dask[distributed]'``); it is imported only when a scheduler is named.

The workers of a cluster do not share the client's file system (another machine, another working
directory, a container): with a scheduler, every file a task reads is read here and travels with the task
(:class:`ShippedFile`); the worker writes it into a temporary directory of its own, under its own name, and
the task reads that copy (:func:`shipped_path`). Messages name the file as the user gave it.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import os
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import BrokenExecutor, Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.protocols.errors import ConfigError

SCHEDULER_TIMEOUT_S = 30.0
"""How long the client waits for the scheduler named by ``--scheduler`` to answer (Dask's own default)."""


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
def executor_for(jobs: int, scheduler: str | None = None, *, isolated: bool = False) -> Iterator[Executor | None]:
    """A process pool of ``jobs`` workers (0: one per core), the executor of the Dask scheduler at
    ``scheduler``, or None for one job in this process; ``isolated``: a pool of one worker for one job
    too, for tasks whose native code may crash the process running them (HiGHS 1.16 can overflow its
    stack on a bounding LP: BENCHMARKS.md, "Record length"), so that a crash costs the tasks of that worker,
    which the caller survives, not the command. A local pool starts anew after a lost worker
    (:class:`RenewingProcessPool`), and it starts its workers at the first task: a caller that maps nothing
    pays nothing."""
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError as err:
            raise ConfigError("--scheduler", "scheduler", "needs Dask: pip install 'dask[distributed]'") from err
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S, set_as_default=False)
        except (OSError, ValueError, TypeError) as err:  # no answer, refused, or an address Dask cannot parse
            raise ValueError(
                f"--scheduler {scheduler}: no Dask scheduler answered ({err}); start one (`dask scheduler`, or "
                "the cluster's own: dask-jobqueue, Dask Kubernetes) and pass the address it prints, "
                "tcp://HOST:PORT") from err
        with client:
            yield client.get_executor()
        return
    workers = usable_cores() if jobs == 0 else jobs
    if workers == 1 and not isolated:
        yield None
        return
    pool = RenewingProcessPool(workers)
    try:
        yield pool
    except BaseException:
        # Ctrl-C or an error: do not wait minutes for the files in progress; the workers ignore SIGINT (the
        # main process alone reports it) and end at SIGTERM without a word
        processes = pool.processes()  # shutdown() forgets them
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            with contextlib.suppress(Exception):
                process.terminate()
        raise
    else:
        pool.shutdown(wait=True)


class RenewingProcessPool(Executor):
    """A local process pool that starts a new one when a worker died: a ``ProcessPoolExecutor`` whose worker
    was killed (a crash in native code, the out-of-memory killer) fails the tasks it held with
    ``BrokenProcessPool`` and refuses every later one; this one fails the same tasks, then takes new ones on a
    fresh pool, so that a caller may solve them again (:class:`identify.linear_block_bounds.windows._GuardedMap`
    retries a lost window once)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._pool = self._new()

    def _new(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, initializer=_worker_start)

    def _renewed(self) -> ProcessPoolExecutor:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = self._new()
        return self._pool

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        try:
            return self._pool.submit(fn, *args, **kwargs)
        except BrokenExecutor:
            return self._renewed().submit(fn, *args, **kwargs)

    def map(self, fn: Callable[..., Any], *iterables: Any, timeout: float | None = None,
            chunksize: int = 1) -> Iterator[Any]:
        """``ProcessPoolExecutor.map`` (tasks sent in chunks) on the current pool, or on a new one if it broke
        (``iterables`` must be sequences then: the refused first chunk was taken from them)."""
        try:
            return self._pool.map(fn, *iterables, timeout=timeout, chunksize=chunksize)
        except BrokenExecutor:
            return self._renewed().map(fn, *iterables, timeout=timeout, chunksize=chunksize)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)

    def processes(self) -> list[Any]:
        """The current pool's worker processes."""
        return list((getattr(self._pool, "_processes", None) or {}).values())


def usable_cores() -> int:
    """The cores this process may run on (the affinity mask, which a container or taskset narrows)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _worker_start() -> None:
    """In each worker process: SIGINT ignored and SIGTERM at its default, so that a Ctrl-C is reported once,
    by the main process (which stops the workers), warnings as the command's one-line notes, and the BLAS
    threads limited as in the command (:mod:`rig.blas_threads`)."""
    import signal
    import warnings

    from rig.cli import show_warning_as_note

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by _sigint_held at the fork
    warnings.showwarning = show_warning_as_note
    from rig.blas_threads import limit_blas_threads

    limit_blas_threads()  # RIG_BLAS_THREADS, as in the command's own process


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
    if isinstance(executor, (ProcessPoolExecutor, RenewingProcessPool)):
        return functools.partial(executor.map, chunksize=chunksize)
    return executor.map


def map_files(function: Callable[[str], Any], paths: Sequence[str], *, jobs: int = 1,
              scheduler: str | None = None, shared_files: Sequence[str] = ()) -> list[FileOutcome]:
    """``function(path)`` for every path, in the order given; ``function`` must be picklable (a
    module-level function or a ``functools.partial`` of one) when it runs in other processes. Local
    processes are capped at the number of files and of usable cores (``--jobs 1000`` on three files
    starts three).

    On a Dask cluster (``scheduler``) each file, and each of ``shared_files`` (read by every task, such as
    a model; the task opens it through :func:`shipped_path`), is read here and shipped with its task:
    a file this machine cannot read is that file's error, a shared one stops the batch before any work."""
    if jobs < 0:
        raise ValueError(f"--jobs: expected 0 (all cores) or a positive number of processes, got {jobs}")
    if scheduler is None:
        jobs = min(usable_cores() if jobs == 0 else jobs, usable_cores(), max(1, len(paths)))
    shared = tuple(ShippedFile.read(path) for path in shared_files) if scheduler is not None else ()
    with executor_for(jobs, scheduler) as executor:
        if executor is None:
            return [_guarded(function, path) for path in paths]
        if scheduler is None:
            with _sigint_held():
                futures = [executor.submit(_guarded, function, path) for path in paths]
            return [future.result() for future in futures]
        outcomes: list[FileOutcome | None] = []
        futures = []
        for path in paths:
            try:
                shipped = ShippedFile.read(path)
            except OSError as err:
                outcomes.append(FileOutcome(path, error=_os_error_message(err)))
                continue
            outcomes.append(None)
            futures.append(executor.submit(_run_shipped, function, shipped, shared))
        results = iter([future.result() for future in futures])
        return [outcome if outcome is not None else next(results) for outcome in outcomes]


@dataclass(frozen=True)
class ShippedFile:
    """A file read on the client, carried to a cluster worker with its task: ``path`` as the user named it,
    ``content`` its bytes."""

    path: str
    content: bytes

    @classmethod
    def read(cls, path: str) -> ShippedFile:
        return cls(str(path), Path(path).read_bytes())


_SHIPPED: contextvars.ContextVar[Mapping[str, str]] = contextvars.ContextVar("rig_shipped_files", default={})
"""In a task on a cluster worker: the user's path of each file shipped with it -> its copy on the worker."""


def shipped_path(path: str) -> str:
    """Where a task reads ``path``: the worker's copy of it when it was shipped with the task (a cluster
    worker, :func:`map_files` with a scheduler), else ``path`` itself."""
    return _SHIPPED.get().get(str(path), str(path))


def user_path(path: str) -> str:
    """The path the user gave for ``path`` when it is a worker's copy of a shipped file, else ``path``."""
    return next((user for user, copy in _SHIPPED.get().items() if copy == str(path)), str(path))


def _run_shipped(function: Callable[[str], Any], shipped: ShippedFile,
                 shared: Sequence[ShippedFile]) -> FileOutcome:
    """On a cluster worker: write the task's files into a temporary directory (each under its own name, in
    a folder of its own), run ``function`` on the copy of ``shipped`` with the BLAS threads limited
    (:mod:`rig.blas_threads`), and name the user's paths in an error message instead of the copies'."""
    with tempfile.TemporaryDirectory(prefix="rig-task-") as folder:
        copies = {}
        for number, file in enumerate((shipped, *shared)):
            copy = Path(folder, str(number), Path(file.path).name or "file")
            copy.parent.mkdir()
            copy.write_bytes(file.content)
            copies[file.path] = str(copy)
        token = _SHIPPED.set(copies)
        from rig.blas_threads import limited_blas_threads

        try:
            with limited_blas_threads():  # the worker's RIG_BLAS_THREADS (default 1), as in a local process
                outcome = _guarded(function, copies[shipped.path])
        finally:
            _SHIPPED.reset(token)
    error = outcome.error
    if error is not None:
        for path, copy in sorted(copies.items(), key=lambda item: -len(item[1])):
            error = error.replace(copy, path)
    return FileOutcome(shipped.path, outcome.result, error)


def _os_error_message(err: OSError) -> str:
    return f"{err.filename}: {err.strerror}" if err.filename is not None and err.strerror else str(err)
