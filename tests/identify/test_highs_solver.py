"""The HiGHS adapter: the private class highspy._core._Highs still works the way the LP code calls it.

If one of these tests fails after a highspy upgrade, the private API changed: adapt identify/highs_solver.py
(and only it), re-run tests/identify, and move the upper bound of highspy in pyproject.toml."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from identify import highs_solver
from identify.highs_solver import HighsBasis, HighsBasisStatus, HighsLp, HighsModelStatus, MatrixFormat, quiet_highs


def _small_lp() -> HighsLp:
    """min x0 + 2 x1 subject to x0 + x1 >= 1, x0 - x1 = 0.2, 0 <= x <= 10: optimum x = (0.6, 0.4), cost 1.4."""
    A = sp.csc_matrix(np.array([[1.0, 1.0], [1.0, -1.0]]))
    model = HighsLp()  # the same fields, in the same way, as identify.linear_block_bounds.certified_lp._Solver
    model.num_col_, model.num_row_ = 2, 2
    model.col_cost_ = np.zeros(2)
    model.col_lower_, model.col_upper_ = np.zeros(2), np.full(2, 10.0)
    model.row_lower_, model.row_upper_ = np.array([1.0, 0.2]), np.array([np.inf, 0.2])
    model.a_matrix_.format_ = MatrixFormat.kColwise
    model.a_matrix_.start_ = A.indptr.astype(np.int32)
    model.a_matrix_.index_ = A.indices.astype(np.int32)
    model.a_matrix_.value_ = A.data.astype(float)
    return model


def test_the_quiet_instance_prints_nothing_and_solves_an_lp_through_every_call_the_lp_code_makes(capfd):
    highs = quiet_highs()
    highs.passModel(_small_lp())
    highs.setOptionValue("time_limit", highs.getRunTime() + 10.0)
    columns = np.arange(2, dtype=np.int32)
    highs.changeColsCost(2, columns, np.array([1.0, 2.0]))
    highs.run()
    assert highs.getModelStatus() == HighsModelStatus.kOptimal
    assert highs.modelStatusToString(highs.getModelStatus()) == "Optimal"
    solution = highs.getSolution()
    np.testing.assert_allclose(solution.col_value, [0.6, 0.4], atol=1e-9)
    np.testing.assert_allclose(solution.row_dual, [1.5, -0.5], atol=1e-9)  # cost = A^T y at the optimum
    basis = highs.getBasis()
    highs.changeColsCost(2, columns, np.array([2.0, 1.0]))  # a new objective, warm-started from the basis
    highs.setBasis(basis)
    highs.setOptionValue("simplex_strategy", 4)
    highs.setOptionValue("presolve", "off")
    highs.run()
    np.testing.assert_allclose(highs.getSolution().col_value, [0.6, 0.4], atol=1e-9)  # x0 = x1 + 0.2, x0 + x1 = 1
    np.testing.assert_allclose(highs.getSolution().row_dual, [1.5, 0.5], atol=1e-9)
    # a basis rebuilt from its status codes (a part's hand-off to its next pass, sent between processes)
    basis = highs.getBasis()
    codes = [int(status) for status in basis.col_status], [int(status) for status in basis.row_status]
    rebuilt = HighsBasis()
    rebuilt.col_status = [HighsBasisStatus(code) for code in codes[0]]
    rebuilt.row_status = [HighsBasisStatus(code) for code in codes[1]]
    rebuilt.valid = True
    highs.clearSolver()
    highs.setBasis(rebuilt)
    highs.setOptionValue("simplex_strategy", 1)
    highs.run()
    assert highs.getBasis().valid and highs.getInfo().simplex_iteration_count == 0  # already optimal
    np.testing.assert_allclose(highs.getSolution().col_value, [0.6, 0.4], atol=1e-9)
    highs.clearSolver()
    highs.run()
    assert highs.getModelStatus() == HighsModelStatus.kOptimal
    # a row added to the solved model (row generation): x1 >= 0.5 moves the optimum of min 2 x0 + x1 to (0.7, 0.5)
    highs.addRows(1, np.array([0.5]), np.array([np.inf]), 1, np.array([0], dtype=np.int32),
                  np.array([1], dtype=np.int32), np.array([1.0]))
    highs.setOptionValue("simplex_strategy", 1)
    highs.run()
    assert highs.getModelStatus() == HighsModelStatus.kOptimal
    np.testing.assert_allclose(highs.getSolution().col_value, [0.7, 0.5], atol=1e-9)
    out, err = capfd.readouterr()  # the file descriptors: HiGHS writes from C++
    assert out == "" and err == ""


def test_an_infeasible_lp_is_reported_as_such():
    model = _small_lp()
    model.col_upper_ = np.full(2, 0.1)  # x0 + x1 <= 0.2 < 1
    highs = quiet_highs()
    highs.passModel(model)
    highs.run()
    assert highs.getModelStatus() == HighsModelStatus.kInfeasible


def test_a_highspy_without_a_method_the_lp_code_calls_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(highs_solver, "SOLVER_METHODS", (*highs_solver.SOLVER_METHODS, "noSuchMethod"))
    with pytest.raises(ImportError, match=r"highspy\._core\._Highs has no noSuchMethod; .*tested with highspy 1\.16\.0"):
        quiet_highs()


def test_the_public_class_is_still_the_private_one_with_a_banner():
    """The adapter exists because highspy.Highs subclasses _Highs only to add the banner and callbacks: if that
    changes, look again whether the public class can be used."""
    import highspy
    from highspy._core import _Highs

    assert issubclass(highspy.Highs, _Highs)
