"""The transport contract against a real rig, when an environment variable names its config.

``RIG_HARDWARE_CONFIG=my_rig.toml pytest tests/transports/test_hardware.py`` brings the rig up, streams
a small, slow excitation within the config's limits, and checks sample accounting and a clean stop.
Without the variable this module defines no tests (the simulated rigs cover the same contract).
"""

from __future__ import annotations

import os

import numpy as np

HARDWARE_CONFIG = os.environ.get("RIG_HARDWARE_CONFIG")

if HARDWARE_CONFIG:
    from identify.experiment_record import SampleFlag
    from rig.rig_config import load_rig_config
    from rig.runner import run_experiment
    from rig.transports import open_transport
    from sim_rigs import ListSink

    def test_real_rig_streams_and_stops_cleanly():
        config = load_rig_config(HARDWARE_CONFIG)
        assert config.simulation is None, "RIG_HARDWARE_CONFIG must name a real rig's config"
        transport = open_transport(config.url, **config.transport_options())
        sink = ListSink()
        num_samples = int(config.sample_rate_hz)  # one second
        # a 0.5 Hz sine of 1% of the allowed range around the middle of the limits, within the rate limit
        middle = 0.5 * (config.limits.position_min_rad + config.limits.position_max_rad)
        amplitude = 0.01 * (config.limits.position_max_rad - config.limits.position_min_rad)
        time_s = np.arange(num_samples) / config.sample_rate_hz
        summary = run_experiment(transport, middle + amplitude * np.sin(np.pi * time_s), sink,
                                 feedback_timeout_s=config.feedback_timeout_s, late_tolerance_s=config.late_tolerance_s)
        assert sink.closed and not transport.is_open
        assert summary.samples == len(sink.rows) == num_samples
        flags = np.array([row[4] for row in sink.rows])
        assert summary.lost == np.count_nonzero(flags & SampleFlag.LOST)
        assert not np.any(flags & SampleFlag.FAULT)
