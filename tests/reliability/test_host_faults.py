"""Host faults during ``rig run`` on a simulated serial rig: SIGINT, SIGTERM, SIGKILL, a disk
that fills up during the run, and an output path that cannot be written at start.

Defined outcomes (the README's fault table):

* SIGINT / SIGTERM: controlled stop (quick stop, then disable), the log closed and readable to the stop, exit
  130 / 143, a message naming the signal and the samples kept.
* SIGKILL: no stop is possible; every sample up to the last flush survives and ``rig inspect`` reads it.
* Disk full (or the file size limit) during the run: controlled stop, exit 5, a message naming the path, the
  OS's reason and the samples flushed before, which are all readable.
* Output path not writable at start: exit 5 naming the path, before the transport is opened (the drive is
  never enabled).
"""

from __future__ import annotations

import errno
import json
import os
import re
import resource
import signal
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from rig import exit_codes
from rig.cli import main
from rig.log_file import LogWriteError, LogWriter, read_log
from rig.runner import run_experiment

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "transports"))
from sim_rigs import ROOT, excitation, no_leaks, simulated, write_test_config  # noqa: E402, F401 (fixture)

RIG = ROOT / ".venv" / "bin" / "rig"
PRBS = ROOT / "configs" / "experiments" / "prbs.toml"


def _rig_command() -> list[str]:
    return [str(RIG)] if RIG.exists() else [sys.executable, "-m", "rig.cli"]


def default_sigint() -> None:
    """In the child: take SIGINT as a terminal does, also when the suite itself runs as a background job
    (which starts with SIGINT ignored, and ``rig`` keeps an ignored signal ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start_run(out: Path, config: Path, in_child: Callable[[], None] | None = None) -> subprocess.Popen:
    """Start ``rig run`` on ``config`` for 60 s; ``in_child`` runs in the child before it starts."""

    def prepare() -> None:
        default_sigint()
        if in_child is not None:
            in_child()

    return subprocess.Popen([*_rig_command(), "run", str(config), "--experiment", str(PRBS), "--out", str(out),
                             "--duration", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, preexec_fn=prepare)


def _streaming_config(directory: Path) -> Path:
    """The simulated serial rig at the test rate with a 0.5 s feedback watchdog (``configs/sim_serial.toml``
    has 0.1 s): the simulated device shares the child's process, and when a loaded machine freezes the whole
    process for longer than the watchdog, the host can wake first, find nothing yet and stop the run with a
    false "no feedback" (reproduced with SIGSTOP/SIGCONT of ``rig run``); these tests are about signals and
    write failures, not that."""
    return write_test_config("serial", directory)


def _wait_for_rows(out: Path, rows: int, process: subprocess.Popen | None = None, timeout_s: float = 30.0) -> int:
    """Wait until ``out`` holds at least ``rows`` complete sample lines; return how many it holds."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if out.exists():
            lines = out.read_bytes().split(b"\n")[:-1]  # the complete ones; comment lines (header, start) are no samples
            complete = sum(1 for line in lines if not line.startswith(b"#")) - 1  # less the column line
            if complete >= rows:
                return complete
        if process is not None and process.poll() is not None:
            raise AssertionError(f"rig run ended early: {process.communicate()}")
        time.sleep(0.02)
    raise AssertionError(f"{out} did not reach {rows} samples in {timeout_s} s")


