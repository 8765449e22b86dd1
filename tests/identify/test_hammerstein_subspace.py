"""Subspace identification of Hammerstein systems with input backlash or switch (Pouliquen et al. 2013)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from identify.border_lifting import PathNodes, lifted_input
from identify.cyclic_excitation import cyclic_random_excitation
from identify.hammerstein_subspace import (HammersteinModel, HammersteinOptions, NodePlay, identify_hammerstein,
                                          pi_moesp_observability)
from identify.plant_blocks import (
    InputBacklash,
    InputSwitch,
    LinearBlock,
    PiecewiseLinearBorder,
    PlantModel,
    pouliquen2013_backlash,
    pouliquen2013_switch,
)
from identify.result_format import ResultFormatError
from identify.validation import InvalidInputError

# Section IV: G(q) = q^-1 (0.1994 - 0.1804 q^-1) / (1 - 1.8858 q^-1 + 0.9048 q^-2), G(1) = 1.
G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=1.0)
TRUE_POLES = np.sort_complex(G.poles)
NODES = PathNodes.uniform(-3.0, 3.0, 8)
X = np.asarray(NODES.ascending)
# Piecewise linear on the nodes, equal at both ends and H_a <= H_d: the model class contains the truth.
H_A = np.array([-1.0, -0.9, -0.7, -0.4, 0.0, 0.4, 0.8, 1.0])
H_D = np.array([-1.0, -0.6, -0.2, 0.2, 0.5, 0.75, 0.9, 1.0])
HOLD = 100


def exact_plant(kind: str) -> PlantModel:
    ascending = PiecewiseLinearBorder(tuple(X), tuple(H_A))
    descending = PiecewiseLinearBorder(tuple(X), tuple(H_D))
    if kind == "switch":
        return PlantModel((InputSwitch(ascending, descending, initial_input_rad=-3.0, initial_ascending=False), G))
    return PlantModel((InputBacklash(ascending, descending, initial_output_rad=-1.0), G))


def paper_noise(y0: np.ndarray, snr_db: float, rng: np.random.Generator) -> np.ndarray:
    """v = (1 + 0.5 q^-1)/(1 - 0.85 q^-1) e, scaled to var(y0)/var(v) = 10^(snr/10) (Section IV)."""
    v = scipy.signal.lfilter([1.0, 0.5], [1.0, -0.85], rng.standard_normal(y0.size))
    return v * np.sqrt(np.var(y0) / 10 ** (snr_db / 10) / np.var(v))


@pytest.fixture(scope="module")
def excitation() -> np.ndarray:
    return cyclic_random_excitation(HOLD + 3000, -3.0, 3.0, HOLD, rng=1)


@pytest.mark.parametrize("kind", ["switch", "backlash"])
@pytest.mark.parametrize("split", ["separate", "rank1"])
def test_noise_free_data_recover_poles_gain_and_borders_to_machine_precision(
    excitation: np.ndarray, kind: str, split: str
) -> None:
    y = exact_plant(kind).simulate(excitation)
    model = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, split=split)
    assert model.order == 2
    assert np.max(np.abs(np.sort_complex(model.poles) - TRUE_POLES)) < 1e-10
    assert np.max(np.abs(np.array(model.ascending_border.values) - H_A)) < 1e-10
    assert np.max(np.abs(np.array(model.descending_border.values) - H_D)) < 1e-10
    assert model.mu0 == pytest.approx(-1.0, abs=1e-12)
    assert model.static_gain == pytest.approx(1.0, abs=1e-12)
    assert abs(model.D) < 1e-10
    numerator, denominator = model.transfer_function
    assert np.allclose(denominator, [1.0, -1.8858, 0.9048], atol=1e-10)
    assert np.allclose(numerator, [0.0, 0.1994, -0.1804], atol=1e-10)
    assert model.fit_percent > 99.999999
    # the identified model reproduces the plant on a fresh cyclic input (after the plant, which starts at
    # output 0, has settled at μ0 during a hold: the model starts at rest at μ0)
    fresh = cyclic_random_excitation(2100, -3.0, 3.0, 600, rng=77)
    assert np.max(np.abs(model.simulate(fresh) - exact_plant(kind).simulate(fresh))[600:]) < 1e-9


def test_held_steps_and_a_plain_node_list_work_too() -> None:
    """A rig that cannot follow a new set-point every sample holds each Table I value for 3 samples."""
    u = cyclic_random_excitation(HOLD + 3 * 2500, -3.0, 3.0, HOLD, rng=6, samples_per_step=3)
    y = exact_plant("backlash").simulate(u)
    model = identify_hammerstein(u, y, list(X), hold_samples=HOLD)
    assert np.max(np.abs(np.sort_complex(model.poles) - TRUE_POLES)) < 1e-10
    assert np.max(np.abs(np.array(model.ascending_border.values) - H_A)) < 1e-10


def test_backlash_mode_simulates_a_backlash_on_inputs_that_reverse_inside_the_interval(excitation) -> None:
    y = exact_plant("backlash").simulate(excitation)
    model = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, feedthrough=False)
    walk = np.clip(np.cumsum(np.random.default_rng(5).normal(0.0, 0.4, 2000)) - 3.0, -3.0, 3.0)
    wander = np.concatenate((np.full(600, -3.0), walk))
    truth = exact_plant("backlash").simulate(wander)[600:]
    assert np.max(np.abs(model.simulate(wander, nonlinearity="backlash")[600:] - truth)) < 1e-9
    # eq. (2) alone (the switch reading) is wrong there: the backlash holds its output between the borders
    assert np.max(np.abs(model.simulate(wander)[600:] - truth)) > 0.05


def _block_hankel(signal, first: int, num_blocks: int, num_columns: int):
    """Transposed block-Hankel matrix: row k is [s(first + k), ..., s(first + k + num_blocks - 1)]."""
    m = signal.shape[1]
    windows = np.lib.stride_tricks.sliding_window_view(signal, (num_blocks, m))[:, 0]
    return windows[first : first + num_columns].reshape(num_columns, num_blocks * m)


def _qr_observability(z, y, p: int, f: int):
    """Reference for pi_moesp_observability: a Householder QR of the stacked, centred [Z_f, Z_p, Y_f] (j rows)
    gives L32 of eq. (11) directly (slow: O(j ((p+f) m + f)^2))."""
    inputs, outputs = np.asarray(z, dtype=float), np.asarray(y, dtype=float).reshape(-1, 1)
    m = inputs.shape[1]
    j = inputs.shape[0] - p - f + 1
    a, b = f * m, (f + p) * m
    stacked = np.hstack((_block_hankel(inputs, p, f, j), _block_hankel(inputs, 0, p, j),
                         _block_hankel(outputs, p, f, j)))
    stacked -= stacked.mean(axis=0)
    R = scipy.linalg.lapack.dgeqrf(stacked, overwrite_a=True)[0][: b + f]
    U, singular_values, _ = scipy.linalg.svd(np.triu(R)[a:b, b:].T)
    return U, singular_values, np.abs(np.diag(R)[:b])


def test_the_gram_factorisation_gives_the_projection_of_a_householder_qr(excitation) -> None:
    y = exact_plant("backlash").simulate(excitation)
    y = y + paper_noise(y, 10.0, np.random.default_rng(3))
    z = lifted_input(excitation, NODES)
    U_gram, s_gram, d_gram = pi_moesp_observability(z, y, 8, 8)
    U_qr, s_qr, d_qr = _qr_observability(z, y, 8, 8)
    assert np.allclose(s_gram, s_qr, rtol=1e-9)
    assert np.allclose(d_gram, d_qr, rtol=1e-8)
    # same 2-dimensional column space of Γ_f
    assert np.linalg.norm(U_gram[:, :2] @ U_gram[:, :2].T - U_qr[:, :2] @ U_qr[:, :2].T) < 1e-9


@pytest.mark.parametrize("kind, make", [("switch", pouliquen2013_switch), ("backlash", pouliquen2013_backlash)])
def test_paper_examples_at_20_db_colored_noise_within_stated_tolerances(kind: str, make) -> None:
    """Single run, N = 4000 (j = 4000 - 29), the paper's arctan borders approximated with 8 nodes.

    Tolerances: 5 standard deviations of a 20-run Monte Carlo at 10 dB (poles 3e-3, border RMS 0.07 per
    run, which includes the approximation error of 8 nodes on arctan borders).
    """
    rng = np.random.default_rng(2024)
    u = cyclic_random_excitation(HOLD + 4000, -3.0, 3.0, HOLD, rng=rng)
    y0 = PlantModel((make(), G)).simulate(u)
    model = identify_hammerstein(u, y0 + paper_noise(y0, 20.0, rng), NODES, hold_samples=HOLD)
    assert model.order == 2
    assert np.max(np.abs(np.sort_complex(model.poles) - TRUE_POLES)) < 0.015
    grid = np.linspace(-3.0, 3.0, 601)
    nonlinearity = make()
    if kind == "backlash":  # the paths: borders with the inner segments of Table I cycles
        true_a = np.maximum(np.arctan(grid - 1.0), np.arctan(-2.0))
        true_d = np.minimum(np.arctan(grid + 1.0), np.arctan(2.0))
    else:
        true_a = np.array([nonlinearity.ascending(v) for v in grid])
        true_d = np.array([nonlinearity.descending(v) for v in grid])
    est_a = np.interp(grid, model.ascending_border.nodes_u, model.ascending_border.values)
    est_d = np.interp(grid, model.descending_border.nodes_u, model.descending_border.values)
    assert np.sqrt(np.mean((est_a - true_a) ** 2)) < 0.1
    assert np.sqrt(np.mean((est_d - true_d) ** 2)) < 0.1


@pytest.mark.parametrize("seed", [11, 12])
def test_order_selection_picks_two_on_the_paper_system_at_10_db(seed: int) -> None:
    rng = np.random.default_rng(seed)
    u = cyclic_random_excitation(HOLD + 4000, -3.0, 3.0, HOLD, rng=rng)
    y0 = PlantModel((pouliquen2013_backlash(), G)).simulate(u)
    model = identify_hammerstein(u, y0 + paper_noise(y0, 10.0, rng), NODES, hold_samples=HOLD)
    assert model.order == 2
    s = model.singular_values
    assert s[1] / s[2] > 3.0 * max(s[0] / s[1], s[2] / s[3])  # a clear gap after 2


def test_mu0_from_hold_given_or_estimated(excitation) -> None:
    y = exact_plant("switch").simulate(excitation) + 0.25  # offset: μ0 = -0.75
    y_noisy = y + 0.05 * np.random.default_rng(8).standard_normal(y.size)
    paper = identify_hammerstein(excitation, y_noisy, NODES, hold_samples=HOLD, estimate_offset=False)
    assert paper.mu0 == pytest.approx(np.mean(y_noisy[:HOLD]), abs=1e-12) == paper.mu0_hold_rad
    given = identify_hammerstein(excitation[HOLD:], y[HOLD:], NODES, mu0_rad=-0.75)
    assert given.mu0 == pytest.approx(-0.75, abs=1e-9) and given.mu0_hold_rad is None
    assert given.ascending_border.values[0] == given.mu0
    estimated = identify_hammerstein(excitation[HOLD:], y[HOLD:], NODES)  # no hold, no μ0
    assert estimated.mu0 == pytest.approx(-0.75, abs=1e-9)


def test_refinement_does_not_increase_the_output_error() -> None:
    rng = np.random.default_rng(21)
    u = cyclic_random_excitation(HOLD + 3000, -3.0, 3.0, HOLD, rng=rng)
    y0 = PlantModel((pouliquen2013_switch(), G)).simulate(u)
    model = identify_hammerstein(u, y0 + paper_noise(y0, 20.0, rng), NODES, hold_samples=HOLD, refine=True)
    report = model.refinement
    assert report is not None and report.applied and report.rms_after_rad < report.rms_before_rad
    assert model.residual_rms_rad == pytest.approx(report.rms_after_rad, rel=1e-6)
    assert model.static_gain == pytest.approx(1.0, abs=1e-9)
    assert np.max(np.abs(np.sort_complex(model.poles) - TRUE_POLES)) < 0.015


def test_result_is_frozen_and_serialises_to_the_issue_json(excitation) -> None:
    y = exact_plant("switch").simulate(excitation)
    model = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, order=2)
    record = json.loads(json.dumps(model.to_dict()))
    assert record["kind"] == "hammerstein_model" and record["version"] == 1
    reopened = HammersteinModel.from_dict(record)
    with pytest.warns(DeprecationWarning, match=r"simulate\(u=...\) is deprecated: the parameter is now input_rad"):
        assert np.array_equal(model.simulate(u=excitation), model.simulate(excitation))
    with pytest.warns(DeprecationWarning, match="identify_hammerstein"):
        again = identify_hammerstein(u=excitation, y=y, nodes=NODES, hold_samples=HOLD, order=2)
    assert again.to_dict() == model.to_dict()
    assert reopened.to_dict() == model.to_dict()
    assert np.array_equal(reopened.simulate(excitation), model.simulate(excitation))
    with pytest.raises(ResultFormatError, match="kind 'hammerstein_model' version 2 cannot be read"):
        HammersteinModel.from_dict({**record, "version": 2})
    assert record["order"] == 2 and len(record["poles"]) == 2
    assert np.allclose(sorted(record["poles"]), sorted([[p.real, p.imag] for p in TRUE_POLES]), atol=1e-10)
    assert np.array(record["A"]).shape == (2, 2) and len(record["B"]) == 2 and len(record["C"]) == 2
    assert record["borders"]["ascending"]["u"] == list(X)
    assert np.allclose(record["borders"]["descending"]["h"], H_D, atol=1e-10)
    assert record["singular_values"] == sorted(record["singular_values"], reverse=True)
    with pytest.raises(AttributeError):
        model.mu0 = 0.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        model.A[0, 0] = 1.0
    w = np.array([0.0, 0.1, np.pi])
    expected = scipy.signal.freqz([0.0, 0.1994, -0.1804], [1.0, -1.8858, 0.9048], worN=w)[1]
    assert np.allclose(model.frequency_response(w), expected, atol=1e-9)


def test_errors_name_the_problem(excitation) -> None:
    y = exact_plant("switch").simulate(excitation)
    bad = y.copy()
    bad[321] = np.inf  # NaN marks a sample not measured (tests/identify/test_missing_samples.py); inf is an error
    with pytest.raises(InvalidInputError, match="output_rad: sample 321 is inf"):
        identify_hammerstein(excitation, bad, NODES, hold_samples=HOLD)
    with pytest.raises(InvalidInputError, match="input_rad has 3100, output_rad has 3099"):
        identify_hammerstein(excitation, y[:-1], NODES, hold_samples=HOLD)
    with pytest.raises(InvalidInputError, match=r"too few .* at least 4"):
        identify_hammerstein(excitation[:400], y[:400], NODES, hold_samples=HOLD)
    with pytest.raises(InvalidInputError, match="sample 101 of the hold is u = 0.07"):
        identify_hammerstein(excitation, y, NODES, hold_samples=HOLD + 2)
    with pytest.raises(InvalidInputError, match="give one of them, not both"):
        identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, mu0_rad=-1.0)
    with pytest.raises(InvalidInputError, match="order: 15 needs future_horizon > 15"):
        identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, order=15)
    with pytest.raises(InvalidInputError, match="the data support at most order 2"):
        identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, order=4)
    with pytest.raises(InvalidInputError, match="nodes: expected a PathNodes or a sequence"):
        identify_hammerstein(excitation, y, "nodes", hold_samples=HOLD)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="split"):
        identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, split="svd")  # type: ignore[arg-type]
    narrow = PathNodes.uniform(-2.0, 2.0, 5)
    with pytest.raises(InvalidInputError, match="outside the node interval"):
        identify_hammerstein(excitation, y, narrow, mu0_rad=-1.0)
    dense = PathNodes(tuple(np.linspace(-3.0, 3.0, 8)), (-3.0, -2.9999, 3.0))
    with pytest.raises(InvalidInputError, match=r"segment 1 \]-3; -2.9999\[ of the descending path"):
        identify_hammerstein(excitation, y, dense, hold_samples=HOLD, min_visits=5)


def test_a_constant_input_is_refused_with_what_to_do():
    with pytest.raises(InvalidInputError, match=r"input_rad: the input is constant \(-3 in all 400 samples\), so it "
                                                r"excites nothing; use the cyclic random excitation"):
        identify_hammerstein(np.full(400, -3.0), np.zeros(400), PathNodes((-3.0, 0.0, 3.0), (-3.0, 0.0, 3.0)),
                             hold_samples=50)


def test_an_unstable_identified_model_says_so_in_json_and_text(capsys) -> None:
    """An unstable pole, |p| >= 1, is flagged (``"stable": false`` and a warning line), never printed silently."""
    from pathlib import Path

    from identify.plant_blocks import LinearBlock
    from rig.commands.identify_hammerstein import _print_table

    u = cyclic_random_excitation(HOLD + 600, -3.0, 3.0, HOLD, rng=3)
    growing = LinearBlock(a=(-1.004,), b=(0.0, 0.05), sample_period_s=G.sample_period_s)
    ascending = PiecewiseLinearBorder(tuple(X), tuple(H_A))
    descending = PiecewiseLinearBorder(tuple(X), tuple(H_D))
    y = PlantModel((InputBacklash(ascending, descending, initial_output_rad=-1.0), growing)).simulate(u)
    model = identify_hammerstein(u, y, NODES, hold_samples=HOLD, order=1)
    assert abs(model.poles[0]) == pytest.approx(1.004, abs=1e-6)
    assert model.stable is False and model.to_dict()["stable"] is False
    assert model.max_pole_magnitude == pytest.approx(1.004, abs=1e-6)
    assert model.to_dict()["max_pole_magnitude"] == pytest.approx(1.004, abs=1e-6)
    _print_table(model, Path("growing.csv"), HOLD)
    assert "WARNING          unstable: a pole has |p| = 1.004" in capsys.readouterr().out


def test_step_data_get_told_what_the_method_needs() -> None:
    u = np.repeat([-3.0, 1.0, -1.0, 3.0, -3.0, 0.5], 300)
    y = exact_plant("backlash").simulate(u)
    with pytest.raises(InvalidInputError, match="cyclic excitation that sweeps from u_min up to u_max"):
        identify_hammerstein(u, y, NODES, hold_samples=300)


def test_the_numbers_the_pole_and_border_figures_show(excitation) -> None:
    y = exact_plant("switch").simulate(excitation)
    model = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, order=2)
    assert model.pole_distance(TRUE_POLES) < 1e-9 and model.pole_distance(TRUE_POLES + 0.1) > 0.05
    natural = model.natural_frequencies_hz(0.01)
    assert natural.size == 1 and natural[0] == pytest.approx(abs(np.log(TRUE_POLES[0])) / (2 * np.pi * 0.01))
    assert model.largest_play_rad == pytest.approx(float(np.max(np.asarray(H_D) - np.asarray(H_A))), abs=1e-9)


def test_the_play_at_the_nodes_is_the_gap_between_the_paths(excitation) -> None:
    # borders on shared nodes: the gap at node i is H_D[i] - H_A[i], the end nodes (where the paths meet) are
    # left out of the median and the spread
    y = exact_plant("backlash").simulate(excitation)
    play = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD).play_at_nodes()
    np.testing.assert_allclose(play.nodes_rad, X)
    np.testing.assert_allclose(play.gaps_rad, H_D - H_A, atol=1e-9)
    interior = (H_D - H_A)[1:-1]
    assert play.median_rad == pytest.approx(float(np.median(interior)), abs=1e-9)
    assert (play.lowest_rad, play.highest_rad) == pytest.approx((interior.min(), interior.max()), abs=1e-9)
    assert f"{play.median_rad:.4g}" in play.describe() and f"{interior.size} interior nodes" in play.describe()
    # two nodes: nothing is interior, both gaps count
    two = NodePlay(np.array([0.0, 1.0]), np.array([0.1, 0.3]))
    assert two.median_rad == pytest.approx(0.2) and two.lowest_rad == 0.1


def test_the_options_object_and_the_keywords_are_one_call(excitation) -> None:
    y = exact_plant("backlash").simulate(excitation)
    y = y + paper_noise(y, 20.0, np.random.default_rng(8))
    options = HammersteinOptions(hold_samples=HOLD, split="rank1", feedthrough=False)
    by_object = identify_hammerstein(excitation, y, NODES, options)
    by_keywords = identify_hammerstein(excitation, y, NODES, hold_samples=HOLD, split="rank1", feedthrough=False)
    assert by_object.to_dict() == by_keywords.to_dict()  # exactly: the same floats
    # keywords override the object's fields
    separate = dataclasses.replace(options, split="separate")
    assert identify_hammerstein(excitation, y, NODES, separate, split="rank1").to_dict() == by_keywords.to_dict()
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'hold' \(the options are hold_samples, mu0_rad, "):
        identify_hammerstein(excitation, y, NODES, hold=HOLD)
    with pytest.raises(InvalidInputError, match="past_horizon: expected an integer >= 1, got 0"):
        HammersteinOptions(past_horizon=0)
    with pytest.raises(InvalidInputError, match="hold_samples, mu0_rad: give one of them, not both"):
        HammersteinOptions(hold_samples=HOLD, mu0_rad=-1.0)
