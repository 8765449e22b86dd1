"""The table of simulated devices beside the transport registry (rig.transports.simulated)."""

from __future__ import annotations

import dataclasses

import pytest

from rig.protocols.errors import ConfigError
from rig.rig_config import load_rig_config
from rig.transports import BACKENDS
from rig.transports.simulated import SIMULATED_DEVICES, simulated_rig
from sim_rigs import write_test_config


def test_every_transport_of_the_registry_has_a_simulated_device():
    assert set(SIMULATED_DEVICES) == set(BACKENDS)
    assert all(entry.scheme == scheme for scheme, entry in SIMULATED_DEVICES.items())


@pytest.mark.parametrize("kind", ["canopen", "can"])
def test_a_simulated_can_rig_off_the_virtual_bus_is_refused_with_the_url_to_use(kind, tmp_path):
    config = load_rig_config(write_test_config(kind, tmp_path))
    config = dataclasses.replace(config, url=f"{kind}://socketcan/can0")
    with pytest.raises(ConfigError, match=rf"transport.url.*runs on the virtual interface: {kind}://virtual/CHANNEL"):
        with simulated_rig(config):
            pass


def test_a_real_rig_has_nothing_to_simulate(tmp_path):
    config = dataclasses.replace(load_rig_config(write_test_config("serial", tmp_path)), simulation=None)
    with pytest.raises(ConfigError, match=r"simulation.*a real rig \(no \[simulation\] table\)"):
        with simulated_rig(config):
            pass

