"""Pure numerics that turn rig logs into identification results.

Arrays and dataclasses in, frozen dataclasses out: no I/O, no plotting and no hardware libraries are
imported here (``tests/identify/test_import_purity.py`` checks it). Signals follow one convention
everywhere: 1-D float arrays of equal length, ordered ``(time_s, inputs, outputs)``, angles in radians,
named ``input_rad``/``output_rad`` by the methods and ``command_rad``/``angle_rad`` where they are a
record's columns, units in every public parameter name (the rules: ``docs/design.md``, "One signal
vocabulary"; ``tests/identify/test_naming_rules.py`` checks them).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("gearbox-rig")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
