"""Opt-in (RIG_REALDATA=1): the model-discrepancy workflow on the real EMPS record (Janot, Gautier, Brunot 2019).

Reference position qg -> measured position qm of the closed position loop, every 5th sample, no model given.
The benchmark's inverse model has Coulomb friction Fc = 20.39 N and an offset of -3.16 N. In the loop
vir = kv (kp (qg - qm) - dqm/dt) with force gtau vir, a friction force F leaves a steady tracking error
F / (gtau kv kp): 14.9 um for Fc and 2.3 um for the offset. Friction without stiction in a position loop is
a play (hysteresis) of that half-width, asymmetric by the offset: the verdict must leave the mechanism open
(ambiguous between play and friction) or name friction. Without RIG_REALDATA=1 this module defines no
test (the default run stays off real data).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

EMPS = next((parent / "shared" / "realdata" / "emps" / "DATA_EMPS.mat" for parent in Path(__file__).resolve().parents
             if (parent / "shared" / "realdata").is_dir()), Path("shared/realdata/emps/DATA_EMPS.mat"))
"""Next to the checkout, or next to a folder above it (a git worktree sits one level deeper)."""

if os.environ.get("RIG_REALDATA") == "1":

    @pytest.mark.realdata
    @pytest.mark.slow
    def test_emps_friction_shows_as_asymmetric_play_of_the_size_the_benchmark_predicts_and_is_not_called_play():
        from scipy.io import loadmat

        from identify.model_discrepancy import diagnose_model

        data = loadmat(EMPS)
        t, qg, qm = (np.ravel(data[key])[::5] for key in ("t", "qg", "qm"))
        gain = float(data["gtau"][0, 0] * data["kv"][0, 0] * data["kp"][0, 0])  # N per m of tracking error
        result = diagnose_model(qg, qm, 1e-6, float(np.median(np.diff(t))), None)
        assert result.missing_effects[:1] in (("backlash",), ("coulomb_friction",))
        step = result.steps[0]
        assert step.gap_after_rad <= 0.5 * step.gap_before_rad
        if step.effect == "backlash":
            half_width = (step.parameters["c_l_rad"] + step.parameters["c_r_rad"]) / 2.0
            offset = (step.parameters["c_l_rad"] - step.parameters["c_r_rad"]) / 2.0
            assert half_width * gain == pytest.approx(20.39, rel=0.25)  # Fc of the benchmark, N
            assert abs(offset) * gain == pytest.approx(3.16, rel=0.5)  # |offset| of the benchmark, N
            # the ball screw has no play: the map is named, the mechanism left open between play and friction
            assert result.verdict == "ambiguous"
            assert set(result.ambiguous_between) == {"backlash", "coulomb_friction"}
        else:  # friction without stiction, then the offset as an effect of its own
            assert step.parameters["sliding_deflection_rad"] * gain == pytest.approx(20.39, rel=0.25)
            offsets = [s for s in result.steps if s.effect == "offset"]
            if offsets:
                assert abs(offsets[0].parameters["offset_rad"]) * gain == pytest.approx(3.16, rel=0.5)
