"""``rig identify hammerstein``: CSV and rig-log input, JSON and table output, errors with exit code 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.cyclic_excitation import cyclic_random_excitation
from identify.experiment_record import ExperimentMetadata
from identify.plant_blocks import InputBacklash, LinearBlock, PiecewiseLinearBorder, PlantModel
from rig.cli import main
from rig.log_file import LogWriter

NODES = tuple(np.linspace(-3.0, 3.0, 8).tolist())
H_A = (-1.0, -0.9, -0.7, -0.4, 0.0, 0.4, 0.8, 1.0)
H_D = (-1.0, -0.6, -0.2, 0.2, 0.5, 0.75, 0.9, 1.0)
G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)
HOLD = 100


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    u = cyclic_random_excitation(HOLD + 2500, -3.0, 3.0, HOLD, rng=3)
    plant = PlantModel((InputBacklash(PiecewiseLinearBorder(NODES, H_A), PiecewiseLinearBorder(NODES, H_D),
                                      initial_output_rad=-1.0), G))
    return u, plant.simulate(u) + 0.5  # offset: mu0 = -0.5


def write_csv(path, u, y) -> None:
    path.write_text("u,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(u, y)))


def test_json_output_has_the_issue_fields_with_offset_included(tmp_path, capsys, data) -> None:
    u, y = data
    csv = tmp_path / "run.csv"
    write_csv(csv, u, y)
    assert main(["identify", "hammerstein", str(csv), "--num-nodes", "8", "--u-min", "-3", "--u-max", "3",
                 "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["order"] == 2
    poles = np.sort_complex([complex(re, im) for re, im in record["poles"]])
    true = np.sort_complex(np.roots([1.0, -1.8858, 0.9048]))
    assert np.allclose(poles, true, atol=1e-9)
    assert record["mu0"] == pytest.approx(-0.5, abs=1e-9)
    assert np.allclose(record["borders"]["ascending"]["u"], NODES)
    assert np.allclose(record["borders"]["ascending"]["h"], np.array(H_A) + 0.5, atol=1e-9)
    assert np.allclose(record["borders"]["descending"]["h"], np.array(H_D) + 0.5, atol=1e-9)
    assert set(record) >= {"A", "B", "C", "D", "singular_values"}


def test_rig_log_input_and_table_output(tmp_path, capsys, data) -> None:
    u, y = data
    log = tmp_path / "run.log.csv"
    with LogWriter(log, ExperimentMetadata(sample_period_s=0.01, source="test"), flush_every=4096) as writer:
        writer.append_many(np.arange(u.size) * 0.01, u, y)
    assert main(["identify", "hammerstein", str(log), "--order", "2", "--hold-samples", str(HOLD), "--refine"]) == 0
    text = capsys.readouterr().out
    assert "refinement       output-error RMS" in text
    assert "order            2" in text
    assert "|p| = 0.951" in text
    rows = [line.split() for line in text.splitlines()]
    assert ["u", "ascending", "h", "descending", "h"] in rows
    assert ["-3", "-0.5", "-0.5"] in rows and ["3", "1.5", "1.5"] in rows  # node values with mu0 = -0.5 included


def test_user_nodes_with_different_descending_nodes(tmp_path, capsys, data) -> None:
    u, y = data
    csv = tmp_path / "run.csv"
    write_csv(csv, u, y)
    code = main(["identify", "hammerstein", str(csv), "--nodes=" + ",".join(map(str, NODES)),
                 "--descending-nodes=-3,0,3", "--mu0", "-0.5", "--json"])
    assert code == 0
    record = json.loads(capsys.readouterr().out)
    assert record["borders"]["descending"]["u"] == [-3.0, 0.0, 3.0]
    # three descending nodes cannot follow H_D exactly; the offset is still re-estimated close to -0.5
    assert record["borders"]["ascending"]["h"][0] == pytest.approx(-0.5, abs=0.01)


def test_bad_input_exits_2_with_a_message_naming_it(tmp_path, capsys, data) -> None:
    u, y = data
    csv = tmp_path / "short.csv"
    write_csv(csv, u[:300], y[:300])
    assert main(["identify", "hammerstein", str(csv)]) == 2
    assert "too few" in capsys.readouterr().err
    shifted = tmp_path / "shifted.csv"
    write_csv(shifted, u[HOLD + 2 :], y[HOLD + 2 :])
    assert main(["identify", "hammerstein", str(shifted), "--u-min", "-3", "--u-max", "3"]) == 2
    assert "not at u_min = -3.0" in capsys.readouterr().err
    missing = tmp_path / "nocol.csv"
    missing.write_text("u,z\n1,2\n")
    assert main(["identify", "hammerstein", str(missing)]) == 2
    assert "missing column(s) y" in capsys.readouterr().err


def test_several_files_in_parallel_processes_match_one_at_a_time(tmp_path, capsys, data) -> None:
    u, y = data
    first, second, broken = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "broken.csv"
    write_csv(first, u, y)
    write_csv(second, u, 2.0 * (y - 0.5) + 0.5)  # a gain of 2 in the borders
    broken.write_text("u,y\n1,nan\n")
    common = ["--num-nodes", "8", "--u-min", "-3", "--u-max", "3", "--json"]
    assert main(["identify", "hammerstein", str(first), *common]) == 0
    alone = json.loads(capsys.readouterr().out)
    code = main(["identify", "hammerstein", str(first), str(second), str(broken), "--jobs", "2", *common])
    results = json.loads(capsys.readouterr().out)["results"]
    assert code == 2  # one file could not be identified; the others still were
    assert [result["file"] for result in results] == [str(first), str(second), str(broken)]
    assert results[0]["model"]["poles"] == alone["poles"]
    scaled = np.array(results[1]["model"]["borders"]["ascending"]["h"])
    assert np.allclose(scaled - 0.5, 2.0 * (np.array(alone["borders"]["ascending"]["h"]) - 0.5), atol=1e-6)
    assert "line 2, column y" in results[2]["error"]
