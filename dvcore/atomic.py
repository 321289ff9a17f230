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

Temporary names start with ``.dvtmp.`` and carry the writing process's id
(``.dvtmp.<name>.<pid>.<random>.tmp``), so that clean-up after a killed run removes exactly
what a dead run of ours left and nothing else (never a live run's temporaries).

Files and folders are created with the modes the user's umask gives (0644/0755 under umask
022), not the 0600/0700 of :mod:`tempfile`.

A folder being written is locked (:func:`output_lock`, an advisory ``fcntl.flock`` on
``.dvtmp.<name>.lock`` beside it, held for the run's life and released by the OS when the
process dies): a second run on the same output is refused at once.

A folder that must not be renamed (a mount point, the current working folder or a parent of
it) is never moved: the result is staged inside it and our files are moved into place one
by one (each atomically).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Callable, Iterable, Iterator

from dvcore import __version__, schema
from dvcore.errors import UsageError
from dvcore.jsonio import loads_strict

#: Marker file of every folder dropvision writes.
MARKER = schema.OUTPUT_MARKER.file
MARKER_SCHEMA = schema.OUTPUT_MARKER.schema
#: Prefix of every temporary file or folder we create (see `remove_leftovers`).
TMP_PREFIX = ".dvtmp."
_LEFTOVER = re.compile(r"^\.dvtmp\..+\.(tmp|old)$")
#: The owner's process id in a temporary name of ours (``.dvtmp.<name>.<pid>.<random>.tmp``).
_OWNER = re.compile(r"\.(\d+)\.[a-z0-9_]{8}\.(tmp|old)$")


class OutputError(UsageError):
    """An output location that would destroy something we did not write, that overlaps an
    input, or that another run writes: the user can fix it (another ``--out``, or
    ``--overwrite``). Exit status 2; its message names the folder (printed as it is)."""


def _tmp_prefix(name: str) -> str:
    return f"{TMP_PREFIX}{name[:80]}.{os.getpid()}."


_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process's umask (read without changing it where the kernel tells it)."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:  # pragma: no cover - kernels without Umask in /proc
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _mkdtemp(name: str, suffix: str, folder: Path) -> Path:
    """A temporary folder of ours in ``folder``, with the mode the umask gives."""
    tmp = tempfile.mkdtemp(prefix=_tmp_prefix(name), suffix=suffix, dir=folder)
    os.chmod(tmp, 0o777 & ~current_umask())
    return Path(tmp)


def _with_name(exc: OSError, path) -> OSError:
    """``exc`` naming ``path`` when it names no file (e.g. a full disk in a library's write)."""
    if exc.filename is not None:
        return exc
    named = OSError(exc.errno, exc.strerror or str(exc) or type(exc).__name__, str(path))
    named.__cause__ = exc
    return named


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (the file's mode follows the umask).

    Raises
    ------
    OSError
        Naming ``path`` (e.g. a full disk); nothing is left behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path.name), suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), 0o666 & ~current_umask())
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _with_name(exc, path) from None
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


def check_outside_inputs(inputs: Iterable, *outputs) -> None:
    """Refuse any of ``outputs`` (paths; None: not written) that equals, lies inside or contains
    one of ``inputs`` (files or folders; links resolved), whatever ``--overwrite`` says: the one
    check every command runs, before any work, on each output it will write (a model file, a
    report or dataset folder, a Rerun recording). Writing a model over ``DATASET/summary.parquet``
    would destroy the data; a file added inside a sequence folder changes its input hash and
    with it a campaign's resume.

    Raises
    ------
    OutputError
        One line naming the output and the input (:func:`check_not_input`).
    """
    inputs = [p for p in inputs if p is not None]
    for out in outputs:
        if out is not None:
            check_not_input(out, inputs)


def _read_marker(folder: Path) -> dict | None:
    try:
        doc = loads_strict((folder / MARKER).read_text(encoding="utf-8"))
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
        files) or "merge" (it holds files we did not write and ``overwrite`` allows writing
        ours into it: nothing else there is touched).

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
    if overwrite == "marked" and _read_marker(final) is None:
        raise OutputError(
            f"{final}: exists and was not written by dropvision ({_describe(foreign)}); --overwrite "
            "replaces only dropvision's own outputs: choose a new folder")
    if not overwrite:
        raise _refusal(final, foreign)
    return "merge"


# ----------------------------------------------------------------------------- the output lock
class _Held:
    def __init__(self, fd: int, path: Path | None, created: list[Path]):
        self.fd, self.path, self.created, self.count, self.pid = fd, path, created, 1, os.getpid()


_HELD: dict[str, _Held] = {}
_HELD_LOCK = threading.Lock()


def _cwd() -> Path | None:
    try:
        return Path(os.getcwd()).resolve()
    except OSError:  # the working folder was deleted
        return None