def _read_cleanly(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a torn last line would warn: the log must have been closed
        return read_log(path)


@pytest.mark.parametrize("signal_number, code", [(signal.SIGINT, exit_codes.INTERRUPTED),
                                                 (signal.SIGTERM, exit_codes.TERMINATED)])

def test_sigint_and_sigterm_end_rig_run_with_a_controlled_stop(signal_number, code, tmp_path):
    out = tmp_path / "run.csv"
    process = _start_run(out, _streaming_config(tmp_path))
    try:
        _wait_for_rows(out, 50, process)
        process.send_signal(signal_number)
        _, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == code, stderr
    record = _read_cleanly(out)
    name = signal.Signals(signal_number).name
    assert re.search(rf"rig: interrupted by {name} \(serial://\S+ drive: quick stop sent, then disable sent; ends "
                     rf"SWITCH ON DISABLED\); {re.escape(str(out))} keeps {record.num_samples} samples, readable up to "
                     r"the stop", stderr), stderr
    assert "Traceback" not in stderr
    assert record.num_samples >= 50 and np.all(np.diff(record.time_s) > 0)


def test_sigterm_disables_the_drive_and_a_second_signal_does_not_cut_the_stop_short(tmp_path, monkeypatch, capsys,
                                                                                    no_leaks):
    """In-process, so the simulated drive's controlwords can be read: quick stop (0x02), then disable (0x00)."""
    import rig.transports.simulated as simulated
    from rig.transports.serial_link import SerialTransport

    drives = []
    real_start, real_close = simulated.start_simulated_devices, SerialTransport.close

    def start_and_keep(*args, **kwargs):
        url, drive = real_start(*args, **kwargs)
        drives.append(drive)
        return url, drive

    def close_after_a_second_sigterm(self) -> None:
        if not drives[0].controlwords[-1:] == [0x00]:
            os.kill(os.getpid(), signal.SIGTERM)  # arrives in the middle of the controlled stop
        real_close(self)

    monkeypatch.setattr(simulated, "start_simulated_devices", start_and_keep)
    monkeypatch.setattr(SerialTransport, "close", close_after_a_second_sigterm)
    out = tmp_path / "run.csv"

    def terminate_when_streaming() -> None:
        _wait_for_rows(out, 20)
        os.kill(os.getpid(), signal.SIGTERM)

    killer = threading.Thread(target=terminate_when_streaming, daemon=True)
    killer.start()
    previous = signal.getsignal(signal.SIGTERM)
    code = main(["run", str(write_test_config("serial", tmp_path)), "--experiment", str(PRBS), "--out", str(out),
                 "--duration", "60", "--json"])
    killer.join(timeout=5)
    stderr = capsys.readouterr().err
    assert code == exit_codes.TERMINATED, stderr
    assert "rig: SIGTERM again: still stopping in a controlled way" in stderr
    assert signal.getsignal(signal.SIGTERM) is previous  # handlers restored
    (drive,) = drives
    assert drive.controlwords[-2:] == [0x02, 0x00]  # quick stop, then disable
    assert _read_cleanly(out).num_samples >= 20


def test_sigkill_keeps_every_flushed_sample_and_rig_inspect_reads_them(tmp_path, capsys):
    out = tmp_path / "run.csv"
    process = _start_run(out, _streaming_config(tmp_path))
    try:
        flushed = _wait_for_rows(out, 100, process)
        process.send_signal(signal.SIGKILL)
        process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == -signal.SIGKILL
    assert main(["inspect", str(out), "--json"]) == exit_codes.SUCCESS
    summary = json.loads(capsys.readouterr().out)
    assert summary["samples"] >= flushed  # a torn last line (if any) is dropped, with a warning
    assert summary["samples"] == len(read_log(out))


def test_file_size_limit_during_rig_run_stops_safely_and_keeps_what_was_flushed(tmp_path):
    """A real write failure from the OS (EFBIG: ``ulimit -f``), the same path as a full disk (ENOSPC)."""
    out = tmp_path / "run.csv"

    def limit_file_size() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # write() fails with EFBIG instead of killing the process
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    process = _start_run(out, _streaming_config(tmp_path), in_child=limit_file_size)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == exit_codes.WRITE_FAILED, stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr
    assert f"rig: error: {out}: cannot write the log" in stderr and "File too large (EFBIG)" in stderr
    kept = int(stderr.split("; the ")[-1].split(" samples flushed before are kept")[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the refused write may have left a torn line
        assert len(read_log(out)) >= kept > 100


class _FillingFile:
    """A log file on a disk with room for ``capacity`` more lines: writes are buffered (like Python's own
    buffer) and the flush that would go past the room fails with ENOSPC, losing the buffered lines."""

    def __init__(self, inner, capacity: int) -> None:
        self.inner, self.capacity, self.pending = inner, capacity, []

    def write(self, text: str) -> int:
        self.pending.append(text)
        return len(text)

    def flush(self) -> None:
        if len(self.pending) > self.capacity:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.capacity -= len(self.pending)
        self.inner.write("".join(self.pending))
        self.pending.clear()
        self.inner.flush()

    def fileno(self) -> int:
        return self.inner.fileno()

    def close(self) -> None:
        self.inner.close()  # what was never flushed is lost, as on a full disk


def test_disk_full_during_a_run_is_a_controlled_stop_naming_the_path(tmp_path, no_leaks):
    from identify.experiment_record import ExperimentMetadata

    path = tmp_path / "run.csv"
    with simulated("serial", tmp_path) as (config, transport, _, drive):
        log = LogWriter(path, ExperimentMetadata(sample_period_s=config.sample_period_s), flush_every=10)
        log._file = _FillingFile(log._file, capacity=35)  # room for 35 more lines: the flush of 31..40 fails
        with pytest.raises(LogWriteError) as caught:
            run_experiment(transport, excitation(120), log, feedback_timeout_s=config.feedback_timeout_s)
        assert drive.controlwords[-2:] == [0x02, 0x00]  # quick stop, then disable
        assert not transport.is_open
    message = str(caught.value)
    assert message.startswith(f"{path}: cannot write the log (flushing samples 30 to 39): No space left on device "
                              "(ENOSPC); "
                              "the disk is full")
    assert message.endswith("the 30 samples flushed before are kept and readable")
    record = _read_cleanly(path)
    assert record.num_samples == 30
    np.testing.assert_allclose(record.time_s, np.arange(30) * config.sample_period_s)


@pytest.mark.parametrize("make_out, reason", [
    (lambda tmp: tmp / "missing" / "run.csv", "the directory {tmp}/missing does not exist"),
    (lambda tmp: tmp, "Is a directory (EISDIR)"),
    (lambda tmp: Path("/dev/full"), "No space left on device (ENOSPC)"),
], ids=["directory-missing", "path-is-a-directory", "disk-full-at-start"])
def test_unwritable_output_fails_before_the_drive_is_enabled(make_out, reason, tmp_path, monkeypatch, capsys,
                                                             no_leaks):
    from rig.transports.serial_link import SerialTransport

    def refuse_open(self) -> None:
        raise AssertionError("the transport was opened before the log was known to be writable")

    monkeypatch.setattr(SerialTransport, "open", refuse_open)
    out = make_out(tmp_path)
    code = main(["run", str(write_test_config("serial", tmp_path)), "--experiment", str(PRBS), "--out", str(out)])
    stderr = capsys.readouterr().err
    assert code == exit_codes.WRITE_FAILED, stderr
    assert stderr.startswith(f"rig: error: {out}: cannot ") and reason.format(tmp=tmp_path) in stderr
    assert stderr.count("\n") == 1
