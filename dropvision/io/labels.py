"""Labels of a shot: the numbers that tell one image from another (voltages, pulse times, a nozzle).

Pure functions, no image is read. A label is a name and a number. They come from

- the file name (`labels_from_name`): its ``name-value`` tokens, split on ``_``
  (``images_V1--86_V2-12_w1-26.jpg`` gives V1 = -86, V2 = 12, w1 = 26; a double dash is a minus
  sign), a name token followed by a number token (``nozzle_03`` gives nozzle = 3); a number
  followed by ``us`` is the strobe delay, not a label (`dropvision.io.discovery.parse_delay_from_name`);
- a regular expression with named groups where names are unusual (`labels_from_pattern`,
  ``--label-pattern``), which replaces the file-name rule;
- a table beside the images (``shots.csv``: a ``file`` column and one column per label,
  `read_label_table`), or sequence.json's ``shots`` list (``[{"file": "a.jpg", "V1": -86}]``,
  `labels_from_document`).

`merge_labels` joins the sources of one file: the same name with two different values is an error
naming the file. `varying_labels` tells a counter (a frame number) from labels that group files.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path, PurePath

from dropvision.io.sequence_meta import SequenceError

__all__ = ["LabelError", "LABEL_TABLE", "labels_from_name", "labels_from_pattern", "read_label_table", "labels_from_document",
           "merge_labels", "varying_labels", "check_one_series", "compile_pattern"]

#: The table of labels beside the images.
LABEL_TABLE = "shots.csv"

_NAME = r"[A-Za-z][A-Za-z0-9]*"
_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
#: ``name-value`` (or ``name=value``): V1-12, V1--86 (value -86), w1-2.5, gain=3
_PAIR = re.compile(rf"^({_NAME})[-=]({_NUMBER})$")
_BARE_NAME = re.compile(rf"^{_NAME}$")
#: a label name in a table or document (no file-name tokens to split): underscores too (``nozzle_outer_diameter_um``)
_TABLE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_BARE_NUMBER = re.compile(rf"^{_NUMBER}$")
#: a delay token (``1150us``, ``t-12.5us``): the delay's, never a label
_DELAY_TOKEN = re.compile(r"(?:^|[-=])\d+(?:\.\d+)?(?:us|µs|μs)$", re.IGNORECASE)


class LabelError(SequenceError):
    """Labels that cannot be read or that contradict each other (the message names the file)."""


def _stem(name: str) -> str:
    return PurePath(str(name).replace("\\", "/")).stem


def _number(text: str, where: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise LabelError(f"{where}: label value {text!r} is not a finite number")
    return value


def labels_from_name(name: str) -> dict[str, float]:
    """Labels in a file name.

    Parameters
    ----------
    name : str
        File name or path; only the last component without its suffix is read.

    Returns
    -------
    dict
        Label name -> value, in the order of the name. Tokens (split on ``_``) of the form
        ``name-value`` or ``name=value`` (a leading letter, then letters or digits; the value a
        decimal number, ``--86`` being -86) give a label; a name token followed by a number token
        gives one too (``nozzle_03`` -> nozzle = 3). Other tokens (``images``, ``a-b``, a bare
        number, a delay such as ``1150us``) are no label.

    Raises
    ------
    LabelError
        The same label twice with different values, naming the file.

    Examples
    --------
    >>> labels_from_name("images_V1--86_V2-12_w1-2.5.jpg")
    {'V1': -86.0, 'V2': 12.0, 'w1': 2.5}
    >>> labels_from_name("nozzle_03_1150us.png")
    {'nozzle': 3.0}
    """
    tokens = _stem(name).split("_")
    out: dict[str, float] = {}

    def put(key: str, value: float) -> None:
        if key in out and out[key] != value:
            raise LabelError(f"{name}: label {key} given twice in the file name ({out[key]:g} and {value:g})")
        out[key] = value

    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if _DELAY_TOKEN.search(tok):
            i += 1
            continue
        pair = _PAIR.match(tok)
        if pair:
            put(pair.group(1), _number(pair.group(2), str(name)))
        elif (_BARE_NAME.match(tok) and i + 1 < len(tokens) and _BARE_NUMBER.match(tokens[i + 1])
              and not _DELAY_TOKEN.search(tokens[i + 1])):
            put(tok, _number(tokens[i + 1], str(name)))
            i += 1
        i += 1
    return out


def labels_from_pattern(name: str, pattern: str | re.Pattern) -> dict[str, float]:
    """Labels from a regular expression with named groups, searched in the file name's stem.

    Parameters
    ----------
    name : str
        File name or path (the last component without its suffix is searched).
    pattern : str or re.Pattern
        ``(?P<label>...)`` groups; each group that matched must be a number.

    Returns
    -------
    dict
        Group name -> value (groups that did not take part in the match are left out).

    Raises
    ------
    LabelError
        The pattern has no named group or is invalid, the name does not match it, or a group is not a
        number; the message names the file.

    Examples
    --------
    >>> labels_from_pattern("run7 at 35V.png", r"run(?P<run>\\d+) at (?P<V>[\\d.]+)V")
    {'run': 7.0, 'V': 35.0}
    """
    rx = compile_pattern(pattern)
    m = rx.search(_stem(name))
    if m is None:
        raise LabelError(f"{name}: the file name does not match the label pattern '{rx.pattern}'")
    out = {}
    for key, text in m.groupdict().items():
        if text is None:
            continue
        if not _BARE_NUMBER.match(text.strip()):
            raise LabelError(f"{name}: label {key} is {text!r} by the label pattern, not a number")
        out[key] = _number(text.strip(), str(name))
    return out


def compile_pattern(pattern: str | re.Pattern) -> re.Pattern:
    """The label pattern compiled, with at least one named group (`LabelError` otherwise)."""
    if isinstance(pattern, re.Pattern):
        rx = pattern
    else:
        try:
            rx = re.compile(pattern)
        except re.error as exc:
            raise LabelError(f"label pattern '{pattern}': not a regular expression ({exc})") from None
    if not rx.groupindex:
        raise LabelError(f"label pattern '{rx.pattern}': no named group (write (?P<V1>[-\\d.]+) for a label V1)")
    return rx


def read_label_table(path) -> dict[str, dict[str, float]]:
    """Labels of a ``shots.csv``: a ``file`` column and one column per label.

    Parameters
    ----------
    path : str or Path
        The CSV file (comma-separated, a header row; UTF-8).

    Returns
    -------
    dict
        File (as written in the ``file`` column, ``\\`` read as ``/``) -> label name -> value. An
        empty cell is no label for that file.

    Raises
    ------
    LabelError
        No ``file`` column, a file listed twice, a value that is not a number, a label name that is
        not a name; naming the table, the row and the column.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise LabelError(f"{path}: not UTF-8 text ({exc.reason})") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows or "file" not in [h.strip() for h in rows[0]]:
        raise LabelError(f"{path}: no 'file' column (the table's first row names the columns: file, then the labels)")
    header = [h.strip() for h in rows[0]]
    for h in header:
        if h != "file" and not _TABLE_NAME.match(h):
            raise LabelError(f"{path}: column {h!r} is not a label name (a letter, then letters, digits or _)")
    if len(set(header)) != len(header):
        raise LabelError(f"{path}: a column is named twice")
    out: dict[str, dict[str, float]] = {}
    for n, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise LabelError(f"{path} row {n}: {len(row)} cells, the header has {len(header)}")
        cells = dict(zip(header, (c.strip() for c in row)))
        file = cells.pop("file").replace("\\", "/")
        if not file:
            raise LabelError(f"{path} row {n}: empty file")
        if file in out:
            raise LabelError(f"{path} row {n}: {file} is listed twice")
        labels = {}
        for key, cell in cells.items():
            if not cell:
                continue
            if not _BARE_NUMBER.match(cell):
                raise LabelError(f"{path} row {n}: {key} is {cell!r}, not a number")
            labels[key] = _number(cell, f"{path} row {n}")
        out[file] = labels
    return out


