"""Legal behaviours of real CANopen devices, switchable in the simulated drive and encoder
(:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`).

Every field defaults to what the simulated devices did before these behaviours existed, so a rig built
without arguments behaves as it always did. Each field names the object of CiA 301 (communication), CiA 402
(drive) or CiA 406 (encoder) it concerns; ``docs/rig_driver.md`` ("Simulated devices") has the table of what
a master must do about each.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from identify.validation import InvalidInputError

__all__ = [
    "DriveBehaviour", "EMCY_ERROR_RESET", "EMCY_FOLLOWING_ERROR", "EMCY_PARAMETER_ERROR", "EMCY_POSITIONING_CONTROLLER",
    "EMCY_SYNC_LOSS", "EMCY_TEMPERATURE_WARNING", "EncoderBehaviour", "IP_UNDERFLOW", "NodeBehaviour",
    "OPTIONAL_OBJECTS_MISSING", "error_register_for", "real_variety",
]

EMCY_ERROR_RESET = 0x0000  # CiA 301: "error reset or no error"
EMCY_FOLLOWING_ERROR = 0x8611  # CiA 402: following error
EMCY_SYNC_LOSS = 0x8700  # CiA 301/402: sync controller (SYNC lost)
EMCY_TEMPERATURE_WARNING = 0x4210  # CiA 301: temperature device (excess temperature, here a warning)
EMCY_POSITIONING_CONTROLLER = 0x8600  # CiA 402: positioning controller (here an empty interpolation buffer)
EMCY_PARAMETER_ERROR = 0x6320  # CiA 301: parameter error (here 0x60C2 unset or not the SYNC period)

IP_UNDERFLOW = ("hold", "fault", "fault_after_first")
"""What a drive does at a SYNC with ip mode active and an empty interpolation buffer (see
:attr:`DriveBehaviour.ip_underflow`)."""

NMT_ON_FAULT = (None, "pre-operational", "stopped")


def error_register_for(code: int) -> int:
    """The error register (0x1001, CiA 301) that goes with an EMCY error code: bit 0 (generic) for
    every error, plus bit 1 current (0x2xxx), bit 2 voltage (0x3xxx), bit 3 temperature (0x4xxx), bit 4
    communication (0x81xx, 0x82xx and 0x87xx, SYNC loss), bit 5 device profile specific (0x86xx, e.g. the
    CiA 402 following error 0x8611), bit 7 manufacturer specific (0xFFxx). 0 for 0x0000 (no error)."""
    if code == EMCY_ERROR_RESET:
        return 0
    register = 0x01
    group = code >> 12
    if group in (0x2, 0x3, 0x4):
        register |= 1 << (group - 1)
    elif code >> 8 in (0x81, 0x82, 0x87):
        register |= 0x10
    elif code >> 8 == 0x86:
        register |= 0x20
    elif code >> 8 == 0xFF:
        register |= 0x80
    return register


def _check(name: str, ok: bool, expected: str, value: object) -> None:
    if not ok:
        raise InvalidInputError(f"{name}: expected {expected}, got {value!r}")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class NodeBehaviour:
    """CiA 301 behaviours shared by the drive and the encoder."""

    tpdo_latency_cycles: int = 0
    """TPDOs sent after SYNC k carry the values latched at SYNC k - L (CiA 301 synchronous TPDOs,
    0x1800 sub 2 = 1..240): a device whose answer comes one SYNC late, or that sends at each SYNC what it
    latched at the previous one; both are legal and look the same on the wire. Before L SYNCs have passed
    the TPDO carries the values the device held when it became OPERATIONAL."""

    static_pdos: bool = False
    """PDO communication and mapping parameters (0x1400-0x15FF, 0x1600-0x17FF, 0x1800-0x19FF,
    0x1A00-0x1BFF, CiA 301) are read-only: every SDO write to them aborts with 0x06010002
    (attempt to write a read only object) and the EDS default layout stays.
    ``SimulatedCanOpenRig.write_eds`` writes the matching vendor EDS (those entries ``AccessType=ro``).
    Note that canopen's ``PdoMap.save()`` silently skips entries its EDS marks read-only: a master must
    read the layout back."""

    static_tpdo_transmission_type: int | None = None
    """With ``static_pdos``: TPDO1's transmission type (0x1800 sub 2), e.g. 2 = sent after every 2nd SYNC
    (CiA 301: type n in 1..240 is sent after every n-th SYNC). None keeps the EDS's (1)."""

    static_tpdo_mapping: tuple[int, ...] | None = None
    """With ``static_pdos``: TPDO1's mapping entries (0x1A00 sub 1..n, each index << 16 | subindex << 8 |
    bits), e.g. ``(0x60040010,)`` for an encoder whose TPDO carries only the low 16 bits of 0x6004."""

    emcy_warning_at_seq: int | None = None
    """At this sample (SYNCs counted from 0 in OPERATION ENABLED) the node sends an EMCY warning
    (``emcy_warning_code``; error register 0x1001 with bit 0 and its class bit, e.g. bit 3 temperature) and
    goes on working: a warning, not a fault (CiA 301). A drive also sets statusword bit 7 (warning)."""

    emcy_warning_code: int = EMCY_TEMPERATURE_WARNING
    """The EMCY error code of the injected warning (default 0x4210, temperature)."""

    emcy_warning_cleared_at_seq: int | None = None
    """At this sample the warning clears: EMCY 0x0000 (error reset) and 0x1001 back to 0."""

    def __post_init__(self) -> None:
        name = type(self).__name__
        _check(f"{name}.tpdo_latency_cycles", _is_int(self.tpdo_latency_cycles) and 0 <= self.tpdo_latency_cycles <= 16,
               "an integer from 0 to 16", self.tpdo_latency_cycles)
        _check(f"{name}.static_pdos", isinstance(self.static_pdos, bool), "true or false", self.static_pdos)
        if self.static_tpdo_transmission_type is not None:
            _check(f"{name}.static_tpdo_transmission_type",
                   _is_int(self.static_tpdo_transmission_type) and 1 <= self.static_tpdo_transmission_type <= 240,
                   "a synchronous transmission type from 1 to 240", self.static_tpdo_transmission_type)
        if self.static_tpdo_mapping is not None:
            mapping = tuple(self.static_tpdo_mapping)
            _check(f"{name}.static_tpdo_mapping",
                   0 < len(mapping) <= 8 and all(_is_int(entry) and 0 <= entry < 1 << 32 and entry & 0xFF
                                                 for entry in mapping)
                   and sum(entry & 0xFF for entry in mapping) <= 64,
                   "1 to 8 mapping entries (index << 16 | subindex << 8 | bits) of 64 bits in all", mapping)
            object.__setattr__(self, "static_tpdo_mapping", mapping)
        if not self.static_pdos:
            for field in ("static_tpdo_transmission_type", "static_tpdo_mapping"):
                _check(f"{name}.{field}", getattr(self, field) is None, "None unless static_pdos is true",
                       getattr(self, field))
        for field in ("emcy_warning_at_seq", "emcy_warning_cleared_at_seq"):
            value = getattr(self, field)
            _check(f"{name}.{field}", value is None or (_is_int(value) and value >= 0),
                   "None or a sample number >= 0", value)
        _check(f"{name}.emcy_warning_code", _is_int(self.emcy_warning_code) and 0 < self.emcy_warning_code <= 0xFFFF,
               "an EMCY error code from 0x0001 to 0xFFFF", self.emcy_warning_code)

    def non_default(self) -> dict[str, object]:
        """The fields that differ from the defaults (for messages and benchmark tables)."""
        default = type(self)()
        return {f.name: getattr(self, f.name) for f in fields(self)
                if getattr(self, f.name) != getattr(default, f.name)}


