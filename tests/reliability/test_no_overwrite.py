"""Captured data is never overwritten silently: an existing output is refused unless --force, a whole file is
written under a temporary name and moved into place, a run's log is claimed before the drive is enabled (a
second run on the same file is refused), a report directory holding the user's files is refused, and a status
line never goes into data written to stdout."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rig import exit_codes
from rig.cli import main
from rig.output_paths import OutputPathError, atomic_output, claim_output_file

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
PRBS = CONFIGS / "experiments" / "prbs.toml"


@pytest.fixture
def log(tmp_path) -> Path:
    path = tmp_path / "run.csv"
    t = np.arange(200) * 1e-3
    u = np.sign(np.sin(40 * t))
    path.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{0.5 * b + 0.01 * a!r}\n" for a, b in zip(t.tolist(), u.tolist())))
    return path


def test_export_mdf_writes_the_name_asked_and_leaves_an_existing_mf4_alone(log, tmp_path, capsys):
    pytest.importorskip("asammdf")
    neighbour = tmp_path / "out.mf4"
    neighbour.write_text("the user's own measurement")
    assert main(["export", str(log), "--out", str(tmp_path / "out.mdf")]) == exit_codes.SUCCESS
    assert f"-> {tmp_path / 'out.mdf'} (mdf, 200 samples)" in capsys.readouterr().out
    assert neighbour.read_text() == "the user's own measurement"
    assert (tmp_path / "out.mdf").read_bytes()[:3] == b"MDF"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mdf", "out.mf4", "run.csv"]  # no temporary left


def test_export_refuses_an_existing_file_unless_forced(log, tmp_path, capsys):
    out = tmp_path / "out.mat"
    out.write_text("keep me")
    assert main(["export", str(log), "--out", str(out)]) == exit_codes.WRITE_FAILED
    err = capsys.readouterr().err
    assert f"{out}: the file exists (--out)" in err and "--force" in err
    assert out.read_text() == "keep me"
    assert main(["export", str(log), "--out", str(out), "--force"]) == exit_codes.SUCCESS
    assert out.read_bytes()[:6] == b"MATLAB"


def test_export_to_stdout_keeps_the_status_line_out_of_the_data(log, capfd):
    assert main(["export", str(log), "--format", "csv", "--out", "/dev/stdout"]) == exit_codes.SUCCESS
    out, err = capfd.readouterr()
    assert out.startswith("# rig-log v1") and " -> " not in out
    assert "-> /dev/stdout (csv, 200 samples)" in err


def test_a_file_written_atomically_is_all_or_nothing(tmp_path):
    target = tmp_path / "result.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(target, "--save", force=True) as written:
        written.write_text("half")
        raise RuntimeError("the disk filled up")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]
    fresh = tmp_path / "fresh.json"
    with pytest.raises(OutputPathError, match="appeared while this command wrote it"):
        with atomic_output(fresh, "--save") as written:
            written.write_text("mine")
            fresh.write_text("another command's")  # written meanwhile
    assert fresh.read_text() == "another command's"


def test_run_refuses_an_existing_log_and_one_another_run_writes_before_the_drive(tmp_path, capsys, monkeypatch):
    import rig.transports

    monkeypatch.setattr(rig.transports, "open_transport", lambda *a, **k: pytest.fail("the transport was opened"))
    out = tmp_path / "run.csv"
    out.write_text("# rig-log v1\nthe samples of an earlier run\n")
    args = ["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(PRBS), "--out", str(out)]
    assert main(args) == exit_codes.WRITE_FAILED
    assert f"{out}: the file exists (--out)" in capsys.readouterr().err
    held = claim_output_file(out, "--out", force=True)  # a run writing it now
    try:
        assert main([*args, "--force"]) == exit_codes.WRITE_FAILED
        assert "another process is writing it now" in capsys.readouterr().err
    finally:
        held.release()
    assert out.read_text() == "# rig-log v1\nthe samples of an earlier run\n"


def test_run_refuses_a_can_trace_another_run_writes_before_the_drive(tmp_path, capsys, monkeypatch):
    """The --can-trace file is claimed as the log is: with --force, a trace another run is writing now is
    refused before anything is driven, and its frames are left as they are."""
    import rig.transports

    monkeypatch.setattr(rig.transports, "open_transport", lambda *a, **k: pytest.fail("the transport was opened"))
    trace = tmp_path / "run.blf"
    trace.write_bytes(b"LOGG the frames of a run going on now")
    held = claim_output_file(trace, "--can-trace", force=True)  # that run
    try:
        code = main(["run", str(CONFIGS / "sim_can.toml"), "--experiment", str(PRBS), "--out",
                     str(tmp_path / "run.csv"), "--can-trace", str(trace), "--force"])
        assert code == exit_codes.WRITE_FAILED
        err = capsys.readouterr().err
        assert "another process is writing it now" in err and "--can-trace" in err
    finally:
        held.release()
    assert trace.read_bytes() == b"LOGG the frames of a run going on now"
    assert not (tmp_path / "run.csv").exists()


def test_a_claimed_log_is_exclusive_and_released_when_the_run_never_started(tmp_path):
    out = tmp_path / "run.csv"
    first = claim_output_file(out, "--out")
    with pytest.raises(OutputPathError, match="the file exists"):
        claim_output_file(out, "--out")
    first.release()
    assert not out.exists()  # created by the claim, never written: removed
    claimed = claim_output_file(out, "--out")
    with claimed.open_text() as handle:
        handle.write("data\n")
    claimed.release()
    assert out.read_text() == "data\n"


def test_demo_and_report_refuse_a_directory_of_the_users_files(tmp_path, log, capsys, monkeypatch):
    import rig.demo

    monkeypatch.setattr(rig.demo, "run_demo", lambda *a, **k: pytest.fail("the demo ran"))
    folder = tmp_path / "site"
    folder.mkdir()
    (folder / "index.html").write_text("<p>my home page</p>")
    assert main(["demo", "--quick", "--out", str(folder)]) == exit_codes.WRITE_FAILED
    err = capsys.readouterr().err
    assert f"{folder}: the directory holds index.html, and is not a report rig wrote (--out)" in err
    assert main(["report", str(log), "--out", str(folder)]) == exit_codes.WRITE_FAILED
    assert "is not a report rig wrote" in capsys.readouterr().err
    assert (folder / "index.html").read_text() == "<p>my home page</p>"


def test_a_report_directory_rig_wrote_may_be_written_again(tmp_path, log, capsys):
    folder = tmp_path / "report"
    assert main(["report", str(log), "--out", str(folder)]) == exit_codes.SUCCESS
    assert main(["report", str(log), "--out", str(folder)]) == exit_codes.SUCCESS
    assert (folder / "index.html").is_file() and (folder / ".rig-report").is_file()


def test_diagnose_refuses_two_files_whose_reports_would_share_a_directory(tmp_path, log, capsys):
    other = tmp_path / "other"
    other.mkdir()
    (other / "run.csv").write_text(log.read_text())
    code = main(["diagnose", str(log), str(other / "run.csv"), "--noise-bound", "0.01", "--report",
                 str(tmp_path / "reports")])
    assert code == exit_codes.BAD_INPUT
    assert "would both write their report to DIR/run/" in capsys.readouterr().err


def test_simulate_refuses_an_existing_file_and_replaces_it_with_force(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    out.write_text("keep")
    code = main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation", str(PRBS), "--out", str(out)])
    assert code == exit_codes.WRITE_FAILED and out.read_text() == "keep"
    assert "the file exists (--out)" in capsys.readouterr().err
    code = main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation", str(PRBS), "--out", str(out),
                 "--force"])
    assert code == exit_codes.SUCCESS and out.read_text().startswith("# rig-log v1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.csv"]