def labels_from_document(entries, where) -> dict[str, dict[str, float]]:
    """Labels of sequence.json's ``shots`` list: ``[{"file": "a.jpg", "V1": -86, ...}, ...]``.

    Parameters
    ----------
    entries : list
        The list as read from the JSON document.
    where : str or Path
        The document, named in errors.

    Returns
    -------
    dict
        File -> label name -> value (``null`` is no label).

    Raises
    ------
    LabelError
        Not a list of objects with a ``file``, a file listed twice, a value that is not a finite number
        (booleans and strings included), a key that is not a label name.
    """
    if not isinstance(entries, list):
        raise LabelError(f"{where}: 'shots' must be a list of objects (file and labels), got {type(entries).__name__}")
    out: dict[str, dict[str, float]] = {}
    for i, entry in enumerate(entries):
        at = f"{where} shots[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str) or not entry["file"].strip():
            raise LabelError(f"{at}: must be an object with a 'file' (a string) and the labels")
        file = entry["file"].strip().replace("\\", "/")
        if file in out:
            raise LabelError(f"{at}: {file} is listed twice")
        labels = {}
        for key, value in entry.items():
            if key == "file" or value is None:
                continue
            if not isinstance(key, str) or not _TABLE_NAME.match(key):
                raise LabelError(f"{at}: {key!r} is not a label name (a letter, then letters, digits or _)")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise LabelError(f"{at}: {key} is {value!r}, not a finite number")
            labels[key] = float(value)
        out[file] = labels
    return out


