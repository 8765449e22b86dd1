"""Opt-in (RIG_REALDATA=1): the K-Scale STS3215 records (``../shared/realdata/kscale_sts3215``) imported as
``rig diagnose`` reads them give one verdict per experiment over its 4 repetitions. Without
RIG_REALDATA=1 this module defines no test."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import pytest

KSCALE = next((parent / "shared" / "realdata" / "kscale_sts3215" for parent in Path(__file__).resolve().parents
               if (parent / "shared" / "realdata").is_dir()), Path("shared/realdata/kscale_sts3215"))

if os.environ.get("RIG_REALDATA") == "1":

    @pytest.mark.realdata
    @pytest.mark.parametrize("trajectory, kp", [("sin_sin", "32"), ("brutal", "8")])
    def test_the_four_repetitions_of_one_experiment_give_one_verdict(trajectory, kp):
        from identify.model_discrepancy import diagnose_model
        from rig.record_import import ImportOptions, read_measurement

        with (KSCALE / "index.csv").open() as handle:
            files = [row["file"] for row in csv.DictReader(handle) if row["trajectory"] == trajectory and row["kp"] == kp]
        assert len(files) == 4
        options = ImportOptions(columns={"t": "timestamp", "u": "goal_position", "y": "position"}, valid="torque_enable")
        answers = set()
        for name in files:
            record, _ = read_measurement(KSCALE / name, options)
            result = diagnose_model(record.command_rad, record.angle_rad, 1.5 * 2 * math.pi / 4096,
                                    record.metadata.sample_period_s)
            answers.add((result.verdict, result.missing_effects, result.ambiguous_between))
        assert len(answers) == 1, answers
        if trajectory == "brutal":  # one step up, one down: the estimation segment never sees a turn
            assert answers == {("not_excited", (), ())}
