"""The BLAS under numpy and scipy runs on RIG_BLAS_THREADS threads (default 1) in the analysis commands and in
their worker processes."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

from rig import exit_codes  # noqa: E402
from rig.blas_threads import blas_thread_limit, limited_blas_threads  # noqa: E402
from rig.cli import main  # noqa: E402


def blas_threads() -> list[int]:
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401

    return [info["num_threads"] for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas"]


def test_the_limit_comes_from_the_environment(monkeypatch):
    monkeypatch.delenv("RIG_BLAS_THREADS", raising=False)
    assert blas_thread_limit() == 1
    monkeypatch.setenv("RIG_BLAS_THREADS", "all")
    assert blas_thread_limit() is None
    monkeypatch.setenv("RIG_BLAS_THREADS", "3")
    assert blas_thread_limit() == 3
    monkeypatch.setenv("RIG_BLAS_THREADS", "many")
    with pytest.raises(ValueError, match=r"RIG_BLAS_THREADS='many': expected a number of BLAS threads >= 1, or 'all'"):
        blas_thread_limit()


def test_inside_the_limit_every_blas_runs_on_one_thread(monkeypatch):
    monkeypatch.delenv("RIG_BLAS_THREADS", raising=False)
    with limited_blas_threads():
        assert blas_threads() and set(blas_threads()) == {1}


def test_an_analysis_command_runs_with_the_limit_and_a_bad_setting_is_named(monkeypatch, capsys):
    import rig.commands.identify_hammerstein as command

    seen = []

    def fake_run(args):
        seen.append(blas_threads())
        return exit_codes.SUCCESS

    fake_run.__module__ = command.__name__
    monkeypatch.setattr(command, "run", fake_run)
    monkeypatch.delenv("RIG_BLAS_THREADS", raising=False)
    assert main(["identify", "hammerstein", "whatever.csv"]) == exit_codes.SUCCESS
    assert set(seen[0]) == {1}
    monkeypatch.setenv("RIG_BLAS_THREADS", "zero")
    assert main(["identify", "hammerstein", "whatever.csv"]) == exit_codes.BAD_INPUT
    assert "RIG_BLAS_THREADS='zero'" in capsys.readouterr().err


def test_worker_processes_limit_their_blas_too(monkeypatch):
    from rig.batch import _worker_start

    monkeypatch.delenv("RIG_BLAS_THREADS", raising=False)
    with ProcessPoolExecutor(max_workers=1, initializer=_worker_start) as pool:
        assert set(pool.submit(blas_threads).result(timeout=60)) == {1}
