"""Atomic, non-destructive writes: after a failure there is either the complete result or none,
and nothing that dropvision did not write is ever deleted or replaced without being asked.

Files are written to a temporary name in the same folder, flushed, then renamed over the
target with `os.replace` (atomic on POSIX). A result folder is built in a temporary sibling
folder and renamed into place.

Ownership
---------
Every folder we write carries a marker file, ``.dropvision-output.json``, listing the files we
put there. An existing output location is only ever replaced when it is provably ours:

- a folder that does not exist, or is empty, is written;
- a folder whose marker lists every file in it is ours: it is replaced atomically;
- any other existing folder (the user's files, files added to our output later, an output of
  an older version without a marker) is refused with :class:`OutputError`, unless
  ``overwrite=True``: then our files are written *into* it one by one (each atomically) and
  nothing else there is touched;
- an existing file where a folder should go is always refused;
- an output location equal to, inside, or a parent of any input is always refused.

Temporary names start with ``.dvtmp.`` so that clean-up after a killed run can recognise
exactly what we left and nothing else.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Iterator

from dvcore import __version__, schema

#: Marker file of every folder dropvision writes.
MARKER = schema.OUTPUT_MARKER.file
MARKER_SCHEMA = schema.OUTPUT_MARKER.schema
#: Prefix of every temporary file or folder we create (see `remove_leftovers`).
TMP_PREFIX = ".dvtmp."
_LEFTOVER = re.compile(r"^\.dvtmp\..+\.(tmp|old)$")


class OutputError(Exception):
    """An output location that would destroy something we did not write, or that overlaps an
    input: the user can fix it (another ``--out``, or ``--overwrite``). Exit status 2."""


def _tmp_prefix(name: str) -> str:
    return f"{TMP_PREFIX}{name[:80]}."


def _umask() -> int:
    """The process's umask (read by setting it and back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path.name), suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600: the result follows the user's umask
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path
def write_text(path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return write_bytes(path, text.encode("utf-8"))


def _json_default(obj):
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def to_json(obj, *, indent: int | None = 2) -> str:
    """JSON text with numpy scalars/arrays and paths converted; NaN written as null."""

    def clean(x):
        if isinstance(x, float) and x != x:
            return None
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        try:
            import numpy as np

            if isinstance(x, np.floating) and np.isnan(x):
                return None
        except ImportError:  # pragma: no cover
            pass
        return x

    return json.dumps(clean(obj), indent=indent, default=_json_default, allow_nan=False) + "\n"


def write_json(path, obj) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (NaN becomes null)."""
    return write_text(path, to_json(obj))


# ----------------------------------------------------------------------------- ownership
def _resolved(p) -> Path:
    return Path(os.path.abspath(Path(p).expanduser())).resolve()


def check_not_input(out, inputs: Iterable = ()) -> None:
    """Refuse an output location equal to, inside, or a parent of any input path."""
    out_r = _resolved(out)
    for inp in inputs:
        if inp is None:
            continue
        in_r = _resolved(inp)
        if out_r == in_r:
            raise OutputError(f"{out}: the output would replace the input {inp}; choose another output")
        if in_r in out_r.parents:
            raise OutputError(f"{out}: the output lies inside the input {inp}; choose a folder outside it")
        if out_r in in_r.parents:
            raise OutputError(f"{out}: the output folder contains the input {inp}; choose a folder outside it")


def _read_marker(folder: Path) -> dict | None:
    try:
        doc = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(doc, dict) or doc.get("schema") != MARKER_SCHEMA:
        return None
    files = doc.get("files")
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return None
    return doc


def _files_below(folder: Path) -> list[str]:
    """Relative paths of everything below ``folder`` that is not a folder (links included)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        rel = Path(dirpath).relative_to(folder)
        for name in filenames:
            out.append((rel / name).as_posix())
        for name in dirnames:  # links to folders are not walked: they count as entries
            if (Path(dirpath) / name).is_symlink():
                out.append((rel / name).as_posix())
    return sorted(out)


def foreign_files(folder) -> list[str]:
    """Files below an existing ``folder`` that our marker does not list (all, without one)."""
    folder = Path(folder)
    doc = _read_marker(folder)
    listed = set(doc.get("files") or []) if doc else set()
    return [f for f in _files_below(folder) if f != MARKER and f not in listed]


def _describe(files: list[str]) -> str:
    shown = ", ".join(files[:3])
    return shown + (f" and {len(files) - 3} more" if len(files) > 3 else "")


def _refusal(final: Path, foreign: list[str]) -> OutputError:
    return OutputError(
        f"{final}: exists and holds files dropvision did not write ({_describe(foreign)}); "
        "choose a new output folder, or pass --overwrite to write our files into it "
        "(nothing else there is touched)")


def _write_marker(folder: Path, files: Iterable[str], kind: str) -> None:
    write_text(folder / MARKER, json.dumps(
        {"schema": MARKER_SCHEMA, "kind": kind, "written_by": f"dropvision {__version__}",
         "files": sorted(set(files))}, indent=1) + "\n")


def _check_folder_target(final: Path) -> None:
    if final.is_symlink():
        raise OutputError(f"{final}: is a link; give the folder it points to, or another output")
    if final.exists() and not final.is_dir():
        raise OutputError(f"{final}: exists and is not a folder; choose another output")
    for parent in final.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{final}: {parent} is a file, not a folder")
            break


def check_output_dir(final, *, inputs: Iterable = (), overwrite: bool | str = False) -> str:
    """Check, before any work, that `atomic_dir` may write the folder ``final``.

    Returns
    -------
    str
        "new" (nothing there, or an empty folder), "ours" (replace it: it holds only our
        files), "merge" (it holds files we did not write and ``overwrite`` is True: our files
        are written into it and nothing else is touched) or "replace" (``overwrite`` is
        "replace": the user asked for the whole folder to be replaced).

    Raises
    ------
    OutputError
        See `atomic_dir`.
    """
    final = Path(final)
    check_not_input(final, inputs)
    _check_folder_target(final)
    if not final.is_dir() or not any(final.iterdir()):
        return "new"
    foreign = foreign_files(final)
    if not foreign:
        return "ours"
    if not overwrite:
        raise _refusal(final, foreign)
    return "replace" if overwrite == "replace" else "merge"


@contextlib.contextmanager
def atomic_dir(final, *, inputs: Iterable = (), overwrite: bool | str = False,
               kind: str = "output") -> Iterator[Path]:
    """Build a folder in a temporary sibling and move it to ``final`` on success.

    Parameters
    ----------
    final : path
        The output folder.
    inputs : iterable of paths
        What the result is computed from: ``final`` may be none of them, nor lie inside or
        contain one.
    overwrite : bool or "replace"
        True: allow writing into an existing folder that holds files we did not write; our
        files are then moved into it one by one, files of our earlier result that this one
        does not rewrite are removed, and nothing else there is touched. "replace": the user
        explicitly asked for such a folder to be replaced as a whole.
    kind : str
        What the folder holds (recorded in its marker).

    Yields the temporary folder to write into. On an exception the temporary folder is
    removed and ``final`` is left as it was.

    Raises
    ------
    OutputError
        ``final`` overlaps an input, is a file, or holds files we did not write (without
        ``overwrite``). Raised before anything is written.
    """
    final = Path(final)
    mode = check_output_dir(final, inputs=inputs, overwrite=overwrite)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=_tmp_prefix(final.name), suffix=".tmp", dir=final.parent))
    try:
        yield tmp
        written = _files_below(tmp)
        if mode == "merge":
            _merge_into(final, tmp, written, kind)
        else:
            _write_marker(tmp, written, kind)
            if final.exists():
                old = Path(tempfile.mkdtemp(prefix=_tmp_prefix(final.name), suffix=".old", dir=final.parent))
                os.replace(final, old / "x")
                os.replace(tmp, final)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _merge_into(final: Path, tmp: Path, written: list[str], kind: str) -> None:
    """Move the entries of ``tmp`` into the existing folder ``final`` (``overwrite``): an entry
    replaces one of ours of the same name; a same-named folder holding files we did not write
    is refused before anything moves."""
    previous = _read_marker(final) or {}
    foreign = foreign_files(final)
    entries = sorted(os.listdir(tmp))
    for entry in entries:
        target = final / entry
        if target.is_dir() and not target.is_symlink():
            clash = [f for f in foreign if f.startswith(entry + "/")]
            if clash or not (tmp / entry).is_dir():
                raise OutputError(f"{target}: a folder of that name holds files dropvision did not "
                                  f"write ({_describe(clash or [entry])}); choose a new output folder")
    for entry in entries:
        target = final / entry
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        os.replace(tmp / entry, target)
    root = _resolved(final)
    for stale in set(previous.get("files") or []) - set(written):  # ours, not rewritten this time
        path = final / stale
        if root in _resolved(path).parents and not path.is_dir():
            with contextlib.suppress(OSError):
                path.unlink()
    _write_marker(final, written, kind)
    shutil.rmtree(tmp, ignore_errors=True)


