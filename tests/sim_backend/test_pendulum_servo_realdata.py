"""Opt-in (RIG_REALDATA=1): configs/plants/pendulum_servo.toml against the STS3215 pendulum records.

The example plant's drive_train was fitted by hand to these records (the torque-off swings of lift_and_drop
for inertia and friction, one repetition of each driven trajectory at kp = 16 for the loop, speed limit and
play). The test holds the fit to what it reached: the free run from the first measured angle stays within
0.08 rad rms of every kp = 16 record, and within 0.05 rad rms of every torque-off swing (all gains; the drive
is off, so the gain does not matter). One-sample read failures (a jump of about pi that comes straight back)
are replaced by the mean of their neighbours. Without RIG_REALDATA=1 this module defines no test.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
# ../shared next to the checkout (the first ancestor that has one, so that a git worktree finds it too)
RECORDS = next((parent / "shared" / "realdata" / "kscale_sts3215" for parent in ROOT.parents
                if (parent / "shared" / "realdata").is_dir()), ROOT.parent / "shared" / "realdata" / "kscale_sts3215")

if os.environ.get("RIG_REALDATA") == "1":

    def _records():
        with open(RECORDS / "index.csv", newline="") as index:
            for row in csv.DictReader(index):
                entries = json.loads((RECORDS / row["file"]).read_text())["entries"]
                angle = np.array([entry["position"] for entry in entries])
                goal = np.array([entry["goal_position"] for entry in entries])
                enabled = np.array([entry["torque_enable"] for entry in entries], dtype=bool)
                for i in range(1, angle.size - 1):
                    if abs(angle[i] - angle[i - 1]) > 1.0 and abs(angle[i + 1] - angle[i - 1]) < 0.3:
                        angle[i] = 0.5 * (angle[i - 1] + angle[i + 1])
                yield row, goal, angle, enabled

    def _train():
        from sim_backend.plant_config import load_plant_config

        (train,) = load_plant_config(ROOT / "configs" / "plants" / "pendulum_servo.toml").plant.blocks
        return train

    @pytest.mark.realdata
    def test_pendulum_servo_follows_the_kp16_records_within_8_centiradians():
        train = _train()
        checked = 0
        for row, goal, angle, enabled in _records():
            if row["kp"] != "16":
                continue
            driven = int(np.flatnonzero(~enabled)[0]) if not enabled.all() else angle.size
            y = dataclasses.replace(train, initial_angle_rad=angle[0]).apply(goal[:driven])
            rms = float(np.sqrt(np.mean((y[1:] - angle[1:driven]) ** 2)))
            assert rms < 0.08, (row["file"], rms)
            checked += 1
        assert checked == 20

    @pytest.mark.realdata
    def test_pendulum_servo_swings_like_the_torque_off_records_within_5_centiradians():
        train = _train()
        checked = 0
        for row, _goal, angle, enabled in _records():
            if enabled.all():
                continue
            swing = angle[int(np.flatnonzero(~enabled)[0]):]
            y = dataclasses.replace(train, drive_enabled=False, initial_angle_rad=swing[0]).apply(np.zeros(swing.size))
            rms = float(np.sqrt(np.mean((y - swing) ** 2)))
            assert rms < 0.05, (row["file"], rms)
            checked += 1
        assert checked == 12
