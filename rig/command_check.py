"""The command as the runner sends it: a :class:`~rig.command_source.CommandSource` read chunk by chunk, each
chunk checked against the software limits before any of its samples can be read.

* The first chunk is checked before the drive is enabled, its first setpoint against the drive's actual
  position (:attr:`Transport.initial_position_rad <rig.transports.base.Transport.initial_position_rad>`);
  a refusal then leaves the drive as it was (:func:`check_command`'s message).
* Later chunks are checked while the run goes, ahead of the samples being sent: each sample read checks up
  to :data:`CHECKS_PER_READ` samples of the chunk ahead, so that a chunk is checked whole while the one
  before it is sent and the check costs microseconds a sample instead of milliseconds at the start of a
  chunk. A read that reaches a chunk not yet checked checks the whole chunk first.
* A sample beyond a limit raises :class:`~rig.transports.base.CommandRefused` naming the sample and the
  limit, before any sample of its chunk was sent; the runner then ends the run with its controlled stop.

:attr:`Transport.plan_step_rad <rig.transports.base.Transport.plan_step_rad>`, the largest step of the plan
(the way back to the plan after a stall moves at most a few of them a sample), is that of the samples
checked so far: it only grows as the run goes, and every sample sent has been checked, so it always covers
the steps of the samples sent and of those about to be.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from rig.command_source import CHUNK_SAMPLES, CommandSource
from rig.transports.base import CommandRefused

if TYPE_CHECKING:
    from rig.transports.base import Transport

__all__ = ["CHECKS_PER_READ", "LOOKAHEAD_SAMPLES", "CheckedCommand", "check_command"]

CHECKS_PER_READ = 2
"""Samples of the chunk ahead checked per sample read: twice as fast as the run sends, so the next chunk is
checked when half of the current one is sent."""
LOOKAHEAD_SAMPLES = 2 * CHUNK_SAMPLES
"""Samples checked ahead of the last one read, at most (more than one chunk: the next chunk is checked whole
before the run reaches it)."""


class CheckedCommand:
    """``source`` read in order (sample numbers from 0), each chunk checked against ``transport``'s limits and
    drive quantisation before any of its samples is returned; at most a few chunks are held at a time.

    Call :meth:`check_first` before enabling the drive; then :meth:`value` (and :meth:`contains`) read the
    command, :meth:`release_below` lets chunks go once no sample of theirs will be read again.
    """

    def __init__(self, transport: Transport, source: CommandSource) -> None:
        self._transport = transport
        self._source = source
        self._chunks: Iterator[np.ndarray] | None = None
        self.total: int | None = source.num_samples
        """The command's samples; None until an open-ended source has ended."""
        self._ready: collections.deque[tuple[int, list[float]]] = collections.deque()  # checked: (start, values)
        self._ready_end = 0  # samples below this are checked
        self._pending: list[float] | None = None  # the chunk being checked (it starts at _ready_end)
        self._pending_done = 0  # its samples checked so far
        self._exhausted = False
        self._previous = 0.0
        self._plan_step = 0.0
        self._read_to = 0  # one past the highest sample read
        self._current: tuple[int, int, list[float]] = (0, 0, [])  # the chunk of the last read: start, end, values

    # -- checking ---------------------------------------------------------------------------------------------

    def check_first(self) -> None:
        """Check the first chunk from the drive's actual position (before enabling); an empty command is a
        ValueError."""
        self._chunks = iter(self._source.chunks())
        self._previous = self._transport.initial_position_rad
        if not self._fetch():
            raise ValueError("command_rad: the command has no sample")
        self._check_pending(len(self._pending or ()))

    def recheck_first(self) -> None:
        """Check the first chunk again from the drive's actual position, which homing moved after enabling;
        nothing has been read yet. The chunks after it do not depend on where the drive started."""
        if self._read_to or not self._ready:
            raise RuntimeError("recheck_first: only between check_first and the first read")
        start, values = self._ready[0]
        if len(self._ready) != 1 or self._pending is not None or start != 0:
            raise RuntimeError("recheck_first: only the first chunk may be checked")
        self._ready.clear()
        self._ready_end = 0
        self._previous = self._transport.initial_position_rad
        self._plan_step = 0.0
        self._pending, self._pending_done = values, 0
        self._check_pending(len(values))

    def _fetch(self) -> bool:
        """Take the next chunk from the source to check; False when the source has ended."""
        if self._exhausted or self._chunks is None:
            return False
        chunk = next(self._chunks, None)
        if chunk is None or chunk.size == 0:
            self._exhausted = True
            self.total = self._ready_end
            return False
        if self.total is not None and self._ready_end + chunk.size > self.total:
            raise ValueError(f"command_rad: the source yielded more than its {self.total} samples")
        self._pending, self._pending_done = np.asarray(chunk, dtype=float).tolist(), 0
        return True

    def _check_pending(self, count: int) -> None:
        """Check up to ``count`` more samples of the pending chunk; a chunk checked whole becomes readable."""
        values = self._pending
        assert values is not None
        transport = self._transport
        drive, limits, period = transport.drive, transport.limits, transport.sample_period_s
        previous, plan_step = self._previous, self._plan_step
        start = self._ready_end
        stop = min(len(values), self._pending_done + count)
        try:
            for index in range(self._pending_done, stop):
                k, value = start + index, values[index]
                if not math.isfinite(value):
                    limits.check(value, previous, period, k)  # refused: not finite
                quantized = drive.quantize_rad(value)
                if k == 0:
                    _check_first_setpoint(transport, quantized, previous)
                limits.check(quantized, previous, period, k)
                if k:  # the plan's own steps (not the first, from wherever the drive stands)
                    plan_step = max(plan_step, abs(quantized - previous))
                    transport.plan_step_rad = plan_step
                previous = quantized
        except CommandRefused as err:
            if self._read_to:  # the run has started: say how far it got
                raise CommandRefused(f"{err}; the command is checked ahead of the run, which had reached sample "
                                     f"{self._read_to - 1}: it stopped before sending any sample of this chunk")
            raise
        self._previous, self._plan_step, self._pending_done = previous, plan_step, stop
        if stop == len(values):
            self._ready.append((start, values))
            self._ready_end = start + len(values)
            self._pending = None

    def _check_ahead(self, count: int) -> None:
        """Check up to ``count`` samples past the readable ones (fetching the next chunk when needed)."""
        if self._pending is None and not self._fetch():
            return
        self._check_pending(count)

    def _check_through(self, k: int) -> bool:
        """Make sample ``k`` readable (checking whole chunks up to its own); False if the command ends before."""
        while k >= self._ready_end:
            if self._pending is None and not self._fetch():
                return False
            assert self._pending is not None
            self._check_pending(len(self._pending))
        return True

    # -- reading ----------------------------------------------------------------------------------------------

    def contains(self, k: int) -> bool:
        """Whether the command has a sample ``k`` (checking the chunks up to it if it is not checked yet)."""
        if self.total is not None:
            return k < self.total
        return k < self._ready_end or self._check_through(k)

    def value(self, k: int) -> float:
        """Sample ``k`` (rad, as planned: the drive receives it quantised), checked; reading a new sample checks
        :data:`CHECKS_PER_READ` samples ahead. IndexError for a sample beyond the command or one released."""
        start, end, values = self._current
        if not start <= k < end:
            if k >= self._ready_end and not self._check_through(k):
                raise IndexError(f"command_rad: no sample {k} (the command has {self.total})")
            for start, values in self._ready:
                end = start + len(values)
                if start <= k < end:
                    break
            else:
                raise IndexError(f"command_rad: sample {k} was released")
            self._current = (start, end, values)
        if k >= self._read_to:
            self._read_to = k + 1
            if self._ready_end - k < LOOKAHEAD_SAMPLES and not self._exhausted:
                self._check_ahead(CHECKS_PER_READ)
        return values[k - start]

    def release_below(self, k: int) -> None:
        """No sample below ``k`` will be read again: let the chunks that end there go."""
        while len(self._ready) > 1 and self._ready[0][0] + len(self._ready[0][1]) <= k:
            self._ready.popleft()

    @property
    def held_samples(self) -> int:
        """Samples held in memory (readable and being checked): a few chunks, whatever the command's length."""
        return sum(len(values) for _, values in self._ready) + len(self._pending or ())


