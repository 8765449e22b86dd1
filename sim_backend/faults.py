"""Wire faults a simulated device injects: ``rig run CONFIG --sim-faults SPEC`` and tests.

A SPEC is a comma-separated list of items, each ``NAME``, ``NAME=VALUE``, ``NAME@SAMPLE`` or
``NAME=VALUE@SAMPLE``:

====================  ===============  =====================================================================
item                  wires            fault
====================  ===============  =====================================================================
``drop=P``            all              each feedback frame is lost with probability P (seeded)
``burst=N@K``         all              the N feedback frames from sample K on are lost
``fault=CODE@K``      all              the drive faults at sample K with error code CODE (CANopen: EMCY +
                                       0x603F; serial and raw CAN: their FAULT message)
``disable@K``         all              the drive drops out of OPERATION ENABLED at sample K without a
                                       fault (enable input or safe torque off lost)
``heartbeat@K``       canopen          both nodes stop their heartbeats at sample K (a node off the bus)
``bus_error@K``       canopen, can     an error frame (protocol violation) on the bus at sample K
``bus_off@K``         canopen, can     the controller reports bus-off at sample K
``delay=MS@K``        canopen          the encoder's answer to SYNC K goes on the bus MS ms late, after
                                       later SYNCs (out of order)
``sdo_abort=INDEX``   canopen          the drive aborts SDO writes to object INDEX during start-up (abort
                                       code 0x06090030), e.g. ``sdo_abort=0x6060`` (a mode it lacks)
``garbage=P``         serial           random bytes precede a reply with probability P
``bitflip=P``         serial           one bit of a reply is flipped with probability P (CRC failure)
``truncate=P``        serial           a reply is cut short with probability P (CRC failure)
``lag=MS@K``          serial           from sample K on, every reply leaves MS milliseconds late
``unplug@K``          serial           the device closes its port at sample K (a USB adapter pulled out);
                                       its own link watchdog then disables the drive
``stall=MS@K``        all (host)       the driver's own thread pauses MS ms once sample K is logged (a
                                       garbage-collector pause, a busy desktop); may be given several times
====================  ===============  =====================================================================

The plan is deterministic for a given ``seed``, so a faulty run can be repeated exactly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.protocols.can_error_frames import CAN_ERR_BUSOFF, CAN_ERR_PROT

__all__ = ["FaultPlan", "FAULT_ITEMS", "parse_fault_spec"]

FAULT_ITEMS: dict[str, tuple[str, frozenset[str]]] = {
    "drop": ("drop=P: lose each feedback frame with probability P", frozenset({"canopen", "can", "serial"})),
    "burst": ("burst=N@K: lose N feedback frames from sample K", frozenset({"canopen", "can", "serial"})),
    "fault": ("fault=CODE@K: drive fault with error CODE at sample K", frozenset({"canopen", "can", "serial"})),
    "disable": ("disable@K: the drive leaves OPERATION ENABLED at sample K", frozenset({"canopen", "can", "serial"})),
    "heartbeat": ("heartbeat@K: both nodes stop their heartbeats at sample K", frozenset({"canopen"})),
    "bus_error": ("bus_error@K: an error frame at sample K", frozenset({"canopen", "can"})),
    "bus_off": ("bus_off@K: the controller goes bus off at sample K", frozenset({"canopen", "can"})),
    "delay": ("delay=MS@K: the encoder's TPDO for sample K sent MS ms late", frozenset({"canopen"})),
    "sdo_abort": ("sdo_abort=INDEX: the drive aborts SDO writes to INDEX at start-up", frozenset({"canopen"})),
    "garbage": ("garbage=P: random bytes before a reply with probability P", frozenset({"serial"})),
    "bitflip": ("bitflip=P: one bit of a reply flipped with probability P", frozenset({"serial"})),
    "truncate": ("truncate=P: a reply cut short with probability P", frozenset({"serial"})),
    "lag": ("lag=MS@K: every reply from sample K on leaves MS ms late", frozenset({"serial"})),
    "unplug": ("unplug@K: the device closes its port at sample K", frozenset({"serial"})),
    "stall": ("stall=MS@K: the driver's thread pauses MS ms at sample K", frozenset({"canopen", "can", "serial"})),
}


@dataclass(frozen=True)
class FaultPlan:
    """The faults of one simulated run (see the module docstring for their meaning)."""

    drop_probability: float = 0.0
    bursts: tuple[tuple[int, int], ...] = ()  # (first sample, number of frames)
    drive_fault: tuple[int, int] | None = None  # (error code, sample)
    heartbeat_loss_at: int | None = None
    disable_at: int | None = None
    refused_sdo_index: int | None = None
    delayed_tpdo: tuple[float, int] | None = None  # (seconds, sample)
    error_frame_at: tuple[int, int] | None = None  # (SocketCAN error class bits, sample)
    garbage_probability: float = 0.0
    bitflip_probability: float = 0.0
    truncate_probability: float = 0.0
    reply_lag: tuple[float, int] | None = None  # (seconds, first sample)
    unplug_at: int | None = None
    host_stalls: tuple[tuple[int, float], ...] = ()  # (sample, seconds): the driver's thread pauses (not a device fault)
    seed: int = 0

    @property
    def items(self) -> frozenset[str]:
        """The SPEC item names this plan uses."""
        used = {"drop": self.drop_probability > 0, "burst": bool(self.bursts), "fault": self.drive_fault is not None,
                "heartbeat": self.heartbeat_loss_at is not None,
                "disable": self.disable_at is not None, "sdo_abort": self.refused_sdo_index is not None,
                "delay": self.delayed_tpdo is not None,
                "bus_error": self.error_frame_at is not None and self.error_frame_at[0] != CAN_ERR_BUSOFF,
                "bus_off": self.error_frame_at is not None and self.error_frame_at[0] == CAN_ERR_BUSOFF,
                "garbage": self.garbage_probability > 0,
                "bitflip": self.bitflip_probability > 0,
                "truncate": self.truncate_probability > 0, "lag": self.reply_lag is not None, "unplug": self.unplug_at is not None,
                "stall": bool(self.host_stalls)}
        return frozenset(name for name, on in used.items() if on)

    def lost_feedback(self, num_samples: int) -> frozenset[int]:
        """Sample numbers (below ``num_samples``) whose feedback frame the device does not send."""
        rng = np.random.default_rng(self.seed)
        lost: set[int] = set()
        if self.drop_probability > 0:
            step = 1 << 20  # drawn a block at a time (the same numbers as one draw): a run of hours needs no
            for start in range(0, num_samples, step):  # array of one number a sample
                block = rng.random(min(step, num_samples - start))
                lost.update((start + np.flatnonzero(block < self.drop_probability)).tolist())
        for first, count in self.bursts:
            lost.update(range(first, first + count))
        return frozenset(lost)

    def device_options(self, scheme: str, num_samples: int) -> dict[str, Any]:
        """Keyword arguments for the simulated device of a ``scheme`` transport (``canopen``, ``can`` or
        ``serial``) running ``num_samples`` samples.

        Raises
        ------
        ValueError
            An item the device of that wire cannot produce (names the item and the wires that can).
        """
        for name in sorted(self.items):
            wires = FAULT_ITEMS[name][1]
            if scheme not in wires:
                raise ValueError(f"--sim-faults: {name!r} cannot be injected on a {scheme}:// rig "
                                 f"(only on {', '.join(sorted(wires))})")
        options: dict[str, Any] = {}
        lost = self.lost_feedback(num_samples)
        if lost:
            options["silent_seqs"] = lost
        if self.drive_fault is not None:
            options["fault_code"], options["fault_at_seq"] = self.drive_fault
        if self.heartbeat_loss_at is not None:
            options["stop_heartbeat_at_seq"] = self.heartbeat_loss_at
        if self.disable_at is not None:
            options["disable_at_seq"] = self.disable_at
        if self.refused_sdo_index is not None:
            options["refuse_sdo_index"] = self.refused_sdo_index
        if self.delayed_tpdo is not None:
            options["delayed_tpdo"] = self.delayed_tpdo
        if self.error_frame_at is not None:
            options["error_frame_at"] = self.error_frame_at
        if scheme == "serial" and self.items & {"garbage", "bitflip", "truncate", "lag", "unplug"}:
            options.update(garbage_probability=self.garbage_probability, bitflip_probability=self.bitflip_probability,
                           truncate_probability=self.truncate_probability, reply_lag=self.reply_lag,
                           unplug_at_seq=self.unplug_at, seed=self.seed)
        return options


def _number(item: str, text: str, kind: type, low: float, high: float) -> Any:
    try:
        value = kind(text, 0) if kind is int else kind(text)
    except ValueError:
        raise ValueError(f"--sim-faults: {item!r}: {text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if not (low <= value <= high):
        raise ValueError(f"--sim-faults: {item!r}: expected {low:g} <= value <= {high:g}, got {text}")
    return value


def parse_fault_spec(spec: str, *, seed: int = 0) -> FaultPlan:
    """Parse ``--sim-faults SPEC`` (module docstring) into a :class:`FaultPlan`.

    >>> parse_fault_spec("drop=0.001,fault=0x2310@300").drive_fault
    (8976, 300)
    """
    fields: dict[str, Any] = {"seed": int(seed)}
    bursts: list[tuple[int, int]] = []
    stalls: list[tuple[int, float]] = []
    for item in (part.strip() for part in spec.split(",")):
        if not item:
            continue
        head, _, at = item.partition("@")
        name, _, value = head.partition("=")
        if name not in FAULT_ITEMS:
            valid = "; ".join(text for text, _ in FAULT_ITEMS.values())
            raise ValueError(f"--sim-faults: unknown fault {name!r} in {item!r}; valid items: {valid}")
        needs_value = name in ("drop", "burst", "fault", "delay", "sdo_abort", "garbage", "bitflip", "truncate", "lag",
                               "stall")
        needs_sample = name in ("burst", "fault", "heartbeat", "disable", "bus_error", "bus_off", "delay", "lag",
                                "unplug", "stall")
        if needs_value != bool(value) or needs_sample != bool(at):
            raise ValueError(f"--sim-faults: {item!r} is malformed; expected {FAULT_ITEMS[name][0]}")
        sample = _number(item, at, int, 0, 2**31) if at else None
        if name in ("drop", "garbage", "bitflip", "truncate"):
            fields[f"{name}_probability"] = _number(item, value, float, 0.0, 1.0)
        elif name == "burst":
            bursts.append((sample, _number(item, value, int, 1, 2**31)))
        elif name == "fault":
            fields["drive_fault"] = (_number(item, value, int, 0x1000, 0xFFFF), sample)
        elif name == "heartbeat":
            fields["heartbeat_loss_at"] = sample
        elif name == "disable":
            fields["disable_at"] = sample
        elif name in ("bus_error", "bus_off"):
            fields["error_frame_at"] = (CAN_ERR_BUSOFF if name == "bus_off" else CAN_ERR_PROT, sample)
        elif name == "delay":
            fields["delayed_tpdo"] = (_number(item, value, float, 0.0, 10_000.0) / 1000.0, sample)
        elif name == "lag":
            fields["reply_lag"] = (_number(item, value, float, 0.0, 10_000.0) / 1000.0, sample)
        elif name == "sdo_abort":
            fields["refused_sdo_index"] = _number(item, value, int, 0x1000, 0xFFFF)
        elif name == "stall":
            stalls.append((sample, _number(item, value, float, 0.0, 60_000.0) / 1000.0))
        else:
            fields["unplug_at"] = sample
    return dataclasses.replace(FaultPlan(**fields), bursts=tuple(bursts), host_stalls=tuple(sorted(stalls)))
