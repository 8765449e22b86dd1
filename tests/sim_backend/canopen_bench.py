"""A bench for the simulated CANopen devices: a :class:`SimulatedCanOpenRig` on its own ``virtual``
channel, scripted by canopen's own master objects (``RemoteNode``, ``BaseNode402``), none of our driver.

Timing rule for every test here: poll with generous deadlines (seconds); assert only what a device can
never do (be early), never how fast the machine is.
"""

from __future__ import annotations

import contextlib
import itertools
import queue
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import canopen
from canopen.profiles.p402 import BaseNode402

from sim_backend.canopen_nodes import DRIVE_EDS, ENCODER_EDS, SimulatedCanOpenRig
from sim_backend.plant import SimulatedGearbox
from sim_backend.plant_config import load_plant_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "transports"))
from sim_rigs import no_leaks  # noqa: E402,F401  (the fixture, re-exported)

PLANT = Path(__file__).resolve().parents[2] / "configs" / "plants" / "precision_gearbox.toml"
DRIVE_ID, ENCODER_ID = 1, 2
DEADLINE_S = 5.0
_channels = itertools.count()

# CiA 402 statusword states (mask, value)
SWITCH_ON_DISABLED = (0x4F, 0x40)
READY_TO_SWITCH_ON = (0x6F, 0x21)
SWITCHED_ON = (0x6F, 0x23)
OPERATION_ENABLED = (0x6F, 0x27)
QUICK_STOP_ACTIVE = (0x6F, 0x07)
FAULT = (0x4F, 0x08)


def is_state(statusword: int, state: tuple[int, int]) -> bool:
    return statusword & state[0] == state[1]


def wait_until(predicate: Callable[[], Any], what: str, timeout_s: float = DEADLINE_S,
               interval_s: float = 0.005) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s:g} s: {what}")
        time.sleep(interval_s)


@dataclass
class Bench:
    rig: SimulatedCanOpenRig
    network: canopen.Network
    drive: BaseNode402
    encoder: canopen.RemoteNode

    def sync_every(self, period_s: float = 0.005) -> None:
        """SYNC from a cyclic task, as a CiA 301 SYNC producer."""
        self.network.sync.start(period_s)

    def stop_sync(self) -> None:
        self.network.sync.stop()

    def syncs(self, count: int) -> None:
        for _ in range(count):
            self.network.sync.transmit()

    def operational(self, *nodes: canopen.RemoteNode) -> None:
        nodes = nodes or (self.drive, self.encoder)
        for node in nodes:
            node.nmt.state = "OPERATIONAL"
        wait_until(lambda: all(self.rig_node(node).nmt.state == "OPERATIONAL" for node in nodes), "nodes OPERATIONAL")

    def rig_node(self, node: canopen.RemoteNode) -> canopen.LocalNode:
        return self.rig.drive if node is self.drive else self.rig.encoder

    def statusword(self) -> int:
        return self.drive.sdo[0x6041].raw

    def wait_state(self, state: tuple[int, int], what: str, timeout_s: float = DEADLINE_S) -> int:
        def reached() -> int | None:
            word = self.statusword()
            return word if is_state(word, state) else None

        return wait_until(reached, what, timeout_s)

    def controlwords(self, *words: int) -> None:
        for word in words:
            self.drive.sdo[0x6040].raw = word

    def enable(self) -> None:
        """Shutdown, switch on, enable operation by SDO; waits for OPERATION ENABLED."""
        self.controlwords(0x06, 0x07, 0x0F)
        self.wait_state(OPERATION_ENABLED, "OPERATION ENABLED")

    def emcy_codes(self, node: canopen.RemoteNode | None = None) -> list[int]:
        return [entry.code for entry in (node or self.drive).emcy.log]


def collect(pdo_map: Any) -> queue.Queue:
    """Every reception of the master-side PDO map as {index: raw value}."""
    received: queue.Queue = queue.Queue()
    pdo_map.add_callback(lambda pdo: received.put({variable.index: variable.raw for variable in pdo}))
    return received


def gearbox(encoder: Any = None) -> SimulatedGearbox:
    box = load_plant_config(PLANT).gearbox(seed=1)
    if encoder is not None:
        box = SimulatedGearbox(box.plant, encoder, box.noise, box.sample_period_s, box.seed, box.name)
    return box


@contextlib.contextmanager
def bench(*, drive_eds: str | Path | None = None, encoder_eds: str | Path | None = None,
          plant: SimulatedGearbox | None = None,
          master_drive_eds: str | Path | None = None, master_encoder_eds: str | Path | None = None,
          sdo_timeout_s: float = 1.0, **rig_options: Any) -> Iterator[Bench]:
    """The simulated rig and canopen's master on a fresh virtual channel; everything closed on exit."""
    channel = f"sim_backend_canopen_{next(_channels)}_{time.monotonic_ns()}"
    rig_options.setdefault("hold_plant_until_first_target", False)  # the device acts on every SYNC
    rig = SimulatedCanOpenRig(plant or gearbox(), channel=channel, drive_eds=drive_eds or DRIVE_EDS,
                              encoder_eds=encoder_eds or ENCODER_EDS, **rig_options)
    with rig:
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.05  # disconnect() waits for the notifier's idle cycle
        network.connect(interface="virtual", channel=channel)
        try:
            drive = BaseNode402(DRIVE_ID, str(master_drive_eds or drive_eds or DRIVE_EDS))
            encoder = canopen.RemoteNode(ENCODER_ID, str(master_encoder_eds or encoder_eds or ENCODER_EDS))
            for node in (drive, encoder):
                network.add_node(node)
                node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            yield Bench(rig, network, drive, encoder)
        finally:
            network.sync.stop()
            network.disconnect()
