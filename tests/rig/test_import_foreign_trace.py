"""`rig import` of CANopen traces of another vendor's master (``tests/peers/foreign_canopen_master``: a master, a
CiA 402 drive and a CiA 406 encoder written from the standards by someone who never read this program): its
own PDO mapping (other PDOs, other order, another encoder COB-ID) read from the trace's SDO writes or from the
nodes' DCF files, and every usable row equal to what its drive and encoder did at that SYNC (its truth file).

That drive latches its TPDOs at a SYNC before it takes the SYNC's target (CiA 301 leaves the order open), so
its 0x6062 shows the target of the SYNC before: on the bus it answers like a drive one SYNC late, and the
config says so (``drive_tpdo_latency_cycles = 1``), as the driver's own check would tell a user of it."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_log

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = ROOT / "tests" / "peers" / "foreign_canopen_master" / "foreign_master.py"
DRIVE_COUNTS, ENCODER_COUNTS = 10000, 8192  # the peer's scaling: drive counts per motor turn, encoder per load turn


def _trace(directory: Path, variant: str, mode: str, *options: str, cycles: int = 600) -> Path:
    out = directory / f"{variant}-{mode}"
    subprocess.run([sys.executable, str(GENERATOR), "--variant", variant, "--mode", mode, "--cycles", str(cycles),
                    "--out", str(out), *options], check=True, capture_output=True)
    return out


def _config(directory: Path, mode: str, latency: int) -> Path:
    """The peer's rig: drive node 3, encoder node 9 (13 bits a turn, 12 of turns, UNSIGNED32), 1 kHz."""
    text = (ROOT / "configs" / "rig_canopen.toml").read_text()
    for old, new in (("drive_node_id = 1", "drive_node_id = 3"), ("encoder_node_id = 2", "encoder_node_id = 9"),
                     ("counts_per_revolution = 131072", f"counts_per_revolution = {DRIVE_COUNTS}"),
                     ("bits = 12", "bits = 13"), ("multi_turn_bits = 0", "multi_turn_bits = 12"),
                     ('mode = "auto"', f'mode = "{mode}"'),
                     ("drive_tpdo_latency_cycles = 0", f"drive_tpdo_latency_cycles = {latency}")):
        assert old in text, old
        text = text.replace(old, new)
    text = "\n".join(line for line in text.splitlines() if not line.startswith(("drive_eds", "encoder_eds")))
    path = directory / f"foreign_{mode}_{latency}.toml"
    path.write_text(text + "\n")
    return path


def _imported(directory: Path, case: Path, config: Path, *options: str) -> tuple[dict, object]:
    out = case / "imported.csv"
    assert main(["import", str(case / "trace.blf"), "--config", str(config), "--out", str(out), "--force", "--json",
                 *options]) == exit_codes.SUCCESS
    return out, read_log(out)


def _against_truth(case: Path, log) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row, aligned by SYNC: (command in drive counts == the target the drive had in force, encoder
    change == the encoder's change, the row's flags); rows whose encoder frame was lost compare True."""
    truth = json.loads((case / "truth.json").read_text())
    start = log.metadata.extra["imported_from"]["origin_sync"] - 1  # the trace's SYNC index of sample 0
    syncs = truth["syncs"][start:start + len(log)]
    assert len(syncs) == len(log)
    target = np.array([s["target"] for s in syncs], dtype=float)
    encoder = np.array([np.nan if s["enc"] is None else s["enc"] for s in syncs], dtype=float)
    command_ok = np.round(log.command_rad * DRIVE_COUNTS / (2 * math.pi)) == target
    first = int(np.flatnonzero(~np.isnan(encoder) & ~np.isnan(log.angle_rad))[0])
    moved = (log.angle_rad - log.angle_rad[first]) * ENCODER_COUNTS / (2 * math.pi)
    angle_ok = np.isnan(encoder) | (np.abs(moved - (encoder - encoder[first])) < 0.5)
    return command_ok, angle_ok, log.flags


@pytest.mark.parametrize("variant, mode", [("foreign", "csp"), ("foreign", "ip"), ("default-ish", "csp")])
def test_another_masters_trace_imports_by_its_own_mapping_row_for_row(variant, mode, tmp_path):
    case = _trace(tmp_path, variant, mode)
    config = _config(tmp_path, "ip_buffer" if mode == "ip" else "csp", latency=1)
    out, log = _imported(tmp_path, case, config)
    assert log.metadata.extra["imported_from"]["pdo_mapping"] == f"the SDO writes in {case / 'trace.blf'}"
    command_ok, angle_ok, flags = _against_truth(case, log)
    assert len(log) == 600 and np.all(command_ok) and np.all(angle_ok)
    assert not np.any(flags)  # every row usable: nothing lost, held, late or ambiguous on this clean run


def test_a_late_rpdo_is_held_and_a_lost_encoder_frame_is_lost_and_nothing_else(tmp_path):
    case = _trace(tmp_path, "foreign", "csp", "--late-rpdo", "300", "--lost-enc", "200")
    _, log = _imported(tmp_path, case, _config(tmp_path, "csp", latency=1))
    command_ok, angle_ok, flags = _against_truth(case, log)
    assert np.all(command_ok) and np.all(angle_ok)  # the held row carries the target the drive kept
    assert np.flatnonzero(flags & SampleFlag.HELD).tolist() == [300]
    assert np.flatnonzero(flags & SampleFlag.LOST).tolist() == [200]
    assert np.count_nonzero(flags) == 2


def test_a_trace_that_starts_after_the_start_up_takes_the_mapping_from_the_nodes_dcf(tmp_path, capsys):
    case = _trace(tmp_path, "eds-only", "csp")
    config = _config(tmp_path, "csp", latency=1)
    assert main(["import", str(case / "trace.blf"), "--config", str(config), "--out", str(tmp_path / "x.csv"),
                 "--json"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert "no node 3 RPDO1 (COB-ID 0x203)" in err and "--dcf NODE=FILE" not in err  # it tried this master's
    _, log = _imported(tmp_path, case, config, "--dcf", f"3={case / 'node3.dcf'}", "--dcf", f"9={case / 'node9.dcf'}")
    command_ok, angle_ok, flags = _against_truth(case, log)
    usable = (flags & SampleFlag.unusable()) == 0
    assert np.all(command_ok[usable]) and np.all(angle_ok[usable])
    # its master switches the drive on and off by PDO: the rows before and after OPERATION ENABLED are in the
    # log, flagged FAULT; the last target went out with the trace's end, before its answer: LOST
    unusable = np.flatnonzero(~usable)
    assert usable.sum() >= 600 and flags[-1] == SampleFlag.LOST
    assert np.all(flags[unusable[:-1]] & SampleFlag.FAULT)
    assert np.all((unusable < 100) | (unusable >= len(log) - 20))


def test_without_the_latency_its_0x6062_makes_every_changed_row_ambiguous_never_wrong(tmp_path):
    case = _trace(tmp_path, "foreign", "csp")
    _, log = _imported(tmp_path, case, _config(tmp_path, "csp", latency=0))
    command_ok, angle_ok, flags = _against_truth(case, log)
    usable = (flags & SampleFlag.unusable()) == 0
    assert np.all(command_ok[usable]) and np.all(angle_ok[usable])
    assert np.count_nonzero(flags & SampleFlag.AMBIGUOUS) > 500
