"""The demo's logs are logs like any run's: `rig identify output-backlash --steady` takes its staircase log,
whose excitation (a filtered staircase, its half-wave length and amplitudes) the log records."""

from __future__ import annotations

from rig import exit_codes
from rig.cli import main
from rig.commands.identify_output_backlash import staircase_steady_points
from rig.log_file import read_log


def test_the_demo_staircase_log_is_taken_by_steady(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["demo", "--quick", "--out", str(out)]) == exit_codes.SUCCESS
    capsys.readouterr()
    staircase = out / "logs" / "staircase.csv"
    excitation = read_log(staircase).metadata.config["excitation"]
    assert excitation["kind"] == "filtered_staircase" and excitation["parameters"]["samples_per_half_wave"] == 300
    u, y, description = staircase_steady_points(staircase)
    assert u.size == len(excitation["parameters"]["amplitudes_rad"]) * 2 and "the end of each half-wave" in description
