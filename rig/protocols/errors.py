"""The driver's error tree (after python-can's ``can/exceptions.py``).

A device that refuses (:class:`DeviceFault`, with its code) is not a link that failed
(:class:`TransportError`). Library errors are translated at the boundary with ``raise ... from err``.
"""

from __future__ import annotations


class RigError(Exception):
    """Root of every error the driver raises on purpose."""


class ConfigError(RigError, ValueError):
    """A config file or config value is wrong; the message names the file, the key and what was expected."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source = source
        self.key = key
        self.problem = problem
        super().__init__(f"{source}: [{key}] {problem}")


class LogFileError(RigError, ValueError):
    """A log or CSV file cannot be read as experiment data; the message names the file and the line."""


class TransportError(RigError):
    """The link to a device failed (bus down, port gone, no answer in time)."""


# Emergency error codes (CiA 301 Table 21 classes; CiA 402-2 codes of servo drives) for fault messages.
_ERROR_CODES = {
    0x2310: "continuous over-current on the device output side", 0x2320: "short circuit or earth leakage",
    0x3210: "DC link over-voltage", 0x3220: "DC link under-voltage", 0x4210: "excess temperature of the device",
    0x4310: "excess temperature of the drive", 0x5441: "safe torque off / enable input inactive",
    0x7121: "motor blocked", 0x7305: "incremental sensor 1 fault", 0x7500: "communication (additional modules)",
    0x8110: "CAN overrun, objects lost", 0x8120: "CAN in error passive mode", 0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off", 0x8210: "PDO not processed due to length error", 0x8220: "PDO length exceeded",
    0x8600: "positioning controller (in interpolated position: an empty interpolation buffer, 0x60C4, an underflow)",
    0x8611: "position following error", 0x8612: "reference limit",
}
_ERROR_CLASSES = {
    0x10: "generic error", 0x20: "current", 0x21: "current on the device input side", 0x22: "current inside the device",
    0x23: "current on the device output side", 0x30: "voltage", 0x31: "mains voltage", 0x32: "voltage inside the device",
    0x33: "output voltage", 0x40: "temperature", 0x41: "ambient temperature", 0x42: "device temperature",
    0x50: "device hardware", 0x60: "device software", 0x61: "internal software", 0x62: "user software",
    0x63: "data set", 0x70: "additional modules", 0x80: "monitoring", 0x81: "communication", 0x82: "protocol error",
    0x90: "external error", 0xF0: "additional functions", 0xFF: "device specific",
}


def error_code_meaning(code: int) -> str:
    """What an emergency / 0x603F error code means: the CiA 402 code if known, else its CiA 301 class."""
    if code > 0xFFFF:
        return "SDO abort code (CiA 301 Table 22)"
    if code in _ERROR_CODES:
        return _ERROR_CODES[code]
    return _ERROR_CLASSES.get(code >> 8, _ERROR_CLASSES.get(code >> 8 & 0xF0, "unknown error code")) + " (class)"


class DeviceFault(RigError):
    """A device reported a fault or refused a request (EMCY, SDO abort, fault state). The message names
    the device and the error code with its meaning (:func:`error_code_meaning`)."""

    def __init__(self, device: str, code: int | None, message: str) -> None:
        self.device = device
        self.code = code
        digits = 8 if code is not None and code > 0xFFFF else 4  # SDO abort codes have 32 bits
        code_text = f" (code 0x{code:0{digits}X}: {error_code_meaning(code)})" if code is not None else ""
        super().__init__(f"{device}{code_text}: {message}")


class DriveMayBeEnabled(DeviceFault):
    """The controlled stop was not confirmed: after quick stop, disable and (where the link has one) its
    escalation, the drive was not seen disabled. Whatever else ended the run, this is what the user must
    hear first; ``cause`` is that other error, if any."""

    def __init__(self, device: str, stop: str, last_seen: str | None, cause: BaseException | None = None) -> None:
        self.stop = stop
        self.cause = cause
        seen = f"last seen {last_seen}" if last_seen else "its state was never read back"
        ended = f"; the run had stopped because: {cause}" if cause is not None else ""
        super().__init__(device, None, (
            f"the drive MAY STILL BE ENABLED ({seen}): the stop was not confirmed ({stop}); make it safe at the rig "
            f"(enable input, safe torque off or mains) before anyone goes near it{ended}"))
