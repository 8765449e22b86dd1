"""Direction signal, piecewise-linear basis and lifted input of Pouliquen et al. (2013), Section II-B."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from identify.border_lifting import (
    PathNodes,
    check_cyclic_input,
    direction_signal,
    path_indicator,
    lifted_input,
    piecewise_linear_basis,
    uniform_nodes,
)
from identify.cyclic_excitation import cyclic_random_excitation
from identify.plant_blocks import InputBacklash, InputSwitch, PiecewiseLinearBorder
from identify.validation import InvalidInputError

NODES = PathNodes.uniform(-3.0, 3.0, 8)


def test_path_indicator_follows_its_definition_and_reads_the_one_direction_signal() -> None:
    u = [0.0, 0.0, 1.0, 1.0, 0.5, 0.5, 2.0, 2.0, -1.0]
    assert path_indicator(u).tolist() == [0, 0, 1, 1, 0, 0, 1, 1, 0]
    assert path_indicator(u, initial_direction=1).tolist()[:2] == [1, 1]
    assert path_indicator([2.0, 2.0]).tolist() == [0, 0]
    assert direction_signal(u).tolist() == [0, 0, 1, 1, -1, -1, 1, 1, -1]


def test_basis_functions_match_eq3_and_sum_to_the_distance_from_u_min() -> None:
    nodes = [-1.0, 0.0, 2.0]
    P = piecewise_linear_basis([-1.0, -0.5, 0.0, 1.0, 2.0], nodes)
    assert P.tolist() == [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.0, 1.0], [1.0, 2.0]]
    u = np.random.default_rng(0).uniform(-3.0, 3.0, 200)
    assert np.allclose(piecewise_linear_basis(u, NODES.ascending).sum(axis=1), u + 3.0, atol=1e-12)


@pytest.mark.parametrize("kind", ["switch", "backlash"])
def test_lifted_input_reproduces_eq4_for_a_switch_and_a_backlash_on_the_cyclic_excitation(kind: str) -> None:
    # Remark 3: different nodes on the two paths. Common ends (A.1 at u_min, and at u_max so that the
    # backlash has no inner segment at the reversals) and H_a <= H_d, so the paths are the borders.
    nodes = PathNodes(ascending=(-3.0, -1.0, 0.0, 0.5, 3.0), descending=(-3.0, -2.0, 1.0, 2.5, 2.9, 3.0))
    ascending = PiecewiseLinearBorder(nodes.ascending, (-1.0, -0.8, -0.5, -0.2, 1.0))
    descending = PiecewiseLinearBorder(nodes.descending, (-1.0, -0.3, 0.6, 0.9, 0.97, 1.0))
    if kind == "switch":
        block = InputSwitch(ascending, descending, initial_input_rad=-3.0, initial_ascending=False)
    else:
        block = InputBacklash(ascending, descending, initial_output_rad=-1.0)
    u = cyclic_random_excitation(2000, -3.0, 3.0, 5, rng=4)
    slopes_a = np.diff(ascending.values) / np.diff(nodes.ascending)
    slopes_d = np.diff(descending.values) / np.diff(nodes.descending)
    z = lifted_input(u, nodes)
    assert z.shape == (2000, nodes.num_lifted_inputs) == (2000, 9)
    assert np.allclose(-1.0 + z @ np.concatenate((slopes_a, slopes_d)), block.apply(u), atol=1e-12)


def test_path_nodes_reject_bad_tables() -> None:
    with pytest.raises(InvalidInputError, match="node 2 is 0.0 after 1.0"):
        PathNodes((-1.0, 1.0, 0.0, 2.0), (-1.0, 2.0))
    with pytest.raises(InvalidInputError, match="same interval"):
        PathNodes((-1.0, 2.0), (-1.0, 3.0))
    with pytest.raises(InvalidInputError, match="num_nodes"):
        uniform_nodes(0.0, 1.0, 1)


def test_check_accepts_the_design_and_names_what_is_wrong() -> None:
    u = cyclic_random_excitation(4000, -3.0, 3.0, 10, rng=1)
    check_cyclic_input(u, NODES)

    outside = u.copy()
    outside[57] = 3.5
    with pytest.raises(InvalidInputError, match="input_rad: sample 57 is 3.5, outside"):
        check_cyclic_input(outside, NODES)

    early_turn = u.copy()
    k = 10 + 1 + 4 * 20 + 1  # the u_max of cycle 21
    early_turn[k] = 2.0
    early_turn[k + 1] = min(early_turn[k + 1], 1.0)
    with pytest.raises(InvalidInputError, match=f"sample {k} turns from ascending to descending at 2.0"):
        check_cyclic_input(early_turn, NODES)

    with pytest.raises(InvalidInputError, match="sample 0 turns from descending to ascending at 0.0, above u_min"):
        check_cyclic_input(np.concatenate(([0.0], [1.0], u)), NODES)

    never_max = np.clip(u, -3.0, 2.0)
    narrow = PathNodes.uniform(-3.0, 3.0, 8)
    with pytest.raises(InvalidInputError, match="turns from ascending to descending"):
        check_cyclic_input(never_max, narrow)

    # segment 7 ]2.14; 3[ of both paths never visited: remove random values above 2.1
    low_only = np.where((u > 2.1) & (u < 3.0), 0.0, u)
    with pytest.raises(InvalidInputError, match=r"segment 7 \]2.14286; 3\[ of the ascending path is visited by 0"):
        check_cyclic_input(low_only, NODES)


def test_check_reports_an_untraversed_path() -> None:
    with pytest.raises(InvalidInputError, match="ascending path is never traversed"):
        check_cyclic_input([-3.0, -3.0, -3.0], NODES)


@settings(max_examples=30, deadline=None)
@given(
    interior_a=st.lists(st.integers(-99, 99), min_size=0, max_size=6, unique=True),  # in hundredths
    interior_d=st.lists(st.integers(-99, 99), min_size=0, max_size=6, unique=True),
    seed=st.integers(0, 2**16),
)
def test_any_node_placement_reproduces_a_piecewise_linear_switch(interior_a, interior_d, seed) -> None:
    """Eq. (4) holds for any nodes (Remark 3): z(t) μ + μ0 equals the switch output on Table I cycles."""
    nodes = PathNodes((-1.0, *(k / 100 for k in sorted(interior_a)), 1.0),
                      (-1.0, *(k / 100 for k in sorted(interior_d)), 1.0))
    rng = np.random.default_rng(seed)
    values_a = np.concatenate(([0.3], rng.normal(size=len(nodes.ascending) - 1)))
    values_d = np.concatenate(([0.3], rng.normal(size=len(nodes.descending) - 1)))
    switch = InputSwitch(PiecewiseLinearBorder(nodes.ascending, tuple(values_a)),
                         PiecewiseLinearBorder(nodes.descending, tuple(values_d)),
                         initial_input_rad=-1.0, initial_ascending=False)
    u = cyclic_random_excitation(400, -1.0, 1.0, 3, rng=rng)
    mu = np.concatenate((np.diff(values_a) / np.diff(nodes.ascending), np.diff(values_d) / np.diff(nodes.descending)))
    assert np.allclose(0.3 + lifted_input(u, nodes) @ mu, switch.apply(u), atol=1e-9)
