"""The experiment record: one data type for what the rig captured and what identification reads.

A record holds, per sample, the time, the commanded input u_t, the measured load angle y_t, the raw encoder
position value (None for data from other tools) and status flags, plus metadata that say where the data
came from (plant or rig, transport, sample period, encoder bits, noise and its bound, excitation and its
seed, config, software version). It checks itself on construction, so every consumer can rely on equal
lengths, finite times that increase, and finite values wherever a sample is not marked lost.

File I/O lives in :mod:`rig.log_file`; this module is pure data.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from datetime import datetime, timezone
from enum import IntFlag
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError

__all__ = ["NOMINAL_TIME_TOLERANCE_S", "OFFLINE_TRANSPORT", "ExperimentMetadata", "ExperimentRecord", "SampleFlag",
           "now_utc", "utc_timestamp"]

OFFLINE_TRANSPORT = "offline"
"""``transport`` of a record simulated offline (``rig simulate``): no wire, no clock; every sample at its instant."""

NOMINAL_TIME_TOLERANCE_S = 1e-9
"""A time column within this of t_0 + k·T at every sample is the nominal grid (float64 rounding of k·T at
an hour of 1 kHz samples is below 1e-12 s): its spacing carries no measured jitter."""


class SampleFlag(IntFlag):
    """Per-sample status bits (several may be set at once)."""

    OK = 0
    LOST = 1  #: no reading arrived for this sample; the angle is NaN
    LATE = 2  #: the reading arrived after the sample's deadline (the value is real but its time is not exact)
    DUPLICATE = 4  #: the device repeated its previous reading (no fresh measurement)
    LIMITED = 8  #: the command was clipped by a configured limit before it was sent
    FAULT = 16  #: the device reported a fault during this sample
    NOT_FOLLOWED = 32  #: the drive said it ignored the target in this sample (CiA 402 CSP statusword bit 12 clear)
    HELD = 64  #: the setpoint missed its sample instant; the device held the previous one (the logged command)
    AMBIGUOUS = 128  #: which sample instant the reading answers, or (HELD) which command was in force, is not certain

    @classmethod
    def unusable(cls) -> SampleFlag:
        """Flags that make a sample unusable for identification."""
        return cls.LOST | cls.DUPLICATE | cls.FAULT | cls.NOT_FOLLOWED | cls.AMBIGUOUS


_ALL_FLAGS = int(SampleFlag.LOST | SampleFlag.LATE | SampleFlag.DUPLICATE | SampleFlag.LIMITED | SampleFlag.FAULT
                 | SampleFlag.NOT_FOLLOWED | SampleFlag.HELD | SampleFlag.AMBIGUOUS)


@dataclass(frozen=True)
class ExperimentMetadata:
    """Where a record came from.

    Attributes
    ----------
    sample_period_s
        The nominal sample period T.
    source
        The plant config name (simulation) or the rig name (hardware), or the file a foreign CSV came from.
    transport
        ``"offline"`` for ``rig simulate``, the transport name on a rig, ``"csv"`` for foreign data.
    encoder_bits
        Single-turn resolution of the load encoder, if known.
    noise_kind, noise_bound_rad
        The noise model, and the bound on the whole measurement error |y_t - w_t| (additive noise plus
        the encoder's rounding; ``inf`` for Gaussian noise): the Delta eta of eq. (5) of Cerone et al.
        (2009) that bounded-error identification may use.
    excitation, excitation_seed
        The excitation's name (or config file) and the seed it was generated with.
    seed
        Seed of the simulated noise, if any.
    config
        Free-form description of the configs used (e.g. file names or their parsed contents).
    software_version
        Version of this package that wrote the record.
    acquisition_start_utc
        When sample 0 was taken, in UTC, as ISO 8601 text (``2025-03-04T09:15:02.123456Z``); None when unknown
        (logs written before it was recorded, data of other tools). :attr:`acquisition_start` is the datetime.
    extra
        Anything else (kept on reading a newer log).
    """

    sample_period_s: float
    source: str = ""
    transport: str = ""
    encoder_bits: int | None = None
    noise_kind: str | None = None
    noise_bound_rad: float | None = None
    excitation: str | None = None
    excitation_seed: int | None = None
    seed: int | None = None
    config: Mapping[str, Any] = field(default_factory=dict)
    software_version: str = ""
    acquisition_start_utc: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.acquisition_start_utc is not None:
            object.__setattr__(self, "acquisition_start_utc", utc_timestamp(self.acquisition_start_utc))
        period = self.sample_period_s
        if isinstance(period, bool) or not isinstance(period, numbers.Real) or not (
                math.isfinite(period) and period > 0):
            raise InvalidInputError(f"sample_period_s: expected a finite number > 0, got {period!r}")
        object.__setattr__(self, "sample_period_s", float(period))
        for name in ("source", "transport", "software_version"):
            if not isinstance(getattr(self, name), str):
                raise InvalidInputError(f"{name}: expected a string, got {getattr(self, name)!r}")
        for name in ("noise_kind", "excitation"):
            if getattr(self, name) is not None and not isinstance(getattr(self, name), str):
                raise InvalidInputError(f"{name}: expected a string or None, got {getattr(self, name)!r}")
        if self.encoder_bits is not None:
            if isinstance(self.encoder_bits, bool) or not isinstance(self.encoder_bits, numbers.Integral) \
                    or not 1 <= self.encoder_bits <= 32:
                raise InvalidInputError(f"encoder_bits: expected an integer from 1 to 32, got {self.encoder_bits!r}")
            object.__setattr__(self, "encoder_bits", int(self.encoder_bits))
        for name in ("excitation_seed", "seed"):
            value = getattr(self, name)
            if value is not None:
                if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
                    raise InvalidInputError(f"{name}: expected an integer >= 0 (a random generator's seed) or None, "
                                            f"got {value!r}")
                object.__setattr__(self, name, int(value))
        if self.noise_bound_rad is not None:
            bound = self.noise_bound_rad
            if isinstance(bound, bool) or not isinstance(bound, numbers.Real) or math.isnan(bound) or bound < 0:
                raise InvalidInputError(f"noise_bound_rad: expected a number >= 0 (inf allowed: no bound known), "
                                        f"got {bound!r}")
            object.__setattr__(self, "noise_bound_rad", float(bound))
        for name in ("config", "extra"):
            if not isinstance(getattr(self, name), Mapping):
                raise InvalidInputError(f"{name}: expected a mapping (a JSON object), got {getattr(self, name)!r}")
        object.__setattr__(self, "config", MappingProxyType(dict(self.config)))
        object.__setattr__(self, "extra", MappingProxyType(dict(self.extra)))

    @property
    def acquisition_start(self) -> datetime | None:
        """:attr:`acquisition_start_utc` as a timezone-aware datetime (UTC), or None when unknown."""
        if self.acquisition_start_utc is None:
            return None
        return datetime.fromisoformat(self.acquisition_start_utc.replace("Z", "+00:00"))

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (``inf`` bound written as the string ``"inf"``)."""
        out: dict[str, Any] = {}
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, Mapping):
                value = dict(value)
            if item.name == "noise_bound_rad" and value is not None and math.isinf(value):
                value = "inf"
            out[item.name] = value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ExperimentMetadata:
        """Inverse of :meth:`to_dict`; unknown keys go to :attr:`extra`."""
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"metadata: expected a mapping, got {type(data).__name__}")
        known = {item.name for item in fields(cls)}
        if "sample_period_s" not in data:
            raise InvalidInputError("metadata: sample_period_s is missing")
        values = {key: value for key, value in data.items() if key in known}
        extra = values.pop("extra", None) or {}
        if not isinstance(extra, Mapping):
            raise InvalidInputError(f"extra: expected a mapping (a JSON object), got {extra!r}")
        extra = dict(extra)
        extra.update({key: value for key, value in data.items() if key not in known})
        if values.get("noise_bound_rad") == "inf":
            values["noise_bound_rad"] = math.inf
        return cls(**values, extra=extra)


