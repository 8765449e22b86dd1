"""The one adapter to highspy's private API: a HiGHS instance that prints nothing.

``highspy.Highs()`` prints a banner to stdout when it is built (it would break ``--json`` output) and
enables callbacks that the bounding LPs do not use, so the LP code uses the bare core class
``highspy._core._Highs`` instead, which is private and may change in any highspy release. This module is
the only place that names it: the LP code (``identify.linear_block_bounds``) takes :func:`quiet_highs`
and the model types re-exported here. ``tests/identify/test_highs_solver.py`` solves a small LP through
exactly the calls the LP code makes, so a highspy that changes any of them fails there, by name;
``pyproject.toml`` pins highspy below the first release that was not tested (:data:`TESTED_HIGHSPY`).
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

__all__ = ["HighsBasis", "HighsBasisStatus", "HighsLp", "HighsModelStatus", "MatrixFormat", "SOLVER_METHODS",
           "TESTED_HIGHSPY", "quiet_highs"]

TESTED_HIGHSPY = "1.16.0"
"""The highspy release this adapter was tested with; ``pyproject.toml`` allows ``highspy>=1.7,<1.17`` (the
lower bound is the project's earlier one, not re-tested here)."""

SOLVER_METHODS = ("setOptionValue", "passModel", "run", "getRunTime", "getModelStatus", "modelStatusToString",
                  "changeColsCost", "getSolution", "getBasis", "setBasis", "clearSolver", "addRows")
"""The methods of the HiGHS instance that the LP code calls."""


def _installed() -> str:
    try:
        return version("highspy")
    except PackageNotFoundError:  # pragma: no cover - highspy is a dependency
        return "unknown"


try:
    from highspy._core import HighsBasis, HighsBasisStatus, HighsLp, HighsModelStatus, MatrixFormat, _Highs
except ImportError as err:  # pragma: no cover - only with an untested highspy
    raise ImportError(
        f"highspy {_installed()} has no private class highspy._core._Highs (or HighsLp, HighsModelStatus, "
        f"MatrixFormat, HighsBasis, HighsBasisStatus), which identify.highs_solver uses to solve LPs without a "
        f"banner on stdout; it was tested with highspy {TESTED_HIGHSPY}: install it (pip install 'highspy==1.16.0')"
    ) from err


def quiet_highs() -> _Highs:
    """A HiGHS instance with its log output off (``output_flag`` false) that printed nothing when built.

    Raises
    ------
    ImportError
        The installed highspy lacks one of :data:`SOLVER_METHODS` (a release this adapter was not tested with).
    """
    highs = _Highs()
    missing = [name for name in SOLVER_METHODS if not callable(getattr(highs, name, None))]
    if missing:
        raise ImportError(f"highspy {_installed()}: highspy._core._Highs has no {', '.join(missing)}; "
                          f"identify.highs_solver was tested with highspy {TESTED_HIGHSPY}: install it "
                          "(pip install 'highspy==1.16.0')")
    highs.setOptionValue("output_flag", False)
    return highs
