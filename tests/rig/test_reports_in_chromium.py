"""Every kind of report page the CLI writes, rendered in headless Chromium by ``scripts/check_report_in_chromium``:
every figure loads and lies within the screenshot of the whole page.

The pages come from small inputs that take seconds: ``rig report`` of every result kind it reads (experiment logs
of both clocks, both set-membership methods with the saved data, a Hammerstein model, a batch of diagnoses with a
file that failed, a run summary) and ``rig diagnose --report``. ``rig demo`` writes its page only after about 40 s
of experiments: ``tests/rig/test_demo.py`` renders the page of the quick demo that its other tests share.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from chromium_check import check_page, require_chromium
from identify.cyclic_excitation import cyclic_random_excitation
from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel, pouliquen2013_backlash
from nominal_model import NOMINAL_TOML
from report_inputs import printed_to, write_csv
from rig import exit_codes
from rig.cli import main
from rig.log_file import LogWriter, write_log
from rig.runner import RunSummary

PERIOD_S = 0.01
SM_PLANT = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), PERIOD_S), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
NOISE = 1e-3


@pytest.fixture(autouse=True)
def _chromium():
    require_chromium()  # before the inputs are made: without Chromium there is nothing to check




@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Logs and data at one sample period (10 ms), so that every figure's frequency axis is that of its data."""
    folder = tmp_path_factory.mktemp("report_kinds")
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 6)), 0.8125, 100)
    steady = staircase_steady_state_indices(6, 100)
    write_csv(folder / "steady.csv", "u,y", staircase[steady],
         SM_PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size))
    u = prbs_sequence(60, 1.0, rng=1)
    write_log(folder / "prbs.log", ExperimentRecord(np.arange(u.size) * PERIOD_S, u,
                                                    SM_PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size), None,
                                                    None, ExperimentMetadata(sample_period_s=PERIOD_S, excitation="prbs")))
    cyclic = cyclic_random_excitation(1200, -3.0, 3.0, hold_samples=50, rng=0)
    G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=PERIOD_S)
    write_csv(folder / "cyclic.csv", "u,y", cyclic, PlantModel((pouliquen2013_backlash(), G)).simulate(cyclic))
    # Device-clocked with HELD samples, and host-paced with one late send: the two timing figures.
    time_s = np.arange(300) * PERIOD_S
    command = np.sin(2 * np.pi * time_s)
    held = np.zeros(300, dtype=np.uint8)
    held[[50, 51, 120]] = SampleFlag.HELD
    for name, times, flags, summary in (
            ("device.csv", time_s, held, {"stop": "", "sample_clock": "device", "min_lead_s": -0.0042}),
            ("host.csv", time_s + np.where(np.arange(300) == 100, 3e-3, 0.0), np.zeros(300, dtype=np.uint8),
             {"stop": "", "sample_clock": "host", "send_lateness_p50_s": 1.2e-5, "send_lateness_p99_s": 8.5e-5,
              "send_lateness_max_s": 3e-3})):
        writer = LogWriter(folder / name, ExperimentMetadata(sample_period_s=PERIOD_S, source="test",
                                                             transport="serial:///dev/ttyUSB0"))
        writer.append_many(times, command, 0.25 * command, None, flags)
        writer.write_summary({"frame_errors": 0, **summary})
        writer.close()
    # A small record the diagnosis finishes in about two seconds (an offset the nominal model lacks).
    nominal = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=0.001)
    small = 0.01 * np.sign(np.sin(np.arange(3000) / 37.0))
    angle = nominal.apply(small) + 0.004 + np.random.default_rng(1).uniform(-2e-4, 2e-4, small.size)
    write_csv(folder / "small.csv", "t,u,y", np.arange(small.size) * 0.001, small, angle)
    (folder / "nominal.toml").write_text(NOMINAL_TOML)
    (folder / "broken.csv").write_text("t,u,y\n0,1,x\n")
    summary = RunSummary(samples=300, lost=3, late=7, duplicate=1, stale=2, frame_errors=4, rate_hz=99.87,
                         send_lateness_s=np.array([1e-5, 3e-5]), cpu_s=0.25, wall_s=3.1, not_followed=5, held=6,
                         min_lead_s=0.0123, stop="quick stop, then disabled (0.8 ms)",
                         warnings=("encoder EMCY 0x4210 at sample 40 (temperature)",), log="device.csv")
    (folder / "run.json").write_text(json.dumps(summary.to_dict()))
    return folder


def test_rig_report_of_every_result_kind_shows_every_figure(inputs, tmp_path, capsys):
    common = ["identify", "output-backlash", "--steady", str(inputs / "steady.csv"), "--dynamic",
              str(inputs / "prbs.log"), "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2", "--json"]
    paper = printed_to(capsys, [*common, "--method", "paper"], tmp_path / "paper.json")
    printed_to(capsys, [*common, "--save", str(tmp_path / "coupled.json")], tmp_path / "coupled_printed.json")
    hammerstein = printed_to(capsys, ["identify", "hammerstein", str(inputs / "cyclic.csv"), "--json"],
                           tmp_path / "hammerstein.json")
    batch = printed_to(capsys, ["diagnose", str(inputs / "small.csv"), str(inputs / "broken.csv"), "--model",
                              str(inputs / "nominal.toml"), "--noise-bound", "0.001", "--jobs", "1", "--json"],
                     tmp_path / "batch.json", expected_code=exit_codes.BAD_INPUT)  # the broken file failed
    out = tmp_path / "report"
    assert main(["report", str(inputs / "device.csv"), str(inputs / "host.csv"), str(inputs / "prbs.log"),
                 str(paper), str(tmp_path / "coupled.json"), str(hammerstein), str(batch), str(inputs / "run.json"),
                 "--out", str(out), "--json"]) == exit_codes.SUCCESS
    printed = json.loads(capsys.readouterr().out)
    page = (out / "index.html").read_text(encoding="utf-8")
    for title in ("Experiment: device.csv", "Experiment: host.csv", "Set membership", "Hammerstein model",
                  "Model discrepancy: batch.json", "Run: run.json", "could not process"):
        assert title in page, title
    # signals of three logs, timing of the two with a timing to draw (the prbs log has no summary and no flag),
    # intervals, Bode, band, polygons, inner bounds, three Hammerstein figures, the diagnosis's gaps
    assert printed["figures"] == 14
    check_page(out / "index.html", tmp_path, printed["figures"])


def test_rig_diagnose_report_shows_every_figure(inputs, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["diagnose", str(inputs / "small.csv"), "--model", str(inputs / "nominal.toml"), "--noise-bound",
                 "0.001", "--json", "--report", str(out)]) == exit_codes.SUCCESS
    capsys.readouterr()
    check_page(out / "index.html", tmp_path, figures=2)