def utc_timestamp(value: str | datetime) -> str:
    """An instant as ISO 8601 text in UTC with a ``Z`` (``2025-03-04T09:15:02.123456Z``), from a timezone-aware
    datetime or ISO 8601 text with an offset; a time without an offset is refused (it could be any zone)."""
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        except ValueError:
            raise InvalidInputError(f"acquisition_start_utc: expected an ISO 8601 time such as "
                                    f"2025-03-04T09:15:02.123Z, got {value!r}") from None
    if not isinstance(value, datetime):
        raise InvalidInputError(f"acquisition_start_utc: expected ISO 8601 text or a datetime, got {value!r}")
    if value.utcoffset() is None:
        raise InvalidInputError(f"acquisition_start_utc: {value.isoformat()} has no time zone; give it in UTC "
                                "(ending in Z or +00:00)")
    utc = value.astimezone(timezone.utc)
    return utc.replace(tzinfo=None).isoformat(timespec="microseconds") + "Z"


def now_utc() -> str:
    """The host's clock now, as :func:`utc_timestamp` writes it."""
    return utc_timestamp(datetime.now(timezone.utc))


def _array(name: str, values: ArrayLike, dtype: Any) -> NDArray[Any]:
    try:
        array = np.array(values, dtype=dtype, copy=True)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name}: expected a 1-D array of numbers, got {type(values).__name__}") from err
    if array.ndim != 1:
        raise InvalidInputError(f"{name}: expected a 1-D array, got shape {array.shape}")
    array.setflags(write=False)
    return array


