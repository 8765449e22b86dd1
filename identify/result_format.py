"""The one shape of a serialised result: ``{"kind": ..., "version": ..., ...}`` (docs/design.md, section 5).

Every result type writes itself with ``to_dict()`` (plain JSON values; infinite numbers as the strings
``"inf"``/``"-inf"``, as the CLI always wrote them) and reads itself back with ``from_dict()``, which checks
the kind and version first: a document of another kind, or of a version this code does not read, is refused
with :class:`ResultFormatError` naming both. Readers (``rig report``) dispatch on :func:`kind_of`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from identify.validation import InvalidInputError

__all__ = ["ResultFormatError", "check_kind", "kind_of", "malformed", "number", "numbers", "require_pandas",
           "results_equal", "tagged", "values_equal"]


class ResultFormatError(InvalidInputError):
    """A document is not a result of the expected kind and version, or a key of it is malformed."""


def tagged(kind: str, version: int, body: Mapping[str, Any]) -> dict[str, Any]:
    """``{"kind": kind, "version": version, **body}``."""
    return {"kind": kind, "version": version, **body}


def kind_of(document: Any) -> tuple[str | None, Any]:
    """(kind, version) of a document; (None, None) when it has no ``kind``."""
    if not isinstance(document, Mapping) or not isinstance(document.get("kind"), str):
        return None, None
    return document["kind"], document.get("version")


def check_kind(document: Any, kind: str, versions: Sequence[int]) -> Mapping[str, Any]:
    """``document`` itself if it is a mapping of ``kind`` at one of ``versions``; else ResultFormatError."""
    if not isinstance(document, Mapping):
        raise ResultFormatError(f"expected a JSON object of kind {kind!r}, got {type(document).__name__}")
    found, version = kind_of(document)
    readable = ", ".join(str(v) for v in versions)
    if found is None:
        raise ResultFormatError(f"expected a result of kind {kind!r} (version {readable}); the document has no "
                                "'kind' key (written before results were tagged: write it again)")
    if found != kind:
        raise ResultFormatError(f"expected a result of kind {kind!r}, got kind {found!r} version {version!r}")
    if isinstance(version, bool) or version not in versions:
        raise ResultFormatError(f"kind {kind!r} version {version!r} cannot be read (this version reads "
                                f"{readable}); write it again with this version")
    return document


def number(value: float) -> float | str:
    """A float for JSON: finite as is, infinite as ``"inf"``/``"-inf"``, NaN as ``"nan"``."""
    value = float(value)
    if math.isfinite(value):
        return value
    return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")


def numbers(values: Any) -> list[float | str]:
    """:func:`number` of every entry of a 1-D sequence."""
    return [number(v) for v in values]


@contextlib.contextmanager
def malformed(kind: str) -> Iterator[None]:
    """Turn a missing key or a wrong value met while reading a ``kind`` document into ResultFormatError."""
    try:
        yield
    except ResultFormatError:
        raise
    except KeyError as err:
        raise ResultFormatError(f"kind {kind!r}: key {err} is missing") from None
    except (TypeError, ValueError, AttributeError, IndexError) as err:
        text = str(err)
        raise ResultFormatError(f"kind {kind!r}: malformed ({text[:160]})") from None


def values_equal(first: Any, second: Any) -> bool:
    """Whether two result values are equal, arrays compared element-wise (shape, values, NaN equal to NaN),
    through tuples, lists, mappings and dataclasses: what ``==`` means for a result type (a result saved and
    reopened equals the original)."""
    if isinstance(first, (np.ndarray, np.generic)) or isinstance(second, (np.ndarray, np.generic)):
        a, b = np.asarray(first), np.asarray(second)
        if a.shape != b.shape:
            return False
        try:
            return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc" and b.dtype.kind in "fc"))
        except TypeError:  # object arrays
            return all(values_equal(x, y) for x, y in zip(a.ravel().tolist(), b.ravel().tolist()))
    if dataclasses.is_dataclass(first) and not isinstance(first, type):
        return type(first) is type(second) and results_equal(first, second)
    if isinstance(first, Mapping):
        return (isinstance(second, Mapping) and first.keys() == second.keys()
                and all(values_equal(first[key], second[key]) for key in first))
    if isinstance(first, (tuple, list)):
        return (isinstance(second, (tuple, list)) and len(first) == len(second)
                and all(values_equal(x, y) for x, y in zip(first, second)))
    if isinstance(first, float) and isinstance(second, float) and math.isnan(first) and math.isnan(second):
        return True
    return bool(first == second)


def results_equal(first: Any, second: Any) -> bool:
    """``first == second`` for two dataclass results: the same type and every field equal by
    :func:`values_equal` (fields that are not compared, ``compare=False``, are skipped)."""
    if type(first) is not type(second):
        return False
    return all(values_equal(getattr(first, item.name), getattr(second, item.name))
               for item in dataclasses.fields(first) if item.compare)


def require_pandas(what: str) -> Any:
    """The pandas module, or ImportError saying that ``what`` needs it and how to install it (pandas is not
    a dependency of this package: only ``to_pandas()`` uses it)."""
    try:
        import pandas
    except ImportError as err:
        raise ImportError(f"{what} needs pandas, which is not installed: pip install pandas") from err
    return pandas
