"""The master's copy of a CiA 402 drive's interpolation buffer, and what goes into it.

In interpolated position mode (0x6060 = 7) the drive keeps a FIFO of interpolation data records (0x60C1:1,
its size in 0x60C4) and, while ip mode is active (controlword bit 4 "enable ip mode", statusword bit 12 "ip
mode active"), takes the oldest one at every SYNC. Records reach the FIFO through an *asynchronous* RPDO
(transmission type 254/255: applied on arrival, CiA 301 7.2.2.2); a synchronous RPDO keeps only the last
frame received before a SYNC and would drop every record but one.

:class:`InterpolationFeed` holds no bus and no lock; the CANopen transport calls it, under its lock, in bus
order: a record put on the bus (:meth:`sent`), its echo (:meth:`echoed`: it is in the drive's FIFO now), a
SYNC at which the drive took a record (:meth:`take`). Its copy of the FIFO therefore trails the drive's by at
most the records whose echo is due, which the margin below the capacity leaves room for.

Two rules make every legal drive accept the stream:

* **Fill first.** Ip mode is enabled only once the FIFO holds the lead (:meth:`ready_to_start`): a drive that
  faults on an empty buffer (maxon EPOS: EMCY on a queue underflow) never sees one at start.
* **Never run dry while streaming.** When the queue has nothing for the next SYNCs, the feed keeps
  :data:`IP_BUFFER_MARGIN_RECORDS` *hold records* (copies of the last record) in the FIFO (:meth:`to_send`;
  two, because a SYNC producer catching up after a stall may put two SYNCs on the bus before the master
  hears of the first): the drive holds as a drive with a
  "hold" underflow behaviour would, the sample is logged HELD, and a drive that faults on underflow does not
  fault at the end of a run or during a host stall. The records of later setpoints then reach the drive at
  later instants, each logged with its instant.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

__all__ = ["AUTO_IP_BUFFER_RECORDS", "IP_BUFFER_MARGIN_RECORDS", "MIN_IP_BUFFER_RECORDS", "InterpolationFeed",
           "Record"]

MIN_IP_BUFFER_RECORDS = 4
"""The smallest interpolation buffer (0x60C4) ``mode = "ip_buffer"`` streams into: below it, the margin
leaves no lead to speak of."""
AUTO_IP_BUFFER_RECORDS = 16
"""The smallest buffer ``mode = "auto"`` takes interpolated position for (CSP otherwise): a buffer holds the
drive through a pause of the whole host process only for its records less the margin (2 ms in 4 records at
1 kHz), and a drive that faults on an empty buffer would fault at the first longer one; a CSP drive holds."""
IP_BUFFER_MARGIN_RECORDS = 2
"""Records of the drive's buffer the lead leaves free: one RPDO on the bus whose echo the master has not
seen yet, and one record the drive may already have taken at a SYNC whose echo the master has not seen
yet."""


@dataclass(frozen=True)
class Record:
    """One interpolation data record: the setpoint ``sample`` it carries (None: a hold record, a copy of the
    record before it) and its value in drive counts."""

    sample: int | None
    counts: int


class InterpolationFeed:
    """The queue of setpoints, the records on the bus, and the master's copy of the drive's FIFO.

    Parameters
    ----------
    capacity
        Records the drive's FIFO holds (0x60C4, the smaller of sub 1 and sub 2).
    lead_records
        How many records the FIFO should hold before ip mode is enabled (capped at what it can hold).
    initial_counts
        The drive's target before the first record (its actual position): the value of a hold record put
        in before any setpoint.
    """

    def __init__(self, capacity: int, lead_records: int, initial_counts: int) -> None:
        self.capacity = int(capacity)
        self.room = self.capacity - IP_BUFFER_MARGIN_RECORDS
        self.lead_records = max(1, min(int(lead_records), self.room))
        self.queue: dict[int, int] = {}  # setpoint -> counts, queued by the runner, not yet on the bus
        self.next_sample = 0  # the setpoint that goes on the bus next
        self.in_flight: collections.deque[Record] = collections.deque()  # on the bus, echo not seen yet
        self.buffer: collections.deque[Record] = collections.deque()  # in the drive's FIFO, oldest first
        self.last_counts = int(initial_counts)
        self.streaming = False  # the drive takes records (ip mode active)
        self.finished = False  # the run's last setpoint is queued: hold records may fill the FIFO

    def queue_setpoint(self, sample: int, counts: int) -> None:
        self.queue[sample] = int(counts)

    def to_send(self) -> list[Record]:
        """The records to put on the bus now, in order: queued setpoints while the FIFO (the master's copy
        plus the records whose echo is due) has room below :data:`IP_BUFFER_MARGIN_RECORDS`; while
        streaming, hold records where the queue has nothing more and the FIFO would otherwise hold fewer than
        :data:`IP_BUFFER_MARGIN_RECORDS`, or, once the run's last setpoint is queued (``finished``), fewer than
        it holds (later setpoints would take their instants later; after the last there are none)."""
        records = []
        room = self.room - len(self.buffer) - len(self.in_flight)
        while room > 0 and self.next_sample in self.queue:
            records.append(Record(self.next_sample, self.queue.pop(self.next_sample)))
            self.next_sample += 1
            room -= 1
        held = len(self.buffer) + len(self.in_flight) + len(records)
        floor = self.room if self.finished else IP_BUFFER_MARGIN_RECORDS  # (after the run no row is shifted)
        while self.streaming and held < floor and self.next_sample not in self.queue:
            records.append(Record(None, records[-1].counts if records else self.last_counts))
            held += 1
        for record in records:
            self.in_flight.append(record)
            self.last_counts = record.counts
        return records

    def unsent(self, record: Record) -> None:
        """Putting ``record`` on the bus failed: it never reaches the drive."""
        self.in_flight.remove(record)

    def echoed(self) -> None:
        """The echo of the oldest record on the bus: it is in the drive's FIFO now."""
        if self.in_flight:
            self.buffer.append(self.in_flight.popleft())

    def ready_to_start(self) -> bool:
        """Ip mode may be enabled: every record sent is in the FIFO, and it holds the lead, or every setpoint
        queued (a run shorter than the lead; the caller asks once the runner has queued what it can before
        the drive's clock runs)."""
        if self.in_flight or not self.buffer:
            return False
        return len(self.buffer) >= self.lead_records or self.next_sample not in self.queue

    def take(self) -> Record | None:
        """A SYNC at which the drive, ip mode active, took the oldest record (None: its FIFO was empty, an
        underrun; the drive holds or faults as its underflow behaviour says)."""
        return self.buffer.popleft() if self.buffer else None

    @property
    def buffered(self) -> int:
        """Records in the drive's FIFO, as far as the echoes tell."""
        return len(self.buffer)