def _first_bad(name: str, mask: NDArray[np.bool_], values: NDArray[Any], problem: str) -> None:
    bad = np.flatnonzero(mask)
    if bad.size:
        value = values[bad[0]]
        shown = value.item() if isinstance(value, np.generic) else value  # 0.1, not np.float64(0.1)
        raise InvalidInputError(f"{name}: sample {bad[0]} is {shown!r}: {problem} ({bad.size} such samples)")


@dataclass(frozen=True)
class ExperimentRecord:
    """Time, command, measured angle, encoder counts and flags of one experiment, with its metadata.

    Attributes
    ----------
    time_s
        Sample times, finite and strictly increasing.
    command_rad
        The commanded input u_t, finite.
    angle_rad
        The measured load angle y_t; NaN exactly where the sample is flagged LOST, finite elsewhere.
    encoder_counts
        Raw position values as the device reported them (int64; 0 where LOST), or None for data that came
        without them.
    flags
        :class:`SampleFlag` bits per sample (uint8); all zero by default.
    metadata
        :class:`ExperimentMetadata`.
    drive_torque
        The torque the drive reported at each sample (the CiA 402 torque actual value, a motor current; in the
        unit it came in, NaN where not measured), or None for data without it.
    """

    time_s: NDArray[np.float64]
    command_rad: NDArray[np.float64]
    angle_rad: NDArray[np.float64]
    encoder_counts: NDArray[np.int64] | None
    flags: NDArray[np.uint8] | None
    metadata: ExperimentMetadata
    drive_torque: NDArray[np.float64] | None = None

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    def __post_init__(self) -> None:
        time = _array("time_s", self.time_s, float)
        command = _array("command_rad", self.command_rad, float)
        angle = _array("angle_rad", self.angle_rad, float)
        if time.size == 0:
            raise InvalidInputError("time_s: expected at least one sample, got none")
        lengths = {"time_s": time.size, "command_rad": command.size, "angle_rad": angle.size}
        counts = None
        if self.encoder_counts is not None:
            raw = np.asarray(self.encoder_counts)
            if raw.dtype.kind == "f":
                if np.any(raw[np.isfinite(raw)] != np.round(raw[np.isfinite(raw)])):
                    raise InvalidInputError("encoder_counts: expected integer position values")
                raw = np.where(np.isfinite(raw), raw, 0)
            counts = _array("encoder_counts", raw, np.int64)
            lengths["encoder_counts"] = counts.size
        if self.flags is None:
            flags = _array("flags", np.zeros(time.size, dtype=np.uint8), np.uint8)
        else:
            raw_flags = np.asarray(self.flags)
            if raw_flags.dtype.kind not in "iub":
                raise InvalidInputError(f"flags: expected SampleFlag bits (integers), got {raw_flags.dtype} values")
            bad = np.flatnonzero((raw_flags < 0) | (raw_flags > _ALL_FLAGS)
                                 | (np.asarray(raw_flags, dtype=np.int64) & ~_ALL_FLAGS))
            if bad.size:  # one sample named, never the whole array
                known = ", ".join(f"{int(flag)} {flag.name}" for flag in SampleFlag if flag.value)
                raise InvalidInputError(f"flags: sample {int(bad[0])} is {int(raw_flags.flat[bad[0]])}; expected "
                                        f"SampleFlag bits ({known}) or their sums ({bad.size} such samples)")
            flags = _array("flags", raw_flags, np.uint8)
            lengths["flags"] = flags.size
        torque = None
        if self.drive_torque is not None:
            torque = _array("drive_torque", self.drive_torque, float)
            lengths["drive_torque"] = torque.size
            _first_bad("drive_torque", np.isinf(torque), torque, "expected a finite torque (or NaN: not measured)")
        if len(set(lengths.values())) > 1:
            described = ", ".join(f"{name} has {n}" for name, n in lengths.items())
            raise InvalidInputError(f"signals must have the same number of samples: {described}")
        if not isinstance(self.metadata, ExperimentMetadata):
            raise InvalidInputError(f"metadata: expected ExperimentMetadata, got {type(self.metadata).__name__}")
        _first_bad("time_s", ~np.isfinite(time), time, "expected a finite time")
        steps = np.diff(time)
        _first_bad("time_s", np.concatenate(([False], steps <= 0)), time, "times must increase strictly")
        _first_bad("command_rad", ~np.isfinite(command), command, "expected a finite command")
        lost = (flags & SampleFlag.LOST) != 0
        _first_bad("angle_rad", ~lost & ~np.isfinite(angle), angle, "expected a finite angle (or the LOST flag)")
        _first_bad("angle_rad", lost & ~np.isnan(angle), angle, "a LOST sample must have angle NaN")
        if counts is not None and np.any(counts[lost] != 0):
            counts = np.where(lost, 0, counts)  # a LOST sample has no reading: its counts are 0 by convention
            counts.setflags(write=False)
        for name, value in (("time_s", time), ("command_rad", command), ("angle_rad", angle),
                            ("encoder_counts", counts), ("flags", flags), ("drive_torque", torque)):
            object.__setattr__(self, name, value)

    def to_pandas(self) -> Any:
        """The record as a ``pandas.DataFrame``: columns ``time_s``, ``command_rad``, ``angle_rad`` (NaN where
        LOST), ``encoder_counts`` (nullable integers, absent for data without them), ``flags`` and, when there,
        ``drive_torque``; the metadata
        as ``attrs["metadata"]`` (:meth:`ExperimentMetadata.to_dict`). Needs pandas (not a dependency)."""
        from identify.result_format import require_pandas

        pandas = require_pandas("ExperimentRecord.to_pandas()")
        columns: dict[str, Any] = {"time_s": self.time_s, "command_rad": self.command_rad, "angle_rad": self.angle_rad}
        if self.encoder_counts is not None:
            lost = (self.flags & int(SampleFlag.LOST)) != 0
            columns["encoder_counts"] = pandas.array(np.where(lost, 0, self.encoder_counts), dtype="Int64")
            columns["encoder_counts"][lost] = pandas.NA
        columns["flags"] = self.flags
        if self.drive_torque is not None:
            columns["drive_torque"] = self.drive_torque
        frame = pandas.DataFrame(columns)
        frame.attrs["metadata"] = self.metadata.to_dict()
        return frame

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def num_samples(self) -> int:
        return len(self)

    @property
    def sample_period_s(self) -> float:
        return self.metadata.sample_period_s

    @property
    def valid_mask(self) -> NDArray[np.bool_]:
        """True where the sample can be used: not LOST, DUPLICATE or FAULT."""
        return (self.flags & int(SampleFlag.unusable())) == 0

    @property
    def lost_count(self) -> int:
        """Number of samples flagged LOST."""
        return int(np.count_nonzero(self.flags & SampleFlag.LOST))

    def count_flag(self, flag: SampleFlag) -> int:
        """Number of samples with ``flag`` set."""
        return int(np.count_nonzero(self.flags & int(flag)))

    @property
    def period_deviation_s(self) -> NDArray[np.float64]:
        """t_k - t_(k-1) - T for k = 1..N-1: how far each measured sample period is from the nominal one."""
        return np.diff(self.time_s) - self.sample_period_s

    def time_column_is_nominal(self) -> bool:
        """Whether ``time_s`` is t_0 + k·T to within :data:`NOMINAL_TIME_TOLERANCE_S` at every sample (a
        device-clocked log: its spacing carries no jitter to measure)."""
        grid = self.time_s[0] + np.arange(len(self)) * self.sample_period_s if len(self) else self.time_s
        return bool(np.all(np.abs(self.time_s - grid) <= NOMINAL_TIME_TOLERANCE_S))
