"""CiA 301 process data objects of the simulated CANopen nodes
(:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`): what a synchronous TPDO carries and latched, and
how an RPDO's data reach the object dictionary by its transmission type (0x1400 + n sub 2).

CiA 301, RPDO transmission types: 0..240 are synchronous: the device has one receive buffer per RPDO, a
frame received overwrites the one before, and the buffered data are applied at the next SYNC; 254 and 255
are event-driven: applied on arrival. 241..251 are reserved and 252/253 (RTR only) exist for TPDOs alone, so
a device refuses them for an RPDO. A frame shorter than its mapping is not processed.
"""

from __future__ import annotations

import collections

__all__ = [
    "LAST_SYNCHRONOUS_TRANSMISSION_TYPE", "RPDO_COMMUNICATION_INDICES", "RpdoReception", "RpdoValues", "Tpdo",
    "is_rpdo_transmission_type",
]

RPDO_COMMUNICATION_INDICES = range(0x1400, 0x1600)  # CiA 301: RPDO communication parameters
LAST_SYNCHRONOUS_TRANSMISSION_TYPE = 240  # CiA 301: types 0..240 act on SYNC
RPDO_EVENT_DRIVEN_TRANSMISSION_TYPES = (254, 255)  # CiA 301: manufacturer-specific / profile event-driven

RpdoValues = list[tuple[int, int, bytes]]  # (index, subindex, data) of each mapped object, in frame order


def is_rpdo_transmission_type(value: int) -> bool:
    """Whether ``value`` is a transmission type an RPDO can have (CiA 301: 0..240, 254, 255)."""
    return 0 <= value <= LAST_SYNCHRONOUS_TRANSMISSION_TYPE or value in RPDO_EVENT_DRIVEN_TRANSMISSION_TYPES


class Tpdo:
    """One synchronous TPDO of a node: what it carries, how often it goes, and what it latched."""

    __slots__ = ("cob_id", "entries", "every", "count", "history", "primed")

    def __init__(self, cob_id: int, entries: list[tuple[int, int, int]], every: int) -> None:
        self.cob_id = cob_id
        self.entries = entries  # (index, subindex, bytes)
        self.every = every  # transmission type n: after every n-th SYNC
        self.count = 0  # SYNCs since the node became OPERATIONAL
        self.history: collections.deque[bytes] = collections.deque()
        self.primed = False


class RpdoReception:
    """The receive side of a node's RPDOs: one receive buffer per synchronous RPDO (CiA 301)."""

    def __init__(self) -> None:
        self._latched: dict[int, RpdoValues] = {}  # communication parameter index -> the last frame's data

    def receive(self, pdo_map: object, transmission_type: int) -> RpdoValues | None:
        """A frame of the RPDO ``pdo_map`` (canopen's ``PdoMap``, holding the frame just received): the
        data to apply now (event-driven), or None (latched for the next SYNC, overwriting what an earlier
        frame left; or a frame shorter than the mapping, not processed)."""
        if len(pdo_map.data) * 8 < pdo_map.length:  # type: ignore[attr-defined]
            return None
        values = [(variable.index, variable.subindex, bytes(variable.get_data()))
                  for variable in pdo_map if variable.length]  # type: ignore[attr-defined]
        if transmission_type > LAST_SYNCHRONOUS_TRANSMISSION_TYPE:
            return values
        self._latched[pdo_map.com_record.od.index] = values  # type: ignore[attr-defined]
        return None

    def take_latched(self) -> list[RpdoValues]:
        """At a SYNC: what each synchronous RPDO received since the last SYNC (its last frame), once."""
        latched, self._latched = self._latched, {}
        return list(latched.values())

    def clear(self) -> None:
        """The node left OPERATIONAL: no PDO is processed, and nothing latched is applied later."""
        self._latched.clear()