def _fixed_in_place(final: Path) -> str | None:
    """Why the existing folder ``final`` can never be renamed, whoever asks (a mount point, a
    folder in a folder we may not write), else None. Such a folder carries its lock itself."""
    try:
        if not final.is_dir() or final.is_symlink():
            return None
        here = final.absolute()
        if os.path.ismount(here) or os.stat(here).st_dev != os.stat(here.parent).st_dev:
            return "a mount point"
        if not os.access(here.parent, os.W_OK):
            return "in a folder we may not write"
    except OSError:
        return None
    return None


def _must_stay(final: Path) -> str | None:
    """Why the existing folder ``final`` may not be renamed now (`_fixed_in_place`, or it is
    the working folder or a parent of it), else None."""
    fixed = _fixed_in_place(final)
    if fixed is not None or not final.is_dir():
        return fixed
    cwd = _cwd()
    real = _resolved(final)
    if cwd is not None and (cwd == real or real in cwd.parents):
        return "the current folder or a parent of it"
    return None


def _lock_file(final: Path) -> Path:
    return final.absolute().parent / f"{TMP_PREFIX}{final.name[:80]}.lock"


def _busy(final: Path, fd: int) -> OutputError:
    with contextlib.suppress(OSError, ValueError):
        pid = int(os.pread(fd, 32, 0).split()[0])
        return OutputError(f"{final}: another dropvision run (process {pid}) is writing this output "
                           "folder; wait for it to end, or choose another output")
    return OutputError(f"{final}: another dropvision run is writing this output folder; wait for it "
                       "to end, or choose another output")


