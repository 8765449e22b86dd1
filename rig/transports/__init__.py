"""Transports, chosen by name or URL from a lazy registry (after python-can's ``can/interfaces`` BACKENDS
and pyserial's ``serial_for_url``).

=============================  =====================================================================
URL                            transport
=============================  =====================================================================
``canopen://IFACE/CHANNEL``    CiA 402 drive + CiA 406 encoder over CANopen (:mod:`.canopen_link`)
``can://IFACE/CHANNEL``        raw CAN frames described by ``configs/raw_can.dbc`` (:mod:`.raw_can`)
``serial:///dev/ttyUSB0``      the COBS/CRC-16 serial protocol (:mod:`.serial_link`)
=============================  =====================================================================

``IFACE`` is any python-can interface name (``socketcan``, ``pcan``, ``kvaser``, ``virtual``, ...);
``udp_multicast``, which joins processes on one host (a simulated device in a process of its own), takes the
multicast group as the channel and its UDP port after the name: ``can://udp_multicast:43113/239.74.163.2``
(:mod:`rig.protocols.can_interfaces`).
A backend module is imported only when chosen, so a missing optional driver fails only then, with a
:class:`~rig.protocols.errors.TransportError` that says what to install. Options the chosen backend does
not know are rejected (:class:`~rig.protocols.errors.ConfigError`), never ignored.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any
from urllib.parse import urlsplit

from rig.protocols.can_interfaces import PORT_INTERFACES
from rig.protocols.errors import ConfigError, TransportError
from rig.transports.base import CommandLimits, CommandRefused, FeedbackSample, Setpoint, Transport

__all__ = ["BACKENDS", "CommandLimits", "CommandRefused", "FeedbackSample", "Setpoint", "Transport",
           "open_transport", "parse_transport_url", "transport_class"]

BACKENDS: dict[str, tuple[str, str, str]] = {
    "canopen": ("rig.transports.canopen_link", "CanOpenTransport", "canopen"),
    "can": ("rig.transports.raw_can", "RawCanTransport", "python-can and cantools"),
    "serial": ("rig.transports.serial_link", "SerialTransport", "pyserial"),
}
"""scheme -> (module, class, what to install if the module's driver is missing)."""


def parse_transport_url(url: str) -> tuple[str, dict[str, Any]]:
    """Split a transport URL into the scheme and the constructor arguments it implies.

    >>> parse_transport_url("canopen://socketcan/can0")
    ('canopen', {'interface': 'socketcan', 'channel': 'can0'})
    >>> parse_transport_url("can://udp_multicast:43200/239.74.1.2")
    ('can', {'interface': 'udp_multicast', 'channel': '239.74.1.2', 'port': 43200})
    >>> parse_transport_url("serial:///dev/ttyUSB0")
    ('serial', {'port': '/dev/ttyUSB0'})
    """
    parts = urlsplit(url)
    scheme = parts.scheme
    if scheme not in BACKENDS:
        known = ", ".join(f"{name}://" for name in BACKENDS)
        raise ConfigError("<transport>", "url", f"unknown transport {url!r} (known: {known})")
    if parts.query or parts.fragment:
        raise ConfigError("<transport>", "url", f"{url!r}: give options as config keys, not in the URL")
    if scheme == "serial":
        port = parts.path if not parts.netloc else parts.netloc + parts.path
        if not port:
            raise ConfigError("<transport>", "url", f"{url!r}: expected serial:///dev/ttyUSB0 (a device path)")
        return scheme, {"port": port}
    interface, _, port = parts.netloc.partition(":")
    channel = parts.path.lstrip("/")
    if not interface or not channel:
        raise ConfigError("<transport>", "url", f"{url!r}: expected {scheme}://INTERFACE/CHANNEL, e.g. {scheme}://socketcan/can0")
    import can

    if interface not in can.interfaces.VALID_INTERFACES:
        raise ConfigError("<transport>", "url", f"{url!r}: {interface!r} is no python-can interface "
                                                f"(known: {', '.join(sorted(can.interfaces.VALID_INTERFACES))})")
    if not port:
        return scheme, {"interface": interface, "channel": channel}
    if interface not in PORT_INTERFACES:
        raise ConfigError("<transport>", "url", f"{url!r}: a port belongs to {', '.join(sorted(PORT_INTERFACES))} "
                                                f"only, not to {interface}")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError("<transport>", "url", f"{url!r}: expected a UDP port 1..65535 after {interface}:")
    return scheme, {"interface": interface, "channel": channel, "port": int(port)}


def transport_class(scheme: str) -> type[Transport]:
    """Import the backend for ``scheme`` now (and only now)."""
    module_name, class_name, requirement = BACKENDS[scheme]
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise TransportError(f"the {scheme} transport needs {requirement} ({err}); install it with "
                             f"`pip install gearbox-rig` or add the package to your environment") from err
    return getattr(module, class_name)


def _accepted_options(cls: type) -> set[str]:
    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        for name, parameter in inspect.signature(klass.__init__).parameters.items():
            if name != "self" and parameter.kind not in (parameter.VAR_KEYWORD, parameter.VAR_POSITIONAL):
                names.add(name)
    return names


def open_transport(url: str, **options: Any) -> Transport:
    """Build (not yet open) the transport named by ``url`` with ``options``; unknown options raise
    :class:`ConfigError` naming them and the options the backend accepts."""
    scheme, arguments = parse_transport_url(url)
    cls = transport_class(scheme)
    accepted = _accepted_options(cls)
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise ConfigError("<transport>", unknown[0], f"not an option of the {scheme} transport "
                                                     f"(accepted: {', '.join(sorted(accepted - set(arguments)))})")
    options.setdefault("name", url)
    return cls(**arguments, **options)
