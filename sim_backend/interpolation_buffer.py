"""The interpolation data buffer of a CiA 402 drive in interpolated position mode (0x6060 = 7): a FIFO of
interpolation data records (0x60C1:1), configured through 0x60C4 (interpolation data configuration).

CiA 402 (IEC 61800-7-201), interpolated position mode:

* 0x60C4:1 maximum buffer size and 0x60C4:2 actual buffer size (1 to the maximum; writing it clears the
  buffer) bound the records the buffer holds;
* 0x60C4:3 buffer organisation: 0 = FIFO, the only organisation this buffer has;
* 0x60C4:4 buffer position: with a FIFO, where the next record goes, i.e. the records held now;
* 0x60C4:6 buffer clear: 0 clears the buffer and disables access to it, 1 enables access;
* each record applied to 0x60C1:1 (by SDO or RPDO) is appended while access is enabled, discarded while
  it is disabled, and discarded on a full buffer (an overflow);
* with ip mode active (controlword bit 4 in OPERATION ENABLED) each SYNC takes the oldest record.

The drive (:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`) owns the object dictionary and the state
machine; it passes the writes of 0x60C4 to :meth:`InterpolationBuffer.configure`, tells the buffer when ip
mode becomes active, and asks it what an empty buffer at a SYNC means
(:attr:`sim_backend.canopen_behaviour.DriveBehaviour.ip_underflow`).
"""

from __future__ import annotations

import collections
from fractions import Fraction

import canopen

from identify.validation import InvalidInputError

__all__ = ["DATA_RECORD_BYTES", "LEVELS_KEPT", "InterpolationBuffer", "ip_period_matches"]

DATA_RECORD_BYTES = 4  # 0x60C4:5: a record is one INTEGER32 position (0x60C1:1)
SDO_ABORT_VALUE_RANGE = 0x06090030  # CiA 301: value range of parameter exceeded
SDO_ABORT_VALUE_TOO_HIGH = 0x06090031  # CiA 301: value of parameter written too high
SDO_ABORT_VALUE_TOO_LOW = 0x06090032  # CiA 301: value of parameter written too low
LEVELS_KEPT = 4096
"""The buffer levels kept (:attr:`InterpolationBuffer.levels`): those of the last this many SYNCs, so that a run of
any length keeps flat memory."""


def ip_period_matches(value: int, index: int, cycle_period_us: int | None) -> bool:
    """Whether an interpolation time period 0x60C2 (CiA 402: sub 1 ``value``, sub 2 ``index``, the period
    being value * 10**index s) is set and, where the communication cycle period 0x1006 (CiA 301,
    microseconds; None or 0 where absent or not written) is set, equal to it (exactly)."""
    if value == 0:
        return False
    return not cycle_period_us or value * Fraction(10) ** index == Fraction(cycle_period_us, 1_000_000)


class InterpolationBuffer:
    """The FIFO of interpolation data records of CiA 402 0x60C1/0x60C4.

    Parameters
    ----------
    max_records
        0x60C4:1, maximum buffer size (records).
    size_records
        0x60C4:2, actual buffer size at power-on (1 to ``max_records``).
    """

    def __init__(self, max_records: int, size_records: int) -> None:
        if max_records < 1:
            raise InvalidInputError(f"0x60C4:1 (maximum buffer size): expected at least 1 record, got {max_records}")
        self.max_records = int(max_records)
        self.size_records = 0
        self.records: collections.deque[int] = collections.deque()
        self.access_enabled = False  # 0x60C4:6 = 1 enables, 0 clears and disables (CiA 402)
        self.overflows = 0  # records that found the buffer full (discarded)
        self.underflows = 0  # SYNCs with ip mode active that found the buffer empty
        # the records each of the last LEVELS_KEPT SYNCs with ip mode active found, before taking one
        self.levels: collections.deque[int] = collections.deque(maxlen=LEVELS_KEPT)
        self.taken_since_ip_mode_start = 0  # records taken since ip mode last became active
        self.resize(size_records)

    def __len__(self) -> int:
        return len(self.records)

    def resize(self, size_records: int) -> None:
        """0x60C4:2 (actual buffer size) written: the buffer is cleared (CiA 402); access stays as it was.

        Raises
        ------
        InvalidInputError
            ``size_records`` outside 1..0x60C4:1.
        """
        if not 1 <= size_records <= self.max_records:
            raise InvalidInputError(
                f"0x60C4:2 (actual buffer size): expected 1 to {self.max_records} records, got {size_records}")
        self.size_records = int(size_records)
        self.records.clear()

    def configure(self, subindex: int, value: int) -> None:
        """0x60C4 written (CiA 402): sub 2 actual buffer size (1 to sub 1; clears the buffer), sub 3 buffer
        organisation (0 = FIFO, the only one), sub 5 size of data record (4 bytes), sub 6 buffer clear (0
        clears and disables access, 1 enables it). Sub 1 and 4 are read-only (the EDS says so).

        Raises
        ------
        canopen.SdoAbortedError
            A value the buffer does not take: 0x06090031/0x06090032 (too high/low) for sub 2, 0x06090030
            (value range) for the others.
        """
        if subindex == 2:
            if value < 1:
                raise canopen.SdoAbortedError(SDO_ABORT_VALUE_TOO_LOW)
            if value > self.max_records:
                raise canopen.SdoAbortedError(SDO_ABORT_VALUE_TOO_HIGH)
            self.resize(value)
        elif ((subindex == 3 and value != 0) or (subindex == 5 and value != DATA_RECORD_BYTES)
              or (subindex == 6 and value not in (0, 1))):
            raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        elif subindex == 6:
            self.clear(enable_access=value == 1)

    def clear(self, enable_access: bool) -> None:
        """0x60C4:6 (buffer clear) written: 0 clears the buffer and disables access to it, 1 enables access
        (CiA 402; the records held stay)."""
        if not enable_access:
            self.records.clear()
        self.access_enabled = bool(enable_access)

    def append(self, record: int) -> bool:
        """An interpolation data record (0x60C1:1) applied: appended while access is enabled and the buffer
        has room; whether it was. A record into a full buffer is counted in :attr:`overflows`."""
        if not self.access_enabled:
            return False
        if len(self.records) >= self.size_records:
            self.overflows += 1
            return False
        self.records.append(record)
        return True

    def start_ip_mode(self) -> None:
        """Ip mode has become active (controlword bit 4 in OPERATION ENABLED): records taken count afresh."""
        self.taken_since_ip_mode_start = 0

    def take(self) -> int | None:
        """A SYNC with ip mode active: the oldest record, or None for an empty buffer (counted in
        :attr:`underflows`)."""
        self.levels.append(len(self.records))
        if not self.records:
            self.underflows += 1
            return None
        self.taken_since_ip_mode_start += 1
        return self.records.popleft()

    def underflow_faults(self, policy: str) -> bool:
        """Whether an empty buffer at a SYNC with ip mode active faults a drive with this ``ip_underflow``
        policy (:data:`sim_backend.canopen_behaviour.IP_UNDERFLOW`): "fault" always, "fault_after_first" once
        a record has been taken since ip mode became active, "hold" never."""
        return policy == "fault" or (policy == "fault_after_first" and self.taken_since_ip_mode_start > 0)