def _check_first_setpoint(transport: Transport, quantized: float, actual: float) -> None:
    """Refuse a first command the rate limit does not allow from the drive's actual position."""
    if math.isclose(quantized, actual, abs_tol=1e-12):
        return
    step_s = transport.sample_period_s
    rate = abs(quantized - actual) / step_s
    if rate > transport.limits.rate_max_rad_per_s * (1 + 1e-12):
        raise CommandRefused(
            f"setpoint 0: the first command {quantized:.6g} rad is {abs(quantized - actual):.6g} rad from the "
            f"drive's actual position {actual:.6g} rad: reaching it in one sample needs {rate:.6g} rad/s, "
            f"above the rate limit {transport.limits.rate_max_rad_per_s:.6g} rad/s; start the experiment at "
            "the actual position (or move the drive there first)")


def check_command(transport: Transport, command_rad: np.ndarray) -> None:
    """Refuse the whole command (an array) if any sample breaks the software limits; the first setpoint is
    checked against the drive's actual position (:attr:`Transport.initial_position_rad`, read by
    :meth:`Transport.prepare`), so a first command the rate limit does not allow from there is refused with the
    distance, instead of making the drive jump. Sets :attr:`Transport.plan_step_rad` to the command's largest
    step."""
    from rig.command_source import ArrayCommand

    checked = CheckedCommand(transport, ArrayCommand(command_rad))
    checked.check_first()
    checked._check_through(checked.total - 1)  # (a finite array: every chunk)
