"""Hardened reading of a JSON file written by someone else (sequence.json, a watcher's notes).

:func:`load_json_hardened` refuses, with one line naming the file, what :func:`json.loads`
would accept but no measurement file should hold: more than :data:`MAX_JSON_BYTES`, text that
is not UTF-8, ``NaN``/``Infinity``, an integer literal of more than :data:`MAX_JSON_INT_DIGITS`
digits (whose conversion is quadratic), a number too large for a float, nesting deeper than
:data:`MAX_JSON_DEPTH`, a key given twice in one object (json.loads keeps the last one
silently), and a top level that is not an object.

:func:`unique_keys` is the ``object_pairs_hook`` that refuses duplicate keys; every JSON
document dropvision reads goes through it (:func:`loads_strict` for text at hand).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["MAX_JSON_BYTES", "MAX_JSON_DEPTH", "MAX_JSON_INT_DIGITS", "JsonRefused", "load_json_hardened",
           "loads_strict", "unique_keys"]

#: Largest JSON file read (bytes), deepest nesting of its containers, longest integer literal.
MAX_JSON_BYTES = 64 * 1024 ** 2
MAX_JSON_DEPTH = 64
MAX_JSON_INT_DIGITS = 100


class JsonRefused(ValueError):
    """A JSON literal the hardened reader refuses (NaN, Infinity, a huge number)."""


def _json_constant(name: str):
    raise JsonRefused(f"{name} is not a JSON number (write null for a missing value)")


def _json_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_JSON_INT_DIGITS:
        raise JsonRefused(f"integer of {digits} digits (at most {MAX_JSON_INT_DIGITS})")
    return int(text)


def _json_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise JsonRefused(f"number {text[:40]} is too large to represent")
    return value


def unique_keys(pairs: list) -> dict:
    """``object_pairs_hook`` of every JSON read: the object as a dict, refusing a key given twice
    (:class:`JsonRefused` naming it) instead of keeping the last one silently."""
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen = set()
        for key, _value in pairs:
            if key in seen:
                raise JsonRefused(f"key {key!r} given twice in one object")
            seen.add(key)
    return obj


def loads_strict(text):
    """``json.loads`` refusing duplicate keys (:class:`JsonRefused`, a ValueError)."""
    return json.loads(text, object_pairs_hook=unique_keys)


def _json_depth_ok(obj) -> bool:
    """True when no container of ``obj`` is nested deeper than :data:`MAX_JSON_DEPTH`."""
    stack = [(obj, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            if depth > MAX_JSON_DEPTH:
                return False
            values = item.values() if isinstance(item, dict) else item
            stack.extend((v, depth + 1) for v in values if isinstance(v, (dict, list)))
    return True


def load_json_hardened(path, error: type[Exception] = ValueError) -> dict:
    """Read a JSON object from ``path``, refusing what a measurement file may not hold.

    Parameters
    ----------
    path : str or Path
        The file.
    error : type of Exception
        Raised (with a one-line message ``"<path>: <problem>"``) for every refusal and for an
        unreadable file, e.g. the caller's ``SequenceError``.

    Returns
    -------
    dict
        The top-level object.

    Raises
    ------
    error
        Unreadable, larger than :data:`MAX_JSON_BYTES`, not UTF-8 (a BOM is skipped), invalid
        JSON, a key given twice in one object, NaN/Infinity, an integer of more than :data:`MAX_JSON_INT_DIGITS` digits, a number
        too large for a float, nesting deeper than :data:`MAX_JSON_DEPTH`, or not an object.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(raw) > MAX_JSON_BYTES:
        raise error(f"{path}: larger than {MAX_JSON_BYTES} bytes (dvcore.jsonio.MAX_JSON_BYTES)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    try:
        obj = json.loads(text, parse_constant=_json_constant, parse_int=_json_int,
                         parse_float=_json_float, object_pairs_hook=unique_keys)
    except JsonRefused as exc:
        raise error(f"{path}: invalid JSON ({exc})") from None
    except RecursionError:
        obj = None
    except ValueError as exc:
        raise error(f"{path}: invalid JSON ({exc})") from None
    if obj is None or not _json_depth_ok(obj):
        raise error(f"{path}: invalid JSON (nested more than {MAX_JSON_DEPTH} levels deep)")
    if not isinstance(obj, dict):
        raise error(f"{path}: must hold a JSON object, got {type(obj).__name__}")
    return obj
