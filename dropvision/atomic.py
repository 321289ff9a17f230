"""Atomic file and folder writes: after a failure there is either the complete result or none.

Files are written to a temporary name in the same folder, flushed, then renamed over the
target with `os.replace` (atomic on POSIX). A result folder is built in a temporary sibling
folder and renamed into place; an older folder of the same name is replaced only then.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
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


@contextlib.contextmanager
def atomic_dir(final) -> Iterator[Path]:
    """Build a folder in a temporary sibling and move it to ``final`` on success.

    Yields the temporary folder to write into. On an exception the temporary folder is
    removed and ``final`` is left as it was.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    try:
        yield tmp
        if final.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent))
            os.replace(final, old / "x")
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
