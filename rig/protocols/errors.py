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


class DeviceFault(RigError):
    """A device reported a fault or refused a request (EMCY, SDO abort, fault state)."""

    def __init__(self, device: str, code: int | None, message: str) -> None:
        self.device = device
        self.code = code
        code_text = f" (code 0x{code:04X})" if code is not None else ""
        super().__init__(f"{device}{code_text}: {message}")
