"""What a simulated device really did, sample by sample: the judge of a host's log (every logged command must
be the target the device applied at that sample), kept by every simulated device (:class:`AppliedTargets`, on
disk, so that a run of any length keeps flat memory) and written by one that runs in a process of its own
(:mod:`sim_backend.device_process`) as a JSON file with the targets in a binary file beside it."""

from __future__ import annotations

import array
import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["DEVICE_STALL_S", "REQUESTS_KEPT", "AppliedTargets", "DeviceRecord", "TickLateness"]

DEVICE_STALL_S = 0.01
"""A tick (or SYNC) this much after its instant is a stall of the device's own process (:class:`TickLateness`)."""

REQUESTS_KEPT = 1024
"""The requests a simulated device keeps for inspection (its ``requests``): the last this many, since a host may
poll the drive's status all through a run of hours."""

TARGET_DTYPE = np.dtype("=i4")
"""A target in drive counts as the device keeps it: INTEGER32 (CiA 402 0x607A; the serial and raw-CAN targets),
in this machine's byte order (the JSON record names it)."""


def _read_only(values: NDArray[Any]) -> NDArray[Any]:
    values.flags.writeable = False
    return values


def _mapped_targets(source: Any, count: int, dtype: np.dtype) -> NDArray[np.int32]:
    """The first ``count`` targets of ``source`` (a path or an open file) mapped read-only (no copy in memory);
    an empty array for none (a file cannot map zero bytes)."""
    if count == 0:
        return _read_only(np.empty(0, dtype))
    return np.memmap(source, dtype=dtype, mode="r", shape=(count,))


class AppliedTargets:
    """Sample k's applied target (drive counts), appended as the device applies it: up to :data:`BLOCK_SAMPLES`
    in memory, then written as a block to an unnamed temporary file (4 bytes a sample: 115 MB for 8 h at 1 kHz),
    which goes when it is closed or collected. :meth:`array` is what has been applied so far, mapped
    from the file; it stays readable after :meth:`close`."""

    BLOCK_SAMPLES = 4096

    def __init__(self) -> None:
        self._block = array.array("i")  # (C int: TARGET_DTYPE's four bytes on every platform CPython runs on)
        self._file: Any = None  # opened at the first block written
        self._written = 0
        self._closed: NDArray[np.int32] | None = None  # every target, once closed

    def append(self, counts: int) -> None:
        """Sample ``len(self)``'s target (an INTEGER32: OverflowError beyond it)."""
        if self._closed is not None:
            raise ValueError("applied targets: closed, no target can be added")
        self._block.append(counts)
        if len(self._block) >= self.BLOCK_SAMPLES:
            self._write_block()

    def __len__(self) -> int:
        return self._written + len(self._block)

    def array(self) -> NDArray[np.int32]:
        """Every target applied so far, read-only (later appends do not change it)."""
        if self._closed is not None:
            return self._closed
        self._write_block()
        return _mapped_targets(self._file, self._written, TARGET_DTYPE)

    def close(self) -> None:
        """No more targets; delete the file (idempotent). :meth:`array` and the arrays taken before stay
        readable (they map it)."""
        if self._closed is None:
            self._closed = self.array()
        if self._file is not None:
            self._file.close()

    def _write_block(self) -> None:
        if not self._block:
            return
        if self._file is None:
            self._file = tempfile.TemporaryFile(prefix="applied-targets-")
        data = self._block.tobytes()
        os.pwrite(self._file.fileno(), data, self._written * TARGET_DTYPE.itemsize)
        self._written += len(self._block)
        del self._block[:]


