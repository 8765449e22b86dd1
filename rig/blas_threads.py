"""How many threads the BLAS under numpy and scipy may use in a process of ``rig``.

The identification methods multiply and factor small matrices many times over (a subspace step, thousands of
free runs and fits in a diagnosis); OpenBLAS starts one thread per core for each call, and on a host of few
cores that share other work the threads wait for each other more than they compute (``identify_hammerstein``
took 243 ms with the BLAS's default threads against 18 ms with one on a 2-core host:
``benchmarks/blas_threads.py``, BENCHMARKS.md). The command line and its worker processes therefore run the
BLAS on one thread, through threadpoolctl (which finds the BLAS libraries numpy and scipy have loaded), and
parallelise by processes (``--jobs``) instead.

``RIG_BLAS_THREADS`` chooses: a number N >= 1 (default 1), or ``all`` to leave the BLAS at its own default
(one thread per core). Worker processes (``--jobs``, the windows of ``identify output-backlash``, Dask workers)
read the same variable.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

__all__ = ["ENVIRONMENT_VARIABLE", "blas_thread_limit", "limit_blas_threads", "limited_blas_threads"]

ENVIRONMENT_VARIABLE = "RIG_BLAS_THREADS"
DEFAULT_LIMIT = 1

_PROCESS_LIMITER: list[Any] = []


def blas_thread_limit(value: str | None = None) -> int | None:
    """The limit ``RIG_BLAS_THREADS`` (or ``value``) asks for: a number of threads, or None for the BLAS's
    own default (``all``). Anything else raises ValueError naming the variable and what it accepts."""
    text = (os.environ.get(ENVIRONMENT_VARIABLE, "") if value is None else value).strip().lower()
    if text == "":
        return DEFAULT_LIMIT
    if text == "all":
        return None
    try:
        limit = int(text)
    except ValueError:
        limit = 0
    if limit < 1:
        raise ValueError(f"{ENVIRONMENT_VARIABLE}={text!r}: expected a number of BLAS threads >= 1, or 'all' for "
                         "the BLAS's own default (one per core)")
    return limit


def _load_blas() -> None:
    """Load the BLAS libraries the methods use (numpy's, and scipy's own for scipy.linalg), so that the limit
    reaches them: threadpoolctl limits the libraries loaded when it is called."""
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401


@contextlib.contextmanager
def limited_blas_threads(limit: int | None | str = "env") -> Iterator[None]:
    """While inside, the BLAS of this process uses at most ``limit`` threads (default: ``RIG_BLAS_THREADS``;
    None: no limit)."""
    limit = blas_thread_limit() if limit == "env" else limit
    if limit is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    _load_blas()
    with threadpool_limits(limits=int(limit), user_api="blas"):
        yield


def limit_blas_threads(limit: int | None | str = "env") -> None:
    """For the rest of this process (a worker's initializer): the limit of :func:`limited_blas_threads`."""
    limit = blas_thread_limit() if limit == "env" else limit
    if limit is None:
        return
    from threadpoolctl import threadpool_limits

    _load_blas()
    _PROCESS_LIMITER.append(threadpool_limits(limits=int(limit), user_api="blas"))