def _acquire(final: Path) -> _Held:
    """Lock ``final`` for this process (see `output_lock`)."""
    if _fixed_in_place(final) is not None:
        # never renamed by anyone: the folder itself carries the lock
        fd = os.open(final, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _busy(final, -1) from None
        return _Held(fd, None, [])
    created = []
    for parent in reversed(final.absolute().parents):
        if not parent.exists():
            try:
                parent.mkdir()
            except FileExistsError:
                continue
            created.append(parent)
    path = _lock_file(final)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            _remove_created(created)
            raise OutputError(f"{final}: cannot write in {path.parent} ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            err = _busy(final, fd)
            os.close(fd)
            raise err from None
        st = os.fstat(fd)
        try:
            now = os.stat(path)
        except FileNotFoundError:
            now = None
        if now is not None and (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino):
            break
        os.close(fd)  # its holder removed it as we opened it: take the new one
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    return _Held(fd, path, created)


def _remove_created(created: list[Path]) -> None:
    for folder in reversed(created):  # parents made for the lock, still empty: the run left nothing
        try:
            folder.rmdir()
        except OSError:
            break


@contextlib.contextmanager
def output_lock(final) -> Iterator[None]:
    """Hold the output folder ``final`` for the life of a run: a second run (another process)
    asking for it is refused at once with :class:`OutputError` naming the folder.

    The lock is an advisory ``fcntl.flock`` on ``.dvtmp.<name>.lock`` beside the folder (on
    the folder itself when it must never be renamed: a mount point, the working folder), held
    open for the run and released by the operating system if the process dies; the lock file
    is removed when the run ends. Re-entrant within a process (`atomic_dir` takes it too).
    Parent folders are created; those created for nothing are removed again.
    """
    final = Path(final)
    key = str(_resolved(final))
    with _HELD_LOCK:
        held = _HELD.get(key)
        if held is not None and held.pid == os.getpid():
            held.count += 1
        else:
            held = _HELD[key] = _acquire(final)
    try:
        yield
    finally:
        with _HELD_LOCK:
            held.count -= 1
            if held.count == 0:
                del _HELD[key]
                if held.path is not None:
                    with contextlib.suppress(OSError):
                        os.unlink(held.path)
                os.close(held.fd)
                _remove_created(held.created)


# ----------------------------------------------------------------------------- atomic folders
def _move_error(final: Path, exc: OSError) -> OutputError:
    return OutputError(f"{final}: cannot move the result into place ({exc.strerror or exc}); "
                       "the folder was left as it was")


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
    overwrite : bool or "marked"
        True: allow writing into an existing folder that holds files we did not write; our
        files are then moved into it one by one, files of our earlier result that this one
        does not rewrite are removed, and nothing else there is touched. "marked": the same,
        but only in a folder that carries our marker (a folder we never wrote is refused).
    kind : str
        What the folder holds (recorded in its marker).

    Yields the temporary folder to write into. On an exception the temporary folder is
    removed and ``final`` is left as it was. ``final`` is locked (`output_lock`) meanwhile.
    A folder that may not be renamed (a mount point, the working folder or a parent of it) is
    staged inside itself and our files are moved into it one by one; a rename the file system
    refuses (a busy or cross-device folder) falls back to the same.

    Raises
    ------
    OutputError
        ``final`` overlaps an input, is a file, holds files we did not write (without
        ``overwrite``), or another run writes it. Raised before anything is written.
    OSError
        Naming ``final`` when the body's writes fail without naming a file (a full disk).
    """
    final = Path(final)
    mode = check_output_dir(final, inputs=inputs, overwrite=overwrite)
    with output_lock(final):
        inside = _must_stay(final) is not None
        tmp = _mkdtemp(final.name, ".tmp", final if inside else final.parent)
        try:
            yield tmp
            written = _files_below(tmp)
            if mode == "merge" or inside:
                _merge_into(final, tmp, written, kind)
            else:
                _write_marker(tmp, written, kind)
                _swap(final, tmp, written, kind)
        except BaseException as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(exc, OSError) and exc.filename is None:
                raise _with_name(exc, final) from None
            raise


def _swap(final: Path, tmp: Path, written: list[str], kind: str) -> None:
    """Rename the complete ``tmp`` to ``final``, the previous ``final`` moved aside first and
    removed after (put back when the second rename fails)."""
    if not final.exists():
        try:
            os.replace(tmp, final)
        except OSError as exc:
            raise _move_error(final, exc) from None
        return
    old = _mkdtemp(final.name, ".old", final.parent)
    try:
        os.replace(final, old / "x")
    except OSError as exc:
        os.rmdir(old)
        if exc.errno in (errno.EXDEV, errno.EBUSY):  # a mount point, a bind mount: never moved
            _merge_into(final, tmp, written, kind)
            return
        raise _move_error(final, exc) from None
    try:
        os.replace(tmp, final)
    except OSError as exc:
        os.replace(old / "x", final)  # the previous result back in place
        os.rmdir(old)
        raise _move_error(final, exc) from None
    shutil.rmtree(old, ignore_errors=True)


def _merge_into(final: Path, tmp: Path, written: list[str], kind: str) -> None:
    """Move the entries of ``tmp`` into the existing folder ``final`` (``overwrite``, or a
    folder that may not be renamed): an entry replaces one of ours of the same name; a
    same-named folder holding files we did not write, or holding the working folder, is
    refused before anything moves."""
    previous = _read_marker(final) or {}
    staged = tmp.name + "/"
    foreign = [f for f in foreign_files(final) if not f.startswith(staged)]
    entries = sorted(os.listdir(tmp))
    cwd = _cwd()
    for entry in entries:
        target = final / entry
        if target.is_dir() and not target.is_symlink():
            clash = [f for f in foreign if f.startswith(entry + "/")]
            if clash or not (tmp / entry).is_dir():
                raise OutputError(f"{target}: a folder of that name holds files dropvision did not "
                                  f"write ({_describe(clash or [entry])}); choose a new output folder")
            real = _resolved(target)
            if cwd is not None and (cwd == real or real in cwd.parents):
                raise OutputError(f"{target}: is the current folder (or holds it) and would be replaced; "
                                  "change to another folder first")
    for entry in entries:
        target = final / entry
        try:
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            os.replace(tmp / entry, target)
        except OSError as exc:
            raise _move_error(final, exc) if entry == entries[0] else _with_name(exc, target) from None
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
    Callers writing it for a whole run hold `output_lock` on it.

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
    """Check that writing the file ``path`` destroys nothing: it may not be an input, lie inside
    an input folder, nor be a folder, and an existing file is replaced only when ``is_ours(path)`` (one of our own
    earlier results) or ``overwrite``.

    Raises
    ------
    OutputError
    """
    path = Path(path)
    check_not_input(path, inputs)  # not an input, nor inside an input folder (a dataset's own files)
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


def check_side_file(path, *, replaced: Iterable = (), inputs: Iterable = (), what: str = "the recording") -> None:
    """Refuse, before any work, a file written while a run goes on (a Rerun recording) inside an
    input folder (dropvision never writes into its inputs) or inside an output folder that the
    run replaces as a whole at its end (the file would be lost, or make the folder foreign).

    Raises
    ------
    OutputError
        Naming the file and the folder.
    """
    if path is None:
        return
    real = _resolved(path)
    for folder in inputs:
        if folder is not None and _resolved(folder) in real.parents:
            raise OutputError(f"{path}: {what} would be written inside the input folder {folder}; dropvision "
                              "never writes into its inputs: choose a place outside it")
    for folder in replaced:
        if folder is not None and _resolved(folder) in real.parents:
            raise OutputError(f"{path}: {what} would be written inside the output folder {folder}, which is "
                              "replaced as a whole when the result is written: choose a place outside it "
                              f"(e.g. {Path(folder).parent / Path(path).name})")


def _owner_alive(name: str) -> bool:
    """True when the temporary ``name`` carries the id of a live process (its writer, or one
    that reuses its id: left alone either way). Names without one (older versions) are dead."""
    m = _OWNER.search(name)
    if m is None:
        return False
    pid = int(m.group(1))
    if pid == os.getpid():
        return True  # another thread of this run may be writing it
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, another user's
        return True
    return True


def remove_leftovers(folder) -> None:
    """Remove what a killed run of ours left in ``folder``: temporary files and folders of
    interrupted atomic writes (named ``.dvtmp.<name>.<pid>.<random>.tmp`` / ``.old``) whose
    writing process is dead. Nothing else is touched: not the user's files, not a live run's
    temporaries."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    for p in folder.iterdir():
        if _LEFTOVER.match(p.name) and not _owner_alive(p.name):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