def merge_labels(file: str, sources: list[tuple[str, dict[str, float]]]) -> tuple[dict[str, float], dict[str, str]]:
    """Join the labels of one file given by several sources.

    Parameters
    ----------
    file : str
        The file (named in the error).
    sources : list of (str, dict)
        (source, labels) in order of precedence for the order of the names, e.g.
        ``[("file name", {...}), ("shots.csv", {...})]``.

    Returns
    -------
    labels : dict
        Name -> value.
    origin : dict
        Name -> the source(s) that gave it, joined by ``" and "`` when several agree.

    Raises
    ------
    LabelError
        Two sources give the same label different values.
    """
    labels: dict[str, float] = {}
    origin: dict[str, str] = {}
    for source, found in sources:
        for key, value in found.items():
            if key in labels:
                if labels[key] != value:
                    raise LabelError(f"{file}: label {key} is {labels[key]:g} by the {origin[key]} but {value:g} "
                                     f"by the {source}")
                origin[key] += f" and {source}"
            else:
                labels[key], origin[key] = value, source
    return labels, origin


def varying_labels(per_file: dict[str, dict[str, float]]) -> tuple[list[str], str | None]:
    """The labels that differ between files, and the counter among them.

    Parameters
    ----------
    per_file : dict
        File -> its labels.

    Returns
    -------
    varying : list of str
        Names with more than one value over the files (a file without the name counts as a value).
    counter : str or None
        The one varying name whose value differs in every file (a frame number:
        ``img_0001.png``, ``img_0002.png``), when it is the only varying name; else None.

    Examples
    --------
    >>> varying_labels({"img_1.png": {"img": 1.0}, "img_2.png": {"img": 2.0}})
    (['img'], 'img')
    >>> varying_labels({"a.png": {"V": 1.0, "w": 3.0}, "b.png": {"V": 2.0, "w": 3.0}, "c.png": {"V": 1.0, "w": 3.0}})
    (['V'], None)
    """
    names: list[str] = []
    for labels in per_file.values():
        names += [k for k in labels if k not in names]
    varying = []
    for key in names:
        values = [labels.get(key) for labels in per_file.values()]
        if len(set(values)) > 1:
            varying.append(key)
    counter = None
    if len(varying) == 1:
        values = [labels.get(varying[0]) for labels in per_file.values()]
        if None not in values and len(set(values)) == len(values):
            counter = varying[0]
    return varying, counter


def check_one_series(files, where) -> None:
    """Refuse to make one time series of files whose names carry different labels.

    Parameters
    ----------
    files : iterable of str
        The files of a recording whose delays come from a frame rate (their order).
    where : str or Path
        The folder, named in the error.

    Raises
    ------
    LabelError
        More than one label varies between the files, or the one that varies repeats a value (it
        groups the files: other settings, not a frame number). A frame number (``img_0001.png``,
        ``img_0002.png``: one label, another value in every file) is accepted.
    """
    per_file = {f: labels_from_name(f) for f in dict.fromkeys(files)}
    varying, counter = varying_labels(per_file)
    if not varying or counter is not None:
        return
    key = varying[0]
    first = next(iter(per_file))
    other = next(f for f in per_file if per_file[f].get(key) != per_file[first].get(key))
    raise LabelError(f"{where}: the file names carry different labels ({', '.join(varying[:4])}"
                     f"{', ...' if len(varying) > 4 else ''} differ, e.g. {first} and {other}): frames of other "
                     "settings are never blended into one time series; without a frame rate each image is measured "
                     "as an independent shot, or give each setting its own folder")
