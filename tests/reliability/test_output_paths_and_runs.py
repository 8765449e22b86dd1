"""Reliability of the outputs and processes: every output path checked before the work starts (exit 5 naming
the path, the OS's reason and what to do), inputs never overwritten, a closed pipe and a full stdout, a --duration
of hours started at once, --jobs capped, and one message on Ctrl-C of a batch."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rig import exit_codes
from rig.cli import main, signals_as_interrupts

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
PRBS = CONFIGS / "experiments" / "prbs.toml"
RIG = ROOT / ".venv" / "bin" / "rig"


def _rig() -> list[str]:
    return [str(RIG)] if RIG.exists() else [sys.executable, "-m", "rig.cli"]


@pytest.fixture
def read_only_dir(tmp_path) -> Path:
    """A directory in which no file can be created: chmod 555 for a normal user; as root (who ignores the
    mode bits) sysfs, whose root refuses new files."""
    if os.geteuid() != 0:
        folder = tmp_path / "read-only"
        folder.mkdir()
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    if not Path("/sys").is_dir():
        pytest.skip("no read-only directory available as root")
    yield Path("/sys")


@pytest.fixture
def log(tmp_path) -> Path:
    path = tmp_path / "run.csv"
    t = np.arange(200) * 1e-3
    u = np.sign(np.sin(40 * t))
    path.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{0.5 * b + 0.01 * a!r}\n" for a, b in zip(t.tolist(), u.tolist())))
    return path


def _one_line_error(capsys, code: int, expected_code: int, *parts: str) -> str:
    err = capsys.readouterr().err
    assert code == expected_code, err
    assert err.startswith("rig: error: ") and err.count("\n") == 1, err
    for part in parts:
        assert part in err, err
    return err


# --- --duration -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("experiment", ["steady_staircase.toml", "prbs.toml"])
def test_a_duration_far_beyond_one_cycle_starts_at_once_and_streams(experiment, tmp_path, monkeypatch):
    """12 hours at 1 kHz (43.2 million samples, 44 times what one run could be when the runner held the whole
    command) is accepted and starts: the command is produced as it is sent. The run is stopped after 300
    samples as Ctrl-C would stop it; the log has every sample up to the stop and says how long the run was
    meant to be."""
    import rig.runner
    from rig.log_file import read_log

    real_run = rig.runner.run_experiment
    seen = {}

    def stopped_after_300(transport, command_rad, sink, **options):
        seen["samples"] = command_rad.num_samples

        def progress(done: int, _late: int) -> None:
            if done >= 300:
                raise KeyboardInterrupt

        return real_run(transport, command_rad, sink, **{**options, "progress": progress})

    monkeypatch.setattr(rig.runner, "run_experiment", stopped_after_300)
    out = tmp_path / "long.csv"
    code = main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(CONFIGS / "experiments" / experiment),
                 "--out", str(out), "--duration", "43200"])
    assert code == exit_codes.INTERRUPTED and seen["samples"] == 43_200_000
    record = read_log(out)
    assert record.metadata.config["num_samples"] == 43_200_000
    assert 300 <= record.time_s.size < 43_200_000  # every sample up to the stop
    assert record.metadata.extra["summary"]["stop"].endswith("ends SWITCH ON DISABLED")


def test_a_duration_takes_seconds_or_a_unit(tmp_path, capsys):
    from rig.commands.run import duration_s

    assert [duration_s(text) for text in ("480", "90s", "20min", "8h", "1.5 h")] == [480, 90, 1200, 28800, 5400]
    with pytest.raises(SystemExit) as exit_info:  # (argparse's usage error)
        main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(PRBS), "--out",
              str(tmp_path / "run.csv"), "--duration", "3 days"])
    assert exit_info.value.code == exit_codes.BAD_INPUT
    assert "expected seconds or a number with s, min or h (8h), got '3 days'" in capsys.readouterr().err


# --- output paths before the work -----------------------------------------------------------------------------

def test_report_out_unwritable_or_a_file_is_exit_5_before_anything_is_read(log, read_only_dir, tmp_path, capsys,
                                                                           monkeypatch):
    import rig.commands.report as report

    monkeypatch.setattr(report, "read_result_file", lambda path: pytest.fail("read before the --out check"))
    code = main(["report", str(log), "--out", str(read_only_dir / "report")])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, f"{read_only_dir / 'report'}: cannot write it (--out)",
                    "choose another path")
    existing = tmp_path / "notes.txt"
    existing.write_text("mine\n")
    code = main(["report", str(log), "--out", str(existing)])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "it is an existing file, not a directory")
    assert existing.read_text() == "mine\n"
    if Path("/proc/self").is_dir():
        code = main(["report", str(log), "--out", "/proc/self"])
        _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "/proc/self: cannot write it (--out): no file can be "
                        "created in /proc/self")


def test_diagnose_report_and_demo_out_are_checked_before_the_work(log, read_only_dir, capsys, monkeypatch):
    import identify.model_discrepancy
    import rig.demo

    monkeypatch.setattr(identify.model_discrepancy, "diagnose_model", lambda *a, **k: pytest.fail("diagnosed first"))
    monkeypatch.setattr(rig.demo, "run_demo", lambda *a, **k: pytest.fail("demo ran first"))
    code = main(["diagnose", str(log), "--noise-bound", "0.01", "--report", str(read_only_dir / "r")])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "(--report)", "Permission denied" if os.geteuid() == 0
                    else "")
    code = main(["demo", "--quick", "--out", str(read_only_dir / "demo")])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, f"{read_only_dir / 'demo'}: cannot write it (--out)")


@pytest.fixture(scope="module")
def backlash_files(tmp_path_factory):
    """A staircase log and a PRBS log of the Cerone et al. plant, as `rig simulate` writes them."""
    folder = tmp_path_factory.mktemp("backlash")
    plant = CONFIGS / "plants" / "cerone2009.toml"
    for name, experiment in (("stair", "steady_staircase"), ("prbs", "prbs")):
        assert main(["simulate", str(plant), "--excitation", str(CONFIGS / "experiments" / f"{experiment}.toml"),
                     "--out", str(folder / f"{name}.csv"), "--json"]) == 0
    return folder / "stair.csv", folder / "prbs.csv"


def _backlash_args(files, *extra: str) -> list[str]:
    stair, prbs = files
    return ["identify", "output-backlash", "--steady", str(stair), "--dynamic", str(prbs), "--noise-bound",
            "0.0015339815193446808", "--na", "2", "--nk", "1", "--nb", "2", "--method", "paper", *extra]


def test_save_into_a_missing_or_read_only_directory_or_over_an_input_is_exit_5(backlash_files, read_only_dir,
                                                                               tmp_path, capsys, monkeypatch):
    import identify.output_backlash_identification as method

    capsys.readouterr()
    real = method.bound_output_backlash_system
    monkeypatch.setattr(method, "bound_output_backlash_system", lambda *a, **k: pytest.fail("bounded first"))
    missing = tmp_path / "nodir" / "x.json"
    code = main(_backlash_args(backlash_files, "--save", str(missing)))
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, f"{missing}: cannot write it (--save): the directory "
                    f"{missing.parent} does not exist; create it (mkdir -p {missing.parent})")
    code = main(_backlash_args(backlash_files, "--save", str(read_only_dir / "x.json")))
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "(--save)")
    before = backlash_files[1].read_bytes()
    code = main(_backlash_args(backlash_files, "--save", str(backlash_files[1])))
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "it is the input file")
    assert backlash_files[1].read_bytes() == before
    monkeypatch.setattr(method, "bound_output_backlash_system", real)
    if Path("/dev/full").exists():  # the disk fills up while the result is written
        code = main(_backlash_args(backlash_files, "--save", "/dev/full"))
        _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "/dev/full: cannot write it (--save): No space left "
                        "on device (ENOSPC)")


def test_run_refuses_to_overwrite_its_config_and_checks_the_can_trace_before_the_drive(tmp_path, read_only_dir,
                                                                                       capsys, monkeypatch):
    import shutil

    import rig.transports.simulated as simulated
    from rig.transports.canopen_link import CanOpenTransport

    monkeypatch.setattr(CanOpenTransport, "open", lambda self: pytest.fail("the drive was enabled"))
    monkeypatch.setattr(simulated, "simulated_rig", lambda *a, **k: pytest.fail("the devices were started"))
    configs = tmp_path / "configs"
    shutil.copytree(CONFIGS, configs, ignore=shutil.ignore_patterns("*.eds", "*.dbc"))
    config = configs / "sim_canopen.toml"
    before = config.read_bytes()
    code = main(["run", str(config), "--experiment", str(PRBS), "--out", str(config)])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, f"{config}: cannot write it (--out): it is the input file")
    assert config.read_bytes() == before
    trace = read_only_dir / "t.blf"
    code = main(["run", str(config), "--experiment", str(PRBS), "--out", str(tmp_path / "run.csv"),
                 "--can-trace", str(trace)])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, f"{trace}: cannot write it (--can-trace)")
    code = main(["simulate", str(configs / "plants" / "cerone2009.toml"), "--excitation", str(PRBS), "--out",
                 str(PRBS)])
    _one_line_error(capsys, code, exit_codes.WRITE_FAILED, "it is the input file")


# --- stdout ---------------------------------------------------------------------------------------------------

def test_json_to_a_full_disk_is_exit_5_and_a_closed_pipe_a_quiet_exit(log):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    with open("/dev/full", "w") as full:
        done = subprocess.run([*_rig(), "inspect", str(log), "--json"], stdout=full, stderr=subprocess.PIPE,
                              text=True, timeout=60)
    assert done.returncode == exit_codes.WRITE_FAILED
    assert done.stderr == ("rig: error: standard output: cannot write: No space left on device (ENOSPC); redirect "
                           "the output to a file on a disk with free space\n")
    read_end, write_end = os.pipe()
    os.close(read_end)  # `| head -1` that has already gone
    try:
        done = subprocess.run([*_rig(), "inspect", str(log)], stdout=write_end, stderr=subprocess.PIPE, text=True,
                              timeout=60)
    finally:
        os.close(write_end)
    assert done.returncode == exit_codes.SUCCESS and done.stderr == ""


# --- processes ------------------------------------------------------------------------------------------------

def _pid(path: str) -> int:
    time.sleep(0.2)  # long enough that one worker cannot take every file
    return os.getpid()


def test_jobs_are_capped_at_the_files_and_the_cores(monkeypatch):
    import rig.batch as batch

    started = []
    real_pool = batch.ProcessPoolExecutor

    def counting_pool(max_workers, **options):
        started.append(max_workers)
        return real_pool(max_workers=max_workers, **options)

    monkeypatch.setattr(batch, "ProcessPoolExecutor", counting_pool)
    monkeypatch.setattr(batch, "usable_cores", lambda: 2)
    outcomes = batch.map_files(_pid, ["a", "b", "c"], jobs=1000)
    assert started == [2] and all(outcome.error is None for outcome in outcomes)
    assert len({outcome.result for outcome in outcomes}) <= 2
    monkeypatch.setattr(batch, "usable_cores", lambda: 64)
    started.clear()
    batch.map_files(_pid, ["a", "b"], jobs=0)
    assert started == [2]  # two files: two processes, not 64


def test_a_second_signal_speaks_of_a_drive_only_where_there_is_one(capsys):
    if sys.platform == "win32":
        pytest.skip("POSIX signals")
    # start from Python's own handlers: an earlier test on this worker may have left SIGTERM ignored, which
    # signals_as_interrupts rightly keeps (a nohup'd command), and then no second signal would arrive
    previous = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        _second_signal_messages(capsys)
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def _second_signal_messages(capsys):
    for drives, expected in ((False, ""), (True, "leaves the drive as it is")):
        with pytest.raises(KeyboardInterrupt):
            with signals_as_interrupts(drives):
                try:
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(1)
                finally:
                    os.kill(os.getpid(), signal.SIGTERM)  # while "stopping"
                    time.sleep(0.05)
        err = capsys.readouterr().err
        # without a drive no line may speak of one (other lines on this worker's stderr, e.g. a warning of an
        # earlier test's leftover thread, are not this handler's)
        assert (expected in err) if expected else "drive" not in err.lower()


def test_ctrl_c_on_diagnose_jobs_2_gives_one_message_and_no_drive_text(tmp_path):
    files = []
    rng = np.random.default_rng(1)
    for name in ("a", "b"):  # 20 000 samples: minutes of work, so the signal surely comes during it
        t = np.arange(20_000) * 1e-3
        u = np.repeat(rng.uniform(-1, 1, 200), 100)
        path = tmp_path / f"{name}.csv"
        np.savetxt(path, np.column_stack([t, u, 0.8 * u + rng.uniform(-1e-3, 1e-3, t.size)]), delimiter=",",
                   header="t,u,y", comments="", fmt="%.9g")
        files.append(str(path))
    process = subprocess.Popen([*_rig(), "diagnose", *files, "--noise-bound", "0.002", "--jobs", "2"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        children: list[str] = []
        while time.monotonic() < deadline and len(children) < 2:  # both workers started
            children = Path(f"/proc/{process.pid}/task/{process.pid}/children").read_text().split()
            time.sleep(0.1)
        assert len(children) >= 2, "the workers did not start"
        time.sleep(0.3)
        os.killpg(process.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == exit_codes.INTERRUPTED, err
    assert err == "rig: interrupted by SIGINT\n"