@dataclass(frozen=True, eq=False)
class DeviceRecord:
    """One run of a simulated device.

    Attributes
    ----------
    applied_targets
        Sample k (the k-th SYNC or tick from the first target on): the target in drive counts the device
        applied, its own or the one it held. Given as any sequence of integers; kept as a read-only int32
        array (mapped from a file, not copied into memory, where the device's :class:`AppliedTargets` or a
        written record's file holds it).
    controlwords
        Every controlword received, in order.
    held
        Samples the device held because their target had not come: ticks without their setpoint (serial, raw
        CAN) or SYNCs that found the interpolation buffer empty (CANopen; a CSP drive cannot tell).
    tick_delay_max_s
        The latest any tick (or SYNC the device process produced) ran after its instant on the device's clock:
        how much the device itself was starved. None where the device does not keep the clock.
    receive_drops
        Frames the device's receive queue dropped when full (udp_multicast), None where unknown.
    position_before_counts
        The target in force before sample 0 (the position the drive held since it was enabled), where the device
        counts its samples from its first target (a CANopen drive); None where sample 0 is the host's (a tick
        number on the wire: serial, raw CAN).
    stalls
        ``(sample, delay_s)`` for every stall of the device's clock: the first tick of each run of ticks more than
        :data:`DEVICE_STALL_S` after their instants (the device then catches up in a burst), and the largest delay
        of the run.
    """

    applied_targets: NDArray[np.int32]
    controlwords: tuple[int, ...]
    held: int
    tick_delay_max_s: float | None = None
    receive_drops: int | None = None
    stalls: tuple[tuple[int, float], ...] = ()
    position_before_counts: int | None = None

    KIND = "device_record"
    VERSION = 2
    """Version 2 keeps the applied targets in a binary file beside the JSON (``applied_targets``: its ``file``,
    ``count`` and ``dtype``); version 1 held them as a JSON list and is refused with a message that says so."""

    def __post_init__(self) -> None:
        targets = self.applied_targets
        if not (isinstance(targets, np.ndarray) and targets.dtype.kind == "i" and targets.dtype.itemsize == 4
                and not targets.flags.writeable):  # (a mapped file's, or a copy that no one else can change)
            targets = _read_only(np.array(targets, dtype=TARGET_DTYPE).reshape(-1))
        object.__setattr__(self, "applied_targets", targets)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DeviceRecord):
            return NotImplemented
        return all(np.array_equal(getattr(self, field.name), getattr(other, field.name)) if field.name ==
                   "applied_targets" else getattr(self, field.name) == getattr(other, field.name)
                   for field in fields(self))

    @staticmethod
    def targets_path(path: str | os.PathLike) -> Path:
        """Where :meth:`write` puts the applied targets of the record written at ``path``."""
        path = Path(path)
        return path.with_name(path.name + ".targets")

    def to_dict(self, targets_file: str) -> dict[str, Any]:
        """The JSON document; the applied targets are in ``targets_file`` (relative to the document's directory),
        written by the caller (:meth:`write` does both)."""
        return {"kind": self.KIND, "version": self.VERSION,
                "applied_targets": {"file": targets_file, "count": int(self.applied_targets.size),
                                    "dtype": self.applied_targets.dtype.str},
                "controlwords": list(self.controlwords), "held": self.held,
                "tick_delay_max_s": self.tick_delay_max_s, "receive_drops": self.receive_drops,
                "stalls": [list(stall) for stall in self.stalls], "position_before_counts": self.position_before_counts}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], directory: str | os.PathLike) -> DeviceRecord:
        """The record of :meth:`to_dict`'s document, its targets file in ``directory`` mapped, not read into memory.

        Raises
        ------
        ValueError
            Not a device record of this version, or a targets file missing or shorter than the document says.
        """
        if data.get("kind") == cls.KIND and data.get("version") == 1:
            raise ValueError(f"a {cls.KIND} version 1 (its targets inline, from an earlier sim_backend): this one reads "
                             f"version {cls.VERSION} only (targets in a file beside it); run the device again")
        if data.get("kind") != cls.KIND or data.get("version") != cls.VERSION:
            raise ValueError(f"not a {cls.KIND} version {cls.VERSION}: kind {data.get('kind')!r}, "
                             f"version {data.get('version')!r}")
        targets = data["applied_targets"]
        path, count, dtype = Path(directory) / targets["file"], int(targets["count"]), np.dtype(targets["dtype"])
        size = path.stat().st_size if path.exists() else None
        if size != count * dtype.itemsize:
            found = "is missing" if size is None else f"has {size} bytes"
            raise ValueError(f"{path}: the record's applied targets file {found}, expected {count} targets of "
                             f"{dtype.itemsize} bytes; write the record again (DeviceRecord.write)")
        return cls(_mapped_targets(path, count, dtype), tuple(int(v) for v in data["controlwords"]),
                   int(data["held"]), data.get("tick_delay_max_s"), data.get("receive_drops"),
                   tuple((int(sample), float(delay)) for sample, delay in data.get("stalls", ())),
                   data.get("position_before_counts"))

    def write(self, path: str | os.PathLike) -> None:
        """The record as JSON at ``path``, its applied targets in :meth:`targets_path` (``path`` + ``.targets``)."""
        targets = self.targets_path(path)
        self.applied_targets.tofile(targets)
        Path(path).write_text(json.dumps(self.to_dict(targets.name)))

    @classmethod
    def read(cls, path: str | os.PathLike) -> DeviceRecord:
        """The record :meth:`write` wrote at ``path`` (see :meth:`from_dict`)."""
        path = Path(path)
        return cls.from_dict(json.loads(path.read_text()), path.parent)

    def row_offset(self, logged_counts: Sequence[int]) -> int:
        """The offset o such that a host's log row k is the device's sample k + o (``logged_counts``: the row's
        commands in drive counts). 0 where sample 0 is the host's. A device that counts its samples from its first
        target (:attr:`position_before_counts`) did not count the SYNCs whose target came too late for the host's
        sample 0 (HELD rows at the start): row and sample are then aligned where the target first moves off that
        position, as the conformance peer's judge does; a log or record that never moves gives 0."""
        if self.position_before_counts is None:
            return 0
        start = self.position_before_counts
        row = np.flatnonzero(np.asarray(logged_counts, dtype=np.int64) != start)
        sample = np.flatnonzero(self.applied_targets != start)
        return 0 if row.size == 0 or sample.size == 0 else int(sample[0] - row[0])

    def wrong_rows(self, logged_counts: Sequence[int], usable: Sequence[bool]) -> int:
        """How many usable rows of a log (``logged_counts``: the commands in drive counts) name another target than
        the device applied at that row's sample (:meth:`row_offset`). A row before the device's first sample is
        right when it names the position the drive held (:attr:`position_before_counts`); a usable row beyond
        the record is wrong."""
        logged = np.asarray(logged_counts, dtype=np.int64)
        usable = np.asarray(usable, dtype=bool)
        rows = min(logged.size, usable.size)
        logged, usable = logged[:rows], usable[:rows]
        samples = np.arange(rows) + self.row_offset(logged)
        right = np.zeros(rows, dtype=bool)
        within = (samples >= 0) & (samples < self.applied_targets.size)
        right[within] = logged[within] == self.applied_targets[samples[within]]
        if self.position_before_counts is not None:
            right[samples < 0] = logged[samples < 0] == self.position_before_counts
        return int(np.count_nonzero(usable & ~right))


class TickLateness:
    """How late a device's clock ran its ticks: the latest (:attr:`delay_max_s`) and its stalls (see
    :attr:`DeviceRecord.stalls`)."""

    def __init__(self) -> None:
        self.delay_max_s = 0.0
        self.stalls: list[tuple[int, float]] = []
        self._stalled = False

    def observe(self, sample: int, delay_s: float) -> None:
        """The tick of ``sample`` ran ``delay_s`` after its instant."""
        self.delay_max_s = max(self.delay_max_s, delay_s)
        stalled = delay_s > DEVICE_STALL_S
        if stalled and not self._stalled:
            self.stalls.append((sample, delay_s))
        elif stalled:
            first, delay_max_s = self.stalls[-1]
            self.stalls[-1] = (first, max(delay_max_s, delay_s))
        self._stalled = stalled
