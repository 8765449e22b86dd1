"""The Python API: the public names at the top level of ``identify`` (loaded on first use), ``to_pandas()`` on
records and results, and ``==`` on result types comparing arrays element by element, so that a result saved and
reopened equals the original (README, "Result files")."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

import identify
from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag


def test_every_public_name_is_at_the_top_level_and_loads_lazily():
    from identify.hammerstein_subspace import identify_hammerstein

    assert identify.identify_hammerstein is identify_hammerstein
    for name in identify.__all__:
        assert getattr(identify, name) is not None, name
    assert {"diagnose_model", "ExperimentRecord", "HammersteinModel", "bound_output_backlash_system",
            "DiscrepancyReport", "PlantModel"} <= set(identify.__all__)
    with pytest.raises(AttributeError, match="no attribute 'identify_everything'"):
        identify.identify_everything  # noqa: B018
    code = ("import sys, identify; loaded = [m for m in sys.modules if m.startswith('identify.')]; "
            "assert not loaded, loaded; from identify import diagnose_model, ExperimentRecord; "
            "assert 'identify.model_discrepancy' in sys.modules and 'identify.hammerstein_subspace' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def _record() -> ExperimentRecord:
    flags = np.zeros(5, dtype=np.uint8)
    flags[2] = SampleFlag.LOST
    return ExperimentRecord(time_s=np.arange(5) * 0.001, command_rad=np.linspace(0, 1, 5),
                            angle_rad=np.array([0.0, 0.1, np.nan, 0.3, 0.4]),
                            encoder_counts=np.array([0, 16, 0, 49, 65]), flags=flags,
                            metadata=ExperimentMetadata(sample_period_s=0.001, source="test"))


def test_a_record_equals_its_copy_and_differs_after_a_change():
    record = _record()
    assert record == _record()  # arrays element-wise, NaN where LOST equal to NaN
    changed = dataclasses.replace(record, command_rad=record.command_rad + 1e-9)
    assert record != changed
    assert record != "a record"


def test_a_hammerstein_model_equals_its_reopened_copy_and_differs_after_a_change():
    from identify import HammersteinModel, PathNodes, cyclic_random_excitation, identify_hammerstein
    from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash

    rng = np.random.default_rng(4)
    u = cyclic_random_excitation(1500, -3.0, 3.0, 100, rng=rng)
    y = PlantModel((pouliquen2013_backlash(), LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804),
                                                         sample_period_s=1.0))).simulate(u)
    model = identify_hammerstein(u, y, PathNodes.uniform(-3.0, 3.0, 8), hold_samples=100)
    reopened = HammersteinModel.from_dict(json.loads(json.dumps(model.to_dict())))
    assert model == reopened
    assert model != dataclasses.replace(model, A=model.A * 1.001)
    table = model.to_pandas()
    assert list(table.columns) == ["path", "node_rad", "border_rad"] and len(table) == 16


def test_an_output_backlash_result_equals_its_reopened_copy_and_differs_after_a_change():
    from identify import OutputBacklashIdentification, bound_output_backlash_system
    from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
    from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel

    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    u = prbs_sequence(100, 1.0, rng=1)
    result = bound_output_backlash_system(staircase[steady], plant.simulate(staircase)[steady], u, plant.simulate(u),
                                          1e-5, na=2, nk=1, nb=2, method="paper")
    reopened = OutputBacklashIdentification.from_dict(json.loads(json.dumps(result.to_dict())))
    assert result == reopened
    bounds = result.inner_signal
    changed = dataclasses.replace(result, inner_signal=dataclasses.replace(bounds, lower_rad=bounds.lower_rad - 1e-6))
    assert result != changed
    table = result.to_pandas()
    assert list(table["parameter"]) == ["m_l", "c_l", "m_r", "c_r", "a1", "a2", "b1", "b2"]
    assert table.loc[table["parameter"] == "a1", "center"].item() == pytest.approx(0.5, abs=1e-3)


def test_a_record_to_pandas_keeps_columns_lost_samples_and_metadata():
    frame = _record().to_pandas()
    assert list(frame.columns) == ["time_s", "command_rad", "angle_rad", "encoder_counts", "flags"]
    assert np.isnan(frame["angle_rad"][2]) and frame["encoder_counts"].isna().tolist() == [False, False, True,
                                                                                         False, False]
    assert frame.attrs["metadata"]["source"] == "test"


def test_to_pandas_without_pandas_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match=r"ExperimentRecord\.to_pandas\(\) needs pandas, which is not installed: "
                                          r"pip install pandas"):
        _record().to_pandas()


def test_linear_dynamics_convert_to_python_control_with_the_same_response():
    """The field's linear-systems library takes our linear parts as they are: the same step response as our
    own simulation, the same frequency response, the sample time kept."""
    control = pytest.importorskip("control")
    from identify import PathNodes, cyclic_random_excitation, identify_hammerstein
    from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash

    block = LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=0.002)  # Cerone et al. (2009), eq. (8)
    system = block.to_control()
    assert isinstance(system, control.TransferFunction) and system.dt == 0.002
    u = np.sin(0.3 * np.arange(200))
    response = control.forced_response(system, T=np.arange(200) * 0.002, U=u)
    np.testing.assert_allclose(np.ravel(response.outputs), block.apply(u), rtol=0, atol=1e-12)
    assert control.dcgain(system) == pytest.approx(block.static_gain, abs=1e-12)

    rng = np.random.default_rng(4)
    excitation = cyclic_random_excitation(1500, -3.0, 3.0, 100, rng=rng)
    y = PlantModel((pouliquen2013_backlash(), LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804),
                                                         sample_period_s=1.0))).simulate(excitation)
    model = identify_hammerstein(excitation, y, PathNodes.uniform(-3.0, 3.0, 8), hold_samples=100)
    identified = model.to_control(1.0)
    omega = np.array([0.01, 0.1, 1.0])
    np.testing.assert_allclose(np.ravel(identified(np.exp(1j * omega))), model.frequency_response(omega),
                               rtol=1e-9)


def test_to_control_without_python_control_says_what_to_install(monkeypatch):
    from identify.plant_blocks import LinearBlock

    monkeypatch.setitem(sys.modules, "control", None)
    with pytest.raises(ImportError, match=r"LinearBlock\.to_control\(\) needs python-control, which is not "
                                          r"installed: pip install control"):
        LinearBlock(a=(0.5,), b=(1.0,), sample_period_s=1.0).to_control()


def test_a_diagnosis_to_pandas_lists_each_named_parameter_with_its_interval_and_the_verdict():
    pytest.importorskip("pandas")
    from identify.discrepancy_cases import hidden_effect_record
    from identify.model_discrepancy import DiscrepancyReport, diagnose_model

    record = hidden_effect_record(("backlash",), 3, num_samples=1500)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    table = result.to_pandas()
    assert table.attrs["verdict"] == result.verdict == "ambiguous"  # a play, or friction without stiction
    step = result.report().missing_effects[0]
    assert list(table["effect"]) == ["backlash"] * len(step.parameters)
    for row in table.itertuples():
        assert row.value == step.parameters[row.parameter]
        assert (row.lower, row.upper) == pytest.approx(step.parameter_intervals[row.parameter])
    reopened = DiscrepancyReport.from_dict(json.loads(json.dumps(result.to_dict())))
    assert reopened.to_pandas().equals(table)
