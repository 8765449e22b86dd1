"""Validation of TOML configs: every key is checked, unknown keys are rejected, and every error names
the file, the dotted key and what was expected (:class:`~rig.protocols.errors.ConfigError`).

Usage::

    table = load_toml(path)
    period_s = table.number("sample_period_s", minimum=1e-5, maximum=1.0)
    plant = table.table("plant")
    bits = plant.integer("encoder_bits", default=12, minimum=1, maximum=32)
    plant.finish()
    table.finish()  # raises ConfigError if the file has keys nobody read
"""

from __future__ import annotations

import math
import stat
import tomllib
from pathlib import Path
from typing import Any

from rig.protocols.errors import ConfigError

_MISSING = object()


def load_toml(path: str | Path) -> ConfigTable:
    """Parse ``path`` as TOML and return its root table, translating parse errors to :class:`ConfigError`."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise ConfigError(str(path), "<file>", "no such file") from None
    except OSError as err:
        raise ConfigError(str(path), "<file>", f"cannot be read: {err.strerror}") from None
    if stat.S_ISDIR(mode):
        raise ConfigError(str(path), "<file>", "is a directory; give a .toml file")
    if not stat.S_ISREG(mode):  # /dev/zero would be read forever
        raise ConfigError(str(path), "<file>", "is not a regular file; give a .toml file")
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(str(path), "<file>", "no such file") from None
    except PermissionError as err:
        raise ConfigError(str(path), "<file>", f"cannot be read: {err.strerror}") from None
    except UnicodeDecodeError as err:
        raise ConfigError(str(path), "<file>", f"not a text file (byte {err.start} is not UTF-8); save it as "
                                               "UTF-8 (TOML files are UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(str(path), "<file>", f"not valid TOML: {err}") from err
    return ConfigTable(str(path), "", data)


class ConfigTable:
    """One TOML table under validation; remembers which keys were read so that :meth:`finish` can reject
    the rest (a misspelt key is an error, never silently ignored)."""

    def __init__(self, source: str, prefix: str, data: dict[str, Any]) -> None:
        self.source = source
        self.prefix = prefix
        self.data = data
        self._read: set[str] = set()

    def key_path(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str, problem: str) -> ConfigError:
        return ConfigError(self.source, self.key_path(key), problem)

    def has(self, key: str) -> bool:
        return key in self.data

    def _get(self, key: str, default: Any) -> Any:
        self._read.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, "is required but missing")
        return default

    def number(self, key: str, default: Any = _MISSING, *, minimum: float | None = None,
               maximum: float | None = None, exclusive_minimum: bool = False) -> float:
        value = self._get(key, default)
        if value is None and default is None:
            return None  # type: ignore[return-value]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(key, f"expected a finite number, got {value!r}")
        value = float(value)
        if minimum is not None and (value < minimum or (exclusive_minimum and value == minimum)):
            relation = ">" if exclusive_minimum else ">="
            raise self.error(key, f"expected a number {relation} {minimum:g}, got {value:g}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"expected a number <= {maximum:g}, got {value:g}")
        return value

    def integer(self, key: str, default: Any = _MISSING, *, minimum: int | None = None,
                maximum: int | None = None) -> int:
        value = self._get(key, default)
        if value is None and default is None:
            return None  # type: ignore[return-value]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"expected an integer >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"expected an integer <= {maximum}, got {value}")
        return value

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {value!r}")
        return value

    def string(self, key: str, default: Any = _MISSING, *, choices: tuple[str, ...] | None = None) -> str:
        value = self._get(key, default)
        if value is None and default is None:
            return None  # type: ignore[return-value]
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    def numbers(self, key: str, default: Any = _MISSING, *, min_length: int = 0) -> list[float]:
        value = self._get(key, default)
        if not isinstance(value, list) or not all(
            isinstance(item, (int, float)) and not isinstance(item, bool) and math.isfinite(item) for item in value
        ):
            raise self.error(key, f"expected a list of finite numbers, got {value!r}")
        if len(value) < min_length:
            raise self.error(key, f"expected at least {min_length} numbers, got {len(value)}")
        return [float(item) for item in value]

    def table(self, key: str, default: Any = _MISSING) -> ConfigTable:
        value = self._get(key, {} if default is not _MISSING else default)
        if not isinstance(value, dict):
            raise self.error(key, f"expected a table [{self.key_path(key)}], got {value!r}")
        return ConfigTable(self.source, self.key_path(key), value)

    def tables(self, key: str, default: Any = _MISSING) -> list[ConfigTable]:
        """An array of tables (``[[key]]`` in TOML), each validated on its own."""
        value = self._get(key, default)
        if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
            raise self.error(key, f"expected an array of tables [[{self.key_path(key)}]], got {value!r}")
        return [ConfigTable(self.source, f"{self.key_path(key)}[{index}]", item) for index, item in enumerate(value)]

    def matrix(self, key: str, default: Any = _MISSING) -> list[list[float]]:
        """A non-empty list of non-empty rows of finite numbers."""
        value = self._get(key, default)
        if not (isinstance(value, list) and value and all(
                isinstance(row, list) and row and all(
                    isinstance(item, (int, float)) and not isinstance(item, bool) and math.isfinite(item) for item in row)
                for row in value)):
            raise self.error(key, f"expected a matrix as a list of rows of numbers, got {value!r}")
        return [[float(item) for item in row] for row in value]

    def finish(self) -> None:
        """Raise :class:`ConfigError` naming the first key that no validator read."""
        unknown = sorted(set(self.data) - self._read)
        if unknown:
            known = ", ".join(sorted(self._read)) or "none"
            raise self.error(unknown[0], f"unknown key (known keys here: {known})")
