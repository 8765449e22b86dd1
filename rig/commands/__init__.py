"""Subcommands of the ``rig`` command line, one module each (see :mod:`rig.cli`)."""