def claim_dir(folder, *, inputs: Iterable = (), overwrite: bool = False, kind: str = "output",
              is_ours: Callable[[Path], bool] | None = None) -> Path:
    """Make ``folder`` a folder we write files into one at a time (a campaign dataset, the
    demo's output): create it, or accept it when it is new, empty, or carries our marker
    (or ``is_ours(folder)`` says so, for outputs of older versions).

    Such a folder is never replaced as a whole: we only ever write our own named files into
    it, each atomically, and clean up only our own temporary names, so files a user adds later
    are safe. The marker written here lists no files (so `atomic_dir` never replaces it).

    Raises
    ------
    OutputError
        ``folder`` overlaps an input, is a file, or is a non-empty folder that is not ours
        (without ``overwrite``).
    """
    folder = Path(folder)
    check_not_input(folder, inputs)
    _check_folder_target(folder)
    if folder.is_dir() and _read_marker(folder) is None:
        entries = [p.name for p in folder.iterdir()]
        if entries and not overwrite and not (is_ours is not None and is_ours(folder)):
            raise _refusal(folder, sorted(entries))
    folder.mkdir(parents=True, exist_ok=True)
    if _read_marker(folder) is None:
        _write_marker(folder, [], kind)
    return folder


def check_output_file(path, *, inputs: Iterable = (), overwrite: bool = False,
                      is_ours: Callable[[Path], bool] | None = None) -> Path:
    """Check that writing the file ``path`` destroys nothing: it may not be an input, nor a
    folder, and an existing file is replaced only when ``is_ours(path)`` (one of our own
    earlier results) or ``overwrite``.

    Raises
    ------
    OutputError
    """
    path = Path(path)
    out_r = _resolved(path)
    for inp in inputs:
        if inp is not None and _resolved(inp) == out_r:
            raise OutputError(f"{path}: the output would replace the input {inp}; choose another output")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{path}: {parent} is a file, not a folder")
            break
    if path.exists() and not overwrite and not (is_ours is not None and is_ours(path)):
        raise OutputError(f"{path}: exists and was not written by dropvision; choose another name, "
                          "or pass --overwrite to replace it")
    return path


def remove_leftovers(folder) -> None:
    """Remove what a killed run of ours left in ``folder``: temporary files and folders of
    interrupted atomic writes (named ``.dvtmp.<name>.<random>.tmp`` / ``.old``). Nothing else
    is touched."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    for p in folder.iterdir():
        if _LEFTOVER.match(p.name):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