@dataclass(frozen=True)
class DriveBehaviour(NodeBehaviour):
    """Legal behaviours of a CiA 402 drive in cyclic synchronous position mode (CSP, 0x6060 = 8) and
    interpolated position mode (0x6060 = 7)."""

    copy_target_on_enable: bool = True
    """True: on entering OPERATION ENABLED the drive sets its target 0x607A to the actual position 0x6064
    (a forgiving drive). False, as a standard drive: 0x607A keeps what it holds, and the drive supervises
    the following error: at a SYNC in OPERATION ENABLED (CSP) with |0x607A - 0x6064| above the following
    error window 0x6065 it faults with 0x8611 (EMCY, 0x603F, statusword bit 13 "following error") instead of
    moving. That covers a stale target at enable and consecutive targets that jump by more than the window.
    0x6065 = 0xFFFFFFFF switches the supervision off (CiA 402)."""

    following_error_window_counts: int | None = None
    """Initial value of 0x6065 (following error window, drive position units); None keeps the EDS's
    (65536, half a revolution at 2**17 counts per revolution)."""

    initial_target_counts: int = 0
    """The value 0x607A holds at power-on (a drive that kept an earlier target): with
    ``copy_target_on_enable=False`` a master that enables without setting 0x607A to 0x6064 moves the plant
    or trips the following error."""

    fault_reset_delay_s: float = 0.0
    """A rising edge of controlword bit 7 (fault reset) in FAULT takes this long to reach SWITCH ON DISABLED;
    meanwhile the statusword stays FAULT (CiA 402 transition 15 takes the drive's own time)."""

    mode_switch_delay_s: float = 0.0
    """0x6061 (modes of operation display) takes the value written to 0x6060 only after this delay (CiA 402:
    the master must wait for 0x6061). In CSP statusword bit 12 = "drive follows the command value":
    it is 0 unless 0x6061 = 8 and OPERATION ENABLED, and while it is 0 the drive ignores 0x607A and holds
    its position."""

    enable_requires_sync: bool = False
    """The drive does not go from SWITCHED ON to OPERATION ENABLED (transition 4) unless SYNC is running:
    at least 3 SYNCs within the last 3 x 0x1006 (communication cycle period, CiA 301), at least
    50 ms to allow for host jitter, 0.3 s if 0x1006 is 0 or absent. The controlword is a level: with
    "enable operation" written, the transition happens once SYNC runs."""

    sync_loss_timeout_s: float | None = None
    """In OPERATION ENABLED with no SYNC for this long, the drive faults with EMCY 0x8700 (sync controller,
    SYNC loss) and 0x603F = 0x8700. None: no SYNC watchdog."""

    quick_stop_option: int | None = None
    """Quick stop option code 0x605A (CiA 402), written at start; the drive then follows 0x605A as
    the master may rewrite it: 0 disable the drive function (to SWITCH ON DISABLED at once), 1-4 slow down
    (``quick_stop_ramp_s``, holding the position) then SWITCH ON DISABLED by itself, 5-8 slow down and stay
    in QUICK STOP ACTIVE (transition 16 back to OPERATION ENABLED allowed). None: as before, the drive stays
    in QUICK STOP ACTIVE until "disable voltage", whatever 0x605A says."""

    quick_stop_ramp_s: float = 0.02
    """How long the quick-stop slow-down takes (options 1-8)."""

    nmt_on_fault: str | None = None
    """On entering FAULT the node also changes its NMT state, as CiA 301's error behaviour 0x1029 lets a
    device do: "pre-operational" (no PDOs), "stopped" (no PDOs, no SDO), or None (stays OPERATIONAL). The
    heartbeat (0x1017) shows the new state; the master must restart the node after the fault reset."""

    emcy_error_reset: bool = False
    """When a fault reset completes, the drive sends EMCY 0x0000 ("error reset", CiA 301) with the
    error register 0x1001 it now holds."""

    ip_underflow: str = "hold"
    """Interpolated position mode (0x6060 = 7): what the drive does at a SYNC with ip mode active
    (controlword bit 4, statusword bit 12) when its interpolation buffer (0x60C4) is empty. "hold": it holds
    the last position (an underrun, counted; the forgiving drive). "fault": it faults with EMCY 0x8600
    (positioning controller) and 0x603F = 0x8600, as maxon EPOS drives do; a master that sets bit 4 on an
    empty buffer faults at the first SYNC. "fault_after_first": it holds until it has taken a record since
    ip mode became active, and faults on an empty buffer from then on."""

    requires_ip_period: bool = False
    """Enabling ip mode (controlword bit 4 in OPERATION ENABLED with 0x6061 = 7) needs the interpolation
    time period 0x60C2 (CiA 402: sub 1 value, sub 2 index, value * 10**index seconds): with 0x60C2 = 0,
    or where the EDS has 0x1006 and it is written (non-zero) with a period other than 0x1006's, the drive
    faults with EMCY 0x6320 (parameter error) and 0x603F = 0x6320. Where the EDS has no 0x1006, 0x60C2 is
    the only period. False: the drive takes one record per SYNC whatever 0x60C2 says."""

    ip_buffer_records: int | None = None
    """The interpolation buffer's capacity (CiA 402 0x60C4:1 maximum buffer size, and 0x60C4:2 actual
    buffer size at power-on), as the drive's EDS gives it (``SimulatedCanOpenRig.write_eds`` writes it);
    e.g. 4 for a drive with a small FIFO. None keeps the EDS's (64)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check("DriveBehaviour.ip_underflow", self.ip_underflow in IP_UNDERFLOW,
               "'hold', 'fault' or 'fault_after_first'", self.ip_underflow)
        for field in ("copy_target_on_enable", "enable_requires_sync", "emcy_error_reset", "requires_ip_period"):
            value = getattr(self, field)
            _check(f"DriveBehaviour.{field}", isinstance(value, bool), "true or false", value)
        if self.following_error_window_counts is not None:
            _check("DriveBehaviour.following_error_window_counts",
                   _is_int(self.following_error_window_counts) and 0 <= self.following_error_window_counts < 1 << 32,
                   "an UNSIGNED32 number of counts", self.following_error_window_counts)
        _check("DriveBehaviour.initial_target_counts",
               _is_int(self.initial_target_counts) and -(1 << 31) <= self.initial_target_counts < 1 << 31,
               "an INTEGER32 position", self.initial_target_counts)
        for field in ("fault_reset_delay_s", "mode_switch_delay_s", "quick_stop_ramp_s"):
            value = getattr(self, field)
            _check(f"DriveBehaviour.{field}", isinstance(value, (int, float)) and not isinstance(value, bool)
                   and 0 <= value <= 60, "seconds from 0 to 60", value)
        if self.sync_loss_timeout_s is not None:
            _check("DriveBehaviour.sync_loss_timeout_s", isinstance(self.sync_loss_timeout_s, (int, float))
                   and 0 < self.sync_loss_timeout_s <= 60, "None or seconds above 0", self.sync_loss_timeout_s)
        if self.quick_stop_option is not None:
            _check("DriveBehaviour.quick_stop_option",
                   _is_int(self.quick_stop_option) and 0 <= self.quick_stop_option <= 8,
                   "None or a quick stop option code from 0 to 8", self.quick_stop_option)
        _check("DriveBehaviour.nmt_on_fault", self.nmt_on_fault in NMT_ON_FAULT,
               "None, 'pre-operational' or 'stopped'", self.nmt_on_fault)
        if self.ip_buffer_records is not None:
            _check("DriveBehaviour.ip_buffer_records",
                   _is_int(self.ip_buffer_records) and 1 <= self.ip_buffer_records <= 0xFFFF,
                   "None or a number of records from 1 to 65535", self.ip_buffer_records)

    @property
    def needs_clock(self) -> bool:
        """Whether the drive has timed transitions that must happen without any frame to trigger them."""
        return bool(self.fault_reset_delay_s or self.mode_switch_delay_s or self.sync_loss_timeout_s is not None
                    or self.quick_stop_option is not None)


@dataclass(frozen=True)
class EncoderBehaviour(NodeBehaviour):
    """Legal behaviours of a CiA 406 absolute encoder (besides its resolution, which is the plant's
    :class:`~rig.protocols.encoder_counts.EncoderResolution`)."""


def real_variety() -> dict[str, tuple[DriveBehaviour, EncoderBehaviour]]:
    """Named devices of the real variety, ``name -> (drive behaviour, encoder behaviour)``, for a contract
    test matrix and the benchmark table (pass them as ``SimulatedCanOpenRig(drive_behaviour=...,
    encoder_behaviour=...)``). Parameters are chosen to stay legal for the test excitations (target steps
    below the default following error window of 65536 counts). For the static ones the master must load
    the devices' own EDS (:meth:`SimulatedCanOpenRig.write_eds`), as it would a vendor's; the fault side
    effects only show when a fault is injected."""
    drive, encoder = DriveBehaviour, EncoderBehaviour
    return {
        "forgiving (default)": (drive(), encoder()),
        "target not copied at enable": (drive(copy_target_on_enable=False), encoder()),
        "stale target within the window (moves at enable)": (
            drive(copy_target_on_enable=False, initial_target_counts=20_000), encoder()),
        "stale target beyond the window (0x8611 at enable)": (
            drive(copy_target_on_enable=False, initial_target_counts=100_000), encoder()),
        "fault reset takes 20 ms": (drive(fault_reset_delay_s=0.02), encoder()),
        "mode switch takes 0.5 s": (drive(mode_switch_delay_s=0.5), encoder()),
        "enable only with SYNC running": (drive(enable_requires_sync=True), encoder()),
        "SYNC watchdog 50 ms (0x8700)": (drive(sync_loss_timeout_s=0.05), encoder()),
        "TPDOs one SYNC late": (drive(tpdo_latency_cycles=1), encoder(tpdo_latency_cycles=1)),
        "encoder TPDO one SYNC late": (drive(), encoder(tpdo_latency_cycles=1)),
        "static PDOs": (drive(static_pdos=True), encoder(static_pdos=True)),
        "static encoder TPDO every 2nd SYNC": (drive(), encoder(static_pdos=True, static_tpdo_transmission_type=2)),
        "static 2-byte encoder TPDO": (drive(), encoder(static_pdos=True, static_tpdo_mapping=(0x60040010,))),
        "quick stop option 2 (to SWITCH ON DISABLED)": (drive(quick_stop_option=2), encoder()),
        "quick stop option 6 (stays in QUICK STOP ACTIVE)": (drive(quick_stop_option=6), encoder()),
        "pre-operational on fault": (drive(nmt_on_fault="pre-operational", emcy_error_reset=True), encoder()),
        "stopped on fault": (drive(nmt_on_fault="stopped"), encoder()),
        "encoder temperature warning at sample 20": (drive(), encoder(emcy_warning_at_seq=20)),
        "interpolation buffer underflow faults (EPOS-like, 0x8600)": (drive(ip_underflow="fault"), encoder()),
        "underflow faults after the first record (0x8600)": (drive(ip_underflow="fault_after_first"), encoder()),
        "needs 0x60C2 = SYNC period (0x6320)": (drive(requires_ip_period=True), encoder()),
        "interpolation buffer of 16 records": (drive(ip_buffer_records=16), encoder()),
        "interpolation buffer of 4 records": (drive(ip_buffer_records=4), encoder()),
        "interpolation buffer of 3 records": (drive(ip_buffer_records=3), encoder()),
        "small buffer, faults on underflow": (drive(ip_buffer_records=4, ip_underflow="fault"), encoder()),
    }


OPTIONAL_OBJECTS_MISSING = {
    "drive EDS without 0x1006": ("drive", (0x1006,)),
    "drive EDS without 0x603F": ("drive", (0x603F,)),
    "drive EDS without 0x6098": ("drive", (0x6098,)),
    "drive EDS without 0x6502": ("drive", (0x6502,)),
    "encoder EDS without 0x6501/0x6002": ("encoder", (0x6501, 0x6002)),
}
"""Vendor EDS files that lack an optional object: ``name -> (device, indices)`` for
:func:`sim_backend.eds_variants.eds_without` (the simulated device then lacks them too)."""
