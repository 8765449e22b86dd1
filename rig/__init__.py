"""The gearbox rig driver: transports, experiment runner, log files, reports and the ``rig`` CLI."""

from identify import __version__

__all__ = ["__version__"]
