"""``--scheduler`` against a real Dask cluster: a scheduler and two workers started as separate processes on
127.0.0.1 (as a cluster runs them), in working directories of their own that do not hold the data. The
batch results equal the local one-process run number by number, and the workers never read the client's
files (they travel with the tasks, rig/batch.py)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from dask.distributed import Client

from identify.cyclic_excitation import cyclic_random_excitation
from identify.discrepancy_cases import hidden_effect_record
from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.plant_blocks import InputBacklash, LinearBlock, OutputBacklash, PiecewiseLinearBorder, PlantModel
from rig import exit_codes
from rig.cli import main
from rig.report import missing_images
from nominal_model import NOMINAL_TOML

START_TIMEOUT_S = 120.0
"""Generous: a scheduler and two workers start in a few seconds on an idle machine, much later on a busy one."""


def _stop(process: subprocess.Popen) -> None:
    """End a process and every process it started (its own process group), at once if it does not go."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The address of a scheduler with two workers (one process, one thread each), and their directories."""
    root = tmp_path_factory.mktemp("cluster")
    scheduler_file = root / "scheduler.json"
    processes: list[subprocess.Popen] = []

    def start(module: str, *arguments: str, cwd: Path) -> None:
        log = open(cwd / f"{module.rsplit('.', 1)[-1]}.log", "wb")
        processes.append(subprocess.Popen([sys.executable, "-m", module, *arguments], cwd=cwd, stdout=log,
                                          stderr=subprocess.STDOUT, start_new_session=True))
        log.close()

    try:
        # should this test process be killed before its finaliser runs: the scheduler ends after two idle
        # minutes, and the workers a minute after it
        start("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(scheduler_file), "--idle-timeout", "120s", cwd=root)
        deadline = time.monotonic() + START_TIMEOUT_S
        address = None
        while address is None:
            assert processes[0].poll() is None, (root / "dask_scheduler.log").read_text()
            assert time.monotonic() < deadline, "the scheduler wrote no scheduler file"
            with contextlib.suppress(FileNotFoundError, json.JSONDecodeError, KeyError):
                address = json.loads(scheduler_file.read_text())["address"]  # once it is written whole
            time.sleep(0.1)
        worker_dirs = []
        for name in ("worker-1", "worker-2"):
            folder = root / name
            folder.mkdir()
            worker_dirs.append(folder)
            start("distributed.cli.dask_worker", address, "--name", name, "--nworkers", "1", "--nthreads", "1",
                  "--host", "127.0.0.1", "--no-dashboard", "--local-directory", str(folder), "--death-timeout", "60s",
                  cwd=folder)
        with Client(address, timeout=START_TIMEOUT_S, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
        yield address, worker_dirs
    finally:
        for process in reversed(processes):
            _stop(process)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Records that only the client can see: the tests run there and name them relative to it."""
    folder = tmp_path_factory.mktemp("client-data")
    for name, effects, seed in (("backlash", ("backlash",), 3), ("dead_zone", ("dead_zone",), 4),
                                ("nothing", (), 5)):
        record = hidden_effect_record(effects, seed, num_samples=1500)
        time_s = np.arange(record.command_rad.size) * record.sample_period_s
        (folder / f"{name}.csv").write_text("t,u,y\n" + "".join(
            f"{t!r},{u!r},{y!r}\n" for t, u, y in
            zip(time_s.tolist(), record.command_rad.tolist(), record.angle_rad.tolist())))
    (folder / "nominal.toml").write_text(NOMINAL_TOML)
    (folder / "broken.csv").write_text("t,u,y\n0,1,x\n")
    nodes = tuple(np.linspace(-3.0, 3.0, 8).tolist())
    u = cyclic_random_excitation(100 + 1500, -3.0, 3.0, 100, rng=3)
    for name, gain in (("cyclic_a", 1.0), ("cyclic_b", 2.0)):
        plant = PlantModel((InputBacklash(PiecewiseLinearBorder(nodes, (-1.0, -0.9, -0.7, -0.4, 0.0, 0.4, 0.8, 1.0)),
                                          PiecewiseLinearBorder(nodes, (-1.0, -0.6, -0.2, 0.2, 0.5, 0.75, 0.9, 1.0)),
                                          initial_output_rad=-1.0),
                            LinearBlock(a=(-1.8858, 0.9048), b=(0.0, gain * 0.1994, -gain * 0.1804),
                                        sample_period_s=0.01)))
        y = plant.simulate(u) + 0.5
        (folder / f"{name}.csv").write_text("u,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(u, y)))
    # a staircase and two PRBS records of a linear system with output backlash (Cerone et al. 2009)
    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_y = plant.simulate(staircase)[steady] + rng.uniform(-NOISE_CERONE, NOISE_CERONE, steady.size)
    (folder / "steady.csv").write_text("u,y\n" + "".join(
        f"{float(a)!r},{float(b)!r}\n" for a, b in zip(staircase[steady], steady_y)))
    for name in ("prbs_a", "prbs_b"):
        u = prbs_sequence(100, 1.0, rng=rng)
        y = plant.simulate(u) + rng.uniform(-NOISE_CERONE, NOISE_CERONE, u.size)
        (folder / f"{name}.csv").write_text("u,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(u, y)))
    return folder


NOISE_CERONE = 2 * np.pi / 2**12


def assert_same_numbers(local, remote, where: str = "") -> None:
    """The same document: the same keys, lengths and strings, and every number within 1e-9 relative (the
    same code on the same machine; a worker's BLAS may sum in another order, so not bit for bit)."""
    assert type(local) is type(remote), where
    if isinstance(local, dict):
        assert local.keys() == remote.keys(), where
        for key in local:
            assert_same_numbers(local[key], remote[key], f"{where}.{key}")
    elif isinstance(local, list):
        assert len(local) == len(remote), where
        for index, (a, b) in enumerate(zip(local, remote)):
            assert_same_numbers(a, b, f"{where}[{index}]")
    elif isinstance(local, float):
        assert (math.isnan(local) and math.isnan(remote)) or local == pytest.approx(remote, rel=1e-9, abs=1e-12), where
    else:
        assert local == remote, where


def run_json(capsys, *argv: str):
    code = main(list(argv))
    return code, json.loads(capsys.readouterr().out)


def tasks_executed(address: str) -> int:
    """Tasks the cluster's workers have run so far (all of them together)."""
    with Client(address, timeout=START_TIMEOUT_S, set_as_default=False) as client:
        return sum(client.run(lambda dask_worker: dask_worker.state.executed_count).values())


def test_the_workers_cannot_see_the_clients_files(cluster, data_dir):
    """The premise of the tests below: a worker that opened the user's path would not find it."""
    address, worker_dirs = cluster
    with Client(address, timeout=START_TIMEOUT_S, set_as_default=False) as client:
        seen = client.run(lambda: (os.getcwd(), os.path.exists("backlash.csv")))
    assert len(seen) == 2
    assert sorted(Path(cwd) for cwd, _ in seen.values()) == sorted(worker_dirs)
    assert not any(exists for _, exists in seen.values())


def test_diagnose_on_the_cluster_equals_the_local_run(cluster, data_dir, monkeypatch, capsys):
    address, _ = cluster
    monkeypatch.chdir(data_dir)
    files = ["backlash.csv", "dead_zone.csv", "nothing.csv"]
    common = ["--model", "nominal.toml", "--noise-bound", "0.00096699", "--json"]
    code, local = run_json(capsys, "diagnose", *files, *common, "--jobs", "1")
    assert code == exit_codes.SUCCESS
    before = tasks_executed(address)
    code, remote = run_json(capsys, "diagnose", *files, *common, "--scheduler", address, "--report", "reports")
    assert code == exit_codes.SUCCESS
    assert tasks_executed(address) - before == len(files)  # one task per file, on the workers
    assert [entry["file"] for entry in remote["results"]] == files
    assert all("diagnosis" in entry for entry in remote["results"])  # no file failed on either side
    assert [effect["effect"] for effect in remote["results"][0]["diagnosis"]["missing_effects"]] == ["backlash"]
    assert_same_numbers(local, remote)
    for name in ("backlash", "dead_zone", "nothing"):  # drawn on the client from the workers' results
        assert missing_images(data_dir / "reports" / name / "index.html") == []


def test_identify_hammerstein_on_the_cluster_equals_the_local_run(cluster, data_dir, monkeypatch, capsys):
    address, _ = cluster
    monkeypatch.chdir(data_dir)
    common = ["cyclic_a.csv", "cyclic_b.csv", "--num-nodes", "8", "--u-min", "-3", "--u-max", "3", "--json"]
    code, local = run_json(capsys, "identify", "hammerstein", *common, "--jobs", "1")
    assert code == exit_codes.SUCCESS
    before = tasks_executed(address)
    code, remote = run_json(capsys, "identify", "hammerstein", *common, "--scheduler", address)
    assert code == exit_codes.SUCCESS
    assert tasks_executed(address) - before == 2
    assert [entry["file"] for entry in remote["results"]] == ["cyclic_a.csv", "cyclic_b.csv"]
    assert all("model" in entry for entry in remote["results"])
    assert_same_numbers(local, remote)


def test_output_backlash_pairs_on_the_cluster_equal_the_local_run(cluster, data_dir, monkeypatch, capsys):
    """Each pair's steady-state file travels with its task too."""
    address, _ = cluster
    monkeypatch.chdir(data_dir)
    common = ["identify", "output-backlash", "--steady", "steady.csv", "--dynamic", "prbs_a.csv", "--steady",
              "steady.csv", "--dynamic", "prbs_b.csv", "--noise-bound", repr(NOISE_CERONE), "--na", "2", "--nk", "1",
              "--nb", "2", "--json"]
    code, local = run_json(capsys, *common, "--jobs", "1")
    assert code == exit_codes.SUCCESS
    code, remote = run_json(capsys, *common, "--scheduler", address)
    assert code == exit_codes.SUCCESS
    assert [entry["dynamic"] for entry in remote["results"]] == ["prbs_a.csv", "prbs_b.csv"]
    assert all("bounds" in entry for entry in remote["results"])
    assert_same_numbers(local, remote)


def test_trend_windows_on_the_cluster_equal_the_local_run(cluster, tmp_path, monkeypatch, capsys):
    """``rig trend --scheduler``: the windows' steady-state points travel with their tasks (the workers never
    read the log), and the bounds equal the local ones."""
    address, _ = cluster
    monkeypatch.chdir(tmp_path)
    configs = Path(__file__).resolve().parents[2] / "configs"
    assert main(["simulate", str(configs / "plants" / "wearing_gearbox.toml"), "--excitation",
                 str(configs / "experiments" / "steady_staircase.toml"), "--duration", "30", "--out",
                 "run.csv"]) == exit_codes.SUCCESS
    capsys.readouterr()
    common = ["trend", "run.csv", "--window", "10s", "--wear-allowance", "2e-4", "--json"]
    code, local = run_json(capsys, *common, "--jobs", "1")
    assert code == exit_codes.SUCCESS
    code, remote = run_json(capsys, *common, "--scheduler", address)
    assert code == exit_codes.SUCCESS
    assert [window["status"] for window in remote["windows"]] == ["bounded"] * 3
    assert_same_numbers(local, remote)


def test_bad_and_missing_files_are_named_as_the_user_gave_them(cluster, data_dir, monkeypatch, capsys):
    address, _ = cluster
    monkeypatch.chdir(data_dir)
    code, remote = run_json(capsys, "identify", "hammerstein", "broken.csv", "absent.csv", "cyclic_a.csv",
                            "--num-nodes", "8", "--json", "--scheduler", address)
    assert code == exit_codes.BAD_INPUT
    broken, absent, good = remote["results"]
    assert broken["error"].startswith("broken.csv") and "line 2" in broken["error"]
    assert "rig-task-" not in broken["error"]  # not the worker's temporary copy
    assert absent["error"] == "absent.csv: No such file or directory"
    assert "model" in good
    assert main(["diagnose", "backlash.csv", "nothing.csv", "--model", "absent.toml", "--noise-bound", "0.001",
                 "--scheduler", address]) == exit_codes.BAD_INPUT
    assert "absent.toml" in capsys.readouterr().err


def test_a_scheduler_that_does_not_answer_is_named(data_dir, monkeypatch, capsys):
    import socket

    from rig import batch

    monkeypatch.setattr(batch, "SCHEDULER_TIMEOUT_S", 1.0)
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    monkeypatch.chdir(data_dir)
    assert main(["identify", "hammerstein", "cyclic_a.csv", "cyclic_b.csv", "--scheduler",
                 f"tcp://127.0.0.1:{port}"]) == exit_codes.BAD_INPUT
    message = capsys.readouterr().err
    assert f"--scheduler tcp://127.0.0.1:{port}: no Dask scheduler answered" in message
    assert "dask scheduler" in message
